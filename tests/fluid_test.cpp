// [fluid]: the stable-fluid projection, obstacles, boundary conditions, symmetry, the advection
// of T without diffusion, the upstream/downstream asymmetry of a dendrite in a flow (the ice
// paper's Figure 4), thread-count determinism.
#include <frostvdb/BuildPaths.h>
#include "test_util.h"
#include "plane_layout_util.h"

#include <frostvdb/core/Error.h>
#include <frostvdb/fluid/Fluid.h>
#include <frostvdb/icephysics/IceState.h>

#include <catch2/catch.hpp>

#include <tbb/global_control.h>

#include <cmath>
#include <cstring>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

const double kH = 3.0 / 64.0;
const double kVelScale = 1e-4 / kH; // PDE units -> world m per unit time (voxel_size 1e-4)

std::vector<uint8_t> discMask(int nx, int ny, double cx, double cy, double r)
{
    std::vector<uint8_t> m(size_t(nx) * ny, 0);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i)
            if ((i - cx) * (i - cx) + (j - cy) * (j - cy) <= r * r) m[size_t(j) * nx + i] = 1;
    return m;
}

/// A bare world with an empty p (so no default crystal) and a [fluid] effect built from @a keys.
struct FluidWorld {
    World world;
    std::unique_ptr<Effect> fx;
    FluidWorld(int nx, int ny, const std::vector<std::pair<std::string, ParamValue>>& keys, bool emptyIce = true,
               LatticeKind lattice = LatticeKind::Square)
    {
        world.domain = makePlaneDomain(Lattice(lattice, kH), openvdb::Coord(nx, ny, 1), 1e-4);
        world.fields = FieldSet(world.domain.transform());
        if (emptyIce) world.fields.require<openvdb::FloatGrid>(ice::kPhase, 0.f);
        ParamDict d("fluid");
        for (auto& [k, v] : keys) d.set(k, v, {"test", 0});
        fx = FluidEffect::create(d, world);
        d.checkAllRead();
    }
    FluidEffect& fluid() { return static_cast<FluidEffect&>(*fx); }
    void step(int n)
    {
        for (int s = 0; s < n; ++s) fx->step(world, StepInfo{s, 1});
    }
};

/// Centroid of |T - T_inf| in index space.
openvdb::Vec2d centroid(const openvdb::FloatGrid& T)
{
    double w = 0, x = 0, y = 0;
    for (auto it = T.cbeginValueOn(); it; ++it) {
        const double a = std::fabs(*it - T.background());
        w += a;
        x += a * it.getCoord().x();
        y += a * it.getCoord().y();
    }
    return {x / w, y / w};
}

/// Farthest frozen cell from the domain centre along +x, -x, +y, -y (cells).
struct Arms { double left = 0, right = 0, down = 0, up = 0; };
Arms armLengths(const openvdb::FloatGrid& p, const Domain& dom)
{
    const auto c = dom.centre();
    Arms a;
    for (auto it = p.cbeginValueOn(); it; ++it) {
        if (*it <= 0.5f) continue;
        const double dx = it.getCoord().x() - c.x(), dy = it.getCoord().y() - c.y();
        if (std::fabs(dy) <= 2) { a.right = std::max(a.right, dx); a.left = std::max(a.left, -dx); }
        if (std::fabs(dx) <= 2) { a.up = std::max(a.up, dy); a.down = std::max(a.down, -dy); }
    }
    return a;
}

/// The Figure 4 inflow speed (PDE units): about the tip speed of the j = 4 dendrite below (19.5
/// cells in 350 steps of dt 0.0002 at h = 3/64 is 13), see docs/fluid.md.
const char* kFigure4Speed = "14";

const char* kHybridScene = R"(
[scene]
name = "fluid_hybrid"
frames = 1
steps_per_frame = 350
[domain]
size = [64, 64]
[phase_field]
anisotropy_mode = 4
delta = 0.05
theta0 = 0.0
[fluid]
inflow_edge = "left"
inflow_speed = 3.5
)";

} // namespace

TEST_CASE("Fluid projection leaves the discrete divergence below the tolerance", "[fast][fluid]")
{
    for (auto edge : {ice::FluidEdge::Left, ice::FluidEdge::Top}) {
        for (auto prof : {fluid::Profile::Uniform, fluid::Profile::Parabolic, fluid::Profile::Quadratic}) {
            ice::FluidParams fp;
            fp.inflowEdge = edge;
            fp.profile = prof;
            fp.tolerance = 1e-6;
            ice::StableFluid2D f(fp, 64, 48, kH);
            f.setSolid(discMask(64, 48, 25.3, 22.1, 6.5));
            f.setFreeStream();
            f.project();
            CHECK(f.stats().pressureConverged);
            CHECK(f.maxDivergence() * kH / fp.inflowSpeed <= 1e-6);
            for (int s = 0; s < 10; ++s) f.step(0.002);
            CHECK(f.stats().pressureConverged);
            CHECK(f.maxDivergence() * kH / fp.inflowSpeed <= 1e-6);
        }
    }
}

TEST_CASE("Fluid velocity is zero inside obstacles and the vel field says so", "[fast][fluid]")
{
    FluidWorld fw(48, 40, {{"inflow_speed", 3.5}, {"viscosity", 0.05}}, false); // default crystal disc
    fw.fx->initialize(fw.world);
    fw.step(5);
    const auto& f = fw.fluid().solver();
    int solidCells = 0;
    for (int j = 0; j < f.ny(); ++j)
        for (int i = 0; i < f.nx(); ++i) {
            if (!f.solid()[size_t(j) * f.nx() + i]) continue;
            ++solidCells;
            CHECK(f.u(i, j) == 0.0);
            CHECK(f.u(i + 1, j) == 0.0);
            CHECK(f.v(i, j) == 0.0);
            CHECK(f.v(i, j + 1) == 0.0);
        }
    CHECK(solidCells > 10);
    auto p = fw.world.fields.get<openvdb::FloatGrid>(ice::kPhase);
    auto vel = fw.world.fields.get<openvdb::Vec3SGrid>(ice::kVelocity);
    REQUIRE(vel);
    CHECK(vel->activeVoxelCount() == fw.world.domain.voxelCount());
    auto va = vel->getConstAccessor();
    double maxFree = 0;
    for (auto it = vel->cbeginValueOn(); it; ++it) {
        if (p->tree().getValue(it.getCoord()) > 0.5f) CHECK(it->length() == 0.f);
        else maxFree = std::max(maxFree, double(it->length()));
    }
    CHECK(maxFree > 3.0 * kVelScale); // flow speeds up around the obstacle
}

TEST_CASE("Uniform inflow with no obstacle stays uniform on every edge", "[fast][fluid]")
{
    for (const char* edge : {"left", "right", "top", "bottom"}) {
        for (const char* walls : {"outflow", "closed"}) {
            FluidWorld fw(40, 32, {{"inflow_edge", std::string(edge)}, {"walls", std::string(walls)}, {"viscosity", 0.1}});
            fw.fx->initialize(fw.world);
            fw.step(10);
            const bool horizontal = std::string(edge) == "left" || std::string(edge) == "right";
            const double sign = (std::string(edge) == "left" || std::string(edge) == "bottom") ? 1.0 : -1.0;
            auto vel = fw.world.fields.get<openvdb::Vec3SGrid>(ice::kVelocity);
            double err = 0;
            for (auto it = vel->cbeginValueOn(); it; ++it) {
                const openvdb::Vec3d want = horizontal ? openvdb::Vec3d(sign * 3.5, 0, 0) : openvdb::Vec3d(0, sign * 3.5, 0);
                err = std::max(err, (openvdb::Vec3d(*it) / kVelScale - want).length());
            }
            INFO(edge << " " << walls);
            CHECK(err < 1e-5);
        }
    }
}

TEST_CASE("A symmetric obstacle in a symmetric flow gives a mirror-symmetric velocity", "[fast][fluid]")
{
    for (auto prof : {fluid::Profile::Uniform, fluid::Profile::Parabolic}) {
        ice::FluidParams fp;
        fp.profile = prof;
        fp.tolerance = 1e-9;
        fp.viscosity = 0.02;
        const int nx = 64, ny = 41;
        ice::StableFluid2D f(fp, nx, ny, kH);
        f.setSolid(discMask(nx, ny, 20.0, 20.0, 5.2)); // centred on the mirror line j = 20
        f.setFreeStream();
        f.project();
        for (int s = 0; s < 30; ++s) f.step(0.004);
        double err = 0, vmax = 0;
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i <= nx; ++i) err = std::max(err, std::fabs(f.u(i, j) - f.u(i, ny - 1 - j)));
        for (int j = 0; j <= ny; ++j)
            for (int i = 0; i < nx; ++i) {
                err = std::max(err, std::fabs(f.v(i, j) + f.v(i, ny - j)));
                vmax = std::max(vmax, std::fabs(f.v(i, j)));
            }
        CHECK(vmax > 0.5); // the obstacle really deflects the flow
        CHECK(err < 1e-5);
    }
}

TEST_CASE("T is carried without diffusion: unchanged at u = 0, shifted by u dt steps in a uniform flow", "[fast][fluid]")
{
    auto stampBlob = [](World& w, double cx, double cy) {
        auto T = w.fields.get<openvdb::FloatGrid>(ice::kTemperature);
        for (int j = 0; j < 32; ++j)
            for (int i = 0; i < 64; ++i) {
                const double r2 = (i - cx) * (i - cx) + (j - cy) * (j - cy);
                if (r2 < 64) T->tree().setValue(openvdb::Coord(i, j, 0), float(0.8 * std::exp(-r2 / 6.0)));
            }
    };
    SECTION("u = 0")
    {
        FluidWorld fw(64, 32, {{"inflow_speed", 0.0}});
        fw.fx->initialize(fw.world);
        stampBlob(fw.world, 30.3, 15.7);
        auto before = fw.world.fields.get<openvdb::FloatGrid>(ice::kTemperature)->deepCopy();
        fw.step(20);
        auto after = fw.world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
        CHECK(maxAbsDiff(*before, *after) == 0.0);
    }
    SECTION("uniform u")
    {
        FluidWorld fw(64, 32, {{"inflow_speed", 3.5}});
        fw.fx->initialize(fw.world);
        ice::shared(fw.world).dt = 0.002; // read at step time, after creation
        stampBlob(fw.world, 20.0, 15.5);
        auto T = fw.world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
        const auto c0 = centroid(*T);
        const int steps = 20;
        fw.step(steps);
        T = fw.world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
        const auto c1 = centroid(*T);
        const double expected = 3.5 * 0.002 * steps / kH; // cells
        CHECK(std::fabs((c1.x() - c0.x()) - expected) < 0.1);
        CHECK(std::fabs(c1.y() - c0.y()) < 1e-3);
        CHECK(expected > 2.5);
    }
}

TEST_CASE("Hexagonal lattice: the fluid runs on the square auxiliary grid and vel is uniform", "[fast][fluid]")
{
    FluidWorld fw(40, 40, {{"inflow_edge", std::string("bottom")}}, true, LatticeKind::Hexagonal);
    fw.fx->initialize(fw.world);
    fw.step(5);
    CHECK(fw.fluid().solver().nx() == 40 + 20);
    CHECK(fw.fluid().solver().ny() == 35);
    auto vel = fw.world.fields.get<openvdb::Vec3SGrid>(ice::kVelocity);
    double err = 0;
    for (auto it = vel->cbeginValueOn(); it; ++it) err = std::max(err, (openvdb::Vec3d(*it) / kVelScale - openvdb::Vec3d(0, 3.5, 0)).length());
    CHECK(err < 1e-5);
}

TEST_CASE("Fluid refuses the dense 2D solver on box domains with a scene error", "[fast][fluid]")
{
    const char* scene = R"(
[domain]
kind = "box"
size = [16, 16, 16]
[fluid]
solver = "dense2d"
)";
    CHECK_THROWS_AS(makeSim(scene), SceneError);
    try { makeSim(scene); } catch (const SceneError& e) { CHECK(std::string(e.what()).find("flat") != std::string::npos); }
}

TEST_CASE("A dendrite in a flow grows faster upstream than downstream (ice paper Figure 4)", "[fast][fluid]")
{
    auto run = [](const std::string& speed) {
        auto sim = makeSim(kHybridScene, {"fluid.inflow_speed=" + speed});
        sim.initialize();
        for (int s = 0; s < 350; ++s) sim.step();
        auto p = sim.world().fields.get<openvdb::FloatGrid>(ice::kPhase);
        auto T = sim.world().fields.get<openvdb::FloatGrid>(ice::kTemperature);
        for (auto it = T->cbeginValueOn(); it; ++it) REQUIRE(std::isfinite(*it));
        return armLengths(*p, sim.world().domain);
    };
    // kFigure4Speed: the flow as fast as the tip grows (docs/fluid.md, "Figure 4: the flow speed").
    const Arms still = run("0");
    const Arms flow = run(kFigure4Speed);
    INFO("still: left " << still.left << " right " << still.right << " up " << still.up << " down " << still.down);
    INFO("flow:  left " << flow.left << " right " << flow.right << " up " << flow.up << " down " << flow.down);
    CHECK(std::fabs(still.left - still.right) <= 1.0);
    CHECK(flow.left > 1.2 * flow.right); // upstream arm longer than the downstream one by > 20 % (1.55 measured)
    CHECK(flow.left > still.left);       // and longer than without flow
    CHECK(flow.right < still.right);     // the downstream arm stunted
}

TEST_CASE("Fluid hybrid runs are bit-identical with 1 and 2 threads and finite", "[fast][fluid][determinism]")
{
    auto run = [](int threads) {
        tbb::global_control gc(tbb::global_control::max_allowed_parallelism, threads);
        auto sim = makeSim(kHybridScene, {"domain.size=[48, 40]", "fluid.viscosity=0.05", "fluid.inflow_profile=\"parabolic\""});
        sim.initialize();
        for (int s = 0; s < 60; ++s) sim.step();
        auto& w = sim.world();
        return std::make_tuple(w.fields.get<openvdb::FloatGrid>(ice::kTemperature)->deepCopy(),
                               w.fields.get<openvdb::FloatGrid>(ice::kPhase)->deepCopy(),
                               w.fields.get<openvdb::Vec3SGrid>(ice::kVelocity)->deepCopy());
    };
    auto [t1, p1, v1] = run(1);
    auto [t2, p2, v2] = run(2);
    CHECK(maxAbsDiff(*t1, *t2) == 0.0);
    CHECK(maxAbsDiff(*p1, *p2) == 0.0);
    CHECK(t1->tree().hasSameTopology(t2->tree()));
    auto a2 = v2->getConstAccessor();
    bool same = true, finite = true;
    for (auto it = v1->cbeginValueOn(); it; ++it) {
        same = same && std::memcmp(&*it, &a2.getValue(it.getCoord()), sizeof(openvdb::Vec3s)) == 0;
        finite = finite && std::isfinite((*it)[0]) && std::isfinite((*it)[1]);
    }
    CHECK(same);
    CHECK(finite);
    for (auto it = t1->cbeginValueOn(); it; ++it) REQUIRE(std::isfinite(*it));
}

namespace {
/// Mean x offset from the centre of the frozen cells of the up and down side arms (|dy| > 6).
double sideArmLean(const openvdb::FloatGrid& p, const Domain& dom)
{
    const auto c = dom.centre();
    double sum = 0;
    int n = 0;
    for (auto it = p.cbeginValueOn(); it; ++it) {
        if (*it <= 0.5f) continue;
        const double dx = it.getCoord().x() - c.x(), dy = it.getCoord().y() - c.y();
        if (std::fabs(dy) > 6 && std::fabs(dx) < std::fabs(dy)) { sum += dx; ++n; }
    }
    return n ? sum / n : 0.0;
}
} // namespace

TEST_CASE("Sparse band solver: the dendrite's upstream arm is longer than the downstream one, side arms lean upstream",
          "[fast][fluid]")
{
    auto run = [](const std::string& speed, openvdb::FloatGrid::Ptr* pOut) {
        auto sim = makeSim(kHybridScene, {"fluid.inflow_speed=" + speed, "fluid.solver=\"sparse\"", "fluid.band_width=8"});
        sim.initialize();
        for (int s = 0; s < 350; ++s) sim.step();
        auto p = sim.world().fields.get<openvdb::FloatGrid>(ice::kPhase);
        *pOut = p->deepCopy();
        return std::make_pair(armLengths(*p, sim.world().domain), sideArmLean(*p, sim.world().domain));
    };
    openvdb::FloatGrid::Ptr p0, p1;
    const auto [still, leanStill] = run("0", &p0);
    const auto [flow, lean] = run(kFigure4Speed, &p1);
    INFO("still: left " << still.left << " right " << still.right << " lean " << leanStill);
    INFO("flow:  left " << flow.left << " right " << flow.right << " up " << flow.up << " down " << flow.down
                        << " lean " << lean);
    CHECK(std::fabs(still.left - still.right) <= 1.0);
    // Upstream (-x) arm longer than the downstream one by more than 20 % (1.59 measured at 64^2,
    // 350 steps, U = 14).
    CHECK(flow.left > 1.2 * flow.right);
    CHECK(flow.left > still.left);
    CHECK(flow.right < still.right);
    CHECK(lean < leanStill - 0.2); // the side arms lean upstream (towards -x)
}

TEST_CASE("Zero inflow equals the run without [fluid], bit for bit (dense and sparse solvers)", "[fast][fluid]")
{
    auto run = [](const std::vector<std::string>& sets, bool fluid) {
        std::string scene = kHybridScene;
        if (!fluid) scene = scene.substr(0, scene.find("[fluid]"));
        auto all = sets;
        all.push_back("domain.size=[40, 40]");
        auto sim = makeSim(scene, fluid ? all : std::vector<std::string>{"domain.size=[40, 40]"});
        sim.initialize();
        for (int s = 0; s < 60; ++s) sim.step();
        // without [fluid] p and T are folded (core/PlaneFold.h), with it not: compare plane layouts
        return std::make_pair(planeLayout(sim.world(), ice::kPhase.name), planeLayout(sim.world(), ice::kTemperature.name));
    };
    const auto ref = run({}, false);
    for (const char* solver : {"\"dense2d\"", "\"sparse\""}) {
        INFO(solver);
        const auto got = run({"fluid.inflow_speed=0", std::string("fluid.solver=") + solver}, true);
        CHECK(maxAbsDiff(*ref.first, *got.first) == 0.0);
        CHECK(maxAbsDiff(*ref.second, *got.second) == 0.0);
    }
}

/// A ball of ice of radius 4 in the centre of an n^3 box, a wind along z entering at the front.
static std::string ballWindScene(int n, int steps, int bandWidth, int wakeLength)
{
    return "[scene]\nname = \"ball_wind\"\nframes = 1\nsteps_per_frame = " + std::to_string(steps) +
           "\n[domain]\nkind = \"box\"\nsize = [" + std::to_string(n) + ", " + std::to_string(n) + ", " +
           std::to_string(n) +
           "]\nvoxel_size = 0.0002\n[[crystal.seed]]\nshape = \"point\"\nposition = [0.5, 0.5, 0.5]\n"
           "radius = 4.0\n[phase_field]\ndt = 0.0001\n[fluid]\ninflow_edge = \"front\"\ninflow_speed = 3.5\n"
           "band_width = " + std::to_string(bandWidth) + "\nwake_length = " + std::to_string(wakeLength) + "\n";
}

TEST_CASE("Sparse fluid on a box domain: flow_vel finite, zero in the ice, same bits at 1 and 2 threads", "[fast][fluid]")
{
    const std::string scene = ballWindScene(24, 20, 5, 8);
    auto run = [&](int threads) {
        tbb::global_control gc(tbb::global_control::max_allowed_parallelism, threads);
        auto sim = makeSim(scene);
        sim.initialize();
        for (int s = 0; s < 20; ++s) sim.step();
        auto& w = sim.world();
        const FluidEffect* found = nullptr;
        for (auto& e : sim.effects())
            if (e->name() == "fluid") found = static_cast<const FluidEffect*>(e.get());
        REQUIRE(found);
        const FluidEffect& fx = *found;
        REQUIRE(fx.sparseSolver());
        CHECK(fx.sparseSolver()->dim() == 3);
        CHECK(fx.sparseSolver()->maxDivergence() < 1e-5 * 3.5 / (3.0 / 64.0) + 1e-12);
        return std::make_tuple(w.fields.get<openvdb::FloatGrid>(ice::kPhase)->deepCopy(),
                               w.fields.get<openvdb::FloatGrid>(ice::kTemperature)->deepCopy(),
                               w.fields.get<openvdb::Vec3SGrid>(ice::kVelocity)->deepCopy());
    };
    auto [p1, t1, v1] = run(1);
    auto [p2, t2, v2] = run(2);
    CHECK(maxAbsDiff(*p1, *p2) == 0.0);
    CHECK(maxAbsDiff(*t1, *t2) == 0.0);
    auto pa = p1->getConstAccessor();
    auto a2 = v2->getConstAccessor();
    bool same = true, finite = true;
    double iceSpeed = 0, maxW = 0;
    for (auto it = v1->cbeginValueOn(); it; ++it) {
        same = same && std::memcmp(&*it, &a2.getValue(it.getCoord()), sizeof(openvdb::Vec3s)) == 0;
        finite = finite && std::isfinite((*it)[0]) && std::isfinite((*it)[1]) && std::isfinite((*it)[2]);
        if (pa.getValue(it.getCoord()) > 0.5f) iceSpeed = std::max(iceSpeed, double((*it).length()));
        maxW = std::max(maxW, double(std::fabs((*it)[2])));
    }
    CHECK(same);
    CHECK(finite);
    CHECK(iceSpeed == 0.0);
    CHECK(maxW > 0.0); // the wind blows along z
}

TEST_CASE("3D: a ball of ice in a wind grows further upstream than downstream", "[slow][fluid]")
{
    const std::string scene = ballWindScene(40, 300, 6, 12);
    // Extent of the ice (p > 1/2) from the centre along -z (upstream) and +z (downstream).
    auto run = [&](const std::string& speed) {
        auto sim = makeSim(scene, {"fluid.inflow_speed=" + speed});
        sim.initialize();
        for (int s = 0; s < 300; ++s) sim.step();
        auto p = sim.world().fields.get<openvdb::FloatGrid>(ice::kPhase);
        const auto c = sim.world().domain.centre();
        double up = 0, down = 0;
        for (auto it = p->cbeginValueOn(); it; ++it) {
            if (*it <= 0.5f) continue;
            const double dz = it.getCoord().z() - c.z();
            up = std::max(up, -dz);
            down = std::max(down, dz);
        }
        return std::make_pair(up, down);
    };
    const auto still = run("0");
    const auto wind = run("3.5");
    INFO("still: up " << still.first << " down " << still.second << "; wind: up " << wind.first << " down "
                      << wind.second);
    CHECK(std::fabs(still.first - still.second) <= 1.0);
    CHECK(wind.first > wind.second);
    CHECK(wind.first >= still.first);
}

TEST_CASE("The fluid scene files load", "[fast][fluid]")
{
    for (const char* f : {"scenes/fluid_dendrite_flow.toml", "scenes/fluid_dendrite_flow_sparse.toml",
                          "scenes/fluid_plate_wind_3d.toml"}) {
        INFO(f);
        Scene scene = Scene::fromString(readFile(std::string(FROSTVDB_SOURCE_DIR) + "/" + f), f);
        CHECK_NOTHROW(Simulation(std::move(scene)));
    }
}

