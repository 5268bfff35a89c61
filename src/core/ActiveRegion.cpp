#include <frostvdb/core/ActiveRegion.h>

#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tree/ValueAccessor.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>

namespace frostvdb {

namespace {

using MaskLeaf = openvdb::MaskTree::LeafNodeType;
constexpr int kLeafDim = int(MaskLeaf::DIM);

/// ORs @a src shifted by -1 and +1 along x (axis 0) or y (axis 1) into @a dst, which holds @a src
/// already. Leaf value masks are 8 words of 64 bits: word = x, bit = (y << 3) | z, so an x shift
/// moves whole words and a y shift moves bits by 8. No z dilation: the plane domain stays flat
/// (tools::dilateActiveValues would dilate into z and need a clip; measured 3x slower here).
void dilateAxis(const openvdb::MaskTree& src, openvdb::MaskTree& dst, int axis)
{
    const openvdb::Coord step = axis == 0 ? openvdb::Coord(kLeafDim, 0, 0) : openvdb::Coord(0, kLeafDim, 0);
    for (auto it = src.cbeginLeaf(); it; ++it) {
        const auto& m = it->getValueMask();
        bool lo = false, hi = false;
        for (openvdb::Index w = 0; w < 8; ++w) {
            const uint64_t word = m.template getWord<uint64_t>(w);
            if (axis == 0) { lo = lo || (w == 0 && word); hi = hi || (w == 7 && word); }
            else { lo = lo || (word & 0xFFull); hi = hi || (word >> 56); }
        }
        if (lo) dst.touchLeaf(it->origin() - step);
        if (hi) dst.touchLeaf(it->origin() + step);
    }
    openvdb::tree::LeafManager<openvdb::MaskTree> leaves(dst);
    leaves.foreach([&](MaskLeaf& leaf, size_t) {
        openvdb::tree::ValueAccessor<const openvdb::MaskTree> acc(src);
        const MaskLeaf* c = acc.probeConstLeaf(leaf.origin());
        const MaskLeaf* l = acc.probeConstLeaf(leaf.origin() - step);
        const MaskLeaf* h = acc.probeConstLeaf(leaf.origin() + step);
        auto word = [](const MaskLeaf* f, int w) -> uint64_t {
            return f ? f->getValueMask().template getWord<uint64_t>(openvdb::Index(w)) : 0ull;
        };
        auto& out = leaf.getValueMask();
        for (int w = 0; w < 8; ++w) {
            uint64_t add;
            if (axis == 0) {
                add = (w > 0 ? word(c, w - 1) : word(l, 7)) | (w < 7 ? word(c, w + 1) : word(h, 0));
            } else {
                const uint64_t cw = word(c, w);
                add = (cw << 8) | (cw >> 8) | (word(h, w) << 56) | (word(l, w) >> 56);
            }
            out.template getWord<uint64_t>(openvdb::Index(w)) |= add;
        }
    });
}

/// One dilation iteration in the plane: the 4-neighbourhood (diamond) or, for lattices that also
/// reach (1,-1) and (-1,1), the 8-neighbourhood (x then y: separable).
void dilatePlane(openvdb::MaskTree& tree, bool eightNeighbours)
{
    if (eightNeighbours) {
        const openvdb::MaskTree src(tree);
        dilateAxis(src, tree, 0);
        const openvdb::MaskTree srcY(tree);
        dilateAxis(srcY, tree, 1);
    } else {
        const openvdb::MaskTree src(tree);
        dilateAxis(src, tree, 0);
        dilateAxis(src, tree, 1);
    }
}

/// Clips a mask to a box: leaves inside are kept, leaves outside dropped, straddling leaves
/// masked voxel by voxel (cheaper than Tree::clip for a handful of boundary leaves).
void clipToBox(openvdb::MaskTree& tree, const openvdb::CoordBBox& box)
{
    std::vector<openvdb::Coord> outside;
    for (auto it = tree.cbeginLeaf(); it; ++it)
        if (!box.hasOverlap(it->getNodeBoundingBox())) outside.push_back(it->origin());
    for (const auto& o : outside) delete tree.stealNode<MaskLeaf>(o, false, false);
    openvdb::tree::LeafManager<openvdb::MaskTree> leaves(tree);
    leaves.foreach([&](MaskLeaf& leaf, size_t) {
        if (box.isInside(leaf.getNodeBoundingBox())) return;
        auto& mask = leaf.getValueMask();
        for (auto it = leaf.cbeginValueOn(); it; ++it)
            if (!box.isInside(it.getCoord())) mask.setOff(it.pos());
    });
}

/// Switches on every voxel of each leaf that lies in the domain's slab (a plane's one z, a box's all).
void fillLeaves(openvdb::MaskTree& tree, const Domain& domain)
{
    openvdb::tree::LeafManager<openvdb::MaskTree> leaves(tree);
    const bool plane = domain.isPlane();
    const int z0 = domain.bbox().min().z();
    const uint64_t planeBits = 0x0101010101010101ull << (z0 & (kLeafDim - 1));
    leaves.foreach([&](MaskLeaf& leaf, size_t) {
        auto& mask = leaf.getValueMask();
        if (!plane) { mask.setOn(); return; }
        if ((leaf.origin().z() & ~(kLeafDim - 1)) != (z0 & ~(kLeafDim - 1))) return;
        for (openvdb::Index w = 0; w < 8; ++w) mask.template getWord<uint64_t>(w) |= planeBits;
    });
}

} // namespace

openvdb::MaskGrid::Ptr buildActiveRegion(const std::vector<const openvdb::FloatGrid*>& fields,
                                         const RegionSettings& settings, int reach, const Domain& domain, int steps)
{
    auto region = openvdb::MaskGrid::create(false);
    region->setTransform(domain.transform()->copy());
    if (settings.dense) {
        region->tree().fill(domain.bbox(), true, true);
        region->tree().voxelizeActiveTiles(); // leaves, so kernels can iterate leaf by leaf
        return region;
    }
    // Union of the fields' topology: values already within tolerance of the far field were
    // removed by truncateToTolerance when the last region was retired.
    for (const auto* f : fields) region->tree().topologyUnion(f->tree());
    region->tree().voxelizeActiveTiles();
    clipToBox(region->tree(), domain.bbox());
    // A support that fills the domain needs no dilation (it would be clipped away again).
    if (regionFillsDomain(*region, domain)) return region;
    const int iterations = std::max(1, steps) * (reach + settings.frontTravel);
    // Hexagonal lattices reach (1,-1) and (-1,1): edge neighbours in index space.
    const bool hex = domain.lattice().kind() == LatticeKind::Hexagonal;
    if (iterations > 0 && !region->tree().empty()) {
        if (domain.isPlane()) {
            for (int i = 0; i < iterations; ++i) dilatePlane(region->tree(), hex);
        } else {
            openvdb::tools::dilateActiveValues(region->tree(), iterations, openvdb::tools::NN_FACE,
                                               openvdb::tools::IGNORE_TILES);
        }
    }
    // Whole leaves: the kernels pay per leaf anyway, and a region that only changes when the
    // front enters a new leaf keeps its topology for many rebuilds, so the output buffers, leaf
    // groups and implicit-system layouts of the last region are reused as they are.
    fillLeaves(region->tree(), domain);
    clipToBox(region->tree(), domain.bbox());
    return region;
}

bool regionFillsDomain(const openvdb::MaskGrid& region, const Domain& domain)
{
    return region.tree().activeVoxelCount() == domain.voxelCount();
}

void matchTopology(openvdb::FloatGrid& grid, const openvdb::MaskGrid& region)
{
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    auto& tree = grid.tree();
    const float bg = grid.background();
    // Leaves the region no longer has.
    {
        openvdb::tree::ValueAccessor<const openvdb::MaskTree> racc(region.tree());
        std::vector<openvdb::Coord> gone;
        for (auto it = tree.cbeginLeaf(); it; ++it)
            if (!racc.probeConstLeaf(it->origin())) gone.push_back(it->origin());
        for (const auto& o : gone) delete tree.stealNode<FloatLeaf>(o, bg, false);
    }
    // Tiles are not expected (kernels write leaves); a tile would hide voxels, so voxelize.
    tree.voxelizeActiveTiles();
    // Leaves it gains (serial: topology changes), then masks and background values in parallel.
    {
        openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(tree);
        for (auto it = region.tree().cbeginLeaf(); it; ++it)
            if (!acc.probeLeaf(it->origin())) acc.touchLeaf(it->origin());
    }
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(tree);
    leaves.foreach([&](FloatLeaf& leaf, size_t) {
        openvdb::tree::ValueAccessor<const openvdb::MaskTree> racc(region.tree());
        const MaskLeaf* m = racc.probeConstLeaf(leaf.origin());
        const auto& want = m->getValueMask();
        if (leaf.getValueMask() == want) return; // off voxels already hold the background
        float* v = leaf.buffer().data();
        for (openvdb::Index n = 0; n < FloatLeaf::SIZE; ++n)
            if (!want.isOn(n)) v[n] = bg;
        leaf.setValueMask(want);
    });
}

namespace {
inline uint64_t mix64(uint64_t x)
{
    x ^= x >> 33;
    x *= 0xff51afd7ed558ccdull;
    x ^= x >> 33;
    x *= 0xc4ceb9fe1a85ec53ull;
    x ^= x >> 33;
    return x;
}
} // namespace

uint64_t gridFingerprint(const openvdb::FloatGrid& grid)
{
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    openvdb::tree::LeafManager<const openvdb::FloatTree> leaves(grid.tree());
    std::atomic<uint64_t> sum{0};
    leaves.foreach([&](const FloatLeaf& leaf, size_t) {
        const openvdb::Coord o = leaf.origin();
        uint64_t h = (uint64_t(uint32_t(o.x())) << 32) ^ (uint64_t(uint32_t(o.y())) << 16) ^ uint32_t(o.z());
        const auto& mask = leaf.getValueMask();
        const float* v = leaf.buffer().data();
        // FNV-1a over the mask words and the active values in leaf order (each step a bijection
        // of h, so any single change changes it), then mixed once per leaf.
        constexpr uint64_t kPrime = 0x100000001b3ull;
        for (openvdb::Index w = 0; w < FloatLeaf::NodeMaskType::WORD_COUNT; ++w) {
            uint64_t word = mask.template getWord<uint64_t>(w);
            h = (h ^ word) * kPrime;
            while (word) {
                const openvdb::Index n = w * 64 + openvdb::Index(__builtin_ctzll(word));
                word &= word - 1;
                uint32_t bits;
                std::memcpy(&bits, v + n, 4);
                h = (h ^ bits) * kPrime;
            }
        }
        h = mix64(h);
        sum.fetch_add(h, std::memory_order_relaxed); // a sum: the same whatever the order
    });
    uint32_t bgBits;
    const float bg = grid.background();
    std::memcpy(&bgBits, &bg, 4);
    return sum.load() + mix64(bgBits) + grid.tree().leafCount();
}

int RegionCadence::automaticSteps(bool forced) const
{
    if (forced) return 1;
    const int perStep = std::max(1, mReach + mSettings.frontTravel);
    return std::max(1, int(MaskLeaf::DIM) / perStep);
}

int RegionCadence::begin(bool forced)
{
    const int k = mSettings.dense ? RegionCadence::kFullDomainSteps
                : mSettings.rebuildEvery > 0 ? mSettings.rebuildEvery
                                             : automaticSteps(forced);
    mLeft = k;
    return k;
}

void RegionCadence::filledDomain()
{
    if (mSettings.rebuildEvery == 0) mLeft = std::max(mLeft, kFullDomainSteps);
}

bool truncateToTolerance(openvdb::FloatGrid& grid, double tolerance)
{
    std::atomic<bool> changed{false};
    const float bg = grid.background();
    const float tol = float(tolerance);
    std::atomic<bool> emptied{false};
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(grid.tree());
    // Word by word over the value mask: most voxels stay on, so only the ones to switch off are
    // touched (the per-voxel iterator was the truncation's cost).
    leaves.foreach([bg, tol, &emptied, &changed](openvdb::FloatTree::LeafNodeType& leaf, size_t) {
        auto& mask = leaf.getValueMask();
        float* v = leaf.buffer().data();
        bool any = false;
        for (openvdb::Index w = 0; w < openvdb::FloatTree::LeafNodeType::NodeMaskType::WORD_COUNT; ++w) {
            uint64_t& word = mask.template getWord<uint64_t>(w);
            uint64_t bits = word, off = 0;
            while (bits) {
                const int b = __builtin_ctzll(bits);
                bits &= bits - 1;
                float& x = v[w * 64 + b];
                if (std::fabs(x - bg) <= tol) { x = bg; off |= uint64_t(1) << b; }
            }
            word &= ~off;
            any = any || word;
            if (off) changed = true;
        }
        if (!any) emptied = true;
    });
    if (emptied) openvdb::tools::pruneInactive(grid.tree());
    return changed;
}

} // namespace frostvdb
