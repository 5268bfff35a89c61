// [dla3d]: off-lattice DLA, mesh loading, constraints, determinism, fractal dimension.
#include "test_util.h"

#include <frostvdb/BuildPaths.h>
#include <frostvdb/dla3d/Aggregate.h>
#include <frostvdb/dla3d/Branches.h>
#include <frostvdb/dla3d/Dla3dEffect.h>
#include <frostvdb/dla3d/Fractal.h>
#include <frostvdb/io/Mesh.h>

#include <openvdb/points/PointCount.h>

#include <catch2/catch.hpp>

#include <tbb/global_control.h>

#include <cstdio>
#include <fstream>

using namespace frostvdb;
using namespace frostvdb::dla3d;
using openvdb::Vec3d;

namespace {

std::string meshPath(const std::string& name) { return std::string(FROSTVDB_SOURCE_DIR) + "/scenes/meshes/" + name; }

/// Independent check: does segment a-b cross any triangle of the mesh (brute force)?
bool crossesAny(const TriangleMesh& m, const Vec3d& a, const Vec3d& b)
{
    for (const auto& f : m.triangles)
        if (segmentHitsTriangle(a, b, Vec3d(m.points[f[0]]), Vec3d(m.points[f[1]]), Vec3d(m.points[f[2]]))) return true;
    return false;
}

double bruteDistance(const TriangleMesh& m, const Vec3d& p)
{
    double best = 1e300;
    for (const auto& f : m.triangles)
        best = std::min(best, (closestPointOnTriangle(p, Vec3d(m.points[f[0]]), Vec3d(m.points[f[1]]),
                                                      Vec3d(m.points[f[2]])) - p).length());
    return best;
}

DlaSettings classic(int dim, uint64_t seed = 1)
{
    DlaSettings s;
    s.dimension = dim;
    s.radius = 0.5;
    s.stickDistance = 0.1;
    s.seed = seed;
    return s;
}

} // namespace

TEST_CASE("Mesh loader places OBJ, STL and PLY and names the file in errors", "[fast][dla3d][mesh]")
{
    const std::string dir = test::tempDir("dla3d_mesh");
    {
        std::ofstream(dir + "/tri.obj") << "v 1 0 0\nv 0 1 0\nv 0 0 0\nf 1 2 3\n";
    }
    MeshPlacement pl;
    pl.scale = Vec3d(2, 2, 2);
    pl.rotateDegrees = Vec3d(0, 0, 90);
    pl.translate = Vec3d(0, 0, 5);
    const TriangleMesh m = loadMesh(dir + "/tri.obj", pl);
    REQUIRE(m.triangles.size() == 1);
    REQUIRE(m.points.size() == 3);
    // (1,0,0) scaled to (2,0,0), turned 90 degrees about z (counter-clockwise) to (0,2,0), lifted to z = 5
    bool found = false;
    for (const auto& p : m.points) found |= (Vec3d(p) - Vec3d(0, 2, 5)).length() < 1e-5;
    CHECK(found);
    CHECK(m.area(0) == Approx(2.0));
    // rotation order: x first, then y
    MeshPlacement xy;
    xy.rotateDegrees = Vec3d(90, 90, 0);
    const TriangleMesh r = loadMesh(dir + "/tri.obj", xy);
    // (0,1,0) -> about x by 90 -> (0,0,1) -> about y by 90 -> (1,0,0)
    found = false;
    for (const auto& p : r.points) found |= (Vec3d(p) - Vec3d(1, 0, 0)).length() < 1e-5;
    CHECK(found);

    const TriangleMesh v = loadMesh(meshPath("vessel.obj"));
    const TriangleMesh s = loadMesh(meshPath("vessel.stl"));
    CHECK(v.triangles.size() == s.triangles.size());
    CHECK(v.totalArea() == Approx(s.totalArea()).epsilon(1e-4));
    writePly(dir + "/v.ply", v.points, v.triangles);
    const TriangleMesh p = loadMesh(dir + "/v.ply");
    CHECK(p.triangles.size() == v.triangles.size());
    CHECK(p.totalArea() == Approx(v.totalArea()).epsilon(1e-5));

    auto message = [](const std::string& path) {
        try {
            loadMesh(path);
        } catch (const std::exception& e) {
            return std::string(e.what());
        }
        return std::string();
    };
    const std::string missing = message(dir + "/nope.obj");
    CHECK(missing.find("nope.obj") != std::string::npos);
    { std::ofstream(dir + "/empty.obj") << "# nothing\n"; }
    const std::string empty = message(dir + "/empty.obj");
    CHECK(empty.find("empty.obj") != std::string::npos);
    { std::ofstream(dir + "/junk.stl") << "this is not a mesh \x01\x02\n"; }
    const std::string junk = message(dir + "/junk.stl");
    CHECK(junk.find("junk.stl") != std::string::npos);
    CHECK(junk.find('\n') == std::string::npos);
}

TEST_CASE("Particles keep their spacing, parents precede children, walkers never overlap", "[fast][dla3d]")
{
    for (int dim : {2, 3}) {
        Aggregate agg(classic(dim));
        REQUIRE(agg.growTo(3000));
        REQUIRE(agg.size() == 3000);
        const auto& p = agg.positions();
        for (size_t i = 1; i < p.size(); ++i) {
            const int32_t par = agg.parents()[i];
            REQUIRE(par >= 0);
            REQUIRE(size_t(par) < i);
            CHECK((p[i] - p[size_t(par)]).length() == Approx(1.0).epsilon(1e-9));
            CHECK(agg.generations()[i] == agg.generations()[size_t(par)] + 1);
            if (dim == 2) CHECK(p[i].z() == 0.0);
        }
        // no two particles closer than the contact distance (less a small slack for the snap)
        size_t overlaps = 0;
        for (uint32_t i = 0; i < p.size(); ++i)
            for (uint32_t j = i + 1; j < p.size(); ++j)
                if ((p[i] - p[j]).lengthSqr() < 0.81) ++overlaps;
        CHECK(overlaps == 0);
    }
}

TEST_CASE("ParticleHash bounds are lower bounds and near answers exact", "[fast][dla3d]")
{
    Aggregate agg(classic(3, 4));
    REQUIRE(agg.growTo(2000));
    const auto& p = agg.positions();
    ParticleHash h(1.5 * 1.1, 3);
    for (uint32_t i = 0; i < p.size(); ++i) h.insert(i, p[i]);
    CounterRng rng(9, 1);
    int hint = 5;
    for (int k = 0; k < 3000; ++k) {
        const Vec3d q = agg.centre() + Vec3d(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5) *
                                           (2.5 * agg.radius() * (k % 3 == 0 ? 0.3 : 1.0));
        double best = 1e300;
        for (const auto& x : p) best = std::min(best, (x - q).length());
        const auto r = h.query(q, p, hint);
        REQUIRE(r.distance <= best + 1e-12);
        if (r.nearest >= 0) CHECK(r.distance == best);
        if (best <= 1.5 * 1.1) CHECK(r.nearest >= 0);
    }
}

TEST_CASE("Fractal dimension of small aggregates is near DLA's (fast check)", "[fast][dla3d][fractal]")
{
    // 20,000 particles: the [slow] test below holds the tight bounds on 100,000
    Aggregate a3(classic(3, 2));
    REQUIRE(a3.growTo(20000));
    const auto g3 = gyrationDimension(a3.positions(), 200);
    INFO("3D D(Rg) = " << g3.dimension);
    CHECK(g3.dimension > 2.3);
    CHECK(g3.dimension < 2.7);
    Aggregate a2(classic(2, 2));
    REQUIRE(a2.growTo(20000));
    const auto g2 = gyrationDimension(a2.positions(), 200);
    INFO("2D D(Rg) = " << g2.dimension);
    CHECK(g2.dimension > 1.6);
    CHECK(g2.dimension < 1.82);
}

TEST_CASE("Fractal dimension on 100,000 particles: 2.5 +- 0.1 (3D), 1.71 +- 0.05 (2D)", "[slow][dla3d][fractal]")
{
    for (int dim : {3, 2}) {
        Aggregate a(classic(dim, 3));
        REQUIRE(a.growTo(100000));
        const auto g = gyrationDimension(a.positions(), 1000);
        const auto m = massRadiusDimension(a.positions(), a.centre(), 10.0, 0.3 * a.radius());
        std::printf("dla3d %dD 100000 particles: D(Rg) = %.4f (r2 %.5f), D(N(r)) = %.4f (r2 %.5f)\n", dim,
                    g.dimension, g.r2, m.dimension, m.r2);
        const double want = dim == 3 ? 2.5 : 1.71, tol = dim == 3 ? 0.1 : 0.05;
        CHECK(std::abs(g.dimension - want) <= tol);
        CHECK(std::abs(m.dimension - want) <= tol);
    }
}

TEST_CASE("Stickiness below 1 gives a denser aggregate", "[fast][dla3d]")
{
    double rg[2];
    for (int k = 0; k < 2; ++k) {
        DlaSettings s = classic(3, 5);
        s.stickiness = k == 0 ? 1.0 : 0.05;
        Aggregate a(s);
        REQUIRE(a.growTo(5000));
        Vec3d c(0.0);
        for (const auto& p : a.positions()) c += p;
        c /= double(a.size());
        double s2 = 0;
        for (const auto& p : a.positions()) s2 += (p - c).lengthSqr();
        rg[k] = std::sqrt(s2 / double(a.size()));
    }
    INFO("Rg stickiness 1: " << rg[0] << ", 0.05: " << rg[1]);
    // same mass in a smaller radius: denser (mass / Rg^3 up by more than 15%)
    CHECK(std::pow(rg[0] / rg[1], 3.0) > 1.15);
}

TEST_CASE("No particle crosses a constraint surface (vessel and sphere)", "[fast][dla3d][constraint]")
{
    SECTION("roots inside an open glass")
    {
        auto mesh = std::make_shared<TriangleMesh>(loadMesh(meshPath("vessel.obj")));
        DlaSettings s;
        s.radius = 0.003;
        s.stickDistance = 0.002;
        s.seeds = {Vec3d(0, 0, 0.17)};
        s.launch = Launch::Plane;
        s.planeOrigin = Vec3d(-0.2, -0.2, 0.01);
        s.planeU = Vec3d(0.4, 0, 0);
        s.planeV = Vec3d(0, 0.4, 0);
        s.bias = Vec3d(0, 0, 0.2);
        s.constraint = std::make_shared<MeshConstraint>(*mesh, 2 * s.contact() + s.stickDistance, s.contact());
        Aggregate a(s);
        REQUIRE(a.growTo(2500));
        // the glass is open at the top: a branch may leave over the rim (z = 0.2) and come down
        // outside, but one that never rose above the rim must stay inside the wall
        size_t crossings = 0, tooClose = 0, outside = 0;
        std::vector<char> overRim(a.size(), 0);
        for (size_t i = 1; i < a.size(); ++i) {
            const Vec3d& p = a.positions()[i];
            const size_t par = size_t(a.parents()[i]);
            overRim[i] = overRim[par] || p.z() >= 0.2;
            crossings += crossesAny(*mesh, a.positions()[par], p);
            tooClose += bruteDistance(*mesh, p) < s.radius * (1 - 1e-6);
            outside += (!overRim[i] && std::hypot(p.x(), p.y()) > 0.08) || p.z() < 0;
        }
        CHECK(crossings == 0);
        CHECK(tooClose == 0);
        CHECK(outside == 0);
        CHECK(a.stats().refusedConstraint > 0); // the walls were met
    }
    SECTION("lichen on a sphere")
    {
        auto mesh = std::make_shared<TriangleMesh>(loadMesh(meshPath("sphere.obj")));
        DlaSettings s;
        s.radius = 0.002;
        s.stickDistance = 0.001;
        s.seeds = {Vec3d(0, 0, 0.1021), Vec3d(0.1021, 0, 0)};
        s.centre = Vec3d(0, 0, 0);
        s.centreGiven = true;
        s.launch = Launch::Surface;
        s.launchMesh = mesh;
        s.launchOffset = 0.02;
        s.constraint = std::make_shared<MeshConstraint>(*mesh, 2 * s.contact() + s.stickDistance, s.contact());
        Aggregate a(s);
        REQUIRE(a.growTo(2500));
        size_t crossings = 0, inside = 0;
        for (size_t i = 2; i < a.size(); ++i) {
            const Vec3d& p = a.positions()[i];
            crossings += crossesAny(*mesh, a.positions()[size_t(a.parents()[i])], p);
            inside += bruteDistance(*mesh, p) < s.radius * (1 - 1e-6) || p.length() < 0.09;
        }
        CHECK(crossings == 0);
        CHECK(inside == 0);
    }
}

namespace {
const char* kScene = R"(
[scene]
name = "d3"
frames = 2
steps_per_frame = 2
seed = 11
[domain]
kind = "box"
size = [8, 8, 8]
voxel_size = 0.01
[output]
preview = "none"
[dla3d]
particles = 3000
radius = 0.01
stick_distance = 0.004
rotation = 30
bias = [0.1, 0.0, -0.2]
launch = "sphere"
seeds = [0, 0, 0, 0.3, 0, 0]
voxel_size = 0.008
batch_fraction = 0.01
)";

/// Byte comparison of two VDB files, ignoring the random per-file UUID (header bytes 21-56).
bool sameBytes(const std::string& a, const std::string& b)
{
    std::string x = test::readFile(a), y = test::readFile(b);
    if (x.size() != y.size() || x.size() < 64) return false;
    for (size_t i = 21; i < 57; ++i) x[i] = y[i] = '-';
    return x == y;
}
} // namespace

TEST_CASE("Same seed gives bit-identical dla3d files with 1 and 2 threads", "[fast][dla3d][determinism]")
{
    std::string paths[2];
    for (int threads : {1, 2}) {
        auto sim = test::makeSim(kScene);
        RunOptions ro;
        ro.progress = false;
        ro.threads = threads;
        ro.outDir = test::tempDir("dla3d_det" + std::to_string(threads));
        sim.run(ro);
        paths[threads - 1] = ro.outDir + "/d3.0002.vdb";
        auto* fx = dynamic_cast<Dla3dEffect*>(sim.effect("dla3d"));
        REQUIRE(fx);
        CHECK(fx->aggregate().size() == 3000);
        CHECK(fx->aggregate().stats().conflicts > 0); // speculation lost some walkers: the path is exercised
    }
    CHECK(sameBytes(paths[0], paths[1]));
    auto other = test::makeSim(kScene, {"scene.seed=12"});
    RunOptions ro;
    ro.progress = false;
    ro.outDir = test::tempDir("dla3d_det_other");
    other.run(ro);
    CHECK(!sameBytes(ro.outDir + "/d3.0002.vdb", paths[0]));

    // the file holds points with their attributes, ice_sdf and ice
    openvdb::io::File f(paths[0]);
    f.open();
    auto grids = f.getGrids();
    std::set<std::string> names;
    for (auto& g : *grids) names.insert(g->getName());
    CHECK(names == std::set<std::string>{"points", "ice_sdf", "aggregate_ice"});
    for (auto& g : *grids)
        if (auto pts = openvdb::gridPtrCast<openvdb::points::PointDataGrid>(g)) {
            CHECK(openvdb::points::pointCount(pts->tree()) == 3000);
            const auto& desc = pts->tree().cbeginLeaf()->attributeSet().descriptor();
            for (const char* a : {"radius", "parent", "generation", "attach_time", "id"})
                CHECK(desc.find(a) != openvdb::points::AttributeSet::INVALID_POS);
        } else if (auto fg = openvdb::gridPtrCast<openvdb::FloatGrid>(g)) {
            CHECK(fg->activeVoxelCount() > 1000);
            for (auto it = fg->cbeginValueOn(); it; ++it) REQUIRE(std::isfinite(*it));
        }
}

TEST_CASE("Branch radii taper from the root to the tips", "[fast][dla3d]")
{
    // a chain 0-1-2-3 with a side tip 4 on 1
    const std::vector<int32_t> parents{-1, 0, 1, 2, 1};
    BranchStyle st;
    st.tipRadius = 1.0;
    st.taper = 0.5;
    st.maxScale = 10;
    const auto r = branchRadii(parents, st);
    CHECK(r[3] == Approx(1.0));
    CHECK(r[4] == Approx(1.0));
    CHECK(r[2] == Approx(std::sqrt(2.0)));
    CHECK(r[1] == Approx(2.0));
    CHECK(r[0] == Approx(std::sqrt(5.0)));
}

TEST_CASE("dla3d scenes load and bad keys are refused with file and key", "[fast][dla3d]")
{
    namespace fs = std::filesystem;
    int n = 0;
    for (const auto& e : fs::directory_iterator(fs::path(FROSTVDB_SOURCE_DIR) / "scenes")) {
        const std::string name = e.path().filename().string();
        if (name.rfind("dla3d_", 0) != 0 || e.path().extension() != ".toml") continue;
        INFO(name);
        CHECK_NOTHROW(Simulation(Scene::load(e.path().string())));
        ++n;
    }
    CHECK(n >= 4);
    try {
        test::makeSim(std::string(kScene) + "stickiness = 2\n");
        FAIL("no error");
    } catch (const std::exception& e) {
        const std::string m = e.what();
        CHECK(m.find("test.toml") != std::string::npos);
        CHECK(m.find("stickiness") != std::string::npos);
    }
    auto sim = test::makeSim(std::string(kScene) + "constraint_mesh = \"no_such_mesh.obj\"\n");
    try {
        sim.initialize();
        FAIL("no error");
    } catch (const std::exception& e) {
        CHECK(std::string(e.what()).find("no_such_mesh.obj") != std::string::npos);
    }
}
