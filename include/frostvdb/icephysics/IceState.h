#pragma once
/// @file IceState.h
/// @brief What the ice effects ([crystal], [dla], [phase_field], [fluid]) share: the field
/// names, the ice clock and the output grids. Each effect is a scene section of its own, so a
/// scene names exactly the parts of the hybrid algorithm it wants (DLA only, phase field only,
/// or both), and they meet only here and in World::fields.
///
/// Fields (all on the domain's transform; the background is the far field):
///   p            FloatGrid, phase: 0 water/vapour, 1 ice                      (background 0)
///   T            FloatGrid, temperature                                  (background T_inf)
///   growth_acc   FloatGrid, accumulated positive dp (PF and DLA), the displacement map
///   freeze_time  FloatGrid, time at which p first exceeded 1/2
///   melt         FloatGrid in [0,1], melt map = DLA sticking probability      (background 1)
///   flow_vel     Vec3SGrid, flow velocity in world units per unit time (written by [fluid])
///   dla_hits     Int32Grid, walkers stuck at a cell that has not yet frozen ([dla], n > 1)
#include <frostvdb/core/Effect.h>

#include <openvdb/openvdb.h>

namespace frostvdb {
namespace ice {

// The field keys (kPhase, kTemperature, kGrowth, kFreezeTime, kMelt, kVelocity, kDlaHits, kClock)
// are in core/FieldKeys.h with their units and meanings.

/// The ice clock and the constants the ice effects share. [phase_field] sets dt, T_inf and K
/// when it is created; without it [dla] sets dt from its own key. Time is step * dt.
struct IceShared {
    double dt = 0.0002;
    bool dtOwnedByPhaseField = false;
    double farTemperature = 0.0; ///< T_inf
    double latentHeat = 1.5;     ///< K (DLA releases L = K/6 by default, eq. 6)
    double meltTemperature = 1.0;
    bool temperatureEvolves = false; ///< true when [phase_field] runs (T is a live field)
    double timeAtStep(int64_t step) const { return double(step) * dt; }
};

inline IceShared& shared(World& world) { return world.state<IceShared>(); } ///< key ice::kClock

/// Allocates p, T, growth_acc and freeze_time if missing. If p did not exist yet (no [crystal]
/// section) and @a defaultCrystal, seeds it with the default crystal: a disc (ball in a box) of
/// radius 3 cells at the domain centre, round in the lattice's own geometry.
void requireIceFields(World& world, bool defaultCrystal = true);

/// Sets p = 1 on a disc/ball of @a radius cells around @a centreFraction (fractions of the
/// domain size; a missing z means 0.5). Used by the default crystal and [crystal] points.
void stampDisc(World& world, openvdb::FloatGrid& p, const std::vector<double>& centreFraction, double radius);

/// Records a phase change at @a c from @a before to @a after at @a time: growth_acc gains the
/// positive part and freeze_time is set when p crosses 1/2. For effects changing p outside a
/// solver kernel (DLA sticking, user edits).
void recordPhaseChange(openvdb::FloatGrid::Accessor& growth, openvdb::FloatGrid::Accessor& freeze,
                       const openvdb::Coord& c, float before, float after, double time);

/// Adds the ice output grids to @a frame: `ice` (fog volume, p clamped to [0,1]), `ice_temperature`,
/// `growth` (growth_acc normalised to [0,1], the paper's displacement map), `freeze_time`.
/// Idempotent: every ice effect calls it, the first call of a frame writes the grids.
void addIceOutputs(World& world, Frame& frame);
/// The same without `ice`, for a domain that writes its own (a shell's frost layer): computing
/// the fog of p only to replace it cost a band-sized grid at every frame.
void addIceFieldOutputs(World& world, Frame& frame);
/// The `growth` output in place: the accumulated growth @a acc scaled to a maximum of 1 (plane
/// layout), named by its output key.
void normaliseGrowth(openvdb::FloatGrid& acc);

} // namespace ice
} // namespace frostvdb
