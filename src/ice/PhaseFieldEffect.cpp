#include <frostvdb/ice/PhaseFieldEffect.h>
#include <frostvdb/core/FieldEdits.h>
#include <frostvdb/core/FieldWriters.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/ice/IceState.h>
#include <frostvdb/shell/ShellDomain.h>
#include <frostvdb/io/Mesh.h>
#include <frostvdb/shell/ShellGrids.h>
#include <frostvdb/shell/ShellTexture.h>
#include <frostvdb/shell/ShellWind.h>

#include <openvdb/tools/Prune.h>
#include <openvdb/tools/ValueTransformer.h>

#include <cmath>
#include <cstdio>
#include <thread>
#include <sstream>

namespace frostvdb {

FROSTVDB_REGISTER_EFFECT(PhaseFieldEffect, "phase_field",
                         "Kobayashi phase field (ice paper eqs. 1-5): kinetics-limited growth in an undercooled melt.");

std::unique_ptr<Effect> PhaseFieldEffect::create(ParamDict& d, const World& world)
{
    auto fx = std::make_unique<PhaseFieldEffect>();
    KobayashiParams& k = fx->mParams;
    const std::string scheme =
        d.getString("scheme", "euler", {"euler", "lw_cn"},
                    "time integration: euler (full eqs. 1-5, forward Euler) or lw_cn (simplified eq. 8: "
                    "advection and diffusion in a Crank-Nicolson average, implicit solve, second order; the paper's section 5)");
    k.scheme = scheme == "euler" ? PhaseFieldScheme::Euler : PhaseFieldScheme::SecondOrder;
    const bool euler = k.scheme == PhaseFieldScheme::Euler;
    // a shell's 7-point stencil (centre weight 6 / h^2) puts lw_cn's limit at h^2 / 3 = 0.00073
    const bool onShell = bool(shell::bandOf(world.domain));
    k.dt = d.getFloat("dt", euler ? 0.0002 : (onShell ? 0.0007 : 0.0008), 1e-8, 0.1, "",
                      "time step (dimensionless; the paper uses 0.0002 for euler and 0.0008 for lw_cn, the defaults; "
                      "lw_cn on shell domains: 0.0007, below its 3D stability limit)");
    const std::string precision = d.getString(
        "precision", "wp", {"wp", "rp", "custom"},
        "lw_cn: solve the implicit systems to working precision (residual 1e-8), reduced precision (5e-3, the "
        "paper's RP) or solver_tolerance");
    const double customTol = d.getFloat("solver_tolerance", 1e-6, 1e-14, 1.0, "",
                                        "lw_cn with precision = custom: max-norm residual of the implicit solves");
    k.solverTolerance = precision == "wp" ? 1e-8 : precision == "rp" ? 5e-3 : customTol;
    k.solverMaxIterations = int(d.getInt("max_iterations", 500, 1, 100000, "",
                                         "lw_cn: iteration cap of the implicit solves (a run reports unconverged solves)"));
    k.useBiCGSTAB = d.getString("solver", "gauss_seidel", {"gauss_seidel", "bicgstab"},
                                "lw_cn: multi-colour Gauss-Seidel (red-black; 3 colours on hexagonal) or Eigen "
                                "BiCGSTAB on the same system") == "bicgstab";
    const std::string eulerOpt = "scheme = \"euler\"";
    d.onlyWhen(k.scheme != PhaseFieldScheme::Euler, "precision", eulerOpt);
    d.onlyWhen(k.scheme != PhaseFieldScheme::Euler, "solver_tolerance", eulerOpt);
    d.onlyWhen(precision == "custom", "solver_tolerance", "precision = \"" + precision + "\"");
    d.onlyWhen(k.scheme != PhaseFieldScheme::Euler, "max_iterations", eulerOpt);
    d.onlyWhen(k.scheme != PhaseFieldScheme::Euler, "solver", eulerOpt);
    const std::string substeps =
        d.getString("substeps", "none", {"none", "auto"},
                    "none: a dt above the stability limit is refused; auto: each step is split into equal "
                    "substeps below the limit");
    k.tau = d.getFloat("tau", 0.0003, 1e-6, 10.0, "", "relaxation time tau");
    k.epsBar = d.getFloat("epsilon", 0.01, 1e-5, 1.0, "", "mean interface width eps_bar");
    k.delta = d.getFloat("delta", 0.1, 0.0, 0.5, "", "strength of anisotropy (critical value 1/(j^2-1))");
    k.anisotropyMode = d.getFloat("anisotropy_mode", 6.0, 0.0, 12.0, "",
                                  "j: number of preferred growth directions (4 square arms, 6 snowflake arms)");
    k.theta0 = d.getFloat("theta0", M_PI / 2.0, -2.0 * M_PI, 2.0 * M_PI, "rad", "orientation of the arms theta0");
    k.alpha = d.getFloat("alpha", 0.9, 0.0, 0.999, "", "alpha in m(T) = alpha/pi atan(gamma (T_e - T)), < 1");
    k.gamma = d.getFloat("gamma", 10.0, 0.0, 100.0, "", "gamma in m(T)");
    k.meltTemperature = d.getFloat("melt_temperature", 1.0, -10.0, 10.0, "", "equilibrium (melt) temperature T_e");
    k.latentHeat = d.getFloat("latent_heat", 1.5, 0.0, 5.0, "", "dimensionless latent heat K");
    k.farTemperature = d.getFloat("far_temperature", 0.0, -10.0, 10.0, "",
                                  "initial and far-field temperature T_inf (undercooling is T_e - T_inf)");
    k.noise = d.getFloat("noise", 0.0, 0.0, 0.1, "", "amplitude a of Kobayashi's interface noise (0: none)");
    fx->mOnShell = bool(shell::bandOf(world.domain));
    fx->mFrostMesh = d.getString("frost_mesh", "none", {"none", "obj", "ply"},
        "shell domains: also write the frost layer (ice's 0.5 iso-surface, OpenVDB volume-to-mesh) as a polygon "
        "mesh beside each preview (<scene>.<frame>.obj/ply), for DCC tools that prefer geometry");
    d.onlyWhen(fx->mOnShell, "frost_mesh", "[domain] kind = \"" + world.domain.kind() + "\"");
    const auto wind = d.getFloatArray("wind", {0, 0, 0}, {3}, -1e4, 1e4, "cells of h per unit ice time",
        "shell domains: a prescribed wind (world direction and speed) projected on each tangent plane, "
        "advecting the heat (first-order upwind; on a plane use [fluid])");
    fx->mWind = openvdb::Vec3d(wind[0], wind[1], wind[2]);
    d.onlyWhen(fx->mOnShell, "wind", "[domain] kind = \"" + world.domain.kind() + "\"");
    fx->mPotentialWind = d.getString("wind_model", "uniform", {"uniform", "potential"},
        "shell domains: uniform: `wind` projected on each tangent plane; potential: the potential flow around the "
        "closed mesh with free stream `wind` (OpenVDB tools::PotentialFlow), its surface velocity on the tangent "
        "planes (about 1.5x the free stream at a sphere's equator, 0 at its stagnation points)") == "potential";
    d.onlyWhen(fx->mOnShell, "wind_model", "[domain] kind = \"" + world.domain.kind() + "\"");
    // lw_cn and the potential flow run on the closest-point band (docs/shells.md "Discretisation")
    if (const auto band = shell::bandOf(world.domain); band && band->surfaceNodes()) {
        if (!euler)
            d.fail("scheme", "lw_cn on a shell runs on the closest-point band: set [domain] discretisation = "
                             "\"closest_point\" (allowed here: euler)");
        if (fx->mPotentialWind)
            d.fail("wind_model", "the potential flow is solved on the closest-point band: set [domain] discretisation = "
                                 "\"closest_point\" (allowed here: uniform)");
    }
    // lw_cn on a shell: the implicit closest-point system (shell/ShellImplicit.h) is not an
    // M-matrix (the extension's cubic weights are not all positive): BiCGSTAB only
    if (fx->mOnShell && !euler) {
        if (d.has("solver") && !k.useBiCGSTAB)
            d.fail("solver", "shell domains solve lw_cn's closest-point band system with BiCGSTAB (allowed: bicgstab)");
        k.useBiCGSTAB = true;
    }
    const double limit = k.stabilityLimit(world.domain.stencil(), !world.domain.flat());
    fx->mStabilityLimit = limit;
    fx->mSubsteps = 1;
    if (k.dt > limit) {
        if (substeps == "auto") {
            fx->mSubsteps = int(std::ceil(k.dt / limit * (1.0 + 1e-9)));
        } else {
            std::ostringstream os;
            os << k.dt << " exceeds the " << (euler ? "explicit (forward Euler)" : "second-order (Crank-Nicolson positivity and reaction)")
               << " stability limit " << limit << " for this lattice spacing (" << world.domain.lattice().spacing()
               << ") and epsilon/delta/tau; lower dt or set substeps = \"auto\"";
            d.fail("dt", os.str());
        }
    }
    if (fx->mOnShell) {
        // dt (6 / h^2 + |v|_1 / h) <= 1 (ShellPhaseField::windStabilityLimit, before projection)
        const double h = world.domain.lattice().spacing();
        // a potential flow is faster than its free stream over the object (1.5x on a sphere): allow 2x
        const double v1 = (fx->mPotentialWind ? 2.0 : 1.0) * (std::fabs(wind[0]) + std::fabs(wind[1]) + std::fabs(wind[2]));
        // lw_cn: only the explicit half of the Crank-Nicolson average needs it (dt / 2)
        const double windLimit = (euler ? 1.0 : 2.0) / (6.0 / (h * h) + v1 / h);
        if (v1 > 0 && k.dt / fx->mSubsteps > windLimit)
            d.fail("wind", "with dt " + std::to_string(k.dt / fx->mSubsteps) + " the wind's upwind heat step needs dt <= " +
                               std::to_string(windLimit) + " (|v|_1 <= " +
                               std::to_string(((euler ? 1.0 : 2.0) * fx->mSubsteps / k.dt - 6.0 / (h * h)) * h) +
                               " at this dt)");
    }
    return fx;
}

MemoryEstimate PhaseFieldEffect::memoryEstimate(const World& world) const
{
    if (const auto band = shell::bandOf(world.domain)) {
        if (!world.region.dense && !band->whole()) return {};
        return perVoxelEstimate(band->surfaceVoxels(), band->bytesPerSurfaceCell(), "domain.voxel_size",
                                "the shell band and the phase field's arrays, per surface cell (mesh area / voxel_size^2)");
    }
    if (!world.region.dense) return {};
    return perVoxelEstimate(double(world.domain.bbox().volume()), 96.0, "domain.size", "dense phase-field arrays");
}

FieldDeclaration PhaseFieldEffect::declaration() const
{
    FieldDeclaration d;
    d.stage = Stage::PhaseField;
    d.use(ice::kClock, kInitialises) // owns dt, T_inf, K, T_e
        .use(ice::kPhase, kReadsAtInit | kReads | kWrites) // seeds the default crystal when none is given
        .use(ice::kTemperature, kInitialises | kReads | kWrites)
        .use(ice::kGrowth, kInitialises | kWrites)
        .use(ice::kFreezeTime, kInitialises | kWrites)
        .use(ice::kMelt, kReads);
    d.output(out::kIce).output(out::kIceTemperature).output(out::kGrowth).output(out::kFreezeTime);
    if (mOnShell) {
        d.use(shell::kSurfaceFields, kInitialises).use(shell::kSurfaceWind, kInitialises);
        d.output(out::kIceSdf);
    }
    return d;
}

void PhaseFieldEffect::initialize(World& world)
{
    ice::IceShared& shared = ice::shared(world);
    shared.dt = mParams.dt;
    shared.dtOwnedByPhaseField = true;
    shared.farTemperature = mParams.farTemperature;
    shared.latentHeat = mParams.latentHeat;
    shared.meltTemperature = mParams.meltTemperature;
    shared.temperatureEvolves = true;
    ice::requireIceFields(world);
    KobayashiParams solverParams = mParams;
    solverParams.dt = mParams.dt / mSubsteps;
    mTime = 0.0;
    if (auto band = shell::bandOf(world.domain)) {
        mShell = std::make_unique<shell::ShellPhaseField>(band, solverParams, world.domain.lattice().spacing());
        if (mPotentialWind) {
            // The potential flow is solved around the whole object (its solid is the whole band),
            // so the band is built whole first; the active region still steps only near the ice.
            band->materialiseAll();
        }
        // [region]: the band around the ice (tolerance) or the whole band (dense, the reference)
        mShell->setActiveRegion(!world.region.dense, world.region.tolerance);
        printShellEstimate(*band, world);
        if (mPotentialWind) {
            mShell->setWindField(shell::potentialFlowWind(*band, mWind, 0));
        } else {
            mShell->setWind(mWind); // projected on each leaf's tangent planes as it is built
        }
        // the tangential wind shared with [dla]'s walker drift (shell/ShellWind.h): [dla] on a
        // shell builds the band whole at creation, so this holds every voxel when it is used
        if (band->whole()) {
            world.state<shell::ShellWindState>().tangential = mShell->windField();
        }
        // [dla] freezes into the band arrays directly (no grid round trip per step)
        world.state<shell::SurfaceFields>().solver = mShell.get();
        gatherShell(world);
        const auto& lum = band->colourLuminance();
        if (band->colourUse() == shell::BandSettings::ColourUse::Seed) // ice where the colour is bright
            for (size_t i = 0; i < lum.size(); ++i)
                if (lum[i] > 0.5f) mShell->p()[i] = 1.f;
        // seed_texture: ice where bright (the domain built every leaf that can hold a seed)
        if (const auto* tex = shell::texturesOf(world.domain); tex && tex->seed) {
            auto& p = mShell->p();
            band->forEachVoxel(nullptr, [&](size_t i) {
                if (tex->seedAt(*band, i) > 0.5f) p[i] = 1.f;
            });
        }
        mShell->extendAll(); // seeds were stamped in 3D: make them closest-point data
        scatterShell(world);
        return;
    }
    mSolver = std::make_unique<PhaseFieldSolver>(solverParams, world.domain, world.region);
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

void PhaseFieldEffect::printShellEstimate(const shell::ShellBand& band, const World& world) const
{
    // One line before the run (stderr): the surface's cells, the memory they ask when the band
    // is whole, and the steps per second once the whole surface is stepped, from the node update
    // rate measured by `frostvdb bench shell pane` (docs/performance.md): an upper bound of the
    // time, as the active region steps only the ice and its heat halo.
    constexpr double kNodeUpdatesPerSecondPerCore = 12e6;
    const double cells = band.surfaceVoxels(), cores = double(std::max(1u, std::thread::hardware_concurrency()));
    const double rate = kNodeUpdatesPerSecondPerCore * cores / std::max(1.0, cells);
    const double steps = double(world.frames * world.stepsPerFrame);
    std::fprintf(stderr, "frostvdb: shell: %.2f M surface cells (%s), %zu built now; whole: about %s; about %.1f steps/s "
                         "when all are stepped (%d steps: at most %.0f s)\n",
                 cells * 1e-6, band.surfaceNodes() ? "surface nodes" : "closest-point band", band.size(),
                 formatBytes(cells * band.bytesPerSurfaceCell()).c_str(), rate, int(steps), steps / rate);
}

void PhaseFieldEffect::gatherShell(World& world)
{
    const shell::ShellBand& band = mShell->band();
    // (building the band's leaves wherever p or T is off its background: seeds)
    shell::fromGrid(band, *world.fields.get<openvdb::FloatGrid>(ice::kPhase), mShell->p(), true);
    shell::fromGrid(band, *world.fields.get<openvdb::FloatGrid>(ice::kTemperature), mShell->T(), true);
    std::vector<float> v;
    shell::fromGrid(band, *world.fields.get<openvdb::FloatGrid>(ice::kGrowth), v);
    mShell->growthValues() = v;
    shell::fromGrid(band, *world.fields.get<openvdb::FloatGrid>(ice::kFreezeTime), v);
    mShell->freezeValues() = v;
    // the melt field x the colour melt map x melt_texture (shell/ShellTexture.h): now for the
    // voxels built so far, and for each leaf the active region builds later
    openvdb::FloatGrid::ConstPtr melt = world.fields.get<openvdb::FloatGrid>(ice::kMelt);
    const auto* tex = shell::texturesOf(world.domain);
    mShell->setMeltSource(shell::meltSource(melt, band, tex), shell::meltMap(band, melt.get(), tex));
    // the arrays now hold what these grids hold: read them again only when someone replaces them
    mShellP = world.fields.get<openvdb::FloatGrid>(ice::kPhase);
    mShellT = world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
}

void PhaseFieldEffect::scatterShell(World& world)
{
    const shell::ShellBand& band = mShell->band();
    auto p = shell::toGrid(band, mShell->p(), 0.f, ice::kPhase.name);
    auto T = shell::toGrid(band, mShell->T(), float(mParams.farTemperature), ice::kTemperature.name);
    mShellP = p;
    mShellT = T;
    world.fields.replace(ice::kPhase, p);
    world.fields.replace(ice::kTemperature, T);
    world.fields.replace(ice::kGrowth, shell::toGrid(band, mShell->growthValues(), 0.f, ice::kGrowth.name));
    world.fields.replace(ice::kFreezeTime, shell::toGrid(band, mShell->freezeValues(), 0.f, ice::kFreezeTime.name));
}

void PhaseFieldEffect::step(World& world, const StepInfo& info)
{
    if (mShell) {
        // another effect may have written p or T since we scattered them: read them back
        if (world.fields.get<openvdb::FloatGrid>(ice::kPhase) != mShellP ||
            world.fields.get<openvdb::FloatGrid>(ice::kTemperature) != mShellT)
            gatherShell(world);
        const double subDt = mParams.dt / mSubsteps;
        for (int s = 0; s < mSubsteps; ++s) // noise keyed by the substep's index, as on a plane
            mShell->step(mTime + (s + 1) * subDt, info.step * mSubsteps + s, world.seed, &mShellStats);
        // the band arrays are the state between steps: World's grids are written back only when
        // the driver reads them (publishFields: frames and checkpoints)
        mTime += mParams.dt;
        return;
    }
    auto p = world.fields.get<openvdb::FloatGrid>(ice::kPhase);
    auto T = world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
    auto growth = world.fields.get<openvdb::FloatGrid>(ice::kGrowth);
    auto freeze = world.fields.get<openvdb::FloatGrid>(ice::kFreezeTime);
    mSolver->setMeltMap(world.fields.get<openvdb::FloatGrid>(ice::kMelt).get());
    {
        // Trust the edit lists only when every other writer of p and T fills them.
        FieldEdits& edits = world.state<FieldEdits>();
        const FieldWriters* w = world.hasState<FieldWriters>() ? &world.state<FieldWriters>() : nullptr;
        auto listed = [&](const std::string& f) { return w && w->of(f) - 1 == edits.reporters(f); };
        const bool all = listed(ice::kPhase.name) && listed(ice::kTemperature.name);
        mSolver->setEditLogs(all ? &edits.cells(ice::kPhase.name) : nullptr,
                             all ? &edits.cells(ice::kTemperature.name) : nullptr);
        mSolver->setCrossingLog(edits.crossingSink(ice::kPhase.name));
    }
    const double subDt = mParams.dt / mSubsteps;
    for (int s = 0; s < mSubsteps; ++s) {
        // Substeps key the noise by their own index so that each draws fresh values.
        const int64_t index = info.step * mSubsteps + s;
        mSolver->step(p, T, growth.get(), freeze.get(), index, mTime + s * subDt, world.seed, &mStats);
    }
    world.fields.replace(ice::kPhase, p);
    world.fields.replace(ice::kTemperature, T);
    mTime += mParams.dt;
}

void PhaseFieldEffect::publishFields(World& world)
{
    if (mShell) scatterShell(world);
}

void PhaseFieldEffect::addToFrame(World& world, Frame& frame)
{
    // A frame is about to be written: the solver's per-step scratch is given back for the
    // output's copies (remade at the next step; once per frame, not per step).
    if (mSolver) mSolver->releaseScratch();
    ice::addIceOutputs(world, frame);
    if (!mShell) return;
    // On a shell, `ice` is the frost layer grown outward along the normal (not p on the band).
    auto fog = shell::frostFog(mShell->band(), mShell->p(), mShell->growthValues());
    for (auto& g : frame.grids)
        if (g->getName() == out::kIce.name) g = fog;
    const shell::ShellBand& band = mShell->band();
    frame.add(band.surfaceNodes() ? shell::frostLevelSetOnNodes(band, mShell->p(), mShell->growthValues())
                                  : shell::frostLevelSet(*fog));
}

bool PhaseFieldEffect::writePreview(World&, const Frame& frame, const std::string& pngPath)
{
    if (!mShell || mFrostMesh == "none") return false;
    for (const auto& g : frame.grids) {
        if (g->getName() != out::kIce.name) continue;
        std::vector<openvdb::Vec3s> points;
        std::vector<openvdb::Vec3I> tris;
        std::vector<openvdb::Vec4I> quads;
        shell::frostMesh(*openvdb::gridConstPtrCast<openvdb::FloatGrid>(g), points, tris, quads);
        const std::string base = pngPath.substr(0, pngPath.size() - 4);
        if (mFrostMesh == "obj") writeObj(base + ".obj", points, tris, quads);
        else writePly(base + ".ply", points, tris, quads);
    }
    return false; // the driver still draws `ice`
}

// p, T, growth_acc and freeze_time are World fields (saved by the driver); the clock and the
// scheme's history grids are ours. The noise is keyed by the step index: no stream to save.
void PhaseFieldEffect::saveState(const World& world, StateWriter& out) const
{
    out.putDouble("time", mTime);
    if (mShell) { // the band fields are World fields; lw_cn's history and the active region are ours
        if (mParams.scheme == PhaseFieldScheme::SecondOrder) {
            const shell::ShellPhaseField& sh = *mShell;
            out.putInt("shell_history", sh.hasHistory() ? 1 : 0);
            out.putDouble("shell_last_step_dt", sh.lastStepDt());
            out.putGrid("shell_history_p", shell::toGrid(mShell->band(), sh.historyP(), 0.f, "shell_history_p"));
            out.putGrid("shell_history_T", shell::toGrid(mShell->band(), sh.historyT(), float(mParams.farTemperature),
                                                         "shell_history_T"));
        }
        if (!mShell->activeRegion()) return;
        auto boxes = openvdb::Int32Grid::create(0);
        auto stepped = openvdb::MaskGrid::create();
        mShell->regionState(*boxes, *stepped);
        out.putGrid("shell_region_boxes", boxes);
        out.putGrid("shell_region_stepped", stepped);
        return;
    }
    for (auto& [name, grid] : mSolver->historyGrids()) out.putGrid(name, *grid);
    out.putDouble("last_step_dt", mSolver->lastStepDt());
    const auto cadence = mSolver->cadenceState(*world.fields.get<openvdb::FloatGrid>(ice::kPhase),
                                               *world.fields.get<openvdb::FloatGrid>(ice::kTemperature));
    out.putGrid("region", cadence.region);
    out.putInt("region_steps_left", cadence.stepsLeft);
    out.putInt("region_inputs_truncated", cadence.inputsTruncated ? 1 : 0);
    out.putInt("region_inputs_ours", cadence.inputsOurs ? 1 : 0);
}

bool PhaseFieldEffect::atCheckpointBoundary() const
{
    return !mSolver || mSolver->cadenceStepsLeft() <= 0;
}

void PhaseFieldEffect::loadState(World& world, const StateReader& in)
{
    mTime = in.getDouble("time");
    if (mShell) {
        gatherShell(world);
        if (in.has("shell_region_stepped"))
            mShell->restoreRegion(*in.getGrid<openvdb::Int32Grid>("shell_region_boxes"),
                                  *in.getGrid<openvdb::MaskGrid>("shell_region_stepped"));
        if (mParams.scheme == PhaseFieldScheme::SecondOrder) {
            mShell->hasHistory() = in.getInt("shell_history") != 0;
            mShell->lastStepDt() = in.getDouble("shell_last_step_dt");
            shell::fromGrid(mShell->band(), *in.getGrid<openvdb::FloatGrid>("shell_history_p"), mShell->historyP());
            shell::fromGrid(mShell->band(), *in.getGrid<openvdb::FloatGrid>("shell_history_T"), mShell->historyT());
        }
        return;
    }
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

std::vector<std::pair<std::string, double>> PhaseFieldEffect::timings() const
{
    if (mShell) {
        std::vector<std::pair<std::string, double>> t{{"kernel", mShellStats.kernelSeconds},
                                                      {"extend", mShellStats.extendSeconds},
                                                      {"voxel_updates", double(mShellStats.voxelUpdates)},
                                                      {"substeps", double(mSubsteps)},
                                                      {"stability_limit_dt", mStabilityLimit}};
        if (mParams.scheme == PhaseFieldScheme::SecondOrder) t.push_back({"solve", mShellStats.solveSeconds});
        return t;
    }
    std::vector<std::pair<std::string, double>> t{
        {"region", mStats.regionSeconds}, {"kernel", mStats.kernelSeconds}, {"truncate", mStats.truncateSeconds}};
    if (mParams.scheme == PhaseFieldScheme::SecondOrder) {
        t.push_back({"solve", mStats.solveSeconds});
        t.push_back({"heat", mStats.heatSeconds});
    }
    return t;
}

std::vector<std::pair<std::string, double>> PhaseFieldEffect::counters() const
{
    if (mShell) {
        std::vector<std::pair<std::string, double>> t{{"region_rebuilds", 0.0}};
        if (mParams.scheme == PhaseFieldScheme::SecondOrder) {
            const double n = double(std::max<int64_t>(1, mShellStats.solves));
            t.push_back({"mean_iterations_p", double(mShellStats.iterationsP) / n});
            t.push_back({"mean_iterations_T", double(mShellStats.iterationsT) / n});
            t.push_back({"unconverged_solves", double(mShellStats.unconverged)});
            t.push_back({"clipped_voxels", double(mShellStats.clippedVoxels)});
        }
        t.push_back({"substeps", double(mSubsteps)});
        t.push_back({"stability_limit_dt", mStabilityLimit});
        return t;
    }
    std::vector<std::pair<std::string, double>> t{{"region_rebuilds", double(mStats.rebuilds)},
                                                  {"region_growths", double(mStats.regionGrowths)}};
    if (mParams.scheme == PhaseFieldScheme::SecondOrder) {
        const double n = std::max<int64_t>(1, mStats.solves);
        t.push_back({"mean_iterations_p", mStats.solverIterationsP / n});
        t.push_back({"mean_iterations_T", mStats.solverIterationsT / n});
        t.push_back({"unconverged_solves", double(mStats.unconverged)});
        t.push_back({"clipped_voxels", double(mStats.clippedVoxels)});
    }
    t.push_back({"substeps", double(mSubsteps)});
    t.push_back({"stability_limit_dt", mStabilityLimit});
    return t;
}

} // namespace frostvdb
