#pragma once
/// @file Branches.h
/// @brief From an aggregate to geometry: per-particle branch radii that taper from the root to
/// the tips, the `PointDataGrid` of the particles, and the `ice_sdf` level set of the
/// sphere-swept branches (each particle joined to its parent by a cone-capped capsule whose
/// radius goes from the parent's to the particle's).
///
/// The capsules are rasterised directly (exact distance to a segment with linearly varying
/// radius, min over capsules): unlike tools::ParticlesToLevelSet it keeps branches thinner than
/// 1.5 voxels (they come out at least about a voxel thick instead of being dropped) and the
/// result is bit-identical whatever the thread count (min is order-independent).
#include <openvdb/openvdb.h>
#include <openvdb/points/PointDataGrid.h>

#include <functional>
#include <vector>

namespace frostvdb::dla3d {

struct BranchStyle {
    double tipRadius = 0.01;   ///< radius at the tips (metres)
    double taper = 0.4;        ///< radius = tip x (particles carried by the branch)^taper
    double maxScale = 4.0;     ///< cap on radius / tip radius (the trunk)
};

/// Radius of each particle's branch: tip x min(maxScale, subtree size^taper). Parents must
/// precede their children (attachment order).
std::vector<float> branchRadii(const std::vector<int32_t>& parents, const BranchStyle& style);

/// Points with attributes radius (float), parent (int32), generation (int32), attach_time (float).
openvdb::points::PointDataGrid::Ptr makePointGrid(const std::vector<openvdb::Vec3d>& positions,
                                                  const std::vector<float>& radii,
                                                  const std::vector<int32_t>& parents,
                                                  const std::vector<int32_t>& generations,
                                                  const std::vector<float>& attachTimes, double voxelSize);

/// Narrow-band level set (half width @a halfWidth voxels) of the union of the branch capsules.
/// @a progress, when given, is called from the calling thread after each of about 100 chunks of
/// particles with (particles done, particles); the result does not depend on it.
openvdb::FloatGrid::Ptr rasterizeBranches(const std::vector<openvdb::Vec3d>& positions,
                                          const std::vector<int32_t>& parents, const std::vector<float>& radii,
                                          double voxelSize, double halfWidth = 3.0,
                                          const std::function<void(size_t, size_t)>& progress = {});

/// The voxels rasterizeBranches visits (each capsule's index box, summed: its work, and an upper
/// bound of the voxels it stores), counted in O(particles) without touching a voxel.
double branchVoxelVisits(const std::vector<openvdb::Vec3d>& positions, const std::vector<int32_t>& parents,
                         const std::vector<float>& radii, double voxelSize, double halfWidth = 3.0);

/// The 8^3 leaves rasterizeBranches allocates, counted before a voxel is written: each capsule's
/// leaves tested by their 4^3 blocks against the capsule's reach (half width included), so a
/// block's corner voxel counts too (a slight over-count, never an under-count). It is what the
/// level set holds before its interior is pruned, the rasterisation's peak.
size_t branchLeafCount(const std::vector<openvdb::Vec3d>& positions, const std::vector<int32_t>& parents,
                       const std::vector<float>& radii, double voxelSize, double halfWidth = 3.0);

/// Bytes of one allocated leaf of a float tree (its node, its 512 values and the allocator's
/// bookkeeping): the level set's memory per branchLeafCount.
double floatLeafBytes();

} // namespace frostvdb::dla3d
