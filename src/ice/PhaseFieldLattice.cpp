/// @file PhaseFieldLattice.cpp
/// @brief [phase_field] on a lattice domain (plane, box): the sparse VDB solver of
/// ice/PhaseFieldSolver.h stepping World's grids in place, its region cadence checkpointed.
#include <frostvdb/core/FieldEdits.h>
#include <frostvdb/core/FieldWriters.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/ice/PhaseFieldBackend.h>
#include <frostvdb/ice/PhaseFieldSolver.h>

namespace frostvdb {
namespace {

class LatticePhaseField final : public PhaseFieldBackend {
public:
    explicit LatticePhaseField(const PhaseFieldSetup& setup) : mSetup(setup) {}

    MemoryEstimate memoryEstimate(const World& world) const override
    {
        // measured on a dense 1024^2 plane (FROSTVDB_MEMORY_TRACE=1): 87 MiB after the first step
        // (p, T, growth_acc, freeze_time, the region and the solver's spare grids), 29 MiB more
        // for the frame's output copies: about 112 bytes per voxel (issue 25: 96 was 1.7x low).
        // A box fills its 8^3 leaves where a plane uses one layer of 8: a dense 160^3 box peaked
        // 61 MiB above the program's own memory for 4.1 M voxels, 15.6 bytes per voxel (112 was 7x).
        // Folded p and T (core/PlaneFold.h, session 13): the same dense 1024^2 plane peaked 71.5 MiB
        // above the program's own memory (Probe 25.2's plane_dense), about 60 bytes per voxel
        // (most of it the frame's plane-layout copies of p and T).
        if (!world.region.dense) return {};
        const double perVoxel = !world.domain.flat() ? 16.0 : foldsByDeclarations(world) ? kFoldedPlaneBytes : 112.0;
        return perVoxelEstimate(double(world.domain.bbox().volume()), perVoxel, "domain.size",
                                "dense phase-field fields, the solver's region and spare grids, a frame's copies");
    }

    /// What layOut will decide, from the scene's declarations (the walkers' edit lists are
    /// registered only when they initialise): a folding plane whose other writers of p and T are
    /// the walkers (they write both; the fluid writes T alone).
    static bool foldsByDeclarations(const World& world)
    {
        if (!plane::foldsPlaneFields(world.domain)) return false;
        if (!world.hasState<FieldWriters>()) return true;
        const FieldWriters& w = const_cast<World&>(world).state<FieldWriters>(); // reads only
        const int p = w.of(ice::kPhase.name), T = w.of(ice::kTemperature.name);
        return p == T && p <= 2;
    }
    static constexpr double kFoldedPlaneBytes = 60.0;

    void initialize(World& world) override
    {
        KobayashiParams solverParams = mSetup.params;
        solverParams.dt = mSetup.params.dt / mSetup.substeps;
        mSolver = std::make_unique<PhaseFieldSolver>(solverParams, world.domain, world.region);
        mDense = world.region.dense;
        if (world.hasState<FieldWriters>()) {
            const FieldWriters& w = world.state<FieldWriters>();
            mSolver->setSoleWriter(w.of(ice::kPhase.name) == 1 && w.of(ice::kTemperature.name) == 1);
        }
        // walkers that list the cells they freeze let the region stand between rebuilds (step())
        FieldEdits& edits = world.state<FieldEdits>();
        edits.listen(ice::kPhase.name);
        edits.listen(ice::kTemperature.name);
        edits.reportsCrossings(ice::kPhase.name, this); // the cells where p crosses 1/2 (walkers' distance map)
    }

    void step(World& world, int64_t step, double time) override
    {
        auto p = world.fields.get<openvdb::FloatGrid>(ice::kPhase);
        auto T = world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
        auto growth = world.fields.get<openvdb::FloatGrid>(ice::kGrowth);
        auto freeze = world.fields.get<openvdb::FloatGrid>(ice::kFreezeTime);
        mSolver->setMeltMap(world.fields.get<openvdb::FloatGrid>(ice::kMelt).get());
        useEditLogs(world);
        layOut(world, p, T);
        const double subDt = mSetup.params.dt / mSetup.substeps;
        for (int s = 0; s < mSetup.substeps; ++s) {
            // Substeps key the noise by their own index so that each draws fresh values.
            const int64_t index = step * mSetup.substeps + s;
            mSolver->step(p, T, growth.get(), freeze.get(), index, time + s * subDt, world.seed, &mStats);
        }
        world.fields.replace(ice::kPhase, p);
        world.fields.replace(ice::kTemperature, T);
        // A frame may be written now, and other effects add their copies to it before ours
        // (addToFrame): give the staging area back first (remade at the next step).
        if (world.stepsPerFrame > 0 && (step + 1) % world.stepsPerFrame == 0) mSolver->releaseScratch();
    }

    void addToFrame(World& world, Frame& frame) override
    {
        // A frame is about to be written: the solver's per-step scratch is given back for the
        // output's copies (remade at the next step; once per frame, not per step).
        mSolver->releaseScratch();
        ice::addIceOutputs(world, frame);
    }

    /// A sparse region is transient between two cadence rebuilds (edits grow it); a dense one is
    /// the whole domain at every step, so its saved cadence state is all there is and any step is
    /// a boundary: a checkpoint lands where it is due, after the last frame (issue 25, finding 12:
    /// it fell on the cadence's 16-step grid and a resume started at step 512, not 600).
    bool atCheckpointBoundary() const override { return mDense || mSolver->cadenceStepsLeft() <= 0; }

    // The scheme's history grids and the region cadence are ours; p, T, growth_acc and
    // freeze_time are World fields (saved by the driver).
    void saveState(const World& world, StateWriter& out) const override
    {
        for (auto& [name, grid] : mSolver->historyGrids()) out.putGrid(name, *grid);
        out.putDouble("last_step_dt", mSolver->lastStepDt());
        const auto cadence = mSolver->cadenceState(*world.fields.get<openvdb::FloatGrid>(ice::kPhase),
                                                   *world.fields.get<openvdb::FloatGrid>(ice::kTemperature));
        out.putGrid("region", cadence.region);
        out.putInt("region_steps_left", cadence.stepsLeft);
        out.putInt("region_inputs_truncated", cadence.inputsTruncated ? 1 : 0);
        out.putInt("region_inputs_ours", cadence.inputsOurs ? 1 : 0);
    }

    void loadState(World& world, const StateReader& in) override
    {
        for (auto& [name, grid] : mSolver->historyGrids()) *grid = in.getGrid<openvdb::FloatGrid>(name);
        mSolver->lastStepDt() = in.getDouble("last_step_dt");
        PhaseFieldSolver::CadenceState cadence;
        cadence.region = in.getGrid<openvdb::MaskGrid>("region");
        cadence.stepsLeft = int(in.getInt("region_steps_left"));
        cadence.inputsTruncated = in.getInt("region_inputs_truncated") != 0;
        cadence.inputsOurs = in.getInt("region_inputs_ours") != 0;
        mSolver->restoreCadence(cadence, *world.fields.get<openvdb::FloatGrid>(ice::kPhase),
                                *world.fields.get<openvdb::FloatGrid>(ice::kTemperature));
    }

    std::vector<std::pair<std::string, double>> timings() const override
    {
        std::vector<std::pair<std::string, double>> t{
            {"region", mStats.regionSeconds}, {"kernel", mStats.kernelSeconds}, {"truncate", mStats.truncateSeconds},
            {"region_build", mStats.regionBuildSeconds}, {"region_match", mStats.regionMatchSeconds},
            {"region_layout", mStats.regionLayoutSeconds}};
        if (secondOrder()) {
            t.push_back({"solve", mStats.solveSeconds});
            t.push_back({"heat", mStats.heatSeconds});
        }
        return t;
    }

    std::vector<std::pair<std::string, double>> counters() const override
    {
        std::vector<std::pair<std::string, double>> t{{"region_rebuilds", double(mStats.rebuilds)},
                                                      {"region_growths", double(mStats.regionGrowths)},
                                                      {"voxel_updates", double(mStats.voxelUpdates)},
                                                      {"region_mib", mSolver ? mSolver->regionBytes() / 1048576.0 : 0.0},
                                                      {"region_view_mib", mSolver ? mSolver->regionViewBytes() / 1048576.0 : 0.0},
                                                      {"staging_peak_mib", mStats.stagingPeakBytes / 1048576.0}};
        if (secondOrder()) {
            const double n = double(std::max<int64_t>(1, mStats.solves));
            t.push_back({"mean_iterations_p", mStats.solverIterationsP / n});
            t.push_back({"mean_iterations_T", mStats.solverIterationsT / n});
            t.push_back({"unconverged_solves", double(mStats.unconverged)});
            t.push_back({"clipped_voxels", double(mStats.clippedVoxels)});
        }
        return t;
    }

private:
    PhaseFieldSetup mSetup;
    std::unique_ptr<PhaseFieldSolver> mSolver;
    PhaseFieldStepStats mStats;
    bool mDense = false; ///< [region] dense: the region is the whole domain at every step

    bool secondOrder() const { return mSetup.params.scheme == PhaseFieldScheme::SecondOrder; }

    /// True when every other writer of p and T lists the cells it writes (the walkers, or none).
    static bool othersListTheirCells(World& world)
    {
        FieldEdits& edits = world.state<FieldEdits>();
        const FieldWriters* w = world.hasState<FieldWriters>() ? &world.state<FieldWriters>() : nullptr;
        auto listed = [&](const std::string& f) { return w && w->of(f) - 1 == edits.reporters(f); };
        return listed(ice::kPhase.name) && listed(ice::kTemperature.name);
    }

    /// p and T on a plane are folded (core/PlaneFold.h) when the domain folds its plane fields
    /// and the only other writers are the walkers (fold-aware): the fluid's heat advection, which
    /// writes T in the plane layout, keeps the plane layout. Fields in the other layout (seeded
    /// at initialisation, an older checkpoint) are converted here, a permutation of their values;
    /// so are lw_cn's start values of the last step.
    void layOut(World& world, openvdb::FloatGrid::Ptr& p, openvdb::FloatGrid::Ptr& T)
    {
        const bool fold = plane::foldsPlaneFields(world.domain) && othersListTheirCells(world);
        for (const auto& history : mSolver->historyGrids()) {
            openvdb::FloatGrid::Ptr& g = *history.second;
            if (g && plane::isFolded(*g) != fold) g = fold ? plane::foldGrid(*g) : plane::unfoldGrid(*g);
        }
        if (plane::isFolded(*p) == fold && plane::isFolded(*T) == fold) return;
        const auto oldP = p, oldT = T;
        for (auto* g : {&p, &T})
            if (plane::isFolded(**g) != fold) *g = fold ? plane::foldGrid(**g) : plane::unfoldGrid(**g);
        mSolver->adoptRelaidFields(*oldP, *oldT, *p, *T);
    }

    /// Trusts the walkers' edit lists only when every other writer of p and T fills them.
    void useEditLogs(World& world)
    {
        FieldEdits& edits = world.state<FieldEdits>();
        const bool all = othersListTheirCells(world);
        mSolver->setEditLogs(all ? &edits.cells(ice::kPhase.name) : nullptr,
                             all ? &edits.cells(ice::kTemperature.name) : nullptr);
        mSolver->setCrossingLog(edits.crossingSink(ice::kPhase.name));
    }
};

PhaseFieldBackendFactory readLatticeKeys(ParamDict&, PhaseFieldSetup& setup, const World&, bool)
{
    return [&setup] { return std::make_unique<LatticePhaseField>(setup); };
}

} // namespace

FROSTVDB_REGISTER_PHASE_FIELD_BACKEND(lattice, {"lattice"}, readLatticeKeys);

} // namespace frostvdb
