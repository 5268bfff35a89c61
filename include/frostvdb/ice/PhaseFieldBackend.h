#pragma once
/// @file PhaseFieldBackend.h
/// @brief The discretisation [phase_field] runs on, chosen by the domain. The effect reads the
/// physics keys (KobayashiParams, substeps) and asks the registry for the back end registered
/// under `Domain::discretisation()`; it never asks which kind the domain is. Built in:
/// - `"lattice"` (planes and boxes: the sparse VDB solver, ice/PhaseFieldSolver.h), in
///   src/ice/PhaseFieldLattice.cpp;
/// - `"surface"` and `"closest_point"` (shells: surface nodes or the closest-point band,
///   shell/ShellPhaseField.h), in src/shell/ShellPhaseFieldBackend.cpp.
/// A domain with a new discretisation registers its back end in its own folder:
/// @code
///   FROSTVDB_REGISTER_PHASE_FIELD_BACKEND(mine, {"my_discretisation"}, readMyKeys);
/// @endcode
#include <frostvdb/core/Effect.h>
#include <frostvdb/icephysics/Kobayashi.h>

#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace frostvdb {

/// What the effect read before the back end: the physics and the step split.
struct PhaseFieldSetup {
    KobayashiParams params; ///< params.dt is the scene step; the solver steps dt / substeps
    int substeps = 1;
    double stabilityLimit = 0.0;
};

/// One discretisation of the phase field. The effect forwards its Effect calls here.
class PhaseFieldBackend {
public:
    virtual ~PhaseFieldBackend() = default;
    /// True when the domain seeds the ice itself (a shell's vertex colours or seed texture): no
    /// default crystal is stamped then.
    virtual bool seedsItself(const World& world) const { (void)world; return false; }
    /// What the back end adds to the effect's declaration (state keys, output grids).
    virtual void declare(FieldDeclaration& d) const { (void)d; }
    virtual void initialize(World& world) = 0;
    /// One scene step (all its substeps) from time @a time; @a step: the scene step index.
    virtual void step(World& world, int64_t step, double time) = 0;
    virtual void publishFields(World& world) { (void)world; }
    virtual void countKeptFields(std::map<std::string, uint64_t>& activeByField) const { (void)activeByField; }
    /// The effect's output grids: ice::addIceOutputs and the back end's own.
    virtual void addToFrame(World& world, Frame& frame) = 0;
    virtual bool writePreview(World& world, const Frame& frame, const std::string& pngPath)
    { (void)world; (void)frame; (void)pngPath; return false; }
    virtual MemoryEstimate memoryEstimate(const World& world) const = 0;
    virtual bool atCheckpointBoundary() const { return true; }
    virtual void saveState(const World& world, StateWriter& out) const = 0;
    virtual void loadState(World& world, const StateReader& in) = 0;
    virtual std::vector<std::pair<std::string, double>> timings() const = 0;
    virtual std::vector<std::pair<std::string, double>> counters() const = 0;
};

using PhaseFieldBackendFactory = std::function<std::unique_ptr<PhaseFieldBackend>()>;

/// Reads a back end's own keys. Called for every registered back end, so `frostvdb keys` lists
/// them all: @a applies is false when the scene's domain uses another back end (its keys are then
/// refused when set, with ParamDict::onlyWhen). Returns the factory (used only when @a applies).
/// @a setup may be adjusted (a back end that needs a particular solver says so here).
using PhaseFieldKeyReader =
    std::function<PhaseFieldBackendFactory(ParamDict& d, PhaseFieldSetup& setup, const World& world, bool applies)>;

struct PhaseFieldBackendInfo {
    std::string id;
    std::vector<std::string> discretisations; ///< the Domain::discretisation() values it serves
    PhaseFieldKeyReader read;
};

class PhaseFieldBackends {
public:
    static void add(PhaseFieldBackendInfo info);
    static std::vector<const PhaseFieldBackendInfo*> all(); ///< sorted by id
};

struct PhaseFieldBackendRegistrar {
    explicit PhaseFieldBackendRegistrar(PhaseFieldBackendInfo info) { PhaseFieldBackends::add(std::move(info)); }
};

} // namespace frostvdb

#define FROSTVDB_REGISTER_PHASE_FIELD_BACKEND(ID, DISCRETISATIONS, READER) \
    static ::frostvdb::PhaseFieldBackendRegistrar frostvdbPhaseFieldBackend_##ID({#ID, DISCRETISATIONS, READER})
