#pragma once
/// @file FieldKeys.h
/// @brief Every grid name frostvdb uses, typed: the fields effects share in World::fields, the
/// grids they write to files, and the shared state they hand each other. A name means one thing
/// in every file; docs/outputs.md is the reader's version of this header.
///
/// A key carries its name, value type, unit, background (far field) and meaning. Effects declare
/// which keys they initialise, read and write (Effect::declaration()); the driver derives the
/// initialisation and step order from those declarations and refuses a scene in which two effects
/// would write the same name with different meanings.
///
/// A key converts to its name, so `fields.get<FloatGrid>(ice::kPhase)` and
/// `fields.replace(ice::kPhase, g)` read as before; the typed overloads of FieldSet check the
/// value type at compile time.
#include <openvdb/openvdb.h>

#include <string>

namespace frostvdb {

enum class FieldType { Float, Vec3f, Int32, Points, State };

/// What kind of thing a key names.
enum class FieldRole {
    Field,  ///< a grid in World::fields (internal, shared by effects)
    Output, ///< a grid written to the frame files
    State,  ///< typed shared state in World (not a grid)
};

struct FieldKey {
    const char* name;
    FieldType type;
    FieldRole role;
    const char* unit;       ///< "" dimensionless
    const char* background; ///< the far-field value, as text ("0", "T_inf", "-1")
    const char* meaning;
    operator std::string() const { return name; }
};

/// A key whose grid type is known at compile time.
template <typename GridT>
struct GridKey : FieldKey {};

inline bool operator==(const FieldKey& a, const std::string& b) { return b == a.name; }
inline bool operator==(const std::string& a, const FieldKey& b) { return a == b.name; }
inline bool operator!=(const std::string& a, const FieldKey& b) { return !(a == b); }

// ---- the ice (hybrid method of Kim, Henson and Lin): fields ------------------------------------
namespace ice {
inline const GridKey<openvdb::FloatGrid> kPhase{{"p", FieldType::Float, FieldRole::Field, "", "0",
    "phase field: 0 water or vapour, 1 ice"}};
inline const GridKey<openvdb::FloatGrid> kTemperature{{"T", FieldType::Float, FieldRole::Field,
    "dimensionless (T_e = melt_temperature, default 1)", "T_inf (phase_field.far_temperature)",
    "temperature of the ice paper's heat equation, in its dimensionless units"}};
inline const GridKey<openvdb::FloatGrid> kGrowth{{"growth_acc", FieldType::Float, FieldRole::Field, "", "0",
    "accumulated positive dp (phase field and DLA): the displacement map before normalisation"}};
inline const GridKey<openvdb::FloatGrid> kFreezeTime{{"freeze_time", FieldType::Float, FieldRole::Field,
    "ice time (step x dt, dimensionless)", "0", "time at which p first exceeded 1/2 (0: not yet)"}};
inline const GridKey<openvdb::FloatGrid> kMelt{{"melt", FieldType::Float, FieldRole::Field, "", "1",
    "melt map in [0,1]: T_e scale of the phase field, sticking probability of DLA"}};
inline const GridKey<openvdb::Vec3SGrid> kVelocity{{"flow_vel", FieldType::Vec3f, FieldRole::Field,
    "m per unit of ice time", "(0, 0, 0)", "the ice flow ([fluid], paper 4.3): drifts walkers, advects T"}};
inline const GridKey<openvdb::Int32Grid> kDlaHits{{"dla_hits", FieldType::Int32, FieldRole::Field, "walkers", "0",
    "walkers stuck at a cell that has not yet frozen ([dla] hits > 1)"}};
inline const FieldKey kClock{"ice_clock", FieldType::State, FieldRole::State, "", "",
    "the ice clock (dt) and constants T_inf, K, T_e: set by [phase_field], else by [dla]"};
} // namespace ice

// ---- procedural gas -------------------------------------------------------------------------
namespace gas {
inline const GridKey<openvdb::FloatGrid> kDensity{{"density", FieldType::Float, FieldRole::Field, "", "0",
    "the frame's gas density (all gases summed), published for other effects (DLA steam humidity)"}};
inline const FieldKey kFlows{"gas_flows", FieldType::State, FieldRole::State, "", "",
    "the flow sections' functions ([attractor], [vortex], ...) that move every gas"};
} // namespace gas

// ---- shells: state shared by the effects on a shell domain -------------------------------------
namespace shell {
inline const FieldKey kSurfaceFields{"surface_fields", FieldType::State, FieldRole::State, "", "",
    "a shell's p, T, growth_acc and freeze_time in band order, kept by [phase_field] between steps (the grids "
    "are written back for frames and checkpoints); [dla] freezes into them"};
inline const FieldKey kSurfaceWind{"surface_wind", FieldType::State, FieldRole::State, "cells of h per unit ice time", "",
    "the tangential wind per band voxel of [phase_field] on a shell: the drift of [dla]'s walkers"};
} // namespace shell

// ---- output grids (names in the .vdb files) -------------------------------------------------
namespace out {
inline const FieldKey kIce{"ice", FieldType::Float, FieldRole::Output, "", "0",
    "hybrid ice as a fog volume: p clamped to [0,1]"};
inline const FieldKey kIceTemperature{"ice_temperature", FieldType::Float, FieldRole::Output,
    "dimensionless (T_e = melt_temperature)", "T_inf", "the ice paper's temperature T (not Kelvin)"};
inline const FieldKey kGrowth{"growth", FieldType::Float, FieldRole::Output, "", "0",
    "accumulated dp normalised to [0,1]: the paper's displacement map"};
inline const FieldKey kFreezeTime{"freeze_time", FieldType::Float, FieldRole::Output,
    "ice time (step x dt, dimensionless)", "0", "time at which p first exceeded 1/2"};
inline const FieldKey kFlowVel{"flow_vel", FieldType::Vec3f, FieldRole::Output, "m per unit of ice time", "(0, 0, 0)",
    "the ice flow ([fluid]); not a motion-blur velocity"};
inline const FieldKey kDensity{"density", FieldType::Float, FieldRole::Output, "", "0",
    "gas density as a fog volume (gases of a scene are summed)"};
inline const FieldKey kVel{"vel", FieldType::Vec3f, FieldRole::Output, "m/s", "(0, 0, 0)",
    "gas velocity, contravariant-relative (what renderers use for motion blur)"};
inline const FieldKey kFlame{"flame", FieldType::Float, FieldRole::Output, "", "0", "[fire] flame intensity in [0,1]"};
inline const FieldKey kTemperature{"temperature", FieldType::Float, FieldRole::Output, "K",
    "gas.ambient_temperature", "[fire] gas temperature in Kelvin"};
inline const FieldKey kColour{"Cd", FieldType::Vec3f, FieldRole::Output, "", "(0, 0, 0)", "[fire] emission colour"};
inline const FieldKey kCells{"cells", FieldType::Float, FieldRole::Output, "", "0",
    "automaton cell state on the hexagonal-prism lattice"};
inline const FieldKey kAutomatonIce{"automaton_ice", FieldType::Float, FieldRole::Output, "", "0",
    "automaton ice as a fog volume on the hexagonal-prism lattice (frozen cells 1)"};
inline const FieldKey kFreezeStep{"freeze_step", FieldType::Float, FieldRole::Output, "steps", "-1",
    "automaton step at which a cell froze (seed 0, never -1)"};
inline const FieldKey kVapour{"vapour", FieldType::Float, FieldRole::Output, "", "rho",
    "Gravner-Griffeath diffusive vapour mass on the automaton lattice"};
inline const FieldKey kIceSdf{"ice_sdf", FieldType::Float, FieldRole::Output, "m", "half band width",
    "level set of the effect's ice or aggregate (negative inside)"};
inline const FieldKey kAggregateIce{"aggregate_ice", FieldType::Float, FieldRole::Output, "", "0",
    "[dla3d] aggregate as a fog volume (1 inside the swept branches, smooth edge)"};
inline const FieldKey kPoints{"points", FieldType::Points, FieldRole::Output, "", "-",
    "[dla3d] particles as a PointDataGrid (radius, parent, generation, attach_time, id)"};
} // namespace out

} // namespace frostvdb
