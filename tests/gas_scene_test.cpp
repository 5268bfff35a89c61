// Gas effects through the driver: sparse output above the threshold, zero outside the cup, frame
// N alone equals frame N of a full run bit for bit, thread independence, smooth animation, vel,
// the published density field, fire grids and flows from their own sections.
#include <frostvdb/BuildPaths.h>
#include "test_util.h"

#include <frostvdb/core/Simulation.h>
#include <frostvdb/gas/GasGrid.h>
#include <frostvdb/gas/GasModels.h>
#include <frostvdb/io/VdbIO.h>

#include <catch2/catch.hpp>

#include <tbb/global_control.h>

#include <cmath>
#include <cstring>

using namespace frostvdb;

namespace {

const char* kSteam = R"(
[scene]
name = "steamtest"
frames = 6
steps_per_frame = 1
seed = 3
[domain]
kind = "box"
size = [8, 8, 8]
voxel_size = 0.002
[output]
preview = "none"
[steam]
center = [0.0, 0.0, 0.0]
radius = 0.03
height = 0.08
noise_scale = 0.015
octaves = 4
rise_speed = 0.04
swirl_period = 30
swirl_radius = [0.005, 0.004]
path_noise = 0.003
turbulence_growth = 0.005
growth_height = 0.05
)";

template <typename GridT>
bool sameGrid(const GridT& a, const GridT& b)
{
    if (a.transform() != b.transform()) return false;
    if (!a.tree().hasSameTopology(b.tree())) return false;
    auto acc = b.getConstAccessor();
    for (auto it = a.cbeginValueOn(); it; ++it) {
        const auto va = *it;
        const auto vb = acc.getValue(it.getCoord());
        if (std::memcmp(&va, &vb, sizeof(va)) != 0) return false;
    }
    return true;
}

bool sameFrameGrids(const openvdb::GridPtrVec& a, const openvdb::GridPtrVec& b, std::string& why)
{
    if (a.size() != b.size()) { why = "grid count"; return false; }
    for (size_t i = 0; i < a.size(); ++i) {
        if (a[i]->getName() != b[i]->getName()) { why = "names"; return false; }
        if (auto fa = openvdb::gridPtrCast<openvdb::FloatGrid>(a[i])) {
            auto fb = openvdb::gridPtrCast<openvdb::FloatGrid>(b[i]);
            if (!fb || !sameGrid(*fa, *fb)) { why = a[i]->getName(); return false; }
        } else if (auto va = openvdb::gridPtrCast<openvdb::Vec3SGrid>(a[i])) {
            auto vb = openvdb::gridPtrCast<openvdb::Vec3SGrid>(b[i]);
            if (!vb || !sameGrid(*va, *vb)) { why = a[i]->getName(); return false; }
        } else { why = "type"; return false; }
    }
    return true;
}

openvdb::FloatGrid::Ptr densityOf(const Frame& f)
{
    for (auto& g : f.grids)
        if (g->getName() == "density") return openvdb::gridPtrCast<openvdb::FloatGrid>(g);
    return nullptr;
}

} // namespace

TEST_CASE("Steam is sparse, above threshold, and zero outside the cup radius", "[fast][gas]")
{
    openvdb::initialize();
    Simulation sim = test::makeSim(kSteam);
    Frame f = sim.currentFrame(3);
    auto d = densityOf(f);
    REQUIRE(d);
    REQUIRE(d->activeVoxelCount() > 1000);
    CHECK(d->getGridClass() == openvdb::GRID_FOG_VOLUME);
    const double r = 0.03, thr = 0.01;
    uint64_t outside = 0, below = 0;
    for (auto it = d->cbeginValueOn(); it; ++it) {
        const auto w = d->indexToWorld(it.getCoord());
        if (std::hypot(w.x(), w.y()) > r + 1e-9 || w.z() < -1e-9) ++outside;
        if (!(*it > thr)) ++below;
    }
    CHECK(outside == 0);
    CHECK(below == 0);
    // sparse: far fewer active voxels than the gas's bounding box
    const auto bb = d->evalActiveVoxelBoundingBox();
    CHECK(double(d->activeVoxelCount()) < 0.8 * double(bb.volume()));
    // motion vectors on the same topology, contravariant-relative, rising on average
    openvdb::Vec3SGrid::Ptr vel;
    for (auto& g : f.grids)
        if (g->getName() == "vel") vel = openvdb::gridPtrCast<openvdb::Vec3SGrid>(g);
    REQUIRE(vel);
    CHECK(vel->getVectorType() == openvdb::VEC_CONTRAVARIANT_RELATIVE);
    CHECK(vel->tree().hasSameTopology(d->tree()));
    double vz = 0;
    for (auto it = vel->cbeginValueOn(); it; ++it) vz += it->z();
    CHECK(vz / double(vel->activeVoxelCount()) == Approx(0.04).epsilon(0.05));
    // published density field for other effects (DLA humidity)
    auto field = sim.world().fields.get<openvdb::FloatGrid>("density");
    REQUIRE(field);
    CHECK(field->activeVoxelCount() == d->activeVoxelCount());
}

TEST_CASE("Steam envelope is monotone with height over the cup centre", "[fast][gas]")
{
    Scene scene = Scene::fromString(kSteam, "t.toml");
    ParamDict& p = scene.section("steam");
    p.set("falloff_noise", 0.0, {"t", 0});
    auto m = gas::readSteam(p);
    const auto ctx = gas::GasContext::at(1, 24, nullptr);
    double prev = 2;
    for (double z = 0.0; z < 0.1; z += 0.001) {
        const double e = m->envelope(gas::V3(0.002, -0.001, z), ctx);
        CHECK(e <= prev + 1e-12);
        prev = e;
    }
    CHECK(m->envelope(gas::V3(0, 0, 0.001), ctx) == Approx(1.0));
    CHECK(m->envelope(gas::V3(0.031, 0, 0.001), ctx) == 0.0);   // outside the radius
    CHECK(m->envelope(gas::V3(0, 0, -0.001), ctx) == 0.0);      // below the surface
    // the spherical ramp at a sample point: rho^2/R^2 = 0.5 -> cos ramp at s = (0.5-0.25)*4/3
    const double rho = 0.03 * std::sqrt(0.5);
    CHECK(m->envelope(gas::V3(rho, 0, 0), ctx) == Approx((std::cos(gas::kPi / 3) + 1) / 2));
}

TEST_CASE("Frame N alone equals frame N of a full run, bit for bit", "[fast][gas]")
{
    openvdb::initialize();
    const std::string full = test::tempDir("gas_full"), one = test::tempDir("gas_one");
    {
        Simulation sim = test::makeSim(kSteam);
        RunOptions o;
        o.outDir = full;
        o.progress = false;
        sim.run(o);
    }
    {
        Simulation sim = test::makeSim(kSteam);
        RunOptions o;
        o.outDir = one;
        o.progress = false;
        o.firstFrame = 4;
        o.lastFrame = 4;
        sim.run(o);
    }
    auto a = readVdb(framePath(full, "steamtest", 4));
    auto b = readVdb(framePath(one, "steamtest", 4));
    std::string why;
    CHECK(sameFrameGrids(*a, *b, why));
    INFO(why);
    CHECK(a->size() == 2);  // density and vel
}

TEST_CASE("Gas grids do not depend on the thread count", "[fast][gas]")
{
    openvdb::initialize();
    Frame f1, f2;
    {
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        Simulation sim = test::makeSim(kSteam);
        f1 = sim.currentFrame(5);
    }
    {
        Simulation sim = test::makeSim(kSteam);
        f2 = sim.currentFrame(5);
    }
    std::string why;
    CHECK(sameFrameGrids(f1.grids, f2.grids, why));
    INFO(why);
}

TEST_CASE("Consecutive frames differ smoothly", "[fast][gas]")
{
    openvdb::initialize();
    Simulation sim = test::makeSim(kSteam);
    auto d1 = densityOf(sim.currentFrame(10))->deepCopy();
    auto d2 = densityOf(sim.currentFrame(11))->deepCopy();
    auto d12 = densityOf(sim.currentFrame(22))->deepCopy();
    // correlation over the union of active voxels
    auto corr = [](const openvdb::FloatGrid& a, const openvdb::FloatGrid& b) {
        openvdb::FloatGrid::Ptr u = a.deepCopy();
        u->topologyUnion(b);
        auto aa = a.getConstAccessor();
        auto ba = b.getConstAccessor();
        double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0, n = 0;
        for (auto it = u->cbeginValueOn(); it; ++it) {
            const double x = aa.getValue(it.getCoord()), y = ba.getValue(it.getCoord());
            sa += x; sb += y; saa += x * x; sbb += y * y; sab += x * y; n += 1;
        }
        const double cov = sab / n - sa / n * sb / n;
        return cov / std::sqrt((saa / n - sa * sa / n / n) * (sbb / n - sb * sb / n / n));
    };
    const double c1 = corr(*d1, *d2), c12 = corr(*d1, *d12);
    INFO("corr 1 frame " << c1 << ", 12 frames " << c12);
    CHECK(test::maxAbsDiff(*d1, *d2) > 0);  // it moves
    CHECK(c1 > 0.5);                        // but little in one frame
    CHECK(c1 > c12 + 0.3);
    // active counts stay close: the envelope is steady
    CHECK(double(d2->activeVoxelCount()) == Approx(double(d1->activeVoxelCount())).epsilon(0.1));
    // in the model, density is continuous in time: a tiny time step changes it a tiny bit
    Scene scene = Scene::fromString(kSteam, "t.toml");
    auto m = gas::readSteam(scene.section("steam"));
    double maxStep = 0;
    for (int i = 0; i < 2000; ++i) {
        const gas::V3 x(0.01 * std::sin(i * 0.7), 0.01 * std::cos(i * 1.3), 0.001 + 0.00003 * i);
        const double a = m->density(x, gas::GasContext::at(10.0, 24, nullptr));
        const double b = m->density(x, gas::GasContext::at(10.001, 24, nullptr));
        maxStep = std::max(maxStep, std::fabs(a - b));
    }
    CHECK(maxStep < 0.01);
}

TEST_CASE("Fire writes density, flame, temperature and colour", "[fast][gas]")
{
    openvdb::initialize();
    Simulation sim = test::makeSim(R"(
[scene]
name = "firetest"
frames = 2
steps_per_frame = 1
[domain]
kind = "box"
size = [8, 8, 8]
voxel_size = 0.01
[output]
preview = "none"
[fire]
radius = 0.15
height = 0.5
)");
    Frame f = sim.currentFrame(2);
    std::map<std::string, openvdb::GridBase::Ptr> g;
    for (auto& x : f.grids) g[x->getName()] = x;
    REQUIRE(g.count("density"));
    REQUIRE(g.count("flame"));
    REQUIRE(g.count("temperature"));
    REQUIRE(g.count("Cd"));
    REQUIRE(g.count("vel"));
    auto t = openvdb::gridPtrCast<openvdb::FloatGrid>(g["temperature"]);
    CHECK(t->background() == Approx(293.15f));
    float lo = 1e9f, hi = 0;
    for (auto it = t->cbeginValueOn(); it; ++it) { lo = std::min(lo, *it); hi = std::max(hi, *it); }
    CHECK(lo >= 293.0f);
    CHECK(hi <= 1700.1f);
    CHECK(hi > 600.0f);
    // base fire: the bottom layer is continuous (every voxel inside the base near the axis is active)
    auto d = openvdb::gridPtrCast<openvdb::FloatGrid>(g["density"]);
    auto acc = d->getConstAccessor();
    int on = 0, total = 0;
    for (int i = -3; i <= 3; ++i)
        for (int j = -3; j <= 3; ++j) {
            ++total;
            if (acc.isValueOn(openvdb::Coord(i, j, 5))) ++on;
        }
    CHECK(on == total);
}

TEST_CASE("Flow sections move every gas of the scene", "[fast][gas]")
{
    openvdb::initialize();
    const std::string base = std::string(kSteam);
    Simulation plain = test::makeSim(base);
    Simulation blown = test::makeSim(base + R"(
[attractor]
center = [0.2, 0.0, 0.08]
distance = 0.5
falloff_start = 0.3
speed = 0.1
strength = [0.0, 0.3]
ramp_frames = [0, 4]
envelope_shift = 0.06
envelope_heights = [0.005, 0.03]
)");
    Frame f0 = plain.currentFrame(6), f1 = blown.currentFrame(6);
    auto d0 = densityOf(f0);
    auto d1 = densityOf(f1);
    // the breeze bends the steam toward +x: the extent of the upper plume shifts
    auto xRange = [](const openvdb::FloatGrid& d, double& lo, double& hi) {
        lo = 1e9; hi = -1e9;
        for (auto it = d.cbeginValueOn(); it; ++it) {
            const auto w = d.indexToWorld(it.getCoord());
            if (w.z() < 0.04) continue;
            lo = std::min(lo, w.x()); hi = std::max(hi, w.x());
        }
    };
    double lo0, hi0, lo1, hi1;
    xRange(*d0, lo0, hi0);
    xRange(*d1, lo1, hi1);
    CHECK(hi1 > hi0 + 0.01);
    CHECK(lo1 > lo0 + 0.01);
    // and the gas itself moves toward the attractor: mean vel.x > 0 (0 without it)
    auto meanVx = [](const Frame& f) {
        for (auto& g : f.grids)
            if (g->getName() == "vel") {
                auto v = openvdb::gridPtrCast<openvdb::Vec3SGrid>(g);
                double s = 0;
                for (auto it = v->cbeginValueOn(); it; ++it) s += it->x();
                return s / double(v->activeVoxelCount());
            }
        return 0.0;
    };
    CHECK(meanVx(f1) > meanVx(f0) + 0.02);  // (the swirl alone gives a uniform vel.x)
    // bad keys are refused by name
    CHECK_THROWS_WITH(test::makeSim(base + "[vortex]\nrate = 1\nfalloff_start = 2\ndistance = 1\n"),
                      Catch::Contains("falloff_start"));
    CHECK_THROWS_WITH(test::makeSim(base + "[steam2]\n"), Catch::Contains("steam2"));
}

TEST_CASE("Every gas scene file is valid", "[fast][gas]")
{
    openvdb::initialize();
    for (const char* s : {"gas_teacup", "gas_teacup_breeze", "gas_wall_hole", "gas_fog", "gas_fire",
                          "gas_molten_marble", "gas_vortex", "frost_with_steam"}) {
        INFO(s);
        CHECK_NOTHROW(Simulation(Scene::load(std::string(FROSTVDB_SOURCE_DIR) + "/scenes/" + s + ".toml")));
    }
}

TEST_CASE("Frost with steam writes ice and density into one frame on one transform", "[fast][gas]")
{
    openvdb::initialize();
    Scene scene = Scene::load(std::string(FROSTVDB_SOURCE_DIR) + "/scenes/frost_with_steam.toml");
    scene.applyOverride("scene.frames=1");
    scene.applyOverride("scene.steps_per_frame=3");
    scene.applyOverride("domain.size=[64, 64]");
    scene.applyOverride("steam.center=[0.024, 0.016, 0.01]");
    scene.applyOverride("steam.radius=0.008");
    scene.applyOverride("steam.height=0.02");
    Simulation sim(std::move(scene));
    const std::string dir = test::tempDir("gas_frost_steam");
    RunOptions o;
    o.outDir = dir;
    o.progress = false;
    sim.run(o);
    auto grids = readVdb(framePath(dir, "frost_with_steam", 1));
    openvdb::GridBase::Ptr ice, density;
    for (auto& g : *grids) {
        if (g->getName() == "ice") ice = g;
        if (g->getName() == "density") density = g;
    }
    REQUIRE(ice);
    REQUIRE(density);
    CHECK(ice->transform() == density->transform());
    CHECK(density->activeVoxelCount() > 0);
    // the steam's density is the world field other effects read
    REQUIRE(sim.world().fields.get<openvdb::FloatGrid>("density"));
}

TEST_CASE("Steam density is published on a hexagonal domain, on the domain's transform", "[fast][gas]")
{
    openvdb::initialize();
    Scene scene = Scene::load(std::string(FROSTVDB_SOURCE_DIR) + "/scenes/dla_frost_with_steam.toml");
    scene.applyOverride("scene.frames=1");
    scene.applyOverride("scene.steps_per_frame=2");
    scene.applyOverride("domain.lattice=\"hexagonal\"");
    scene.applyOverride("domain.size=[64, 64]");
    scene.applyOverride("domain.voxel_size=0.001");
    scene.applyOverride("steam.center=[0.03, 0.02, 0.01]");
    scene.applyOverride("steam.radius=0.008");
    scene.applyOverride("steam.height=0.02");
    Simulation sim(std::move(scene));
    const std::string dir = test::tempDir("gas_hex_steam");
    RunOptions o;
    o.outDir = dir;
    o.progress = false;
    sim.run(o);
    auto field = sim.world().fields.get<openvdb::FloatGrid>("density");
    REQUIRE(field);
    CHECK(field->transform() == *sim.world().fields.transform());
    CHECK(field->activeVoxelCount() > 0);
    float mx = 0.f;
    for (auto it = field->cbeginValueOn(); it; ++it) mx = std::max(mx, *it);
    CHECK(mx > 0.f);
}
