#pragma once
/// @file PhaseFieldEffect.h
/// @brief Section [phase_field]: the Kobayashi phase field (p, T) of the ice paper as an effect,
/// with either scheme of Kobayashi.h (forward Euler on eqs. 1-5, or the second-order lw_cn on eq. 8).
/// Writes the fields p, T, growth_acc, freeze_time and the output grids `ice` (fog volume,
/// p clamped to [0,1]), `ice_temperature`, `growth` (accumulated positive dp normalised to [0,1],
/// the paper's displacement map) and `freeze_time` (time p first exceeded 1/2).
/// The effect reads the physics; the discretisation is the back end the domain asks for
/// (ice/PhaseFieldBackend.h): the VDB lattice solver on planes and boxes, surface nodes or the
/// closest-point band on shells.
#include <frostvdb/core/Effect.h>
#include <frostvdb/ice/PhaseFieldBackend.h>

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
    void countKeptFields(std::map<std::string, uint64_t>& activeByField) const override;
    /// On a shell with frost_mesh set: writes the frost layer as OBJ/PLY beside the preview.
    bool writePreview(World& world, const Frame& frame, const std::string& pngPath) override;
    double time() const override { return mTime; }
    std::vector<std::pair<std::string, double>> timings() const override;
    std::vector<std::pair<std::string, double>> counters() const override;
    /// The back end's: on a lattice about 21 float arrays over the active region (the whole
    /// domain in region.dense mode; the sparse region's size is not known before the run); on a
    /// shell the band and the solver's arrays per surface cell when the band is built whole
    /// (dense, or [dla] built it), else nothing is known before the ice grows.
    MemoryEstimate memoryEstimate(const World& world) const override;
    bool supportsCheckpoint() const override { return true; }
    /// On a lattice, checkpoints fall where the region cadence rebuilds (PhaseFieldSolver::CadenceState).
    bool atCheckpointBoundary() const override;
    void saveState(const World& world, StateWriter& out) const override;
    void loadState(World& world, const StateReader& in) override;

    const KobayashiParams& params() const { return mParams; }

private:
    KobayashiParams mParams;
    double mTime = 0.0;
    double mStabilityLimit = 0.0;
    int mSubsteps = 1; ///< solver steps per scene step (substeps = auto above the limit)
    std::unique_ptr<PhaseFieldBackend> mBackend;
};

} // namespace frostvdb
