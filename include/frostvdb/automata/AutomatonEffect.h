#pragma once
/// @file AutomatonEffect.h
/// @brief The snowflake automata as scene effects, one section per rule:
///   [packard] [coxe_reiter] [probabilistic_ca] [reiter] [gravner_griffeath] [gravner_griffeath_3d]
/// Each writes per frame `cells` (one voxel per hexagonal cell, axial index (q, r) centred on the
/// flake, sheared transform of core/Lattice.h; prisms (q, r, layer) for the 3D model), `ice` (fog
/// volume on a cubic voxel grid: hexagonal-prism plates, or the true 3D crystal) and `freeze_time`
/// (step at which each cell froze), and draws its PNG preview on hexagons in the Coxe-Reiter
/// colours. `batch = K` grows K distinct flakes at once (see docs/automata.md).
#include <frostvdb/automata/Automata.h>
#include <frostvdb/core/Effect.h>

#include <memory>
#include <string>
#include <vector>

namespace frostvdb {
namespace automata {

struct OutputOptions {
    std::string thickness = "age"; ///< "age" | "value" | "uniform"
    double plateThickness = 1.5;   ///< full plate thickness in cell spacings
    double plateMin = 0.25;        ///< thinnest plate as a fraction of plateThickness
    double ageSteps = 0;           ///< age (steps) of full thickness; 0: the steps run so far
    int voxelsPerCell = 2;         ///< `ice` voxels per cell spacing
    double prismHeight = 1.0;      ///< 3D: prism height in cell spacings
    int batch = 1;                 ///< number of distinct flakes
    double vary = 0.05;            ///< relative parameter jitter of flakes 1..K-1
    int seedRadius = 3;            ///< radius of the random symmetric seeds of flakes 1..K-1
    bool writeVapour = false;      ///< GG: also write the vapour field `vapour`
    /// Coxe-Reiter sweeps: flake k uses sweepBackground[k] (and sweepBackground2[k],
    /// sweepSeedCells[k]) exactly, instead of random variations. Non-empty sets batch.
    std::vector<double> sweepBackground, sweepBackground2, sweepSeedCells;
};

class AutomatonEffect : public Effect {
public:
    AutomatonEffect(std::string section, AutomatonConfig cfg, OutputOptions out);

    std::string name() const override { return mSection; }
    FieldDeclaration declaration() const override;
    void initialize(World& world) override;
    void step(World& world, const StepInfo& info) override;
    void addToFrame(World& world, Frame& frame) override;
    bool writePreview(World& world, const Frame& frame, const std::string& pngPath) override;
    std::vector<std::pair<std::string, double>> timings() const override;
    /// frozen_cells: cells frozen over all flakes at the last step.
    std::vector<std::pair<std::string, double>> counters() const override;
    /// batch flakes x (lattice cells + the output grids of one flake, whose `ice` voxel count
    /// grows with voxels_per_cell^2 (3D: ^3)).
    MemoryEstimate memoryEstimate(const World& world) const override;
    bool supportsCheckpoint() const override { return true; }
    /// Every flake's state through HexAutomaton::visitState (generic over the rules' arrays).
    void saveState(const World& world, StateWriter& out) const override;
    void loadState(World& world, const StateReader& in) override;

    /// The flakes (after initialize); flake 0 uses the scene's parameters unchanged.
    const std::vector<std::unique_ptr<HexAutomaton>>& flakes() const { return mFlakes; }
    const OutputOptions& output() const { return mOut; }

    /// The configuration of batch flake @a k (k = 0 returns @a base unchanged).
    static AutomatonConfig flakeConfig(const AutomatonConfig& base, const OutputOptions& out, int k);

protected:
    std::string mSection;
    AutomatonConfig mCfg;
    OutputOptions mOut;
    std::vector<std::unique_ptr<HexAutomaton>> mFlakes;
    double mCellSize = 1e-4;
    double mStepSeconds = 0, mOutputSeconds = 0;
};

} // namespace automata
} // namespace frostvdb
