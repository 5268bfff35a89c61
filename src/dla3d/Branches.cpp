/// @file Branches.cpp
#include <frostvdb/core/FieldKeys.h>
#include <frostvdb/dla3d/Branches.h>

#include <openvdb/points/PointConversion.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/PointIndexGrid.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tools/SignedFloodFill.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>

namespace frostvdb::dla3d {

using openvdb::Vec3d;

std::vector<float> branchRadii(const std::vector<int32_t>& parents, const BranchStyle& style)
{
    std::vector<double> carried(parents.size(), 1.0);
    for (size_t i = parents.size(); i-- > 0;)
        if (parents[i] >= 0) carried[size_t(parents[i])] += carried[i];
    std::vector<float> r(parents.size());
    for (size_t i = 0; i < parents.size(); ++i)
        r[i] = float(style.tipRadius * std::min(style.maxScale, std::pow(carried[i], style.taper)));
    return r;
}

openvdb::points::PointDataGrid::Ptr makePointGrid(const std::vector<Vec3d>& positions, const std::vector<float>& radii,
                                                  const std::vector<int32_t>& parents,
                                                  const std::vector<int32_t>& generations,
                                                  const std::vector<float>& attachTimes, double voxelSize)
{
    using namespace openvdb::points;
    auto xform = openvdb::math::Transform::createLinearTransform(voxelSize);
    std::vector<openvdb::Vec3R> pos(positions.begin(), positions.end());
    PointAttributeVector<openvdb::Vec3R> wrapper(pos);
    auto index = openvdb::tools::createPointIndexGrid<openvdb::tools::PointIndexGrid>(wrapper, *xform);
    auto grid = createPointDataGrid<NullCodec, PointDataGrid>(*index, wrapper, *xform);
    auto& tree = grid->tree();
    appendAttribute<float>(tree, "radius");
    populateAttribute(tree, index->tree(), "radius", PointAttributeVector<float>(radii));
    appendAttribute<int32_t>(tree, "parent");
    populateAttribute(tree, index->tree(), "parent", PointAttributeVector<int32_t>(parents));
    appendAttribute<int32_t>(tree, "generation");
    populateAttribute(tree, index->tree(), "generation", PointAttributeVector<int32_t>(generations));
    appendAttribute<float>(tree, "attach_time");
    populateAttribute(tree, index->tree(), "attach_time", PointAttributeVector<float>(attachTimes));
    // the particle's own index, so tools can rebuild the parent links after any reordering
    std::vector<int32_t> ids(positions.size());
    for (size_t i = 0; i < ids.size(); ++i) ids[i] = int32_t(i);
    appendAttribute<int32_t>(tree, "id");
    populateAttribute(tree, index->tree(), "id", PointAttributeVector<int32_t>(ids));
    grid->setName(out::kPoints.name);
    return grid;
}

namespace {

/// Capsule i of the branches: from its parent's centre a (its own when it has none) to its
/// centre b, radii of at least half a voxel, and how far beyond the segment the level set
/// reaches (the larger radius plus the background width). Shared by the raster and the two
/// counts that must see its boxes.
struct Capsule {
    Vec3d a, b;
    double ra, rb, reach;
};
Capsule capsuleOf(size_t i, const std::vector<Vec3d>& pos, const std::vector<int32_t>& parents,
                  const std::vector<float>& radii, double dx, double background)
{
    Capsule c;
    c.b = pos[i];
    c.rb = std::max<double>(radii[i], 0.5 * dx);
    c.a = parents[i] >= 0 ? pos[size_t(parents[i])] : c.b;
    c.ra = parents[i] >= 0 ? std::max<double>(radii[size_t(parents[i])], 0.5 * dx) : c.rb;
    c.reach = std::max(c.ra, c.rb) + background;
    return c;
}

/// Rasterises a range of capsules into its own tree; joined by a voxel-wise minimum.
struct CapsuleRaster {
    const std::vector<Vec3d>& pos;
    const std::vector<int32_t>& parents;
    const std::vector<float>& radii;
    const openvdb::math::Transform& xform;
    float background;
    /// held by pointer, so the grid takes the tree itself (a copy doubled the rasterisation's peak)
    openvdb::FloatTree::Ptr tree;

    CapsuleRaster(const std::vector<Vec3d>& p, const std::vector<int32_t>& par, const std::vector<float>& r,
                  const openvdb::math::Transform& x, float bg)
        : pos(p), parents(par), radii(r), xform(x), background(bg), tree(std::make_shared<openvdb::FloatTree>(bg)) {}
    CapsuleRaster(CapsuleRaster& o, tbb::split)
        : pos(o.pos), parents(o.parents), radii(o.radii), xform(o.xform), background(o.background),
          tree(std::make_shared<openvdb::FloatTree>(o.background)) {}

    void operator()(const tbb::blocked_range<size_t>& range)
    {
        openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(*tree);
        const double dx = xform.voxelSize()[0];
        for (size_t i = range.begin(); i != range.end(); ++i) {
            const auto [a, b, ra, rb, reach] = capsuleOf(i, pos, parents, radii, dx, background);
            const Vec3d lo = xform.worldToIndex(openvdb::math::minComponent(a, b) - Vec3d(reach));
            const Vec3d hi = xform.worldToIndex(openvdb::math::maxComponent(a, b) + Vec3d(reach));
            const Vec3d ab = b - a;
            const double len2 = ab.lengthSqr();
            openvdb::Coord c;
            for (c.x() = int(std::floor(lo.x())); c.x() <= int(std::ceil(hi.x())); ++c.x())
                for (c.y() = int(std::floor(lo.y())); c.y() <= int(std::ceil(hi.y())); ++c.y())
                    for (c.z() = int(std::floor(lo.z())); c.z() <= int(std::ceil(hi.z())); ++c.z()) {
                        const Vec3d x = xform.indexToWorld(c);
                        const double t = len2 > 0 ? std::clamp((x - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
                        const double d = (x - (a + ab * t)).length() - (ra + (rb - ra) * t);
                        if (d >= background) continue;
                        const float v = float(std::max(d, -double(background)));
                        if (v < acc.getValue(c)) acc.setValueOn(c, v);
                    }
        }
    }
    void join(CapsuleRaster& o)
    {
        openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(*tree);
        for (auto it = o.tree->cbeginValueOn(); it; ++it)
            if (*it < acc.getValue(it.getCoord())) acc.setValueOn(it.getCoord(), *it);
    }
};

} // namespace

openvdb::FloatGrid::Ptr rasterizeBranches(const std::vector<Vec3d>& positions, const std::vector<int32_t>& parents,
                                          const std::vector<float>& radii, double voxelSize, double halfWidth,
                                          const std::function<void(size_t, size_t)>& progress)
{
    auto xform = openvdb::math::Transform::createLinearTransform(voxelSize);
    const float bg = float(halfWidth * voxelSize);
    CapsuleRaster body(positions, parents, radii, *xform, bg);
    if (!progress) {
        tbb::parallel_reduce(tbb::blocked_range<size_t>(0, positions.size(), 64), body);
    } else { // chunks, each reduced into the same body: the voxel-wise minimum is order-independent
        const size_t n = positions.size(), chunk = std::max<size_t>(64, n / 100);
        for (size_t b = 0; b < n; b += chunk) {
            tbb::parallel_reduce(tbb::blocked_range<size_t>(b, std::min(n, b + chunk), 64), body);
            progress(std::min(n, b + chunk), n);
        }
    }
    auto grid = openvdb::FloatGrid::create(bg);
    grid->setTransform(xform);
    grid->setTree(body.tree);
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
    openvdb::tools::signedFloodFill(grid->tree());
    openvdb::tools::pruneLevelSet(grid->tree());
    grid->setName(out::kIceSdf.name);
    return grid;
}

double branchVoxelVisits(const std::vector<Vec3d>& pos, const std::vector<int32_t>& parents,
                         const std::vector<float>& radii, double voxelSize, double halfWidth)
{
    // the same boxes as CapsuleRaster::operator(), in double (a box may pass int's range)
    const double dx = voxelSize, background = float(halfWidth * voxelSize);
    double visits = 0;
    for (size_t i = 0; i < pos.size(); ++i) {
        const auto [a, b, ra, rb, reach] = capsuleOf(i, pos, parents, radii, dx, background);
        const Vec3d lo = (openvdb::math::minComponent(a, b) - Vec3d(reach)) / dx;
        const Vec3d hi = (openvdb::math::maxComponent(a, b) + Vec3d(reach)) / dx;
        double box = 1;
        for (int k = 0; k < 3; ++k) box *= std::max(0.0, std::ceil(hi[k]) - std::floor(lo[k]) + 1.0);
        visits += box;
    }
    return visits;
}

namespace {

/// Marks the leaves a range of capsules reaches (CapsuleRaster's boxes, at 4^3-block resolution).
struct LeafReach {
    const std::vector<Vec3d>& pos;
    const std::vector<int32_t>& parents;
    const std::vector<float>& radii;
    double dx, background;
    openvdb::MaskTree leaves;

    LeafReach(const std::vector<Vec3d>& p, const std::vector<int32_t>& par, const std::vector<float>& r, double d,
              double bg)
        : pos(p), parents(par), radii(r), dx(d), background(bg) {}
    LeafReach(LeafReach& o, tbb::split)
        : pos(o.pos), parents(o.parents), radii(o.radii), dx(o.dx), background(o.background) {}

    void operator()(const tbb::blocked_range<size_t>& range)
    {
        openvdb::tree::ValueAccessor<openvdb::MaskTree> acc(leaves);
        // a 4^3 block's voxel centres lie within 1.5 voxels of its centre on each axis
        const double blockReach = std::sqrt(3.0) * 1.5 * dx;
        for (size_t i = range.begin(); i != range.end(); ++i) {
            const auto [a, b, ra, rb, reach] = capsuleOf(i, pos, parents, radii, dx, background);
            const Vec3d lo = (openvdb::math::minComponent(a, b) - Vec3d(reach)) / dx;
            const Vec3d hi = (openvdb::math::maxComponent(a, b) + Vec3d(reach)) / dx;
            const Vec3d ab = b - a;
            const double len2 = ab.lengthSqr();
            // the raster's distance changes by at most this much per metre (its radius varies along t)
            const double lipschitz = 1.0 + (len2 > 0 ? std::fabs(rb - ra) / std::sqrt(len2) : 0.0);
            openvdb::Coord c;
            for (c.x() = int(std::floor(lo.x())) & ~3; c.x() <= int(std::ceil(hi.x())); c.x() += 4)
                for (c.y() = int(std::floor(lo.y())) & ~3; c.y() <= int(std::ceil(hi.y())); c.y() += 4)
                    for (c.z() = int(std::floor(lo.z())) & ~3; c.z() <= int(std::ceil(hi.z())); c.z() += 4) {
                        const openvdb::Coord leaf = c & ~7;
                        if (acc.isValueOn(leaf)) continue;
                        const Vec3d x = (c.asVec3d() + Vec3d(1.5)) * dx;
                        const double t = len2 > 0 ? std::clamp((x - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
                        const double d = (x - (a + ab * t)).length() - (ra + (rb - ra) * t);
                        if (d < background + lipschitz * blockReach) acc.setValueOn(leaf);
                    }
        }
    }
    void join(LeafReach& o) { leaves.topologyUnion(o.leaves); }
};

} // namespace

size_t branchLeafCount(const std::vector<Vec3d>& pos, const std::vector<int32_t>& parents,
                       const std::vector<float>& radii, double voxelSize, double halfWidth)
{
    LeafReach body(pos, parents, radii, voxelSize, double(float(halfWidth * voxelSize)));
    tbb::parallel_reduce(tbb::blocked_range<size_t>(0, pos.size(), 256), body);
    return size_t(body.leaves.activeVoxelCount());
}

double floatLeafBytes()
{
    using Leaf = openvdb::FloatTree::LeafNodeType;
    return double(sizeof(Leaf) + Leaf::SIZE * sizeof(float) + 16);
}

} // namespace frostvdb::dla3d
