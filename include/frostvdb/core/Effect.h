#pragma once
/// @file Effect.h
/// @brief An effect is one scene section (`phase_field`, `dla`, `steam`, `automaton`, ...):
/// created from its parameters by a registered factory, it declares the fields it writes,
/// advances them one step at a time and contributes grids to each written frame.
///
/// Life cycle, driven by Simulation:
/// @code
///   auto fx = EffectRegistry::create("phase_field", params, world); // reads params only
///   fx->declaration();                     // its stage and the field keys it uses (FieldKeys.h)
///   fx->initialize(world);                 // allocates its fields, sets initial state
///   for each step: fx->step(world, info);  // in the order derived from the declarations
///   at each frame: fx->addToFrame(world, frame);
/// @endcode
/// The driver orders effects from their declarations (core/StepOrder.h): initialisation puts
/// the effects that initialise a field or state before those that read it then; steps follow
/// the paper's stages (walkers, phase field, obstacle copy, fluid, heat advection).
/// A factory must not allocate fields or do heavy work: `frostvdb keys` builds every effect with
/// empty parameters to list its keys.
#include <frostvdb/core/Budget.h>
///
/// Checkpoints (`run --checkpoint-every`, `--resume`): the driver saves every field of World and
/// the step counter itself; an effect saves only what it keeps beyond the fields (clocks, solver
/// buffers, private arrays). Resume runs initialize() as usual, puts the saved fields back, then
/// calls loadState(), so state derived from the parameters needs no saving.
#include <frostvdb/core/Domain.h>
#include <frostvdb/core/FieldKeys.h>
#include <frostvdb/core/Fields.h>
#include <frostvdb/core/Params.h>
#include <frostvdb/core/State.h>

#include <openvdb/openvdb.h>

#include <functional>
#include <map>
#include <memory>
#include <typeindex>
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
    double worldScale = 1.0; ///< output.world_scale: multiplies the world size of everything written
    double memoryLimitBytes = 0; ///< [run] memory_limit resolved (0: no limit); see core/Budget.h
    bool progress = false;       ///< the run reports progress on stderr (effects with long single steps may too)

    /// Typed state several effects share beyond grids (the ice clock ice::IceShared, the gas
    /// flows gas::FlowState), one object per type, created on first request. Declare it with
    /// its FieldKey (role State) so the driver orders the effects that set and read it.
    template <typename T>
    T& state()
    {
        auto& slot = mState[std::type_index(typeid(T))];
        if (!slot) slot = std::make_shared<T>();
        return *static_cast<T*>(slot.get());
    }
    template <typename T>
    bool hasState() const { return mState.count(std::type_index(typeid(T))) > 0; }

private:
    std::map<std::type_index, std::shared_ptr<void>> mState;
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
    /// Adds @a g named by its output key (core/FieldKeys.h, listed in docs/outputs.md), with
    /// @a suffix appended (one grid per flake: `cells_0`, ...). Every grid name comes from a key.
    void add(const FieldKey& key, openvdb::GridBase::Ptr g, const std::string& suffix = std::string())
    {
        g->setName(key.name + suffix);
        grids.push_back(std::move(g));
    }
    /// Adds @a g as it is named (a grid named from its key already, or a merged copy of one).
    void add(openvdb::GridBase::Ptr g) { grids.push_back(std::move(g)); }
    /// Adds @a g, a copy of a live field that @a again makes anew, named by @a key. The frame
    /// writer drops such a grid once the PNGs are drawn and makes it again just before writing it
    /// into the VDB, so a frame of a large domain holds one such copy at a time. A grid another
    /// effect replaced in `grids` is not the one made here and is kept as it is.
    void addCopy(const FieldKey& key, openvdb::GridBase::Ptr g, std::function<openvdb::GridBase::Ptr()> again)
    {
        const std::string name = key.name;
        g->setName(name);
        addCopy(std::move(g), [name, again = std::move(again)] {
            auto made = again();
            made->setName(name);
            return made;
        });
    }
    void addCopy(openvdb::GridBase::Ptr g, std::function<openvdb::GridBase::Ptr()> again)
    {
        remake.resize(grids.size());
        made.resize(grids.size(), nullptr);
        made.push_back(g.get());
        remake.push_back(std::move(again));
        grids.push_back(std::move(g));
    }
    /// Adds a float grid named by @a key that @a make builds from its effect's own state only when
    /// it is needed: the run loop's frame holds an empty placeholder of that name until the VDB
    /// writer (or a PNG that asks for it by name, makeNamed) makes it, so a frame being written
    /// holds one such grid at a time (a shell's outputs: docs/shells.md "Memory"). The effect's
    /// state must not change before then: the run loop writes a frame before the next step, and
    /// Simulation::currentFrame makes every deferred grid before it hands a frame out.
    void addDeferred(const FieldKey& key, std::function<openvdb::GridBase::Ptr()> make)
    {
        auto placeholder = openvdb::FloatGrid::create();
        addCopy(key, placeholder, std::move(make));
        deferred.resize(grids.size(), false);
        deferred.back() = true;
        held.resize(grids.size());
        held.back() = placeholder; // alive while the frame is: its address is never reused
    }
    /// Drops the grids addCopy made that can be made again (still the grids it made).
    void dropCopies()
    {
        for (size_t i = 0; i < remake.size(); ++i)
            if (remake[i] && grids[i] && grids[i].get() == made[i]) grids[i].reset();
    }
    /// Grid @a i, made again if dropCopies dropped it, or made for the first time if deferred.
    openvdb::GridBase::Ptr grid(size_t i)
    {
        if (i < deferred.size() && deferred[i]) {
            if (grids[i].get() == held[i].get()) grids[i].reset(); // else replaced by another effect, or dropped
            deferred[i] = false;
            made[i] = nullptr; // made once: kept through dropCopies
        }
        if (!grids[i] && i < remake.size() && remake[i]) grids[i] = remake[i]();
        return grids[i];
    }
    /// Makes the deferred grids named @a name (for a PNG that reads it).
    void makeNamed(const std::string& name)
    {
        for (size_t i = 0; i < grids.size(); ++i)
            if (grids[i] && grids[i]->getName() == name) grid(i);
    }
    /// Makes every deferred grid (a frame handed to a caller holds real grids only).
    void makeDeferred()
    {
        for (size_t i = 0; i < deferred.size(); ++i) grid(i);
    }

private:
    std::vector<std::function<openvdb::GridBase::Ptr()>> remake; ///< per grid; empty: not remakeable
    std::vector<const openvdb::GridBase*> made;                  ///< the grid addCopy made
    std::vector<bool> deferred;                                  ///< per grid: a placeholder until made
    std::vector<openvdb::GridBase::Ptr> held;                    ///< per deferred grid: its placeholder
};

/// Where an effect runs in a step: the ice paper's order (section 4), after the sources whose
/// fields the stages read (seeds and maps, gases, gas flows, automata).
enum class Stage { Sources = 0, Walkers = 1, PhaseField = 2, ObstacleCopy = 3, Fluid = 4, HeatAdvection = 5 };
const char* stageName(Stage s);

/// How an effect uses a key (bits).
enum FieldAccess : unsigned {
    kInitialises = 1, ///< initialize() creates or sets it (seeds, the ice clock, flows)
    kReadsAtInit = 2, ///< initialize() reads it (it runs after the key's initialisers)
    kReads = 4,       ///< step() reads it
    kWrites = 8,      ///< step() writes it
};

struct FieldUse {
    const FieldKey* key;
    unsigned access;
};

/// What an effect declares: its stage, the fields and state it uses, the grids it writes to frames.
struct FieldDeclaration {
    Stage stage = Stage::Sources;
    std::vector<FieldUse> uses;
    std::vector<const FieldKey*> outputs;
    FieldDeclaration& use(const FieldKey& k, unsigned access) { uses.push_back({&k, access}); return *this; }
    FieldDeclaration& output(const FieldKey& k) { outputs.push_back(&k); return *this; }
};

class Effect {
public:
    virtual ~Effect() = default;
    /// The scene section this effect was created from.
    virtual std::string name() const = 0;
    /// Its stage, the keys it initialises, reads and writes, and its output grids.
    virtual FieldDeclaration declaration() const = 0;
    /// Names of the fields this effect initialises or writes (from declaration()).
    std::vector<std::string> fieldsWritten() const;
    /// Allocates fields and sets the initial state.
    virtual void initialize(World& world) = 0;
    /// Advances one step.
    virtual void step(World& world, const StepInfo& info) = 0;
    /// Adds this effect's output grids to a frame.
    virtual void addToFrame(World& world, Frame& frame) = 0;
    /// Brings World's fields up to date before the driver reads them outside the step loop (a
    /// checkpoint, a caller of Simulation::world()). An effect that keeps fields in its own layout
    /// between steps (the phase field on a shell keeps them in band order) writes them back here;
    /// its addToFrame makes the frame's grids from its own state (frames do not publish: the
    /// published grids would be held beside the frame's). Default: nothing.
    virtual void publishFields(World& world) { (void)world; }
    /// The active voxels of the fields such an effect keeps in its own layout (what publishFields
    /// would write), by field name: the driver counts a frame's fields without publishing them.
    virtual void countKeptFields(std::map<std::string, uint64_t>& activeByField) const { (void)activeByField; }
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
    /// Named counts and other figures that are not seconds (iterations, rebuilds, a dt), printed
    /// without a unit and written to run.json's "detail_counts".
    virtual std::vector<std::pair<std::string, double>> counters() const { return {}; }

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
