/// @file ShellGrids.cpp
#include <frostvdb/shell/ShellGrids.h>

#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <openvdb/tree/LeafManager.h>

#include <algorithm>

namespace frostvdb::shell {

openvdb::FloatGrid::Ptr toGrid(const ShellBand& band, const std::vector<float>& values, float background,
                               const std::string& name)
{
    auto grid = openvdb::FloatGrid::create(background);
    grid->setTransform(band.transform()->copy());
    grid->setName(name);
    grid->tree().topologyUnion(band.mask().tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(grid->tree());
    const openvdb::Int32Tree& index = band.indexGrid().tree();
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType& leaf, size_t) {
        const auto* il = index.probeConstLeaf(leaf.origin()); // same topology, same leaves
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const int32_t i = il ? il->getValue(it.pos()) : -1;
            it.setValue(i >= 0 ? values[size_t(i)] : background);
        }
    });
    return grid;
}

void fromGrid(const ShellBand& band, const openvdb::FloatGrid& grid, std::vector<float>& values, bool materialise)
{
    if (materialise && !band.whole()) {
        std::vector<openvdb::Coord> origins;
        const float bg = grid.background();
        for (auto it = grid.cbeginValueOn(); it; ++it) {
            if (*it == bg) continue;
            if (it.isVoxelValue()) {
                const openvdb::Coord o = leafOrigin(it.getCoord());
                if (origins.empty() || origins.back() != o) origins.push_back(o);
            }
            else band.materialiseBox(it.getBoundingBox()); // a tile: every leaf in it
        }
        band.materialise(std::move(origins));
    }
    values.resize(band.size());
    openvdb::tree::LeafManager<const openvdb::Int32Tree> leaves(band.indexGrid().tree());
    leaves.foreach([&](const openvdb::Int32Tree::LeafNodeType& il, size_t) {
        const auto* fl = grid.tree().probeConstLeaf(il.origin());
        auto acc = grid.getConstAccessor();
        for (auto it = il.cbeginValueOn(); it; ++it)
            values[size_t(*it)] = fl ? fl->getValue(it.pos()) : acc.getValue(it.getCoord());
    });
}

openvdb::FloatGrid::Ptr frostFog(const ShellBand& band, const std::vector<float>& p, const std::vector<float>& growth)
{
    std::vector<float> fog(band.size(), 0.f);
    auto ramp = [](double v) { return std::clamp(v, 0.0, 1.0); };
    for (size_t i = 0; i < band.size(); ++i) {
        if (band.lateralOffset(i) > 0.5f) continue; // beyond an open mesh's border
        const double s = band.normalOffset(i);
        // max with p: a seed's voxels start as ice and never grow, yet carry the full layer
        // (elsewhere growth >= p, since p started at 0)
        const double th = band.frostThickness() * std::min(1.0, double(std::max({0.f, growth[i], p[i]})));
        fog[i] = float(ramp(p[i]) * ramp(s + 0.5) * ramp(th - s + 0.5));
    }
    auto grid = toGrid(band, fog, 0.f, "ice");
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(grid->tree());
    leaves.foreach([](openvdb::FloatTree::LeafNodeType& leaf, size_t) {
        for (openvdb::Index n = 0; n < openvdb::FloatTree::LeafNodeType::SIZE; ++n)
            if (leaf.isValueOn(n) && leaf.getValue(n) <= 0.f) leaf.setValueOff(n, 0.f);
    });
    openvdb::tools::pruneInactive(grid->tree());
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    return grid;
}

void frostMesh(const openvdb::FloatGrid& fog, std::vector<openvdb::Vec3s>& points,
               std::vector<openvdb::Vec3I>& triangles, std::vector<openvdb::Vec4I>& quads)
{
    points.clear();
    triangles.clear();
    quads.clear();
    if (fog.activeVoxelCount() == 0) return;
    openvdb::tools::volumeToMesh(fog, points, triangles, quads, 0.5, 0.0);
}

openvdb::FloatGrid::Ptr frostLevelSet(const openvdb::FloatGrid& fog)
{
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec4I> quads;
    frostMesh(fog, points, triangles, quads);
    openvdb::FloatGrid::Ptr sdf;
    if (points.empty()) {
        sdf = openvdb::FloatGrid::create(float(3.0 * fog.voxelSize()[0]));
        sdf->setTransform(fog.transform().copy());
    } else {
        // volumeToMesh's winding faces into the fog (its inside has values above the iso value)
        sdf = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(fog.transform(), points, triangles, quads, 3.0f);
    }
    sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    sdf->setName("ice_sdf");
    return sdf;
}

} // namespace frostvdb::shell
