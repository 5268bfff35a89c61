#include <frostvdb/io/Export.h>
#include <frostvdb/io/Png.h>

#include <openvdb/tools/GridTransformer.h>
#include <openvdb/tools/Interpolation.h>

#include <tbb/parallel_for.h>

#include <cmath>
#include <stdexcept>

namespace frostvdb {

namespace {

template <typename GridT, typename Sampler>
openvdb::GridBase::Ptr resampleAs(const openvdb::GridBase& base, const openvdb::math::Transform& target)
{
    const auto& in = static_cast<const GridT&>(base);
    auto out = GridT::create(in.background());
    out->setTransform(target.copy());
    openvdb::tools::resampleToMatch<Sampler>(in, *out);
    // Name, class, vector type, units and every other piece of metadata, as they were.
    for (auto it = in.beginMeta(); it != in.endMeta(); ++it) out->insertMeta(it->first, *it->second);
    return out;
}

} // namespace

SquareRaster squareRaster(const Domain& dom)
{
    const auto& bb = dom.bbox();
    const auto& xf = *dom.transform();
    double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
    for (int c = 0; c < 4; ++c) {
        const openvdb::Vec3d ip((c & 1) ? bb.max().x() : bb.min().x(), (c & 2) ? bb.max().y() : bb.min().y(),
                                bb.min().z());
        const auto w = xf.indexToWorld(ip);
        x0 = std::min(x0, w.x());
        x1 = std::max(x1, w.x());
        y0 = std::min(y0, w.y());
        y1 = std::max(y1, w.y());
    }
    SquareRaster r;
    r.h = dom.voxelSize();
    const double eps = 1e-6;
    r.a0 = int(std::ceil(x0 / r.h - eps));
    r.a1 = int(std::floor(x1 / r.h + eps));
    r.b0 = int(std::ceil(y0 / r.h - eps));
    r.b1 = int(std::floor(y1 / r.h + eps));
    return r;
}

openvdb::math::Transform::Ptr squareTransform(const Domain& dom)
{
    return openvdb::math::Transform::createLinearTransform(dom.voxelSize());
}

openvdb::GridBase::Ptr resampleGrid(const openvdb::GridBase& grid, const openvdb::math::Transform& target)
{
    using namespace openvdb;
    if (grid.isType<FloatGrid>()) return resampleAs<FloatGrid, tools::BoxSampler>(grid, target);
    if (grid.isType<DoubleGrid>()) return resampleAs<DoubleGrid, tools::BoxSampler>(grid, target);
    if (grid.isType<Vec3SGrid>()) return resampleAs<Vec3SGrid, tools::BoxSampler>(grid, target);
    if (grid.isType<Int32Grid>()) return resampleAs<Int32Grid, tools::PointSampler>(grid, target);
    if (grid.isType<Int64Grid>()) return resampleAs<Int64Grid, tools::PointSampler>(grid, target);
    return grid.deepCopyGrid(); // unknown type: as it is
}

openvdb::GridPtrVec exportGrids(const openvdb::GridPtrVec& grids, const Domain& dom, bool keepLattice)
{
    const bool hex = dom.lattice().kind() == LatticeKind::Hexagonal;
    if (!hex) return grids;
    openvdb::GridPtrVec out;
    auto square = squareTransform(dom);
    for (const auto& g : grids) {
        if (g->transform() != *dom.transform()) { // an effect's own raster: leave it alone
            out.push_back(g);
            continue;
        }
        if (keepLattice) {
            auto c = g->copyGrid(); // shares the tree, own metadata
            c->insertMeta("frostvdb_lattice", openvdb::StringMetadata(
                "hexagonal axial (i, j), sheared transform: world = h (i + j/2, j sqrt(3)/2)"));
            out.push_back(c);
            continue;
        }
        auto r = resampleGrid(*g, *square);
        // A flat domain stays one voxel thick: the shear's rounding leaves near-background
        // values in the layers above and below, and nothing lies outside the raster.
        if (dom.flat()) {
            const SquareRaster sr = squareRaster(dom);
            const int z = dom.bbox().min().z();
            r->clip(openvdb::CoordBBox(openvdb::Coord(sr.a0, sr.b0, z), openvdb::Coord(sr.a1, sr.b1, z)));
        }
        r->insertMeta("frostvdb_lattice", openvdb::StringMetadata(
            "square, resampled (trilinear) from the hexagonal lattice of the simulation"));
        out.push_back(r);
    }
    return out;
}

void writeDisplacementPng(const openvdb::FloatGrid& growth, const Domain& dom, const std::string& path)
{
    if (!dom.flat()) throw std::invalid_argument("displacement PNGs are for flat domains");
    const SquareRaster r = squareRaster(dom);
    const int W = r.width(), H = r.height();
    std::vector<float> values(size_t(W) * H);
    const double z = dom.transform()->indexToWorld(openvdb::Vec3d(0, 0, dom.bbox().min().z())).z();
    tbb::parallel_for(0, H, [&](int y) {
        auto acc = growth.getConstAccessor();
        openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> s(
            acc, growth.transform());
        const int b = r.b1 - y; // row 0 at the top (+y)
        for (int x = 0; x < W; ++x)
            values[size_t(y) * W + x] = s.wsSample(openvdb::Vec3d((r.a0 + x) * r.h, b * r.h, z));
    });
    writePngGray(path, W, H, values, 16);
}

} // namespace frostvdb
