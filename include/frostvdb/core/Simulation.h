#pragma once
/// @file Simulation.h
/// @brief The driver: builds the world and the effects a scene names (only those), runs the
/// steps in scene order, writes frames and previews, and summarises where the time went.
///
/// Core sections (all optional):
///   [scene]  name, seed, frames, steps_per_frame, description
///   [domain] kind, lattice, size, voxel_size, spacing
///   [region] tolerance, dense, front_travel
///   [output] vdb, preview, preview_grid, half_float, keep_lattice, displacement_png
///   [run]    memory_limit
/// Every other section must be a registered effect; the initialisation and step order come from
/// the effects' declarations (core/StepOrder.h), whatever the order of the sections.
#include <frostvdb/core/Checkpoint.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Effect.h>
#include <frostvdb/core/Scene.h>
#include <frostvdb/core/StepOrder.h>

#include <openvdb/io/Compression.h>

#include <memory>
#include <string>
#include <vector>

namespace frostvdb {

/// An allocation failed that no memory estimate foresaw (the driver turns std::bad_alloc inside an
/// effect into this, naming the section). A SceneError for callers that catch those.
class OutOfMemoryError : public SceneError {
public:
    using SceneError::SceneError;
};

/// The process exit status for a failure, one per class (README, docs/guide.md):
/// 2 bad input (SceneError, CheckpointError, VdbFileError: the scene, the command line, an input
/// file, a checkpoint that does not fit, an estimate over run.memory_limit), 3 the simulation left
/// its bounds (SimulationError), 4 a write failed (WriteError: frames, PNGs, run.json,
/// checkpoints), 5 the output folder is locked by another run (OutputBusyError), 6 out of memory
/// that no estimate foresaw (OutOfMemoryError, std::bad_alloc), 1 anything else (a bug).
/// A signal (SIGINT, SIGTERM, SIGHUP) ends the process with 128 + its number.
int exitCodeOf(const std::exception& e);

struct RunOptions {
    std::string outDir;      ///< "" -> out/<scene name>
    int threads = 0;         ///< 0: all cores
    bool progress = true;    ///< progress bar / log lines on stderr
    bool progressJson = false; ///< with progress: JSON lines on stderr instead (`--progress json`, core/Progress.h)
    bool writeFiles = true;  ///< false: simulate only (tests, benchmarks)
    int64_t firstFrame = 0;  ///< 0: from frame 1
    int64_t lastFrame = 0;   ///< 0: to the last frame
    bool overwrite = false;  ///< replace this scene's frames of another run in outDir (--overwrite)
    std::string commandLine; ///< recorded in run.json and every frame's metadata
    /// Checkpoints into outDir (`--checkpoint-every`); also one after the last frame of the run.
    CheckpointPolicy checkpoint;
    /// Continue from the checkpoint in this folder (`--resume`): frames after it are written.
    std::string resumeDir;
    /// Another run holds the output folder's lock on these frames (io/OutputLock.h): wait for it
    /// (`--wait-lock`) instead of refusing with OutputBusyError.
    bool waitLock = false;
};

struct OutputSettings {
    bool vdb = true;
    bool preview = true;
    bool previewEvery = false; ///< a PNG for every frame, not only the last
    std::string previewGrid; ///< "" -> first of ice, density, cells
    bool halfFloat = false;       ///< precision = "half": float grids stored as 16-bit halves
    /// OpenVDB stream compression flags (io/Compression.h) from `compression`: blosc (default) or
    /// zip with the active mask, or none.
    uint32_t compression = openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK;
    bool keepLattice = false;     ///< hexagonal domains: write the sheared grids, not square resamples
    bool displacementPng = true;  ///< flat domains with a `growth` grid: <name>.<frame>.displacement.png
    int displacementTile = 4096;  ///< larger rasters: UDIM tiles of this many pixels, only those with ice
};

struct RunSummary {
    std::string scene;
    /// run.json: "running" (written at the start), "failed", "complete", or "interrupted" (a signal)
    std::string status = "complete";
    std::string error;               ///< the failure, when status is "failed"
    std::string signal;              ///< "SIGTERM", ... when status is "interrupted"
    int exitCode = -1;               ///< the process's exit status when it is known (failed, interrupted)
    std::string commandLine;
    std::vector<std::string> overrides;  ///< --set (and --seed, --keep-lattice) as section.key=value
    std::string effectiveScene;          ///< the scene after overrides (TOML)
    std::string sceneHash;               ///< FNV-1a of effectiveScene: identifies "the same scene + overrides"
    int64_t firstFrame = 0, lastFrame = 0;
    std::string summaryFile = "run.json"; ///< run.json, or run.frames-A-B.json for a chunk of the range
    std::vector<std::string> effects;
    std::vector<std::string> fields;
    int64_t steps = 0;
    int64_t framesWritten = 0;
    double totalSeconds = 0, outputSeconds = 0;
    std::vector<std::pair<std::string, double>> effectSeconds;          ///< per effect step()
    /// The process's CPU seconds (all threads) in each effect's step() and in the output, for
    /// benchmarks: CPU / wall is how parallel a phase ran. Not in run.json.
    std::vector<std::pair<std::string, double>> effectCpuSeconds;
    double outputCpuSeconds = 0;
    std::vector<std::pair<std::string, double>> detailSeconds;          ///< effect sub-timings
    std::vector<std::pair<std::string, double>> detailCounts;           ///< effect counters (no unit)
    std::vector<std::pair<int64_t, uint64_t>> activeVoxels;             ///< (step, voxels) per frame
    uint64_t peakRssBytes = 0;
    std::vector<std::string> files;      ///< complete files only (each listed after its rename)
    int64_t resumedFromStep = -1; ///< -1: a fresh run
    int64_t checkpoints = 0;      ///< checkpoint files written
    std::string toJson() const;
    std::string toText() const;
};

/// What `frostvdb run --estimate` reports: the effects' memory estimates and a time measured on
/// a short probe of the first steps (nothing is written).
struct RunEstimate {
    std::vector<MemoryEstimate> memory; ///< one per effect (and the displacement raster), by key
    double memoryBytes = 0;             ///< their sum
    double memoryLimitBytes = 0;        ///< [run] memory_limit in bytes (0: none)
    int64_t steps = 0, frames = 0;      ///< what the run would do
    int64_t probeSteps = 0;             ///< steps simulated by the probe
    double probeSeconds = 0;            ///< their wall time (after initialisation)
    double initSeconds = 0;             ///< initialisation (band build, seeds, tables)
    double frameSeconds = 0;            ///< gathering one frame's grids (not writing them)
    double seconds = 0;                 ///< init + steps x probe rate + frames x frameSeconds
    uint64_t peakRssBytes = 0;          ///< measured during the probe
    std::string toText() const;
    std::string toJson() const;
};

class Simulation {
public:
    /// Validates the whole scene (every section and key) before anything runs; throws SceneError.
    explicit Simulation(Scene scene);
    ~Simulation();

    /// The world, its fields brought up to date first (Effect::publishFields: an effect may keep
    /// fields in its own layout between steps; the run loop itself writes them back only for
    /// frames and checkpoints).
    World& world()
    {
        publishFields();
        return mWorld;
    }
    /// Every effect's publishFields (after initialisation; nothing before).
    void publishFields();
    const std::vector<std::unique_ptr<Effect>>& effects() const { return mEffects; }
    const OutputSettings& output() const { return mOutput; }
    Effect* effect(const std::string& section) const;

    /// Initialises (once) and runs all frames, writing what the options ask.
    RunSummary run(const RunOptions& options);

    /// Estimates memory (the effects' own estimates) and time (by simulating the first steps for
    /// about @a probeSeconds of wall time and extrapolating linearly) without writing anything.
    /// The Simulation has stepped afterwards: use a fresh one for the run.
    RunEstimate estimate(const RunOptions& options, double probeSeconds = 1.5);

    /// Lower-level stepping for tests and benchmarks.
    void initialize();
    void step();
    int64_t stepsTaken() const { return mStep; }
    /// Initialisation and step order (indices into effects()), derived from the declarations.
    const EffectOrder& order() const { return mOrder; }
    /// Gathers the current frame's grids without writing (every grid made: none deferred).
    Frame currentFrame(int64_t frameNumber);
    /// Active voxels over all fields as they stand now: World's grids, and what effects that keep
    /// fields in their own layout would publish (Effect::countKeptFields), without publishing.
    uint64_t fieldActiveVoxels() const;
    /// Writes a frame file (+ metadata) and returns its path. Grids of a hexagonal domain are
    /// resampled to a square grid unless output.keep_lattice (core/Export.h).
    std::string writeFrame(const Frame& frame, const std::string& dir);
    /// The same, consuming the frame: each grid is released once exported, so a hexagonal
    /// domain's frame holds one resampled copy at a time beyond what is written.
    std::string writeFrame(Frame&& frame, const std::string& dir);
    /// Writes the frame's `growth` grid as a 16-bit PNG `<name>.<frame>.displacement.png`, or as
    /// UDIM tiles `<name>.<frame>.displacement.<udim>.png` beyond output.displacement_tile pixels
    /// (flat domains; none when there is nothing to write or output.displacement_png is off).
    std::vector<std::string> writeDisplacement(const Frame& frame, const std::string& dir);

    /// Saves the whole state (every field, the step counter, each effect's own state) atomically
    /// to @a path. Throws CheckpointError if an effect cannot save its history.
    void saveCheckpoint(const std::string& path);
    /// True when every effect can be checkpointed exactly now (Effect::atCheckpointBoundary).
    bool atCheckpointBoundary() const;
    /// Initialises, then restores a checkpoint written by the same scene and parameters (output
    /// settings and scene.frames may differ); the next step() continues from it bit for bit.
    void loadCheckpoint(const std::string& path);
    /// The parameters a checkpoint must match: every section but [output], without scene.frames
    /// and scene.description.
    std::string checkpointParameters();

private:
    // Pieces of run(), kept small so other drivers (checkpoint/resume) can reuse them.
    template <typename F>
    void atEffect(const Effect& e, const char* phase, F&& call);
    template <typename F>
    void atSection(const std::string& section, const char* phase, F&& call) const;
    void checkMemoryBudget() const;
    void refuseDisplacementTiling() const;
    void refuseOutputClashes(const std::vector<DeclaredEffect>& declared) const;
    void refuseChangedInputs(const std::string& saved, const std::string& checkpoint);
    /// Keeps what SIGINT/SIGTERM/SIGHUP would write into run.json up to date (io/AtomicFile.h).
    void updateSignalRecord(const std::string& dir, const RunSummary& sum) const;
    void checkFrameRange(int64_t first, int64_t last) const;
    RunSummary startSummary(const RunOptions& opt, int64_t first, int64_t last) const;
    void prepareOutputFolder(const std::string& dir, const RunOptions& opt, RunSummary& sum) const;
    void simulateFrames(int64_t first, int64_t last, const RunOptions& opt, const std::string& dir,
                        RunSummary& sum);
    static void returnFreePages();
    /// The frame as the run loop writes it: grids an effect deferred (Frame::addDeferred) are made
    /// only as the writer reaches them.
    Frame buildFrame(int64_t frameNumber);
    void writeFrameOutputs(int64_t f, int64_t last, const std::string& dir, RunSummary& sum);
    std::string writeFramePreview(const Frame& frame, int64_t f, const std::string& dir);
    void finishSummary(RunSummary& sum) const;
    std::string runSummaryName(const RunSummary& sum) const;
    void writeRunJson(const std::string& dir, const RunSummary& sum) const;
    struct CheckpointClock;
    void refuseUncheckpointable(const char* what) const;
    int64_t resumeForRun(const RunOptions& opt, const std::string& dir, int64_t first, int64_t last);
    void checkpointIfDue(const RunOptions& opt, const std::string& dir, CheckpointClock& clock, bool final,
                         RunSummary& sum);

    Scene mScene;
    std::string mCommandLine;
    World mWorld;
    OutputSettings mOutput;
    std::vector<std::unique_ptr<Effect>> mEffects;
    EffectOrder mOrder;                    ///< derived from the effects' declarations
    std::vector<double> mEffectSeconds;
    std::vector<double> mEffectCpuSeconds; ///< the process's CPU in each effect's step()
    int64_t mStep = 0;
    bool mInitialized = false;
};

/// The frame files (`<name>.<4+ digits>.<ext>`) in @a dir, sorted; @a sceneName "" matches any name.
std::vector<std::string> frameFilesIn(const std::string& dir, const std::string& sceneName = "");

/// Lists every key of every section with default, unit, range and description (Markdown).
std::string sceneReferenceMarkdown();

} // namespace frostvdb
