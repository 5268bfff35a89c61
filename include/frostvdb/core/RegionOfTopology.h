#pragma once
/// @file RegionOfTopology.h
/// @brief buildActiveRegion (core/ActiveRegion.h) from the fields' topologies alone: the active
/// voxels of masks instead of float fields, and from folded plane fields (core/PlaneFold.h).
#include <frostvdb/core/ActiveRegion.h>

namespace frostvdb {

openvdb::MaskGrid::Ptr buildActiveRegionOfTopology(const std::vector<const openvdb::MaskGrid*>& topologies,
                                                   const RegionSettings& settings, int reach, const Domain& domain,
                                                   int steps = 1, const openvdb::MaskGrid::Ptr& previous = nullptr);

/// buildActiveRegion from folded plane fields (core/PlaneFold.h): the same region (a plane-layout
/// mask) the unfolded fields give. The leaf-level plane path reads each folded leaf's 8 x 8
/// chunks as plane leaves (no unfolded copy); a reach beyond it or active tiles go through
/// plane::unfoldTopology and the mask overload above.
openvdb::MaskGrid::Ptr buildActiveRegionOfFolded(const std::vector<const openvdb::FloatGrid*>& folded,
                                                 const RegionSettings& settings, int reach, const Domain& domain,
                                                 int steps = 1, const openvdb::MaskGrid::Ptr& previous = nullptr);

} // namespace frostvdb
