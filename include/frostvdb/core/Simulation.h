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
/// Every other section must be a registered effect; the initialisation and step order come from
/// the effects' declarations (core/StepOrder.h), whatever the order of the sections.
#include <frostvdb/core/Effect.h>
#include <frostvdb/core/Scene.h>
#include <frostvdb/core/StepOrder.h>

#include <memory>
#include <string>
#include <vector>

namespace frostvdb {

struct RunOptions {
    std::string outDir;      ///< "" -> out/<scene name>
    int threads = 0;         ///< 0: all cores
    bool progress = true;    ///< progress bar / log lines on stderr
    bool writeFiles = true;  ///< false: simulate only (tests, benchmarks)
    int64_t firstFrame = 0;  ///< 0: from frame 1
    int64_t lastFrame = 0;   ///< 0: to the last frame
};

struct OutputSettings {
    bool vdb = true;
    bool preview = true;
    bool previewEvery = false; ///< a PNG for every frame, not only the last
    std::string previewGrid; ///< "" -> first of ice, density, cells
    bool halfFloat = false;
    bool keepLattice = false;     ///< hexagonal domains: write the sheared grids, not square resamples
    bool displacementPng = true;  ///< flat domains with a `growth` grid: <name>.<frame>.displacement.png
};

struct RunSummary {
    std::string scene;
    std::vector<std::string> effects;
    std::vector<std::string> fields;
    int64_t steps = 0;
    int64_t framesWritten = 0;
    double totalSeconds = 0, outputSeconds = 0;
    std::vector<std::pair<std::string, double>> effectSeconds;          ///< per effect step()
    std::vector<std::pair<std::string, double>> detailSeconds;          ///< effect sub-timings
    std::vector<std::pair<int64_t, uint64_t>> activeVoxels;             ///< (step, voxels) per frame
    uint64_t peakRssBytes = 0;
    std::vector<std::string> files;
    std::string toJson() const;
    std::string toText() const;
};

class Simulation {
public:
    /// Validates the whole scene (every section and key) before anything runs; throws SceneError.
    explicit Simulation(Scene scene);
    ~Simulation();

    World& world() { return mWorld; }
    const std::vector<std::unique_ptr<Effect>>& effects() const { return mEffects; }
    const OutputSettings& output() const { return mOutput; }
    Effect* effect(const std::string& section) const;

    /// Initialises (once) and runs all frames, writing what the options ask.
    RunSummary run(const RunOptions& options);

    /// Lower-level stepping for tests and benchmarks.
    void initialize();
    void step();
    int64_t stepsTaken() const { return mStep; }
    /// Initialisation and step order (indices into effects()), derived from the declarations.
    const EffectOrder& order() const { return mOrder; }
    /// Gathers the current frame's grids without writing.
    Frame currentFrame(int64_t frameNumber);
    /// Writes a frame file (+ metadata) and returns its path. Grids of a hexagonal domain are
    /// resampled to a square grid unless output.keep_lattice (io/Export.h).
    std::string writeFrame(const Frame& frame, const std::string& dir);
    /// Writes the frame's `growth` grid as a 16-bit PNG `<name>.<frame>.displacement.png` (flat
    /// domains; "" when there is nothing to write or output.displacement_png is off).
    std::string writeDisplacement(const Frame& frame, const std::string& dir);

private:
    Scene mScene;
    World mWorld;
    OutputSettings mOutput;
    std::vector<std::unique_ptr<Effect>> mEffects;
    EffectOrder mOrder;                    ///< derived from the effects' declarations
    std::vector<std::string> mWrittenFields; ///< fields some effect writes: the domain's post-step hook sees them
    std::vector<double> mEffectSeconds;
    int64_t mStep = 0;
    bool mInitialized = false;
};

/// Lists every key of every section with default, unit, range and description (Markdown).
std::string sceneReferenceMarkdown();

} // namespace frostvdb
