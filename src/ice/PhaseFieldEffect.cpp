#include <frostvdb/ice/PhaseFieldEffect.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/ice/IceState.h>

#include <openvdb/tools/Prune.h>
#include <openvdb/tools/ValueTransformer.h>

#include <cmath>
#include <sstream>

namespace frostvdb {

FROSTVDB_REGISTER_EFFECT(PhaseFieldEffect, "phase_field",
                         "Kobayashi phase field (ice paper eqs. 1-5): kinetics-limited growth in an undercooled melt.");

std::unique_ptr<Effect> PhaseFieldEffect::create(ParamDict& d, const World& world)
{
    auto fx = std::make_unique<PhaseFieldEffect>();
    KobayashiParams& k = fx->mParams;
    d.getString("scheme", "euler", {"euler"}, "time integration: euler (forward Euler, eqs. 1-5)");
    k.dt = d.getFloat("dt", 0.0002, 1e-8, 0.1, "", "time step (dimensionless; the paper's Euler step is 0.0002)");
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
    const double limit = k.explicitStabilityLimit(world.domain.stencil());
    if (k.dt > limit) {
        std::ostringstream os;
        os << k.dt << " exceeds the explicit (forward Euler) stability limit " << limit
           << " for this lattice spacing (" << world.domain.lattice().spacing() << ") and epsilon/delta/tau";
        d.fail("dt", os.str());
    }
    return fx;
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
    mSolver = std::make_unique<PhaseFieldSolver>(mParams, world.domain, world.region);
    mTime = 0.0;
}

void PhaseFieldEffect::step(World& world, const StepInfo& info)
{
    auto p = world.fields.get<openvdb::FloatGrid>("p");
    auto T = world.fields.get<openvdb::FloatGrid>("T");
    auto growth = world.fields.get<openvdb::FloatGrid>("growth_acc");
    auto freeze = world.fields.get<openvdb::FloatGrid>("freeze_time");
    mSolver->step(p, T, growth.get(), freeze.get(), info.step, mTime, world.seed, &mStats);
    world.fields.replace("p", p);
    world.fields.replace("T", T);
    mTime += mParams.dt;
}

void PhaseFieldEffect::addToFrame(World& world, Frame& frame) { ice::addIceOutputs(world, frame); }

std::vector<std::pair<std::string, double>> PhaseFieldEffect::timings() const
{
    return {{"region", mStats.regionSeconds}, {"kernel", mStats.kernelSeconds}, {"truncate", mStats.truncateSeconds}};
}

} // namespace frostvdb
