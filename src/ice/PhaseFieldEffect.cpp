#include <frostvdb/ice/PhaseFieldEffect.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/icephysics/IceState.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
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
    // a stencil reaching z (shells, boxes: centre weight 6 / h^2) puts lw_cn's limit at h^2 / 3 = 0.00073
    const bool reachesZ = !world.domain.flat();
    k.dt = d.getFloat("dt", euler ? 0.0002 : (reachesZ ? 0.0007 : 0.0008), 1e-8, 0.1, "",
                      "time step (dimensionless; the paper uses 0.0002 for euler and 0.0008 for lw_cn, the defaults; "
                      "lw_cn on shells and boxes: 0.0007, below its 3D stability limit)");
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
    // the back end the domain's discretisation asks for; every back end reads (or refuses) its keys
    PhaseFieldSetup setup{k, fx->mSubsteps, fx->mStabilityLimit};
    PhaseFieldBackendFactory make;
    for (const PhaseFieldBackendInfo* info : PhaseFieldBackends::all()) {
        const auto& serves = info->discretisations;
        const bool applies = std::find(serves.begin(), serves.end(), world.domain.discretisation()) != serves.end();
        auto factory = info->read(d, setup, world, applies);
        if (applies) make = std::move(factory);
    }
    if (!make)
        throw SceneError(world.sceneLabel, 0, "domain.kind",
                         "[phase_field] has no back end for the domain's discretisation \"" +
                             world.domain.discretisation() + "\"");
    fx->mBackend = make();
    fx->mParams = setup.params;
    return fx;
}


MemoryEstimate PhaseFieldEffect::memoryEstimate(const World& world) const { return mBackend->memoryEstimate(world); }

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
    mBackend->declare(d);
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
    ice::requireIceFields(world, !mBackend->seedsItself(world));
    mTime = 0.0;
    mBackend->initialize(world);
}

void PhaseFieldEffect::step(World& world, const StepInfo& info)
{
    mBackend->step(world, info.step, mTime);
    mTime += mParams.dt;
}

void PhaseFieldEffect::publishFields(World& world) { mBackend->publishFields(world); }

void PhaseFieldEffect::countKeptFields(std::map<std::string, uint64_t>& activeByField) const
{
    mBackend->countKeptFields(activeByField);
}

void PhaseFieldEffect::addToFrame(World& world, Frame& frame)
{
    mBackend->addToFrame(world, frame); // ice::addIceOutputs and the back end's own grids
}

bool PhaseFieldEffect::writePreview(World& world, const Frame& frame, const std::string& pngPath)
{
    return mBackend->writePreview(world, frame, pngPath);
}

// The clock is ours; the noise is keyed by the step index: no stream to save. p, T, growth_acc
// and freeze_time are World fields (saved by the driver); the back end saves the rest.
void PhaseFieldEffect::saveState(const World& world, StateWriter& out) const
{
    out.putDouble("time", mTime);
    mBackend->saveState(world, out);
}

bool PhaseFieldEffect::atCheckpointBoundary() const { return mBackend->atCheckpointBoundary(); }

void PhaseFieldEffect::loadState(World& world, const StateReader& in)
{
    mTime = in.getDouble("time");
    mBackend->loadState(world, in);
}

std::vector<std::pair<std::string, double>> PhaseFieldEffect::timings() const { return mBackend->timings(); }

std::vector<std::pair<std::string, double>> PhaseFieldEffect::counters() const
{
    auto t = mBackend->counters();
    t.push_back({"substeps", double(mSubsteps)});
    t.push_back({"stability_limit_dt", mStabilityLimit});
    return t;
}

// ---- the back-end registry ----------------------------------------------------------------------

namespace {
std::map<std::string, PhaseFieldBackendInfo>& backendRegistry()
{
    static std::map<std::string, PhaseFieldBackendInfo> r;
    return r;
}
} // namespace

void PhaseFieldBackends::add(PhaseFieldBackendInfo info)
{
    const std::string id = info.id;
    backendRegistry()[id] = std::move(info);
}

std::vector<const PhaseFieldBackendInfo*> PhaseFieldBackends::all()
{
    std::vector<const PhaseFieldBackendInfo*> out;
    for (const auto& [id, info] : backendRegistry()) out.push_back(&info);
    return out;
}

} // namespace frostvdb
