/// @file PlaneFold.cpp
/// @brief Folding and unfolding whole plane grids (core/PlaneFold.h): a permutation of leaf
/// values, leaf by leaf, so values and active states keep their bits.
#include <frostvdb/core/PlaneFold.h>

#include <frostvdb/core/RemoveLeaves.h>

#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <stdexcept>
#include <string>

namespace frostvdb {
namespace plane {
namespace {

/// The source tree, with active tiles expanded when it has any (a copy then).
template <typename TreeT>
const TreeT& voxelTree(const TreeT& tree, typename TreeT::Ptr& hold)
{
    if (!tree.hasActiveTiles()) return tree;
    hold = std::make_shared<TreeT>(tree);
    hold->voxelizeActiveTiles();
    return *hold;
}

template <typename GridT>
typename GridT::Ptr emptyLike(const GridT& g, bool folded)
{
    auto out = openvdb::gridPtrCast<GridT>(g.copyGridWithNewTree());
    out->removeMeta(kFoldMeta);
    if (folded) markFolded(*out);
    return out;
}

} // namespace

template <typename GridT>
typename GridT::Ptr unfoldGrid(const GridT& folded)
{
    using TreeT = typename GridT::TreeType;
    using LeafT = typename TreeT::LeafNodeType;
    if (!isFolded(folded)) return folded.deepCopy();
    typename TreeT::Ptr hold;
    const TreeT& src = voxelTree(folded.tree(), hold);
    auto out = emptyLike(folded, false);
    TreeT& dst = out->tree();
    for (auto it = src.cbeginLeaf(); it; ++it) {
        const LeafT& fl = *it;
        const openvdb::Coord fo = fl.origin();
        if (!plane::isFoldedLeafOrigin(fo)) throw std::logic_error("unfoldGrid: a folded plane grid has a leaf off its layers");
        const auto& fm = fl.getValueMask();
        for (int g = 0; g < 8; ++g) {
            bool any = false; // a plane leaf only where the folded chunk has an active voxel
            for (int dy = 0; dy < 8 && !any; ++dy)
                any = ((fm.template getWord<uint64_t>(openvdb::Index(dy)) >> (g * 8)) & 0xffu) != 0;
            if (!any) continue;
            LeafT* pl = dst.touchLeaf(plane::planeLeafOfChunk(fo, g));
            for (int dy = 0; dy < 8; ++dy)
                for (int dx = 0; dx < 8; ++dx) {
                    const openvdb::Index s = openvdb::Index((dy << 6) | (g << 3) | dx);
                    const openvdb::Index n = openvdb::Index((dx << 6) | (dy << 3));
                    pl->setValueOnly(n, fl.getValue(s));
                    if (fm.isOn(s)) pl->setValueOn(n);
                }
        }
    }
    return out;
}

template <typename GridT>
typename GridT::Ptr foldGrid(const GridT& planeGrid)
{
    using TreeT = typename GridT::TreeType;
    using LeafT = typename TreeT::LeafNodeType;
    if (isFolded(planeGrid)) return planeGrid.deepCopy();
    typename TreeT::Ptr hold;
    const TreeT& src = voxelTree(planeGrid.tree(), hold);
    auto out = emptyLike(planeGrid, true);
    TreeT& dst = out->tree();
    for (auto it = src.cbeginLeaf(); it; ++it) {
        const LeafT& pl = *it;
        const openvdb::Coord lo = pl.origin();
        if (lo.z() != 0) throw std::logic_error("foldGrid: a plane grid has a leaf off layer 0");
        if (pl.isEmpty()) continue;
        LeafT* fl = dst.touchLeaf(foldedLeafOrigin(lo));
        for (int dx = 0; dx < 8; ++dx)
            for (int dy = 0; dy < 8; ++dy) {
                const openvdb::Index n = openvdb::Index((dx << 6) | (dy << 3));
                const openvdb::Index s = foldedOffset(lo, dx, dy);
                fl->setValueOnly(s, pl.getValue(n));
                if (pl.isValueOn(n)) fl->setValueOn(s);
            }
    }
    return out;
}

namespace {

using MaskLeaf = openvdb::MaskTree::LeafNodeType;

/// Sets the folded bits of plane leaf @a pl (layer 0) in its folded leaf's mask @a fm.
void foldLeafInto(const MaskLeaf& pl, openvdb::util::NodeMask<3>& fm)
{
    // plane word dx holds bit (dy << 3) of (dx, dy); the folded row dy takes it at bit (lo.x & 63) | dx
    const int g = pl.origin().x() & 63;
    // a region's plane leaves are whole leaves (all 64 cells of layer 0) but at the support's
    // edge: those fill their byte of every folded row at once
    constexpr uint64_t kLayer0 = 0x0101010101010101ull;
    bool whole = true;
    for (int dx = 0; dx < 8 && whole; ++dx)
        whole = (pl.getValueMask().template getWord<uint64_t>(openvdb::Index(dx)) & kLayer0) == kLayer0;
    if (whole) {
        for (int dy = 0; dy < 8; ++dy) fm.template getWord<uint64_t>(openvdb::Index(dy)) |= uint64_t(0xff) << g;
        return;
    }
    for (int dx = 0; dx < 8; ++dx) {
        const uint64_t w = pl.getValueMask().template getWord<uint64_t>(openvdb::Index(dx));
        for (int dy = 0; dy < 8; ++dy)
            if ((w >> (dy << 3)) & 1u) fm.template getWord<uint64_t>(openvdb::Index(dy)) |= uint64_t(1) << (g | dx);
    }
}

void requireLayer0(const openvdb::Coord& lo, const char* who)
{
    if (lo.z() != 0) throw std::logic_error(std::string(who) + ": a plane region has a leaf off layer 0");
}

} // namespace

openvdb::MaskGrid::Ptr foldTopology(const openvdb::MaskGrid& planeRegion)
{
    auto out = openvdb::MaskGrid::create(false);
    out->setTransform(planeRegion.transform().copy());
    markFolded(*out);
    openvdb::tree::ValueAccessor<openvdb::MaskTree> acc(out->tree());
    for (auto it = planeRegion.tree().cbeginLeaf(); it; ++it) {
        requireLayer0(it->origin(), "foldTopology");
        // every plane leaf has its folded leaf, even an empty one (the kernel looks it up)
        foldLeafInto(*it, acc.touchLeaf(foldedLeafOrigin(it->origin()))->getValueMask());
    }
    auto tiles = planeRegion.tree().cbeginValueOn();
    tiles.setMaxDepth(openvdb::MaskTree::ValueOnCIter::LEAF_DEPTH - 1);
    if (tiles) throw std::logic_error("foldTopology: a plane region with active tiles");
    return out;
}

void foldLeavesInto(openvdb::MaskTree& folded, const openvdb::MaskTree& planeLeaves)
{
    openvdb::tree::ValueAccessor<openvdb::MaskTree> acc(folded);
    for (auto it = planeLeaves.cbeginLeaf(); it; ++it) {
        requireLayer0(it->origin(), "foldLeavesInto");
        foldLeafInto(*it, acc.touchLeaf(foldedLeafOrigin(it->origin()))->getValueMask());
    }
}

void clearFoldedChunks(openvdb::MaskTree& folded, const std::vector<openvdb::Coord>& planeLeafOrigins)
{
    std::vector<openvdb::Coord> emptied; // folded leaves none of whose chunks has a cell left
    {
        openvdb::tree::ValueAccessor<openvdb::MaskTree> acc(folded);
        for (const openvdb::Coord& lo : planeLeafOrigins) {
            MaskLeaf* fl = acc.probeLeaf(foldedLeafOrigin(lo));
            if (!fl) continue;
            auto& mask = fl->getValueMask();
            const int g = lo.x() & 63;
            for (int dy = 0; dy < 8; ++dy) mask.template getWord<uint64_t>(openvdb::Index(dy)) &= ~(uint64_t(0xff) << g);
            if (mask.isOff()) emptied.push_back(fl->origin());
        }
    }
    std::sort(emptied.begin(), emptied.end());
    emptied.erase(std::unique(emptied.begin(), emptied.end()), emptied.end());
    removeLeaves(folded, emptied);
}

PlaneLeaves::PlaneLeaves(const openvdb::MaskGrid& foldedRegion, Order order)
{
    if (order == Order::Plane) { // the plane-layout tree's order: read from a transient copy of it
        const auto planeRegion = unfoldTopology(foldedRegion);
        mLeaves.reserve(planeRegion->tree().leafCount());
        for (auto it = planeRegion->tree().cbeginLeaf(); it; ++it) {
            uint64_t rows = 0;
            for (int x = 0; x < 8; ++x)
                rows |= (it->getValueMask().template getWord<uint64_t>(openvdb::Index(x)) & 0x0101010101010101ull) << x;
            mLeaves.push_back({it->origin(), rows});
        }
        return;
    }
    // folded leaf by folded leaf, chunk by chunk: counted, placed, then filled in parallel
    openvdb::tree::LeafManager<const openvdb::MaskTree> folded(foldedRegion.tree());
    std::vector<size_t> first(folded.leafCount() + 1, 0);
    for (size_t i = 0; i < folded.leafCount(); ++i) {
        if (!isFoldedLeafOrigin(folded.leaf(i).origin())) throw std::logic_error("PlaneLeaves: a folded region has a leaf off its layers");
        size_t chunks = 0;
        for (int g = 0; g < 8; ++g) chunks += chunkRows(folded.leaf(i).getValueMask(), g) != 0;
        first[i + 1] = first[i] + chunks;
    }
    mLeaves.resize(first.back());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, folded.leafCount(), 256), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i != r.end(); ++i) {
            PlaneLeafView* out = &mLeaves[first[i]];
            for (int g = 0; g < 8; ++g)
                if (const uint64_t rows = chunkRows(folded.leaf(i).getValueMask(), g))
                    *out++ = {planeLeafOfChunk(folded.leaf(i).origin(), g), rows};
        }
    });
}

template <typename GridT>
openvdb::MaskGrid::Ptr unfoldTopology(const GridT& folded)
{
    using TreeT = typename GridT::TreeType;
    typename TreeT::Ptr hold;
    const TreeT& src = voxelTree(folded.tree(), hold);
    auto out = openvdb::MaskGrid::create(false);
    out->setTransform(folded.transform().copy());
    openvdb::tree::ValueAccessor<openvdb::MaskTree> acc(out->tree());
    for (auto it = src.cbeginLeaf(); it; ++it) {
        const openvdb::Coord fo = it->origin();
        if (!plane::isFoldedLeafOrigin(fo)) throw std::logic_error("unfoldTopology: a folded plane grid has a leaf off its layers");
        const auto& fm = it->getValueMask();
        for (int g = 0; g < 8; ++g) {
            uint64_t rows[8];
            bool any = false;
            for (int dy = 0; dy < 8; ++dy) {
                rows[dy] = (fm.template getWord<uint64_t>(openvdb::Index(dy)) >> (g * 8)) & 0xffu;
                any = any || rows[dy];
            }
            if (!any) continue; // a plane leaf only where the chunk has an active voxel (as unfoldGrid)
            auto& pm = acc.touchLeaf(plane::planeLeafOfChunk(fo, g))->getValueMask();
            for (int dy = 0; dy < 8; ++dy)
                for (uint64_t b = rows[dy]; b; b &= b - 1)
                    pm.template getWord<uint64_t>(openvdb::Index(__builtin_ctzll(b))) |= uint64_t(1) << (dy << 3);
        }
    }
    return out;
}

namespace {

/// upgradeLegacyFold on one grid type: each leaf copied whole to its new origin.
template <typename GridT>
bool moveLegacyLeaves(openvdb::GridBase& base)
{
    auto* g = dynamic_cast<GridT*>(&base);
    if (!g) return false;
    using TreeT = typename GridT::TreeType;
    using LeafT = typename TreeT::LeafNodeType;
    typename TreeT::Ptr hold;
    const TreeT& src = voxelTree(g->tree(), hold);
    auto moved = std::make_shared<TreeT>(g->tree().background());
    for (auto it = src.cbeginLeaf(); it; ++it) {
        const openvdb::Coord fo = it->origin(); // the first fold: Coord(y, x >> 3, x & 7)
        if (fo.z() != 0) throw std::logic_error("upgradeLegacyFold: a folded plane grid has a leaf off layer 0");
        auto* leaf = new LeafT(*it);
        leaf->setOrigin(foldedLeafOrigin(openvdb::Coord(fo.y() * 8, fo.x(), 0)));
        moved->addLeaf(leaf);
    }
    g->setTree(moved);
    return true;
}

} // namespace

void upgradeLegacyFold(openvdb::GridBase& g)
{
    const auto legacy = g.getMetadata<openvdb::BoolMetadata>(kFoldMeta);
    if (!legacy) return;
    g.removeMeta(kFoldMeta);
    if (!legacy->value()) return;
    if (!moveLegacyLeaves<openvdb::FloatGrid>(g) && !moveLegacyLeaves<openvdb::Int32Grid>(g) &&
        !moveLegacyLeaves<openvdb::MaskGrid>(g))
        throw std::logic_error("upgradeLegacyFold: a folded grid of type " + g.type());
    markFolded(g);
}

template openvdb::MaskGrid::Ptr unfoldTopology<openvdb::FloatGrid>(const openvdb::FloatGrid&);
template openvdb::MaskGrid::Ptr unfoldTopology<openvdb::MaskGrid>(const openvdb::MaskGrid&);

template openvdb::FloatGrid::Ptr unfoldGrid<openvdb::FloatGrid>(const openvdb::FloatGrid&);
template openvdb::Int32Grid::Ptr unfoldGrid<openvdb::Int32Grid>(const openvdb::Int32Grid&);
template openvdb::FloatGrid::Ptr foldGrid<openvdb::FloatGrid>(const openvdb::FloatGrid&);
template openvdb::Int32Grid::Ptr foldGrid<openvdb::Int32Grid>(const openvdb::Int32Grid&);

} // namespace plane
} // namespace frostvdb
