#include <frostvdb/ice/PhaseFieldEffect.h>
#include <frostvdb/core/Error.h>

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
    fx->mSeedRadius = d.getFloat("seed_radius", 3.0, 0.5, 1e5, "cells", "radius of the initial ice disc (sphere in a box)");
    fx->mSeedPosition = d.getFloatArray("seed_position", {0.5, 0.5}, {2, 3}, 0.0, 1.0, "fraction of domain",
                                        "centre of the initial ice, as a fraction of the domain size");
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
    const Domain& dom = world.domain;
    auto p = world.fields.require<openvdb::FloatGrid>("p", 0.f);
    auto T = world.fields.require<openvdb::FloatGrid>("T", float(mParams.farTemperature));
    world.fields.require<openvdb::FloatGrid>("growth_acc", 0.f);
    world.fields.require<openvdb::FloatGrid>("freeze_time", 0.f);
    // Seed: a disc (plane) or ball (box) of p = 1 around seed_position, measured in the
    // lattice's own geometry so a hexagonal seed is round too.
    const auto& bb = dom.bbox();
    const openvdb::Vec3d size = (bb.max() - bb.min()).asVec3d() + openvdb::Vec3d(1.0);
    const openvdb::Vec3d centreIdx(bb.min().x() + mSeedPosition[0] * (size.x() - 1),
                                   bb.min().y() + mSeedPosition[1] * (size.y() - 1),
                                   dom.isPlane() ? 0.0
                                                 : bb.min().z() + (mSeedPosition.size() > 2 ? mSeedPosition[2] : 0.5) *
                                                                      (size.z() - 1));
    const openvdb::Vec2d c2 = dom.lattice().planePosition(centreIdx.x(), centreIdx.y());
    const int r = int(std::ceil(mSeedRadius * 2.0)) + 1;
    auto acc = p->getAccessor();
    for (int k = dom.isPlane() ? 0 : int(centreIdx.z()) - r; k <= (dom.isPlane() ? 0 : int(centreIdx.z()) + r); ++k)
        for (int j = int(centreIdx.y()) - r; j <= int(centreIdx.y()) + r; ++j)
            for (int i = int(centreIdx.x()) - r; i <= int(centreIdx.x()) + r; ++i) {
                const openvdb::Coord c(i, j, k);
                if (!dom.contains(c)) continue;
                const openvdb::Vec2d q = dom.lattice().planePosition(i, j) - c2;
                const double dz = dom.isPlane() ? 0.0 : k - centreIdx.z();
                if (q.lengthSqr() + dz * dz <= mSeedRadius * mSeedRadius) acc.setValue(c, 1.f);
            }
    mSolver = std::make_unique<PhaseFieldSolver>(mParams, dom, world.region);
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

void PhaseFieldEffect::addToFrame(World& world, Frame& frame)
{
    auto p = world.fields.get<openvdb::FloatGrid>("p");
    auto ice = p->deepCopy();
    // Fog volume: values in [0,1], background 0, nothing stored where there is no ice.
    openvdb::tools::foreach(ice->beginValueOn(), [](const openvdb::FloatGrid::ValueOnIter& it) {
        const float v = std::min(std::max(*it, 0.f), 1.f);
        it.setValue(v);
        if (v <= 0.f) it.setValueOff();
    });
    openvdb::tools::pruneInactive(ice->tree());
    ice->setName("ice");
    ice->setGridClass(openvdb::GRID_FOG_VOLUME);
    frame.add(ice);

    auto temperature = world.fields.get<openvdb::FloatGrid>("T")->deepCopy();
    temperature->setName("temperature");
    temperature->setGridClass(openvdb::GRID_UNKNOWN);
    frame.add(temperature);

    auto growth = world.fields.get<openvdb::FloatGrid>("growth_acc")->deepCopy();
    float mn = 0, mx = 0;
    if (growth->activeVoxelCount() > 0) growth->evalMinMax(mn, mx);
    const float scale = mx > 0 ? 1.f / mx : 0.f;
    openvdb::tools::foreach(growth->beginValueOn(), [scale](const openvdb::FloatGrid::ValueOnIter& it) {
        it.setValue(std::min(1.f, *it * scale));
    });
    growth->setName("growth");
    frame.add(growth);

    auto freeze = world.fields.get<openvdb::FloatGrid>("freeze_time")->deepCopy();
    freeze->setName("freeze_time");
    frame.add(freeze);
}

std::vector<std::pair<std::string, double>> PhaseFieldEffect::timings() const
{
    return {{"region", mStats.regionSeconds}, {"kernel", mStats.kernelSeconds}, {"truncate", mStats.truncateSeconds}};
}

} // namespace frostvdb
