#pragma once
/// @file ShellWind.h
/// @brief Wind over a shell's object (issue 11 item 5): a uniform free stream projected on each
/// tangent plane, or the potential flow around the closed mesh (OpenVDB tools::PotentialFlow:
/// the solid is the band's signed offset, flood-filled), sampled at each band voxel's closest
/// point and projected on its tangent plane. The result advects the shell's heat and drifts its
/// walkers.
#include <frostvdb/shell/ShellBand.h>

#include <openvdb/openvdb.h>

#include <vector>

namespace frostvdb::shell {

/// The tangential wind per band voxel (cells of h per unit ice time), shared by [phase_field]
/// (heat advection) and [dla] (walker drift) on a shell. Empty: no wind.
struct ShellWindState {
    std::vector<openvdb::Vec3f> tangential;
};

/// @a wind projected on each band voxel's tangent plane.
std::vector<openvdb::Vec3f> uniformWind(const ShellBand& band, const openvdb::Vec3d& wind);

struct PotentialFlowStats {
    double solveSeconds = 0;
    int iterations = 0;
    double absoluteError = 0;
    size_t domainVoxels = 0;
};

/// The potential flow past the band's (closed) object with free stream @a freeStream, sampled at
/// each band voxel's closest point (the flow's voxels just outside the surface, trilinear) and
/// projected on its tangent plane. @a padding: voxels of fluid around the object (the flow
/// domain, whose outer boundary holds the free stream; 0: the object's half size). @a full (optional) receives the
/// flow's 3D velocity (grad Phi) 1.5 flow voxels off the surface, per band voxel (for checks).
std::vector<openvdb::Vec3f> potentialFlowWind(const ShellBand& band, const openvdb::Vec3d& freeStream, int padding,
                                              PotentialFlowStats* stats = nullptr,
                                              std::vector<openvdb::Vec3f>* full = nullptr);

} // namespace frostvdb::shell
