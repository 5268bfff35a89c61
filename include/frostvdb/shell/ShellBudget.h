#pragma once
/// @file ShellBudget.h
/// @brief What a shell's whole band costs, for the memory estimates of the effects that build it
/// whole ([region] dense = true, [dla], the potential flow): one estimate, so that two effects that
/// build the same band report the same allocation and the driver counts it once (core/Simulation.cpp).
#include <frostvdb/base/Budget.h>
#include <frostvdb/core/Domain.h>

namespace frostvdb::shell {

/// The surface nodes (or closest-point band voxels) the whole band would hold, in surface cells of
/// the generic orientation: mesh area / voxel_size^2, corrected for triangles that lie in a
/// lattice plane (an axis-aligned plate holds one node layer per cell, or two, where a tilted
/// surface holds 2 x kLayerReach = 1.41 on average). 0 when @a domain is not a shell.
double wholeBandCells(const Domain& domain);

/// The whole band and the arrays of the effects that step it, at the band's bytes per surface
/// cell (ShellBand::bytesPerSurfaceCell), under the key domain.voxel_size.
MemoryEstimate wholeBandEstimate(const Domain& domain);

} // namespace frostvdb::shell
