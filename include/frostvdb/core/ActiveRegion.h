#pragma once
/// @file ActiveRegion.h
/// @brief The sparse active region of a PDE effect: the voxels where any of its fields differs
/// from the far field by more than the tolerance, dilated by the stencil reach plus the front's
/// travel for each step it must serve, clipped to the domain. In dense mode it is the whole
/// domain, so the same kernels give the dense reference answer.
///
/// Cadence: a region built for k steps is dilated by k (reach + front travel) cells. A voxel
/// farther than k reach from every non-background voxel stays exactly at the background for k
/// steps (each step reads at most reach cells away), so with tolerance 0 any k gives the dense
/// answer bit for bit; RegionCadence decides k and when a rebuild is due.
#include <frostvdb/core/Domain.h>
#include <frostvdb/core/Effect.h>

#include <openvdb/openvdb.h>

#include <vector>

namespace frostvdb {

/// Builds the region mask. @a reach is the stencil's dependency radius in cells (an update at a
/// voxel reads voxels at most this far away along lattice directions).
/// @a steps: how many steps the region must serve before the next rebuild (dilation
/// steps * (reach + front travel)). Where the support already fills the domain, no dilation.
/// On a plane the region is computed leaf by leaf (cost follows the fields' leaves). When it
/// has exactly the topology of @a previous, @a previous itself is returned.
openvdb::MaskGrid::Ptr buildActiveRegion(const std::vector<const openvdb::FloatGrid*>& fields,
                                         const RegionSettings& settings, int reach, const Domain& domain,
                                         int steps = 1, const openvdb::MaskGrid::Ptr& previous = nullptr);

/// Grows a standing region around cells written since it was built (walkers freezing cells):
/// adds every whole leaf, clipped to the domain's support, that meets the box of @a radius cells
/// around a cell (a box holds any lattice's reach of that many steps), as buildActiveRegion
/// would have included them had the cells held their values at the build. Leaves already in
/// the region are whole, so a cell inside one adds nothing. Cost: the cells, not the region.
/// Returns true when leaves were added. A folded @a region (core/PlaneFold.h) is grown folded.
bool growActiveRegion(openvdb::MaskGrid& region, const std::vector<openvdb::Coord>& cells, int radius,
                      const Domain& domain);

/// Gives @a grid exactly the topology of @a region, reusing the leaves it has: leaves outside the
/// region are deleted, missing ones added, value masks copied, and every voxel the region leaves
/// off holds the background (kernels read neighbours from the raw leaf buffers). Values of the
/// region's voxels are left as they are: the caller overwrites them. @a offHoldsBackground: the
/// grid's off voxels already hold the background (a grid this code or truncateToTolerance made),
/// so only voxels switched off are written.
void matchTopology(openvdb::FloatGrid& grid, const openvdb::MaskGrid& region, bool offHoldsBackground = false);

/// A 64-bit fingerprint of a grid's leaf origins, value masks and active values: an
/// order-independent sum of per-voxel hashes, so it does not depend on the thread count. Equal
/// fingerprints mean unchanged content (up to a 2^-64 chance of collision).
uint64_t gridFingerprint(const openvdb::FloatGrid& grid);

/// When a solver that keeps its region between steps must rebuild it.
class RegionCadence {
public:
    RegionCadence(const RegionSettings& settings, int reach) : mSettings(settings), mReach(reach) {}

    /// True when the last region has served all its steps.
    bool due() const { return mLeft <= 0; }
    /// Starts a region: returns k, the number of steps it must be built for. @a forced: the
    /// fields were changed by someone else since the last step (a rebuild out of turn).
    int begin(bool forced);
    /// The region just built covers the whole domain: nothing outside it can change, so it serves
    /// more steps (kFullDomainSteps in automatic mode; only truncation is then deferred).
    void filledDomain();
    /// One step taken on the current region; true when the next step rebuilds (truncate now).
    bool stepTaken() { return --mLeft <= 0; }
    /// Steps the current region still serves (checkpoints save and restore it).
    int stepsLeft() const { return mLeft; }
    void setStepsLeft(int left) { mLeft = left; }

    /// The automatic k: the widened dilation stays within one leaf (8 cells), the granularity at
    /// which the kernels pay; 1 while others write the fields (their writes force rebuilds).
    int automaticSteps(bool forced) const;
    static constexpr int kFullDomainSteps = 16;

private:
    RegionSettings mSettings;
    int mReach;
    int mLeft = 0;
};
/// Sets every active voxel whose |value - background| <= tolerance to the background, turns it
/// off, and prunes: what stays stored is what differs from the far field. Returns true when a
/// voxel was switched off (the topology changed).
bool truncateToTolerance(openvdb::FloatGrid& grid, double tolerance);

/// True when @a region holds every voxel of the domain.
bool regionFillsDomain(const openvdb::MaskGrid& region, const Domain& domain);

} // namespace frostvdb
