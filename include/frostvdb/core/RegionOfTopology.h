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

/// buildActiveRegion from folded plane fields (core/PlaneFold.h), returned folded: the region
/// the unfolded fields give, as plane::foldTopology makes it (a folded mask, 15x smaller than the
/// plane layout's, whose internal nodes use one z slab in 16). The leaf-level plane path reads
/// each folded leaf's 8 x 8 chunks as plane leaves and writes the marked ones into the folded
/// mask, clipped to the support, without a plane-layout copy of either; dense mode, a reach
/// beyond it or active tiles go through plane::unfoldTopology, the mask overload above and
/// foldTopology. @a previous (folded): returned itself when the region is unchanged.
/// @a edit (with @a previous, which nobody else may hold): the leaf-level path edits
/// @a previous into the new region, clearing the chunks of the plane leaves it lost and adding
/// the ones it gained (a tree built afresh costs its internal nodes and leaves every rebuild),
/// returns it, and lists both in @a edit; the tree is then node for node the one a fresh build
/// gives. Other paths return a new grid and leave @a edit empty.
openvdb::MaskGrid::Ptr buildActiveRegionOfFolded(const std::vector<const openvdb::FloatGrid*>& folded,
                                                 const RegionSettings& settings, int reach, const Domain& domain,
                                                 int steps = 1, const openvdb::MaskGrid::Ptr& previous = nullptr,
                                                 RegionEdit* edit = nullptr);

} // namespace frostvdb
