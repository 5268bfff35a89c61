#pragma once
/// @file Effect.h
/// @brief An effect is one scene section (`phase_field`, `dla`, `steam`, `automaton`, ...):
/// created from its parameters by a registered factory, it declares the fields it writes,
/// advances them one step at a time and contributes grids to each written frame.
///
/// Life cycle, driven by Simulation:
/// @code
///   auto fx = EffectRegistry::create("phase_field", params, world); // reads params only
///   fx->initialize(world);                 // allocates its fields, sets initial state
///   for each step: fx->step(world, info);  // the paper's step order is the scene's order
///   at each frame: fx->addToFrame(world, frame);
/// @endcode
/// A factory must not allocate fields or do heavy work: `frostvdb keys` builds every effect with
/// empty parameters to list its keys.
#include <frostvdb/core/Budget.h>
///
/// Checkpoints (`run --checkpoint-every`, `--resume`): the driver saves every field of World and
/// the step counter itself; an effect saves only what it keeps beyond the fields (clocks, solver
/// buffers, private arrays). Resume runs initialize() as usual, puts the saved fields back, then
/// calls loadState(), so state derived from the parameters needs no saving.
#include <frostvdb/core/Domain.h>
#include <frostvdb/core/Fields.h>
#include <frostvdb/core/Params.h>
#include <frostvdb/core/State.h>

#include <openvdb/openvdb.h>

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace frostvdb {

/// The sparse active region's settings (section [region]).
struct RegionSettings {
    double tolerance = 1e-6; ///< |v - far field| above this keeps a voxel active
    bool dense = false;      ///< reference mode: the whole domain is active every step
    int frontTravel = 1;     ///< extra dilation (cells) for the front's travel in one step
    int rebuildEvery = 0;    ///< steps between region rebuilds (and truncations); 0: automatic
};

/// Everything a run shares: the domain, its fields and the run-wide settings.
struct World {
    std::string sceneName;
    std::string sceneLabel; ///< scene file path or a description
    std::string sceneText;
    uint64_t seed = 1;
    int64_t frames = 1;
    int64_t stepsPerFrame = 1;
    Domain domain;
    FieldSet fields;
    RegionSettings region;
    double memoryLimitBytes = 0; ///< [run] memory_limit resolved (0: no limit); see core/Budget.h

    /// State several effects share beyond grids (e.g. the ice clock in ice/IceState.h), created
    /// on first request and keyed by name. T must be default-constructible.
    template <typename T>
    T& shared(const std::string& key)
    {
        auto& slot = mShared[key];
        if (!slot) slot = std::make_shared<T>();
        return *static_cast<T*>(slot.get());
    }
    bool hasShared(const std::string& key) const { return mShared.count(key) > 0; }

private:
    std::map<std::string, std::shared_ptr<void>> mShared;
};

struct StepInfo {
    int64_t step = 0;  ///< 0-based index of the step being taken
    int64_t frame = 1; ///< 1-based frame this step belongs to
};

/// The grids and metadata of one output frame.
struct Frame {
    int64_t frame = 1;
    int64_t step = 0;   ///< steps taken so far
    double time = 0.0;  ///< simulation time of the first effect with a clock
    openvdb::GridPtrVec grids;
    void add(openvdb::GridBase::Ptr g) { grids.push_back(std::move(g)); }
};

class Effect {
public:
    virtual ~Effect() = default;
    /// The scene section this effect was created from.
    virtual std::string name() const = 0;
    /// Names of the fields this effect writes (for the run summary).
    virtual std::vector<std::string> fieldsWritten() const = 0;
    /// Allocates fields and sets the initial state.
    virtual void initialize(World& world) = 0;
    /// Effects are initialised by increasing order, then in scene order; steps always run in
    /// scene order. Providers of state others read at initialisation use lower numbers: the
    /// [crystal] seeds and maps 0, [phase_field] (owner of the ice clock and T_inf) 1.
    virtual int initializationOrder() const { return 2; }
    /// Advances one step.
    virtual void step(World& world, const StepInfo& info) = 0;
    /// Adds this effect's output grids to a frame.
    virtual void addToFrame(World& world, Frame& frame) = 0;
    /// False for effects whose frame N is a pure function of N (procedural gas): the driver may
    /// then skip the steps of frames that are not written.
    virtual bool needsHistory() const { return true; }
    /// The simulation time this effect has reached (0 for effects without a clock).
    virtual double time() const { return 0.0; }
    /// Writes a PNG preview of the frame; return false to let the driver draw the default one.
    virtual bool writePreview(World& world, const Frame& frame, const std::string& pngPath)
    { return false; }
    /// The memory the effect will allocate for this world, estimated from the scene keys alone
    /// (called after every effect is created, before any is initialised); the driver refuses
    /// the run when it exceeds the budget. Effects whose size depends on other effects' state
    /// also check at the point of allocation (checkMemoryEstimate with world.memoryLimitBytes).
    virtual MemoryEstimate memoryEstimate(const World& world) const { return {}; }
    /// Named sub-timings (seconds) for the run summary, e.g. {"kernel", 1.2}.
    virtual std::vector<std::pair<std::string, double>> timings() const { return {}; }

    /// True when saveState/loadState capture everything this effect carries from step to step
    /// beyond World's fields. Default: only effects without history (their frames are pure
    /// functions of the frame number). The driver refuses --checkpoint-every/--resume otherwise.
    virtual bool supportsCheckpoint() const { return !needsHistory(); }
    /// Saves the effect's own state (keys are scoped to its section). Default: nothing for effects
    /// without history; refuses (CheckpointError) for effects with history.
    virtual void saveState(const World& world, StateWriter& out) const;
    /// Restores what saveState wrote; called after initialize() and after World's fields are back.
    virtual void loadState(World& world, const StateReader& in);
    /// False while the effect holds transient state that saveState does not capture (the phase
    /// field's region between two cadence rebuilds): the driver then defers a due checkpoint to
    /// the next step where every effect is at a boundary.
    virtual bool atCheckpointBoundary() const { return true; }
};

using EffectFactory = std::function<std::unique_ptr<Effect>(ParamDict&, const World&)>;

struct EffectInfo {
    std::string section;
    std::string summary;
    EffectFactory create;
};

class EffectRegistry {
public:
    static void add(EffectInfo info);
    static const EffectInfo* find(const std::string& section);
    static std::vector<const EffectInfo*> all(); ///< sorted by section name
};

struct EffectRegistrar {
    EffectRegistrar(const std::string& section, const std::string& summary, EffectFactory f)
    { EffectRegistry::add({section, summary, std::move(f)}); }
};

} // namespace frostvdb

/// Registers an effect class with a static `create(ParamDict&, const World&)` under a section.
#define FROSTVDB_REGISTER_EFFECT(CLASS, SECTION, SUMMARY)                                       \
    static ::frostvdb::EffectRegistrar frostvdbEffectRegistrar_##CLASS(                          \
        SECTION, SUMMARY,                                                                       \
        [](::frostvdb::ParamDict& p, const ::frostvdb::World& w) { return CLASS::create(p, w); })
