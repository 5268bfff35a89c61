#pragma once
/// @file RegionOfTopology.h
/// @brief buildActiveRegion (core/ActiveRegion.h) from the fields' topologies alone: the active
/// voxels of masks instead of float fields, and from folded plane fields (core/PlaneFold.h).
#include <frostvdb/core/ActiveRegion.h>

namespace frostvdb {

openvdb::MaskGrid::Ptr buildActiveRegionOfTopology(const std::vector<const openvdb::MaskGrid*>& topologies,
                                                   const RegionSettings& settings, int reach, const Domain& domain,
                                                   int steps = 1, const openvdb::MaskGrid::Ptr& previous = nullptr);

/// The plane leaves (origins) a region edited in place lost and gained.
struct RegionEdit {
    std::vector<openvdb::Coord> removed, added;
    bool empty() const { return removed.empty() && added.empty(); }
};

/// buildActiveRegion from folded plane fields (core/PlaneFold.h): the same region (a plane-layout
/// mask) the unfolded fields give. The leaf-level plane path reads each folded leaf's 8 x 8
/// chunks as plane leaves (no unfolded copy); a reach beyond it or active tiles go through
/// plane::unfoldTopology and the mask overload above.
/// @a edit (with @a previous, which nobody else may hold): the leaf-level path edits
/// @a previous into the new region, removing and adding only the leaves that changed (a tree
/// built afresh costs its internal nodes and leaves every rebuild), returns it, and lists the
/// changes in @a edit; the tree is then node for node the one a fresh build gives. Other paths
/// return a new grid and leave @a edit empty.
openvdb::MaskGrid::Ptr buildActiveRegionOfFolded(const std::vector<const openvdb::FloatGrid*>& folded,
                                                 const RegionSettings& settings, int reach, const Domain& domain,
                                                 int steps = 1, const openvdb::MaskGrid::Ptr& previous = nullptr,
                                                 RegionEdit* edit = nullptr);

} // namespace frostvdb
