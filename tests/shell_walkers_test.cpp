// DLA walkers on a shell's surface (issue 11 item 4): against the plane's engine on a flat plate,
// on the surface of a sphere, and bit-identical at 1 and 2 threads.
#include "test_util.h"

#include <frostvdb/ice/Dla.h>
#include <frostvdb/shell/ShellDomain.h>
#include <frostvdb/shell/ShellWalkers.h>

#include <catch2/catch.hpp>

#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstring>

using namespace frostvdb;
using openvdb::Vec3d;

namespace {

/// Sticks of a growing aggregate: positions in the plane's coordinates, in freezing order.
struct Aggregate {
    std::vector<openvdb::Vec2d> points;
    uint64_t released = 0;
};

constexpr int kN = 64;          // domain: a kN x kN rhombus of the hexagonal lattice
constexpr int kTarget = 300;    // freezes
constexpr uint64_t kWalkersPerStep = 256;

/// The plane's engine: hexagonal kN x kN, one ice cell at the centre, uniform release, sticks
/// applied in walker order (a walker whose cell froze earlier in the batch is dropped).
Aggregate growPlane(uint64_t seed)
{
    const Domain dom = makePlaneDomain(Lattice(LatticeKind::Hexagonal), openvdb::Coord(kN, kN, 1), 1e-4);
    auto p = openvdb::FloatGrid::create(0.f);
    p->tree().setValue(openvdb::Coord(kN / 2, kN / 2, 0), 1.f);
    ice::DlaParams prm;
    ice::DlaEngine eng(dom, prm, seed);
    eng.sync(*p);
    Aggregate a;
    std::vector<ice::WalkEnd> ends;
    ice::DlaEngine::Inputs in;
    for (int64_t step = 0; int(a.points.size()) < kTarget; ++step) {
        eng.walkBatch(step, 0, kWalkersPerStep, in, ends);
        a.released += kWalkersPerStep;
        for (const auto& e : ends) {
            if (e.kind != ice::WalkEnd::Stuck || eng.isIce(e.cell)) continue;
            eng.freeze(e.cell);
            const auto c = eng.coord(e.cell);
            a.points.push_back(dom.lattice().planePosition(c.x(), c.y()));
        }
    }
    return a;
}

/// The same rhombus as a plate mesh (axial (i, j) -> X = i + j/2, Y = j sqrt(3)/2, voxels of 1),
/// tilted by @a tiltDeg about x, with the crystal axis along the rhombus's first edge.
struct RhombusPlate {
    std::shared_ptr<const shell::ShellBand> band;
    openvdb::Mat4d placement;
    /// The plate point of plane position (X, Y).
    Vec3d toWorld(const openvdb::Vec2d& q) const { return placement.transform(Vec3d(q.x(), q.y(), 0)); }
    openvdb::Vec2d toPlane(const Vec3d& w) const
    {
        const Vec3d q = placement.inverse().transform(w);
        return openvdb::Vec2d(q.x(), q.y());
    }
};

RhombusPlate makeRhombus(double tiltDeg)
{
    TriangleMesh mesh = makePlate(double(kN), kN / 4); // [-kN/2, kN/2]^2
    for (auto& v : mesh.points) {                     // -> the plane's cell rhombus
        const double i = double(v.x()) + kN / 2 - 0.5, j = double(v.y()) + kN / 2 - 0.5;
        v = openvdb::Vec3s(float(i + 0.5 * j), float(j * std::sqrt(3.0) / 2.0), 0.f);
    }
    MeshPlacement m;
    m.rotateDegrees = Vec3d(tiltDeg, 0, 0);
    m.translate = Vec3d(0.3, 0.2, 0.1); // off the voxel centres
    mesh.transform(m);
    RhombusPlate r;
    r.placement = m.matrix();
    shell::BandSettings bs;
    bs.voxelSize = 1.0;
    bs.crystalAxis = r.placement.transform3x3(Vec3d(1, 0, 0));
    bs.secondaryAxis = r.placement.transform3x3(Vec3d(0, 1, 0));
    r.band = shell::ShellBand::build(mesh, bs);
    return r;
}

/// Walkers on the plate: one stick disc at the centre, then the same release and order.
Aggregate growShell(const RhombusPlate& plate, uint64_t seed, std::vector<Vec3d>* sticks = nullptr)
{
    ice::DlaParams prm;
    shell::ShellWalkers w(plate.band, prm, seed);
    std::vector<float> p(plate.band->size(), 0.f);
    const Vec3d centre = plate.toWorld(Lattice(LatticeKind::Hexagonal).planePosition(kN / 2, kN / 2));
    Vec3d c0;
    REQUIRE(w.project(centre, c0));
    w.sync(p);
    w.addIce(c0); // one stick point, as the plane's one cell
    Aggregate a;
    std::vector<shell::ShellWalkEnd> ends;
    shell::ShellWalkers::Inputs in;
    for (int64_t step = 0; int(a.points.size()) < kTarget; ++step) {
        w.walkBatch(step, 0, kWalkersPerStep, in, ends);
        a.released += kWalkersPerStep;
        for (const auto& e : ends) {
            if (e.kind != shell::ShellWalkEnd::Stuck || w.iceDistance(e.point) < 0.5) continue;
            w.addIce(e.point);
            a.points.push_back(plate.toPlane(e.point));
            if (sticks) sticks->push_back(e.point);
        }
    }
    return a;
}

/// Radius of gyration of the first @a n points about the seed.
double gyration(const Aggregate& a, size_t n, const openvdb::Vec2d& centre)
{
    double s = 0;
    for (size_t k = 0; k < n; ++k) s += (a.points[k] - centre).lengthSqr();
    return std::sqrt(s / double(n));
}

} // namespace

TEST_CASE("Shell walkers on a flat plate grow the plane's DLA (radius of gyration, fractal dimension)",
          "[fast][shell][dla]")
{
    // The same rhombus, seed and release on the plane's hexagonal engine and on a plate mesh
    // tilted 30 degrees; over 4 seeds: the mean radius of gyration at kTarget sticks and the mass
    // dimension D = log(4) / log(Rg(kTarget) / Rg(kTarget / 4)).
    const openvdb::Vec2d centre = Lattice(LatticeKind::Hexagonal).planePosition(kN / 2, kN / 2);
    const RhombusPlate plate = makeRhombus(30.0);
    double rgPlane = 0, rgShell = 0, dPlane = 0, dShell = 0, relPlane = 0, relShell = 0;
    const int seeds = 4;
    for (int s = 0; s < seeds; ++s) {
        const Aggregate a = growPlane(100 + s), b = growShell(plate, 100 + s);
        const double a1 = gyration(a, kTarget / 4, centre), a2 = gyration(a, kTarget, centre);
        const double b1 = gyration(b, kTarget / 4, centre), b2 = gyration(b, kTarget, centre);
        rgPlane += a2 / seeds;
        rgShell += b2 / seeds;
        dPlane += std::log(4.0) / std::log(a2 / a1) / seeds;
        dShell += std::log(4.0) / std::log(b2 / b1) / seeds;
        relPlane += double(a.released) / seeds;
        relShell += double(b.released) / seeds;
    }
    WARN("Rg(" << kTarget << ") plane " << rgPlane << " shell " << rgShell << "; D plane " << dPlane << " shell " << dShell
                          << "; walkers released plane " << relPlane << " shell " << relShell);
    CHECK(rgShell == Approx(rgPlane).epsilon(0.10)); // measured -1.3 %
    CHECK(dShell == Approx(dPlane).epsilon(0.10)); // measured -3.9 %
}

TEST_CASE("Shell walkers stay on the surface of a sphere and stick on the ice", "[fast][shell][dla]")
{
    const double R = 20.0;
    shell::BandSettings bs;
    bs.voxelSize = 1.0;
    auto band = shell::ShellBand::build(makeIcosphere(R, 5), bs);
    ice::DlaParams prm;
    shell::ShellWalkers w(band, prm, 7);
    std::vector<float> p(band->size(), 0.f);
    {   // no ice on a closed surface: nothing to stick to, no border to leave by; the walkers end
        w.sync(p);
        std::vector<shell::ShellWalkEnd> none;
        w.walkBatch(0, 0, 50, {}, none);
        for (const auto& e : none) REQUIRE(e.kind == shell::ShellWalkEnd::Killed);
    }
    Vec3d top;
    REQUIRE(w.project(Vec3d(0, 0, R), top));
    for (size_t i : w.markDisc(top)) p[i] = 1.f;
    w.sync(p);
    std::vector<shell::ShellWalkEnd> ends;
    size_t stuck = 0;
    double worstOff = 0, worstGap = 0;
    for (int64_t step = 0; step < 40; ++step) {
        w.walkBatch(step, 0, 10, {}, ends);
        for (const auto& e : ends) {
            REQUIRE(e.kind == shell::ShellWalkEnd::Stuck); // a closed surface: every walker sticks
            if (w.iceDistance(e.point) < 0.5) continue;
            ++stuck;
            worstOff = std::max(worstOff, std::fabs(e.point.length() - R));
            worstGap = std::max(worstGap, w.iceDistance(e.point));
            const auto disc = w.markDisc(e.point);
            REQUIRE(!disc.empty());
            for (size_t i : disc) REQUIRE(band->distance(i) <= shell::kHalfWidth);
            w.addIce(e.point);
        }
    }
    INFO("stuck " << stuck << ", farthest from the sphere " << worstOff << ", from the ice " << worstGap);
    CHECK(stuck > 100);
    CHECK(worstOff < 0.05); // on the surface (the icosphere's facets sag by < 0.01 voxels)
    CHECK(worstGap <= shell::ShellWalkers::kStickRadius);
}

TEST_CASE("Shell walkers: an open border removes walkers, the perimeter release starts there", "[fast][shell][dla]")
{
    const RhombusPlate plate = makeRhombus(0.0);
    ice::DlaParams prm;
    prm.release = ice::DlaRelease::Perimeter;
    shell::ShellWalkers w(plate.band, prm, 3);
    REQUIRE(!w.borderLayer().empty());
    w.sync(std::vector<float>(plate.band->size(), 0.f)); // no ice: every walker leaves
    std::vector<shell::ShellWalkEnd> ends;
    w.walkBatch(0, 0, 300, {}, ends);
    for (const auto& e : ends) CHECK(e.kind == shell::ShellWalkEnd::Killed);
}

TEST_CASE("Shell walkers: bit-identical at 1 and 2 threads", "[fast][shell][dla][determinism]")
{
    const RhombusPlate plate = makeRhombus(45.0);
    std::vector<Vec3d> sticks[2];
    for (int threads : {1, 2}) {
        tbb::global_control gc(tbb::global_control::max_allowed_parallelism, size_t(threads));
        growShell(plate, 11, &sticks[threads - 1]);
    }
    REQUIRE(sticks[0].size() == sticks[1].size());
    CHECK(std::memcmp(sticks[0].data(), sticks[1].data(), sticks[0].size() * sizeof(Vec3d)) == 0);
}

TEST_CASE("Shell [dla] + [phase_field] scene: walkers before the phase field, bit-identical at 1 and 2 threads",
          "[fast][shell][dla][determinism]")
{
    // surface nodes (the default) with a uniform wind, and the closest-point band with the potential flow
    const bool surface = GENERATE(true, false);
    INFO((surface ? "surface nodes" : "closest point"));
    const std::string scene = std::string("[scene]\nname = \"shd\"\nframes = 1\nsteps_per_frame = 12\n"
                              "[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.0012\n") +
                              (surface ? "" : "discretisation = \"closest_point\"\n") +
                              "[[crystal.seed]]\nshape = \"point\"\nspace = \"world\"\nposition = [0, 0, 0.0012]\n"
                              "radius = 3\n[dla]\nhumidity = 150\nbatch = 64\n"
                              "[phase_field]\nwind = [20, 0, 0]\n" + (surface ? "" : "wind_model = \"potential\"\n");
    std::string paths[2];
    for (int threads : {1, 2}) {
        auto sim = test::makeSim(scene);
        // the driver's order: the walkers' stage comes before the phase field's
        std::vector<std::string> order;
        for (size_t k : sim.order().step) order.push_back(sim.effects()[k]->name());
        REQUIRE(order.size() >= 2);
        CHECK(std::find(order.begin(), order.end(), "dla") < std::find(order.begin(), order.end(), "phase_field"));
        RunOptions ro;
        ro.progress = false;
        ro.threads = threads;
        ro.outDir = test::tempDir("shell_dla_det" + std::to_string(threads));
        auto sum = sim.run(ro);
        REQUIRE(!sum.files.empty());
        paths[threads - 1] = ro.outDir + "/shd.0001.vdb";
        double frozen = 0;
        for (const auto& e : sim.effects())
            if (e->name() == "dla")
                for (const auto& [k, v] : e->counters())
                    if (k == "frozen") frozen = v;
        INFO("frozen " << frozen);
        CHECK(frozen > 50);
    }
    std::string why;
    CHECK(test::sameVdbContent(paths[0], paths[1], &why));
    INFO(why);
}

TEST_CASE("Shell walkers drift with the tangential wind: more sticks on the upwind side", "[fast][shell][dla]")
{
    // a static ice disc at the centre of a plate tilted 30 degrees; walkers released uniformly;
    // a drift of 0.2 voxels per step along the plate's +x (and one along its normal, which the
    // projection removes): the share of sticks on the -x (upwind) half
    const RhombusPlate plate = makeRhombus(30.0);
    const openvdb::Vec2d centre = Lattice(LatticeKind::Hexagonal).planePosition(kN / 2, kN / 2);
    auto upwindShare = [&](const Vec3d& driftPlate) {
        ice::DlaParams prm;
        shell::ShellWalkers w(plate.band, prm, 9);
        std::vector<float> p(plate.band->size(), 0.f);
        w.sync(p);
        for (int k = 0; k < 24; ++k) { // a ring of ice points of radius 4
            Vec3d q;
            const double a = 2 * M_PI * k / 24;
            REQUIRE(w.project(plate.toWorld(centre + openvdb::Vec2d(4 * std::cos(a), 4 * std::sin(a))), q));
            w.addIce(q);
        }
        std::vector<openvdb::Vec3f> drift(plate.band->size(), openvdb::Vec3f(plate.placement.transform3x3(driftPlate)));
        shell::ShellWalkers::Inputs in;
        in.drift = &drift;
        std::vector<shell::ShellWalkEnd> ends;
        w.walkBatch(0, 0, 3000, in, ends);
        double up = 0, all = 0;
        for (const auto& e : ends) {
            if (e.kind != shell::ShellWalkEnd::Stuck) continue;
            all += 1;
            if (plate.toPlane(e.point).x() < centre.x()) up += 1;
        }
        return up / std::max(1.0, all);
    };
    const double calm = upwindShare(Vec3d(0.0)), windy = upwindShare(Vec3d(0.2, 0, 0)),
                 normal = upwindShare(Vec3d(0, 0, 0.2));
    INFO("upwind share: calm " << calm << ", drift along the plate " << windy << ", along the normal " << normal);
    CHECK(std::fabs(calm - 0.5) < 0.06);
    CHECK(windy > 0.7);
    CHECK(std::fabs(normal - calm) < 0.03);
}

TEST_CASE("Shell [dla] scene: a run resumed from a checkpoint steps the same bits", "[fast][shell][dla][checkpoint]")
{
    // walkers alone (with [phase_field] the front's new ice, re-read each step, shields the stick
    // points, so a lost ice set went unnoticed); hits = 2: hit counts in the state
    const std::string text = "[scene]\nname = \"shdr\"\nseed = 3\nframes = 1\nsteps_per_frame = 12\n"
                             "[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.0012\n"
                             "[[crystal.seed]]\nshape = \"point\"\nspace = \"world\"\nposition = [0, 0, 0.0012]\n"
                             "radius = 3\n[dla]\nhumidity = 150\nbatch = 64\nhits = 2\n";
    const std::string path = test::tempDir("shell_dla_resume") + "/x.checkpoint";
    Simulation straight = test::makeSim(text);
    for (int s = 0; s < 12; ++s) straight.step();
    {
        Simulation first = test::makeSim(text);
        for (int s = 0; s < 5; ++s) first.step();
        REQUIRE(first.atCheckpointBoundary());
        first.saveCheckpoint(path);
    }
    Simulation resumed = test::makeSim(text);
    resumed.loadCheckpoint(path);
    for (int s = 5; s < 12; ++s) resumed.step();
    for (const char* f : {"p", "T", "growth_acc", "freeze_time"}) {
        INFO("field " << f);
        auto a = straight.world().fields.get<openvdb::FloatGrid>(f);
        auto b = resumed.world().fields.get<openvdb::FloatGrid>(f);
        CHECK(test::maxAbsDiff(*a, *b) == 0.0);
        CHECK(test::maxAbsDiff(*b, *a) == 0.0);
    }
    double frozen[2] = {0, 0};
    int k = 0;
    for (Simulation* sim : {&straight, &resumed}) {
        for (const auto& e : sim->effects())
            if (e->name() == "dla")
                for (const auto& [key, v] : e->counters())
                    if (key == "frozen") frozen[k] = v;
        ++k;
    }
    INFO("frozen straight " << frozen[0] << ", resumed (after the checkpoint) " << frozen[1]);
    CHECK(frozen[0] > 20); // the walkers did freeze ice, before and after the checkpoint
    CHECK(frozen[1] > 0);
}

TEST_CASE("Shell [dla] with melting ice: a run resumed from a checkpoint steps the same bits",
          "[fast][shell][dla][checkpoint]")
{
    // far warmer than the melt temperature: the phase field melts what walkers freeze. The nodes
    // walkers treat as ice are state of their own (a restored stick point next to a node that
    // melted would mark it again: this failed before they were saved); the pending full resync's
    // condition (ice melted since the last one) is saved too
    const std::string text = "[scene]\nname = \"shdm\"\nseed = 5\nframes = 1\nsteps_per_frame = 72\n"
                             "[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.0012\n"
                             "[[crystal.seed]]\nshape = \"point\"\nspace = \"world\"\nposition = [0, 0, 0.0012]\n"
                             "radius = 4\n[dla]\nhumidity = 60\nbatch = 64\n"
                             "[phase_field]\nfar_temperature = 2.0\n";
    const std::string path = test::tempDir("shell_dla_melt_resume") + "/x.checkpoint";
    Simulation straight = test::makeSim(text);
    for (int s = 0; s < 100; ++s) straight.step();
    int at = 0;
    {
        Simulation first = test::makeSim(text);
        while (at < 56 || !first.atCheckpointBoundary()) {
            first.step();
            ++at;
        }
        REQUIRE(at < 64);
        first.saveCheckpoint(path);
    }
    Simulation resumed = test::makeSim(text);
    resumed.loadCheckpoint(path);
    for (int s = at; s < 100; ++s) resumed.step();
    for (const char* f : {"p", "T", "growth_acc", "freeze_time"}) {
        INFO("field " << f << ", checkpoint at step " << at);
        auto a = straight.world().fields.get<openvdb::FloatGrid>(f);
        auto b = resumed.world().fields.get<openvdb::FloatGrid>(f);
        CHECK(test::maxAbsDiff(*a, *b) == 0.0);
        CHECK(test::maxAbsDiff(*b, *a) == 0.0);
    }
}

TEST_CASE("Shell [dla] steam_humidity: steam beside the object adds walkers released under it",
          "[fast][shell][dla]")
{
    // a sphere of radius 16 voxels with ice at both poles of x; a steam column beside its +x side
    // (summed over three seeds: one run's growth per side varies by about its square root)
    auto runSeed = [](double gain, int seed) {
        const std::string text =
            "[scene]\nname = \"shst\"\nseed = " + std::to_string(seed) + "\nframes = 1\nsteps_per_frame = 8\n"
            "[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.0016\n"
            "[[crystal.seed]]\nshape = \"point\"\nspace = \"world\"\nposition = [0.0016, 0, 0]\nradius = 3\n"
            "[[crystal.seed]]\nshape = \"point\"\nspace = \"world\"\nposition = [-0.0016, 0, 0]\nradius = 3\n"
            "[steam]\ncenter = [0.0024, 0, -0.001]\nradius = 0.0012\nheight = 0.002\ndensity_scale = 40.0\n"
            "threshold = 0.01\n"
            "[dla]\nhumidity = 40\nbatch = 64\nsteam_humidity = " + std::to_string(gain) + "\n";
        auto sim = test::makeSim(text);
        for (int s = 0; s < 8; ++s) sim.step();
        double released = 0;
        for (const auto& e : sim.effects())
            if (e->name() == "dla")
                for (const auto& [k, v] : e->counters())
                    if (k == "released") released = v;
        // growth on the steam side (x > 0) and the other
        auto g = sim.world().fields.get<openvdb::FloatGrid>("growth_acc");
        double plus = 0, minus = 0;
        for (auto it = g->cbeginValueOn(); it; ++it) (it.getCoord().x() > 0 ? plus : minus) += *it;
        return std::array<double, 3>{released, plus, minus};
    };
    auto run = [&](double gain) {
        std::array<double, 3> sum{0, 0, 0};
        for (int seed : {5, 6, 7}) {
            const auto one = runSeed(gain, seed);
            for (int k = 0; k < 3; ++k) sum[size_t(k)] += one[size_t(k)];
        }
        return sum;
    };
    const auto dry = run(0.0), wet = run(200.0);
    INFO("released " << dry[0] << " -> " << wet[0] << "; growth +x/-x " << dry[1] << "/" << dry[2] << " -> " << wet[1]
                     << "/" << wet[2]);
    CHECK(dry[0] == 3 * 8 * 40);
    CHECK(wet[0] > dry[0] * 1.2); // extra walkers from the steam
    // and they freeze on the steam side: its growth rises, by far more than the other side's moves
    CHECK(wet[1] - dry[1] > 0.1 * dry[1]);
    CHECK(wet[1] - dry[1] > 3.0 * std::fabs(wet[2] - dry[2]));
    CHECK(std::fabs(wet[2] - dry[2]) < 0.5 * std::max(1.0, dry[2]) + 0.3 * (wet[1] - dry[1]));
}

TEST_CASE("Surface point index: bucket clearances are lower bounds, exact below a bucket, whatever the history",
          "[fast][shell][dla]")
{
    // points on a sphere of radius 40 voxels (a Fibonacci lattice); the ice is a cluster of them
    constexpr double kR = 40.0;
    std::vector<Vec3d> sphere;
    const int n = 20000;
    for (int i = 0; i < n; ++i) {
        const double z = 1.0 - (2.0 * i + 1.0) / n, r = std::sqrt(1.0 - z * z), a = 2.399963229728653 * i;
        sphere.emplace_back(kR * r * std::cos(a), kR * r * std::sin(a), kR * z);
    }
    ice::WalkerRng rng(7, 0, 0, 0);
    auto pick = [&] { return sphere[size_t((static_cast<unsigned __int128>(rng.next()) * sphere.size()) >> 64)]; };
    auto queryAll = [&](const shell::SurfacePointIndex& index) {
        std::vector<double> d;
        for (size_t i = 0; i < sphere.size(); i += 7) d.push_back(index.distance(sphere[i]));
        return d;
    };
    // history: inserts (ice near the +z pole and a few elsewhere), queries that compute
    // clearances, erases of some of them and more inserts, queries between each
    shell::SurfacePointIndex grown;
    grown.enableClearance(sphere.size(), [&](size_t i) { return sphere[i]; });
    std::vector<Vec3d> ice;
    for (int round = 0; round < 6; ++round) {
        for (int k = 0; k < 60; ++k) {
            Vec3d q = pick();
            if (q.z() < 0.0 && k % 5 != 0) q.z() = -q.z(); // mostly the +z half
            grown.insert(q);
            ice.push_back(q);
        }
        queryAll(grown);
        for (int k = 0; k < 25 && !ice.empty(); ++k) {
            const size_t at = size_t((static_cast<unsigned __int128>(rng.next()) * ice.size()) >> 64);
            REQUIRE(grown.erase(ice[at]));
            ice.erase(ice.begin() + long(at));
        }
        if (round % 2) queryAll(grown);
    }
    shell::SurfacePointIndex fresh;
    fresh.enableClearance(sphere.size(), [&](size_t i) { return sphere[i]; });
    fresh.assign(ice);
    shell::SurfacePointIndex pyramid; // no clearances: the occupancy pyramid's bound alone
    pyramid.assign(ice);
    const auto a = queryAll(grown), b = queryAll(fresh), c = queryAll(pyramid);
    REQUIRE(a.size() == b.size());
    size_t differ = 0, farQueries = 0;
    double worstGap = 0, meanGap = 0, pyramidGap = 0;
    for (size_t k = 0; k < a.size(); ++k) {
        differ += a[k] != b[k];
        const Vec3d& x = sphere[k * 7];
        double truth = 1e18;
        for (const Vec3d& q : ice) truth = std::min(truth, (q - x).length());
        CHECK(a[k] <= truth + 1e-12); // a lower bound
        if (truth <= shell::SurfacePointIndex::kBucket) CHECK(a[k] == Approx(truth).margin(1e-12));
        if (truth > 6.0 && truth < shell::SurfacePointIndex::kClearCap - 1.0) {
            // within a bucket's diagonal of the truth (the pyramid alone gave 4 for 4-16 voxels)
            worstGap = std::max(worstGap, truth - a[k]);
            meanGap += truth - a[k];
            pyramidGap += truth - c[k];
            ++farQueries;
        }
    }
    INFO("queries 6-23 voxels from the ice: " << farQueries << ", mean gap " << meanGap / double(farQueries)
                                              << ", worst " << worstGap << "; the pyramid's mean gap "
                                              << pyramidGap / double(farQueries));
    CHECK(differ == 0); // the same values as an index built from the final points
    REQUIRE(farQueries > 100);
    CHECK(worstGap <= shell::SurfacePointIndex::kBucket * std::sqrt(3.0));
    CHECK(meanGap < 0.5 * pyramidGap);
}

TEST_CASE("Surface point index: a walk's distance is distance() beyond a bucket, and below it says only "
          "whether a point lies within the sticking radius",
          "[fast][shell][dla]")
{
    // ice: a random cluster on a plane z = 0.3 (the walkers' points lie on the surface)
    std::mt19937 gen(11);
    std::uniform_real_distribution<double> u(-30.0, 30.0);
    std::vector<Vec3d> ice, queries;
    for (int k = 0; k < 400; ++k) ice.emplace_back(0.5 * u(gen), 0.5 * u(gen), 0.3);
    for (int k = 0; k < 20000; ++k) queries.emplace_back(u(gen), u(gen), 0.3 + 0.01 * u(gen));
    shell::SurfacePointIndex index;
    index.enableClearance(queries.size(), [&](size_t i) { return queries[i]; });
    index.assign(ice);
    index.flushClearances();
    shell::SurfacePointIndex::Cursor exact(index), walk(index);
    const double stick = shell::ShellWalkers::kStickRadius;
    size_t within = 0, near = 0, far = 0;
    for (const Vec3d& x : queries) {
        const double d = exact.distance(x), w = walk.walkDistance(x, stick);
        if (d > shell::SurfacePointIndex::kBucket) {
            ++far;
            REQUIRE(w == d);
            continue;
        }
        ++near;
        within += d <= stick;
        REQUIRE((w <= stick) == (d <= stick)); // the one comparison a walk makes there
        REQUIRE(w <= d);                       // still a lower bound
    }
    INFO("far " << far << ", near " << near << ", within the sticking radius " << within);
    CHECK(far > 1000);
    CHECK(near > 1000);
    CHECK(within > 100);
}
