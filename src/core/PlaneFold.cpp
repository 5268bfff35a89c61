/// @file PlaneFold.cpp
/// @brief Folding and unfolding whole plane grids (core/PlaneFold.h): a permutation of leaf
/// values, leaf by leaf, so values and active states keep their bits.
#include <frostvdb/core/PlaneFold.h>

#include <stdexcept>

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
        if (fo.z() != 0) throw std::logic_error("unfoldGrid: a folded plane grid has a leaf off layer 0");
        const auto& fm = fl.getValueMask();
        for (int g = 0; g < 8; ++g) {
            bool any = false; // a plane leaf only where the folded chunk has an active voxel
            for (int dy = 0; dy < 8 && !any; ++dy)
                any = ((fm.template getWord<uint64_t>(openvdb::Index(dy)) >> (g * 8)) & 0xffu) != 0;
            if (!any) continue;
            LeafT* pl = dst.touchLeaf(openvdb::Coord((fo.y() + g) * 8, fo.x(), 0));
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

openvdb::MaskGrid::Ptr foldTopology(const openvdb::MaskGrid& planeRegion)
{
    using MaskLeaf = openvdb::MaskTree::LeafNodeType;
    auto out = openvdb::MaskGrid::create(false);
    out->setTransform(planeRegion.transform().copy());
    markFolded(*out);
    openvdb::tree::ValueAccessor<openvdb::MaskTree> acc(out->tree());
    for (auto it = planeRegion.tree().cbeginLeaf(); it; ++it) {
        const MaskLeaf& pl = *it;
        const openvdb::Coord lo = pl.origin();
        if (lo.z() != 0) throw std::logic_error("foldTopology: a plane region has a leaf off layer 0");
        // every plane leaf has its folded leaf, even an empty one (the kernel looks it up)
        auto& fm = acc.touchLeaf(foldedLeafOrigin(lo))->getValueMask();
        // plane word dx holds bit (dy << 3) of (dx, dy); the folded row dy takes it at bit (lo.x & 63) | dx
        const int g = lo.x() & 63;
        for (int dx = 0; dx < 8; ++dx) {
            const uint64_t w = pl.getValueMask().template getWord<uint64_t>(openvdb::Index(dx));
            for (int dy = 0; dy < 8; ++dy)
                if ((w >> (dy << 3)) & 1u) fm.template getWord<uint64_t>(openvdb::Index(dy)) |= uint64_t(1) << (g | dx);
        }
    }
    auto tiles = planeRegion.tree().cbeginValueOn();
    tiles.setMaxDepth(openvdb::MaskTree::ValueOnCIter::LEAF_DEPTH - 1);
    if (tiles) throw std::logic_error("foldTopology: a plane region with active tiles");
    return out;
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
        if (fo.z() != 0) throw std::logic_error("unfoldTopology: a folded plane grid has a leaf off layer 0");
        const auto& fm = it->getValueMask();
        for (int g = 0; g < 8; ++g) {
            uint64_t rows[8];
            bool any = false;
            for (int dy = 0; dy < 8; ++dy) {
                rows[dy] = (fm.template getWord<uint64_t>(openvdb::Index(dy)) >> (g * 8)) & 0xffu;
                any = any || rows[dy];
            }
            if (!any) continue; // a plane leaf only where the chunk has an active voxel (as unfoldGrid)
            auto& pm = acc.touchLeaf(openvdb::Coord((fo.y() + g) * 8, fo.x(), 0))->getValueMask();
            for (int dy = 0; dy < 8; ++dy)
                for (uint64_t b = rows[dy]; b; b &= b - 1)
                    pm.template getWord<uint64_t>(openvdb::Index(__builtin_ctzll(b))) |= uint64_t(1) << (dy << 3);
        }
    }
    return out;
}

template openvdb::MaskGrid::Ptr unfoldTopology<openvdb::FloatGrid>(const openvdb::FloatGrid&);

template openvdb::FloatGrid::Ptr unfoldGrid<openvdb::FloatGrid>(const openvdb::FloatGrid&);
template openvdb::Int32Grid::Ptr unfoldGrid<openvdb::Int32Grid>(const openvdb::Int32Grid&);
template openvdb::FloatGrid::Ptr foldGrid<openvdb::FloatGrid>(const openvdb::FloatGrid&);
template openvdb::Int32Grid::Ptr foldGrid<openvdb::Int32Grid>(const openvdb::Int32Grid&);

} // namespace plane
} // namespace frostvdb
