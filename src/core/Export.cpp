#include <frostvdb/core/Export.h>
#include <frostvdb/core/FoldedReader.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/io/StreamedGrid.h>
#include <frostvdb/io/Png.h>

#include <openvdb/tools/GridTransformer.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <functional>
#include <cmath>
#include <optional>
#include <stdexcept>

namespace frostvdb {

namespace {

/// Output index bounding box of the points whose resampling stencil can reach an input voxel of
/// @a inBox (input index space): the input box widened by one cell, mapped through the (affine)
/// input -> world -> output chain, open at its ends (a point exactly one cell away has weight 0).
openvdb::CoordBBox footprint(const openvdb::CoordBBox& inBox, const openvdb::math::Transform& in,
                             const openvdb::math::Transform& out, bool nearest)
{
    const double w = nearest ? 0.5 + 1e-6 : 1.0;
    openvdb::Vec3d lo(1e300), hi(-1e300);
    for (int c = 0; c < 8; ++c) {
        const openvdb::Vec3d ip((c & 1) ? inBox.max().x() + w : inBox.min().x() - w,
                                (c & 2) ? inBox.max().y() + w : inBox.min().y() - w,
                                (c & 4) ? inBox.max().z() + w : inBox.min().z() - w);
        const openvdb::Vec3d op = out.worldToIndex(in.indexToWorld(ip));
        lo = openvdb::math::minComponent(lo, op);
        hi = openvdb::math::maxComponent(hi, op);
    }
    const double eps = 1e-9;
    return openvdb::CoordBBox(
        openvdb::Coord(int(std::ceil(lo.x() + eps)), int(std::ceil(lo.y() + eps)), int(std::ceil(lo.z() + eps))),
        openvdb::Coord(int(std::floor(hi.x() - eps)), int(std::floor(hi.y() - eps)), int(std::floor(hi.z() - eps))));
}

/// Sparse resampling onto an affine target: only output leaves under the footprint of the
/// input's active leaves and tiles are visited, so the cost follows the active voxels (not the
/// bounding box, and not the 8^3 node boxes tools::resampleToMatch walks, which for a flat grid
/// is 8 layers where 1 is active). An output voxel is active when an input voxel with a non-zero
/// interpolation weight is; its value is the sampler's (BoxSampler: trilinear; PointSampler:
/// nearest). Each output voxel is a pure function of its position: the result does not depend
/// on the thread count.
///
/// @a boxes: the input's active voxels, as index boxes (each widened by one voxel within its
/// leaf); @a makeReader: a per-thread reader of the input (getValue, probeValue, isValueOn by
/// input index), a grid's accessor or a folded plane field's plane-layout view (FoldedReader);
/// @a like: the input grid whose background and metadata the output takes.
/// resampleBoxes' plan: the output leaves under the footprints of the input's active voxels
/// (@a inBoxes: index boxes, each widened by one voxel within its leaf), the zone outside which
/// no voxel is touched, and the affine map from output index to input index.
struct ResamplePlan {
    std::vector<openvdb::Coord> origins; ///< output leaf origins, sorted and unique
    openvdb::CoordBBox zone;             ///< voxels outside every footprint are never touched
    openvdb::Vec3d p0, ax, ay, az;       ///< output index c -> input index p0 + A c

    ResamplePlan(const std::vector<openvdb::CoordBBox>& inBoxes, const openvdb::math::Transform& in,
                 const openvdb::math::Transform& target, bool nearest, int leafDim);
    openvdb::Vec3d inputIndex(const openvdb::Coord& c) const
    {
        return p0 + ax * double(c.x()) + ay * double(c.y()) + az * double(c.z());
    }
    /// Whether output voxel @a c is active (in the zone, and an input voxel with a non-zero
    /// interpolation weight is; Nearest: the voxel it rounds to is), and its input index @a p.
    template <bool Nearest, typename Reader>
    bool active(const Reader& acc, const openvdb::Coord& c, openvdb::Vec3d& p) const
    {
        if (!zone.isInside(c)) return false;
        p = inputIndex(c);
        if (Nearest) return acc.isValueOn(openvdb::Coord::round(p));
        const openvdb::Coord i0 = openvdb::Coord::floor(p);
        const openvdb::Vec3d f = p - i0.asVec3d();
        for (int k = 0; k < 8; ++k) {
            const double wx = (k & 1) ? f.x() : 1.0 - f.x(), wy = (k & 2) ? f.y() : 1.0 - f.y(),
                         wz = (k & 4) ? f.z() : 1.0 - f.z();
            if (wx * wy * wz > 0.0 && acc.isValueOn(i0.offsetBy((k & 1) ? 1 : 0, (k & 2) ? 1 : 0, (k & 4) ? 1 : 0)))
                return true;
        }
        return false;
    }
};

ResamplePlan::ResamplePlan(const std::vector<openvdb::CoordBBox>& inBoxes, const openvdb::math::Transform& in,
                           const openvdb::math::Transform& target, bool nearest, int leafDim)
{
    std::vector<openvdb::CoordBBox> boxes(inBoxes.size());
    tbb::parallel_for(size_t(0), inBoxes.size(), [&](size_t i) {
        if (!inBoxes[i].empty()) boxes[i] = footprint(inBoxes[i], in, target, nearest);
    });
    std::vector<std::vector<openvdb::Coord>> per(boxes.size());
    tbb::parallel_for(size_t(0), boxes.size(), [&](size_t i) {
        const auto& b = boxes[i];
        if (b.empty()) return;
        const int m = ~(leafDim - 1);
        for (int x = b.min().x() & m; x <= b.max().x(); x += leafDim)
            for (int y = b.min().y() & m; y <= b.max().y(); y += leafDim)
                for (int z = b.min().z() & m; z <= b.max().z(); z += leafDim) per[i].emplace_back(x, y, z);
    });
    for (size_t i = 0; i < boxes.size(); ++i) {
        if (!boxes[i].empty()) zone.expand(boxes[i]);
        origins.insert(origins.end(), per[i].begin(), per[i].end());
    }
    std::vector<std::vector<openvdb::Coord>>().swap(per);
    std::sort(origins.begin(), origins.end());
    origins.erase(std::unique(origins.begin(), origins.end()), origins.end());
    auto map = [&](const openvdb::Vec3d& c) { return in.worldToIndex(target.indexToWorld(c)); };
    p0 = map(openvdb::Vec3d(0.0));
    ax = map(openvdb::Vec3d(1, 0, 0)) - p0;
    ay = map(openvdb::Vec3d(0, 1, 0)) - p0;
    az = map(openvdb::Vec3d(0, 0, 1)) - p0;
}

/// Sparse resampling onto an affine target: only output leaves under the footprint of the
/// input's active leaves and tiles are visited, so the cost follows the active voxels (not the
/// bounding box, and not the 8^3 node boxes tools::resampleToMatch walks, which for a flat grid
/// is 8 layers where 1 is active). An output voxel is active when an input voxel with a non-zero
/// interpolation weight is; its value is the sampler's (BoxSampler: trilinear; PointSampler:
/// nearest). Each output voxel is a pure function of its position: the result does not depend
/// on the thread count.
///
/// @a boxes: the input's active voxels, as index boxes (each widened by one voxel within its
/// leaf); @a makeReader: a per-thread reader of the input (getValue, probeValue, isValueOn by
/// input index), a grid's accessor or a folded plane field's plane-layout view (FoldedReader);
/// @a like: the input grid whose background and metadata the output takes.
template <typename GridT, typename Sampler, bool Nearest, typename MakeReader>
typename GridT::Ptr resampleBoxes(const std::vector<openvdb::CoordBBox>& inBoxes, const MakeReader& makeReader,
                                  const GridT& like, const openvdb::math::Transform& target)
{
    using TreeT = typename GridT::TreeType;
    using LeafT = typename TreeT::LeafNodeType;
    auto out = GridT::create(like.background());
    out->setTransform(target.copy());
    for (auto it = like.beginMeta(); it != like.endMeta(); ++it) out->insertMeta(it->first, *it->second);
    const ResamplePlan plan(inBoxes, like.transform(), target, Nearest, int(LeafT::DIM));
    std::vector<LeafT*> outLeaves;
    for (const auto& o : plan.origins) outLeaves.push_back(out->tree().touchLeaf(o));
    // sample every voxel of those leaves that is active
    tbb::parallel_for(tbb::blocked_range<size_t>(0, outLeaves.size(), 4), [&](const tbb::blocked_range<size_t>& r) {
        const auto acc = makeReader();
        for (size_t l = r.begin(); l != r.end(); ++l) {
            LeafT& leaf = *outLeaves[l];
            for (openvdb::Index n = 0; n < LeafT::SIZE; ++n) {
                openvdb::Vec3d p;
                if (!plan.template active<Nearest>(acc, leaf.offsetToGlobalCoord(n), p)) continue;
                typename GridT::ValueType v;
                Sampler::sample(acc, p, v);
                leaf.setValueOn(n, v);
            }
        }
    });
    openvdb::tools::pruneInactive(out->tree());
    return out;
}

template <typename GridT, typename Sampler, bool Nearest>
openvdb::GridBase::Ptr resampleSparse(const openvdb::GridBase& base, const openvdb::math::Transform& target)
{
    using TreeT = typename GridT::TreeType;
    const auto& in = static_cast<const GridT&>(base);
    // every active leaf and tile
    std::vector<openvdb::CoordBBox> boxes;
    {
        openvdb::tree::LeafManager<const TreeT> leaves(in.tree());
        boxes.resize(leaves.leafCount());
        tbb::parallel_for(size_t(0), leaves.leafCount(), [&](size_t i) {
            const auto& leaf = leaves.leaf(i);
            if (leaf.isEmpty()) return;
            // The active voxels' box widened by one voxel (a margin far above the footprint's
            // rounding), within the leaf's node box: not the whole node box, which for a flat
            // grid samples all 8 z layers of the output leaves where 1 or 2 can be reached.
            openvdb::CoordBBox bb;
            leaf.evalActiveBoundingBox(bb, true);
            bb.expand(1);
            bb.intersect(leaf.getNodeBoundingBox());
            boxes[i] = bb;
        });
        auto tile = in.tree().cbeginValueOn();
        tile.setMaxDepth(TreeT::ValueOnCIter::LEAF_DEPTH - 1);
        for (; tile; ++tile) boxes.push_back(tile.getBoundingBox());
    }
    return resampleBoxes<GridT, Sampler, Nearest>(boxes, [&] { return in.getConstAccessor(); }, in, target);
}

using plane::FoldedReader;

/// The boxes resampleSparse takes from plane::unfoldGrid(@a folded): one per 8 x 8 chunk with an
/// active voxel, the plane leaf's tight active box widened by one voxel within its node box.
std::vector<openvdb::CoordBBox> foldedBoxes(const openvdb::FloatGrid& folded)
{
    openvdb::tree::LeafManager<const openvdb::FloatTree> leaves(folded.tree());
    std::vector<openvdb::CoordBBox> boxes(leaves.leafCount() * 8);
    tbb::parallel_for(size_t(0), leaves.leafCount(), [&](size_t i) {
        const auto& leaf = leaves.leaf(i);
        const openvdb::Coord fo = leaf.origin();
        const auto& m = leaf.getValueMask();
        for (int g = 0; g < 8; ++g) {
            uint64_t cols = 0; // bit dx: column dx has an active voxel
            int y0 = 8, y1 = -1;
            for (int dy = 0; dy < 8; ++dy) {
                const uint64_t row = (m.template getWord<uint64_t>(openvdb::Index(dy)) >> (g * 8)) & 0xffu;
                cols |= row;
                if (row) { y0 = std::min(y0, dy); y1 = dy; }
            }
            if (!cols) continue;
            const openvdb::Coord lo = plane::planeLeafOfChunk(fo, g);
            openvdb::CoordBBox bb(lo.offsetBy(__builtin_ctzll(cols), y0, 0), lo.offsetBy(63 - __builtin_clzll(cols), y1, 0));
            bb.expand(1);
            bb.intersect(openvdb::CoordBBox::createCube(lo, 8));
            boxes[i * 8 + size_t(g)] = bb;
        }
    });
    return boxes;
}

/// resampleSparse of plane::unfoldGrid(@a folded) (its metadata and background from @a like),
/// reading the folded leaves in place (FoldedReader).
openvdb::FloatGrid::Ptr resampleFolded(const openvdb::FloatGrid& folded, const openvdb::FloatGrid& like,
                                       const openvdb::math::Transform& target)
{
    return resampleBoxes<openvdb::FloatGrid, openvdb::tools::BoxSampler, false>(
        foldedBoxes(folded), [&] { return FoldedReader(folded); }, like, target);
}

/// resampleFolded followed by a clip to @a clip, as a StreamedFloatGrid (io/StreamedGrid.h): the
/// topology is made now by the same test (leaves without buffers, only those left with an active
/// voxel), the values by the same sampler while the grid is written, from @a folded, which the
/// grid keeps. The file holds the eager grid's bits.
openvdb::FloatGrid::Ptr streamFolded(const openvdb::FloatGrid::ConstPtr& folded, const openvdb::FloatGrid& like,
                                     const openvdb::math::Transform& target, const openvdb::CoordBBox& clip)
{
    using LeafT = openvdb::FloatTree::LeafNodeType;
    auto plan = std::make_shared<const ResamplePlan>(foldedBoxes(*folded), like.transform(), target, false, int(LeafT::DIM));
    std::vector<LeafT::NodeMaskType> masks(plan->origins.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, masks.size(), 16), [&](const tbb::blocked_range<size_t>& r) {
        const FoldedReader acc(*folded);
        for (size_t l = r.begin(); l != r.end(); ++l)
            for (openvdb::Index n = 0; n < LeafT::SIZE; ++n) {
                const openvdb::Coord c = plan->origins[l] + LeafT::offsetToLocalCoord(n);
                openvdb::Vec3d p;
                if (clip.isInside(c) && plan->active<false>(acc, c, p)) masks[l].setOn(n);
            }
    });
    auto tree = std::make_shared<openvdb::FloatTree>(like.background());
    for (size_t l = 0; l < masks.size(); ++l) {
        if (masks[l].isOff()) continue;
        auto* leaf = new LeafT(openvdb::PartialCreate(), plan->origins[l], like.background());
        leaf->setValueMask(masks[l]);
        tree->addLeaf(leaf);
    }
    auto fill = [folded, plan](const LeafT* const* leaves, size_t count, float* values) {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 16), [&](const tbb::blocked_range<size_t>& r) {
            const FoldedReader acc(*folded);
            for (size_t i = r.begin(); i != r.end(); ++i)
                for (auto on = leaves[i]->cbeginValueOn(); on; ++on)
                    openvdb::tools::BoxSampler::sample(acc, plan->inputIndex(on.getCoord()), values[i * LeafT::SIZE + on.pos()]);
        });
    };
    auto out = std::make_shared<StreamedFloatGrid>(tree, like, fill);
    out->setTransform(target.copy());
    return out;
}

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
    // level sets are rebuilt by OpenVDB (their narrow band and sign need it); the rest sparsely
    const bool sparse = grid.getGridClass() != GRID_LEVEL_SET && grid.transform().isLinear() && target.isLinear();
    if (grid.isType<FloatGrid>())
        return sparse ? resampleSparse<FloatGrid, tools::BoxSampler, false>(grid, target)
                      : resampleAs<FloatGrid, tools::BoxSampler>(grid, target);
    if (grid.isType<DoubleGrid>())
        return sparse ? resampleSparse<DoubleGrid, tools::BoxSampler, false>(grid, target)
                      : resampleAs<DoubleGrid, tools::BoxSampler>(grid, target);
    if (grid.isType<Vec3SGrid>())
        return sparse ? resampleSparse<Vec3SGrid, tools::BoxSampler, false>(grid, target)
                      : resampleAs<Vec3SGrid, tools::BoxSampler>(grid, target);
    if (grid.isType<Int32Grid>())
        return sparse ? resampleSparse<Int32Grid, tools::PointSampler, true>(grid, target)
                      : resampleAs<Int32Grid, tools::PointSampler>(grid, target);
    if (grid.isType<Int64Grid>())
        return sparse ? resampleSparse<Int64Grid, tools::PointSampler, true>(grid, target)
                      : resampleAs<Int64Grid, tools::PointSampler>(grid, target);
    return grid.deepCopyGrid(); // unknown type: as it is
}

namespace {

/// GridBase::clip without its cost: OpenVDB's clip refills every tile that straddles the box
/// with leaves (for a one-voxel-thick box that is every tile of the plane: 140 MB for a 2048^2
/// raster, GBs at 16384^2). Here only the grid's own leaves are visited: voxels outside the box
/// become inactive background, and leaves left without active voxels are pruned. Active tiles,
/// which the sparse resampling does not make, go through OpenVDB's clip.
template <typename GridT>
bool clipLeaves(openvdb::GridBase& grid, const openvdb::CoordBBox& box)
{
    auto* g = dynamic_cast<GridT*>(&grid);
    if (!g) return false;
    using TreeT = typename GridT::TreeType;
    auto tile = g->tree().cbeginValueOn();
    tile.setMaxDepth(TreeT::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tile; ++tile)
        if (!tile.isVoxelValue()) return false;
    const auto bg = g->background();
    openvdb::tree::LeafManager<TreeT> leaves(g->tree());
    leaves.foreach([&](typename TreeT::LeafNodeType& leaf, size_t) {
        if (box.isInside(leaf.getNodeBoundingBox())) return;
        for (openvdb::Index n = 0; n < TreeT::LeafNodeType::SIZE; ++n)
            if (!box.isInside(leaf.offsetToGlobalCoord(n))) leaf.setValueOff(n, bg);
    });
    openvdb::tools::pruneInactive(g->tree());
    return true;
}

void clipSparse(openvdb::GridBase& grid, const openvdb::CoordBBox& box)
{
    using namespace openvdb;
    if (clipLeaves<FloatGrid>(grid, box) || clipLeaves<DoubleGrid>(grid, box) || clipLeaves<Vec3SGrid>(grid, box) ||
        clipLeaves<Int32Grid>(grid, box) || clipLeaves<Int64Grid>(grid, box))
        return;
    grid.clip(box);
}

} // namespace

namespace {

/// The box a grid resampled from a flat hexagonal domain is clipped to: a flat domain stays one
/// voxel thick (the shear's rounding leaves near-background values in the layers above and
/// below), and nothing lies outside the raster. Infinite for other domains.
openvdb::CoordBBox exportClip(const Domain& dom)
{
    if (!dom.flat()) return openvdb::CoordBBox::inf();
    const SquareRaster sr = squareRaster(dom);
    const int z = dom.bbox().min().z();
    return openvdb::CoordBBox(openvdb::Coord(sr.a0, sr.b0, z), openvdb::Coord(sr.a1, sr.b1, z));
}

openvdb::GridBase::Ptr noteResampled(openvdb::GridBase::Ptr r)
{
    r->insertMeta("frostvdb_lattice", openvdb::StringMetadata(
        "square, resampled (trilinear) from the hexagonal lattice of the simulation"));
    return r;
}

/// exportGrid's last stage for a grid resampled from a hexagonal domain.
openvdb::GridBase::Ptr finishResampled(openvdb::GridBase::Ptr r, const Domain& dom)
{
    if (dom.flat()) clipSparse(*r, exportClip(dom));
    return noteResampled(r);
}

} // namespace

openvdb::GridBase::Ptr exportGrid(const openvdb::GridBase::Ptr& g, const Domain& dom, bool keepLattice)
{
    const bool hex = dom.lattice().kind() == LatticeKind::Hexagonal;
    if (!hex) return g;
    if (g->transform() != *dom.transform()) return g; // an effect's own raster: leave it alone
    if (keepLattice) {
        auto c = g->copyGrid(); // shares the tree, own metadata
        c->insertMeta("frostvdb_lattice", openvdb::StringMetadata(
            "hexagonal axial (i, j), sheared transform: world = h (i + j/2, j sqrt(3)/2)"));
        return c;
    }
    return finishResampled(resampleGrid(*g, *squareTransform(dom)), dom);
}

namespace {
thread_local const ExportScope* tExportScope = nullptr;
} // namespace

ExportScope::ExportScope(const Domain& domain, bool keepLattice)
    : mDomain(domain), mKeepLattice(keepLattice), mPrevious(tExportScope)
{
    tExportScope = this;
}

ExportScope::~ExportScope() { tExportScope = mPrevious; }

const ExportScope* ExportScope::current() { return tExportScope; }

bool exportsFoldedInPlace(const openvdb::FloatGrid& folded)
{
    const ExportScope* s = ExportScope::current();
    return s && !s->keepLattice() && plane::isFolded(folded) && s->domain().lattice().kind() == LatticeKind::Hexagonal &&
           folded.transform() == *s->domain().transform();
}

namespace {

/// The plane-layout grid a frame holds of @a folded (unfoldGrid's copy, dressed), without its
/// tree: the metadata, transform and background an export takes.
openvdb::FloatGrid::Ptr exportShell(const openvdb::FloatGrid& folded, const std::function<void(openvdb::FloatGrid&)>& dress)
{
    auto like = openvdb::gridPtrCast<openvdb::FloatGrid>(folded.copyGridWithNewTree());
    like->removeMeta(plane::kFoldMeta);
    if (dress) dress(*like);
    return like;
}

/// Whether exportFolded resamples the folded leaves in place (else it exports the unfolded copy).
bool resamplesInPlace(const openvdb::FloatGrid& folded, const openvdb::FloatGrid& like, const Domain& dom,
                      bool keepLattice, const openvdb::math::Transform& target)
{
    return plane::isFolded(folded) && dom.lattice().kind() == LatticeKind::Hexagonal && !keepLattice &&
           like.transform() == *dom.transform() && like.getGridClass() != openvdb::GRID_LEVEL_SET &&
           like.transform().isLinear() && target.isLinear() && !folded.tree().hasActiveTiles();
}

/// exportGrid of the unfolded copy (the export when the leaves are not resampled in place).
openvdb::GridBase::Ptr exportUnfolded(const openvdb::FloatGrid& folded, const Domain& dom, bool keepLattice,
                                      const std::function<void(openvdb::FloatGrid&)>& dress)
{
    auto g = plane::unfoldGrid(folded);
    if (dress) dress(*g);
    return exportGrid(g, dom, keepLattice);
}

} // namespace

openvdb::GridBase::Ptr exportFolded(const openvdb::FloatGrid& folded, const Domain& dom, bool keepLattice,
                                    const std::function<void(openvdb::FloatGrid&)>& dress)
{
    const auto like = exportShell(folded, dress);
    const auto target = squareTransform(dom);
    if (!resamplesInPlace(folded, *like, dom, keepLattice, *target)) return exportUnfolded(folded, dom, keepLattice, dress);
    return finishResampled(resampleFolded(folded, *like, *target), dom);
}

openvdb::GridBase::Ptr exportFoldedStreamed(const openvdb::FloatGrid::ConstPtr& folded, const Domain& dom,
                                            bool keepLattice, const std::function<void(openvdb::FloatGrid&)>& dress)
{
    const auto like = exportShell(*folded, dress);
    const auto target = squareTransform(dom);
    if (!resamplesInPlace(*folded, *like, dom, keepLattice, *target)) return exportUnfolded(*folded, dom, keepLattice, dress);
    return noteResampled(streamFolded(folded, *like, *target, exportClip(dom)));
}

openvdb::GridPtrVec exportGrids(const openvdb::GridPtrVec& grids, const Domain& dom, bool keepLattice)
{
    openvdb::GridPtrVec out;
    for (const auto& g : grids) out.push_back(exportGrid(g, dom, keepLattice));
    return out;
}

namespace {

/// The raster pixels (a, b) a flat grid's active voxels can colour under BoxSampler, as 8x8
/// pixel blocks (block = (a >> 3, b >> 3) relative to the raster origin), sorted and unique.
std::vector<std::pair<int, int>> touchedBlocks(const openvdb::FloatGrid& g, const SquareRaster& r, double z)
{
    const auto& xf = g.transform();
    auto raster = openvdb::math::Transform::createLinearTransform(r.h);
    openvdb::tree::LeafManager<const openvdb::FloatTree> leaves(g.tree());
    const bool folded = plane::isFolded(g); // then one box per plane leaf unfoldGrid would make
    std::vector<openvdb::CoordBBox> boxes(leaves.leafCount() * (folded ? 8 : 1));
    tbb::parallel_for(size_t(0), leaves.leafCount(), [&](size_t i) {
        if (leaves.leaf(i).isEmpty()) return;
        if (folded) {
            plane::PlaneChunk chunks[8];
            const int n = plane::chunksOf(leaves.leaf(i), chunks);
            for (int c = 0; c < n; ++c) // a plane leaf's node box, as evalActiveBoundingBox(bb, false) gives
                boxes[i * 8 + size_t(c)] = footprint(openvdb::CoordBBox::createCube(chunks[c].origin, 8), xf, *raster, false);
            return;
        }
        openvdb::CoordBBox bb;
        leaves.leaf(i).evalActiveBoundingBox(bb, false);
        boxes[i] = footprint(bb, xf, *raster, false);
    });
    auto tile = g.tree().cbeginValueOn();
    tile.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    if (folded && tile) throw std::logic_error("touchedBlocks: a folded plane grid with active tiles");
    for (; tile; ++tile) boxes.push_back(footprint(tile.getBoundingBox(), xf, *raster, false));
    (void)z;
    std::vector<std::pair<int, int>> blocks;
    for (const auto& b : boxes) {
        if (b.min().x() > b.max().x() || b.min().y() > b.max().y()) continue; // (z is not looked at)
        const int x0 = std::max(b.min().x(), r.a0) - r.a0, x1 = std::min(b.max().x(), r.a1) - r.a0;
        const int y0 = std::max(b.min().y(), r.b0) - r.b0, y1 = std::min(b.max().y(), r.b1) - r.b0;
        for (int by = y0 >> 3; by <= (y1 >> 3) && y0 <= y1; ++by)
            for (int bx = x0 >> 3; bx <= (x1 >> 3) && x0 <= x1; ++bx) blocks.emplace_back(bx, by);
    }
    std::sort(blocks.begin(), blocks.end());
    blocks.erase(std::unique(blocks.begin(), blocks.end()), blocks.end());
    return blocks;
}

/// Samples @a growth at the raster pixels of @a blocks that fall in the image window
/// [ia, ia + W) x [ib, ib + H) (raster offsets; image row 0 at the top) into @a values.
/// A folded growth (core/PlaneFold.h) is read in place as its plane layout (FoldedReader).
void sampleBlocks(const openvdb::FloatGrid& growth, const SquareRaster& r, double z,
                  const std::vector<std::pair<int, int>>& blocks, int ia, int ib, int W, int H,
                  std::vector<uint16_t>& values)
{
    const bool folded = plane::isFolded(growth);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, blocks.size(), 16), [&](const tbb::blocked_range<size_t>& rg) {
        auto acc = growth.getConstAccessor();
        openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> s(
            acc, growth.transform());
        std::optional<FoldedReader> reader;
        if (folded) reader.emplace(growth);
        for (size_t k = rg.begin(); k != rg.end(); ++k) {
            for (int dy = 0; dy < 8; ++dy)
                for (int dx = 0; dx < 8; ++dx) {
                    const int a = blocks[k].first * 8 + dx - ia, b = blocks[k].second * 8 + dy - ib;
                    if (a < 0 || b < 0 || a >= W || b >= H) continue;
                    const int ra = r.a0 + ia + a, rb = r.b0 + ib + b;
                    if (ra > r.a1 || rb > r.b1) continue;
                    const openvdb::Vec3d ws(ra * r.h, rb * r.h, z);
                    float v;
                    if (reader) // what GridSampler::wsSample does, on the plane-layout view
                        openvdb::tools::BoxSampler::sample(*reader, growth.transform().worldToIndex(ws), v);
                    else
                        v = s.wsSample(ws);
                    values[size_t(H - 1 - b) * W + a] = toSample16(float(v));
                }
        }
    });
}

} // namespace

std::vector<std::string> writeDisplacementMaps(const openvdb::FloatGrid& growth, const Domain& dom,
                                               const std::string& stem, int tileSize)
{
    if (!dom.flat()) throw std::invalid_argument("displacement PNGs are for flat domains");
    if (tileSize < 8) throw std::invalid_argument("displacement tile size must be at least 8 pixels");
    const SquareRaster r = squareRaster(dom);
    const int W = r.width(), H = r.height();
    const double z = dom.transform()->indexToWorld(openvdb::Vec3d(0, 0, dom.bbox().min().z())).z();
    const float bg = growth.background();
    const auto blocks = touchedBlocks(growth, r, z);
    if (W <= tileSize && H <= tileSize) { // one image, as large as the raster
        std::vector<uint16_t> values(size_t(W) * H, toSample16(bg));
        sampleBlocks(growth, r, z, blocks, 0, 0, W, H, values);
        writePngGray16(stem + ".png", W, H, values);
        return {stem + ".png"};
    }
    // UDIM tiles: tile (u, v) holds raster offsets [u T, (u+1) T) x [v T, (v+1) T), u along +x
    // from the raster's left edge, v along +y from its bottom; number 1001 + u + 10 v
    const int nu = udimTilesAcross(W, tileSize), nv = udimTilesAcross(H, tileSize);
    if (nu > kUdimTilesAcross) // Simulation refuses such scenes at load; a direct caller gets this
        throw std::invalid_argument("displacement map " + std::to_string(W) + " pixels wide needs " +
                                    std::to_string(nu) + " UDIM tiles across (at most " +
                                    std::to_string(kUdimTilesAcross) + "): raise output.displacement_tile");
    std::vector<std::vector<std::pair<int, int>>> perTile(size_t(nu) * nv);
    const int bt = tileSize / 8; // blocks per tile side when the tile is a multiple of 8
    for (const auto& b : blocks) {
        // a block may straddle two tiles when tileSize is not a multiple of 8: give it to both
        for (int cy = 0; cy < 2; ++cy)
            for (int cx = 0; cx < 2; ++cx) {
                const int u = (b.first * 8 + cx * 7) / tileSize, v = (b.second * 8 + cy * 7) / tileSize;
                if (u >= nu || v >= nv) continue;
                auto& t = perTile[size_t(v) * nu + u];
                if (t.empty() || t.back() != b) t.push_back(b);
            }
    }
    (void)bt;
    std::vector<int> udims;
    for (int v = 0; v < nv; ++v)
        for (int u = 0; u < nu; ++u)
            if (!perTile[size_t(v) * nu + u].empty()) udims.push_back(1001 + u + 10 * v);
    std::vector<std::string> files(udims.size());
    // two tiles at a time at most: each holds tileSize^2 16-bit samples while it is encoded
    tbb::parallel_for(tbb::blocked_range<size_t>(0, udims.size(), 1), [&](const tbb::blocked_range<size_t>& rg) {
        for (size_t i = rg.begin(); i != rg.end(); ++i) {
            const int u = (udims[i] - 1001) % 10, v = (udims[i] - 1001) / 10;
            auto& t = perTile[size_t(v) * nu + u];
            std::sort(t.begin(), t.end());
            t.erase(std::unique(t.begin(), t.end()), t.end());
            std::vector<uint16_t> values(size_t(tileSize) * tileSize, toSample16(bg)); // 32 MiB at 4096^2
            sampleBlocks(growth, r, z, t, u * tileSize, v * tileSize, tileSize, tileSize, values);
            files[i] = stem + "." + std::to_string(udims[i]) + ".png";
            writePngGray16(files[i], tileSize, tileSize, values);
        }
    });
    return files;
}

void writeDisplacementPng(const openvdb::FloatGrid& growth, const Domain& dom, const std::string& path)
{
    const std::string stem = path.size() > 4 && path.substr(path.size() - 4) == ".png" ? path.substr(0, path.size() - 4) : path;
    writeDisplacementMaps(growth, dom, stem, 1 << 30);
}

} // namespace frostvdb
