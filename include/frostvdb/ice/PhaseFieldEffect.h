#pragma once
/// @file PhaseFieldEffect.h
/// @brief Section [phase_field]: the Kobayashi phase field (p, T) of the ice paper as an effect,
/// with either scheme of Kobayashi.h (forward Euler on eqs. 1-5, or the second-order lw_cn on eq. 8).
/// Writes the fields p, T, growth_acc, freeze_time and the output grids `ice` (fog volume,
/// p clamped to [0,1]), `ice_temperature`, `growth` (accumulated positive dp normalised to [0,1],
/// the paper's displacement map) and `freeze_time` (time p first exceeded 1/2).
#include <frostvdb/core/Effect.h>
#include <frostvdb/ice/PhaseFieldSolver.h>
#include <frostvdb/shell/ShellPhaseField.h>

#include <memory>

namespace frostvdb {

class PhaseFieldEffect : public Effect {
public:
    static std::unique_ptr<Effect> create(ParamDict& params, const World& world);

    std::string name() const override { return "phase_field"; }
    FieldDeclaration declaration() const override;
    void initialize(World& world) override;
    void step(World& world, const StepInfo& info) override;
    void addToFrame(World& world, Frame& frame) override;
    void publishFields(World& world) override;
    /// On a shell with frost_mesh set: writes the frost layer as OBJ/PLY beside the preview.
    bool writePreview(World& world, const Frame& frame, const std::string& pngPath) override;
    double time() const override { return mTime; }
    std::vector<std::pair<std::string, double>> timings() const override;
    std::vector<std::pair<std::string, double>> counters() const override;
    /// PhaseFieldSolver keeps about 21 float arrays over the active region: the whole domain in
    /// region.dense mode; the sparse region's size is not known before the run. On a shell: the
    /// band and the solver's arrays per surface cell when the band is built whole (dense, or
    /// [dla] built it), else nothing is known before the ice grows.
    MemoryEstimate memoryEstimate(const World& world) const override;
    bool supportsCheckpoint() const override { return true; }
    /// Checkpoints fall where the region cadence rebuilds (see PhaseFieldSolver::CadenceState).
    bool atCheckpointBoundary() const override;
    void saveState(const World& world, StateWriter& out) const override;
    void loadState(World& world, const StateReader& in) override;

    const KobayashiParams& params() const { return mParams; }

private:
    KobayashiParams mParams;
    double mTime = 0.0;
    double mStabilityLimit = 0.0;
    int mSubsteps = 1; ///< solver steps per scene step (substeps = auto above the limit)
    std::unique_ptr<PhaseFieldSolver> mSolver;
    PhaseFieldStepStats mStats;
    /// On a shell domain (a band around a mesh) the closest-point solver runs instead.
    std::unique_ptr<shell::ShellPhaseField> mShell;
    bool mOnShell = false;
    std::string mFrostMesh = "none"; ///< shells: none, obj or ply
    openvdb::Vec3d mWind{0, 0, 0};   ///< shells: prescribed wind advecting the heat
    bool mPotentialWind = false;     ///< shells: wind_model = "potential" (shell/ShellWind.h)
    /// The p and T grids scatterShell last wrote (held, so a new grid never reuses the address).
    openvdb::FloatGrid::Ptr mShellP, mShellT;
    shell::ShellStepStats mShellStats;
    void gatherShell(World& world);
    void printShellEstimate(const shell::ShellBand& band, const World& world) const;
    void scatterShell(World& world);
};

} // namespace frostvdb
