#pragma once
/// @file ActiveRegion.h
/// @brief The sparse active region of a PDE effect, recomputed every step: the voxels where any
/// of its fields differs from the far field by more than the tolerance, dilated by the stencil
/// reach plus the front's travel, clipped to the domain. In dense mode it is the whole domain,
/// so the same kernels give the dense reference answer.
#include <frostvdb/core/Domain.h>
#include <frostvdb/core/Effect.h>

#include <openvdb/openvdb.h>

#include <vector>

namespace frostvdb {

/// Builds the region mask. @a reach is the stencil's dependency radius in cells (an update at a
/// voxel reads voxels at most this far away along lattice directions).
openvdb::MaskGrid::Ptr buildActiveRegion(const std::vector<const openvdb::FloatGrid*>& fields,
                                         const RegionSettings& settings, int reach, const Domain& domain);

/// Sets every active voxel whose |value - background| <= tolerance to the background, turns it
/// off, and prunes: what stays stored is what differs from the far field.
void truncateToTolerance(openvdb::FloatGrid& grid, double tolerance);

} // namespace frostvdb
