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

template openvdb::FloatGrid::Ptr unfoldGrid<openvdb::FloatGrid>(const openvdb::FloatGrid&);
template openvdb::Int32Grid::Ptr unfoldGrid<openvdb::Int32Grid>(const openvdb::Int32Grid&);
template openvdb::FloatGrid::Ptr foldGrid<openvdb::FloatGrid>(const openvdb::FloatGrid&);
template openvdb::Int32Grid::Ptr foldGrid<openvdb::Int32Grid>(const openvdb::Int32Grid&);

} // namespace plane
} // namespace frostvdb
