#pragma once
/// @file GG3DEffect.h
/// @brief Section [gravner_griffeath_3d]: the Gravner-Griffeath 3D model (GG3D.h) with the
/// paper's named cases as presets, the guard-rail check, a memory estimate, and the grids it
/// writes: `cells` and `freeze_time` on the prism lattice, `ice` (fog on cubes), `ice_sdf`
/// (level set), optionally a mesh file.
#include <frostvdb/automata/GG3D.h>
#include <frostvdb/core/Effect.h>

#include <memory>
#include <string>
#include <vector>

namespace frostvdb {
namespace automata {

/// One published case (facts sheet table), with what it needs beyond the parameters.
struct GG3DPreset {
    std::string name;   ///< "fig14_classic_dendrite"
    std::string family; ///< "classic dendrite", "plate with ridges", ...
    GG3DParams p;
    int seedHeight = 1;
    std::vector<GG3DSwitch> switches;
};
const std::vector<GG3DPreset>& gg3dPresets();
const GG3DPreset* findGG3DPreset(const std::string& name);

/// The paper's guard rails, one message per violated inequality ("(1 - kappa_01) rho = 0.2 >=
/// beta_01 = 0.1: runaway Packard-like growth"); empty when all hold.
std::vector<std::string> gg3dGuardRails(const GG3DParams& p);

struct GG3DOutput {
    int voxelsPerCell = 3;     ///< `ice` voxels per cell spacing
    double prismHeight = 1.0;  ///< prism height in cell spacings
    bool sdf = true;           ///< write `ice_sdf`
    int sdfSmoothing = 1;      ///< smoothing passes of the level set
    std::string mesh = "none"; ///< "none" | "obj" | "ply"
    std::string meshPath;      ///< file name (frame number appended before the extension)
    double meshAdaptivity = 0.0;
    int batch = 1;
    double vary = 0.05;
};

/// The crystal's grids for one flake. @a h is the cell spacing in metres; @a scale multiplies it.
struct GG3DGrids {
    openvdb::FloatGrid::Ptr cells, freeze, ice, sdf;
};
GG3DGrids buildGG3DGrids(const GG3D& a, const GG3DOutput& out, double h);
/// Writes the zero level set of @a sdf as OBJ or PLY (by the path's extension).
void writeGG3DMesh(const openvdb::FloatGrid& sdf, const std::string& path, double adaptivity);

/// Sphere-traced, shaded picture of a level set seen obliquely from above (the gallery pictures).
void renderGG3DPreview(const openvdb::FloatGrid& sdf, const std::string& path, int width = 640);

class GG3DEffect : public Effect {
public:
    GG3DEffect(GG3DConfig cfg, GG3DOutput out, std::string preset);
    static std::unique_ptr<Effect> create(ParamDict& d, const World& world);

    std::string name() const override { return "gravner_griffeath_3d"; }
    FieldDeclaration declaration() const override;
    void initialize(World& world) override;
    void step(World& world, const StepInfo& info) override;
    void addToFrame(World& world, Frame& frame) override;
    bool writePreview(World& world, const Frame& frame, const std::string& pngPath) override;
    std::vector<std::pair<std::string, double>> timings() const override;
    /// The solvers' arrays of every flake (each box grown to the whole domain), against
    /// run.memory_limit as well as this section's own memory_budget.
    MemoryEstimate memoryEstimate(const World& world) const override;
    /// steps_grown: the most steps a flake took (a flake stops at stop_radius, so this is below
    /// the run's step count when it stopped early); flakes_stopped.
    std::vector<std::pair<std::string, double>> counters() const override;
    /// Checkpoints: each flake's counters and active-box arrays (GG3D::stateScalars, visitArrays).
    bool supportsCheckpoint() const override { return true; }
    void saveState(const World& world, StateWriter& out) const override;
    void loadState(World& world, const StateReader& in) override;

    const std::vector<std::unique_ptr<GG3D>>& flakes() const { return mFlakes; }
    /// Batch flake @a k's configuration (k = 0: @a base unchanged).
    static GG3DConfig flakeConfig(const GG3DConfig& base, double vary, int k);

private:
    GG3DConfig mCfg;
    GG3DOutput mOut;
    std::string mPreset;
    std::vector<std::unique_ptr<GG3D>> mFlakes;
    double mCellSize = 1e-6;
    double mStepSeconds = 0, mOutputSeconds = 0;
};

} // namespace automata
} // namespace frostvdb
