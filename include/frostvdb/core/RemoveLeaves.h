#pragma once
/// @file RemoveLeaves.h
/// @brief Removes leaves from a tree and the internal nodes left empty by it, so the tree has
/// the nodes a tree built afresh from its remaining leaves has (regions edited in place,
/// core/RegionOfTopology.h, stay node for node what a rebuild gives).
#include <openvdb/openvdb.h>

#include <type_traits>
#include <vector>

namespace frostvdb {

/// Deletes the leaves at @a origins (those present) from @a tree, then every internal node on
/// their paths that holds neither a child nor an active tile, and the root's background tiles.
template <typename TreeT>
void removeLeaves(TreeT& tree, const std::vector<openvdb::Coord>& origins)
{
    using RootT = typename TreeT::RootNodeType;
    using Upper = typename RootT::ChildNodeType;  // level 2
    using Lower = typename Upper::ChildNodeType;  // level 1
    using LeafT = typename TreeT::LeafNodeType;
    static_assert(std::is_same<typename Lower::ChildNodeType, LeafT>::value, "a three-level tree");
    if (origins.empty()) return;
    tree.clearAllAccessors();
    const auto bg = tree.background();
    auto empty = [](const auto* node) { return node && node->getChildMask().isOff() && node->getValueMask().isOff(); };
    for (const openvdb::Coord& o : origins) delete tree.template stealNode<LeafT>(o, bg, false);
    for (const openvdb::Coord& o : origins)
        if (empty(tree.template probeConstNode<Lower>(o))) delete tree.template stealNode<Lower>(o, bg, false);
    for (const openvdb::Coord& o : origins)
        if (empty(tree.template probeConstNode<Upper>(o))) delete tree.template stealNode<Upper>(o, bg, false);
    tree.root().eraseBackgroundTiles();
}

} // namespace frostvdb
