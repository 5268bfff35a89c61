#pragma once
/// @file RegionOfTopology.h
/// @brief buildActiveRegion (core/ActiveRegion.h) from the fields' topologies alone: the active
/// voxels of masks instead of float fields. Folded plane fields (core/PlaneFold.h) give their
/// plane-layout topology (plane::unfoldTopology), from which the region is built as from the
/// unfolded fields.
#include <frostvdb/core/ActiveRegion.h>

namespace frostvdb {

openvdb::MaskGrid::Ptr buildActiveRegionOfTopology(const std::vector<const openvdb::MaskGrid*>& topologies,
                                                   const RegionSettings& settings, int reach, const Domain& domain,
                                                   int steps = 1, const openvdb::MaskGrid::Ptr& previous = nullptr);

} // namespace frostvdb
