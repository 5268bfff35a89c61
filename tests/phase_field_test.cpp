// The Kobayashi phase field on the sparse engine: dense reference, tolerance convergence,
// arm count, determinism.
#include "test_util.h"
#include "plane_layout_util.h"

#include <frostvdb/core/Error.h>
#include <frostvdb/ice/PhaseFieldSolver.h>

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <tbb/global_control.h>

#include <cmath>
#include <complex>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

const char* kSmallScene = R"(
[scene]
name = "small"
frames = 1
steps_per_frame = 300
[domain]
size = [64, 64]
[phase_field]
anisotropy_mode = 4
)";

/// Angular Fourier amplitudes |sum p r e^{i m phi}| of the frozen cells beyond 40% of the
/// largest radius (the arms, not the core), around the domain centre, for m = 1..8.
std::vector<double> angularModes(const openvdb::FloatGrid& p, const Domain& dom)
{
    const auto c3 = dom.centre();
    const auto c = dom.lattice().planePosition(c3.x(), c3.y());
    double rmax = 0;
    for (auto it = p.cbeginValueOn(); it; ++it)
        if (*it > 0.5f) {
            auto q = dom.lattice().planePosition(it.getCoord().x(), it.getCoord().y()) - c;
            rmax = std::max(rmax, q.length());
        }
    std::vector<std::complex<double>> f(9);
    for (auto it = p.cbeginValueOn(); it; ++it) {
        if (*it <= 0.5f) continue;
        auto q = dom.lattice().planePosition(it.getCoord().x(), it.getCoord().y()) - c;
        const double r = q.length();
        if (r < 0.4 * rmax) continue;
        const double phi = std::atan2(q.y(), q.x());
        for (int m = 1; m <= 8; ++m) f[m] += r * std::polar(1.0, m * phi);
    }
    std::vector<double> a(9, 0.0);
    for (int m = 1; m <= 8; ++m) a[m] = std::abs(f[m]);
    return a;
}

} // namespace

TEST_CASE("Sparse kernel in dense mode equals the plain dense-array loop bit for bit", "[fast][phase_field]")
{
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        KobayashiParams k;
        k.anisotropyMode = kind == LatticeKind::Square ? 4 : 6;
        const int n = 40;
        Lattice lat(kind, 3.0 / 64.0);
        const Domain dom = makePlaneDomain(lat, openvdb::Coord(n, n, 1), 1e-4);
        RegionSettings rs;
        rs.dense = true;
        PhaseFieldSolver solver(k, dom, rs);
        DensePhaseField ref(k, lat, n, n);
        auto p = openvdb::FloatGrid::create(0.f);
        auto T = openvdb::FloatGrid::create(0.f);
        for (int j = 17; j <= 22; ++j)
            for (int i = 17; i <= 22; ++i) {
                p->tree().setValue(openvdb::Coord(i, j, 0), 1.f);
                ref.p()[ref.index(i, j)] = 1.f;
            }
        for (int s = 0; s < 60; ++s) {
            solver.step(p, T, nullptr, nullptr, s, s * k.dt, 1);
            ref.step();
        }
        auto pa = p->getConstAccessor();
        auto ta = T->getConstAccessor();
        size_t mismatches = 0;
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) {
                mismatches += pa.getValue(openvdb::Coord(i, j, 0)) != ref.p()[ref.index(i, j)];
                mismatches += ta.getValue(openvdb::Coord(i, j, 0)) != ref.T()[ref.index(i, j)];
            }
        INFO(Lattice::kindName(kind));
        CHECK(mismatches == 0);
        CHECK(ref.p()[ref.index(20, 20)] > 0.9f); // the seed survived: a real solution
    }
}

TEST_CASE("Sparse results converge to the dense reference as the tolerance goes to 0", "[fast][phase_field][region]")
{
    auto run = [](const std::vector<std::string>& extra) {
        auto sim = makeSim(kSmallScene, extra);
        sim.initialize();
        for (int s = 0; s < 300; ++s) sim.step();
        auto p = sim.world().fields.get<openvdb::FloatGrid>("p");
        auto T = sim.world().fields.get<openvdb::FloatGrid>("T");
        return std::make_pair(p, T);
    };
    auto dense = run({"region.dense=true"});
    double prev = 1e9;
    for (double tol : {1e-2, 1e-3, 1e-4, 1e-6, 0.0}) {
        auto sparse = run({"region.tolerance=" + std::to_string(tol)});
        const double dp = maxAbsDiff(*sparse.first, *dense.first);
        const double dT = maxAbsDiff(*sparse.second, *dense.second);
        const double err = std::max(dp, dT);
        // Reported so the trade can be read from the test log (ctest --output-on-failure -V).
        WARN("tolerance " << tol << ": max |p - p_dense| = " << dp << ", max |T - T_dense| = " << dT
                          << ", active T voxels " << sparse.second->activeVoxelCount() << " of "
                          << dense.second->activeVoxelCount());
        CHECK(err <= prev + 1e-12);
        if (tol <= 1e-6) CHECK(err < 1e-4);
        if (tol == 0.0) CHECK(err == 0.0); // tolerance 0 is the dense answer, bit for bit
        prev = err;
    }
}

TEST_CASE("The default dendrite has 4 arms with j=4 and 6 arms with j=6", "[fast][phase_field]")
{
    for (int j : {4, 6}) {
        Scene scene = Scene::builtinDefault();
        scene.applyOverride("phase_field.anisotropy_mode=" + std::to_string(j));
        scene.applyOverride("scene.frames=6");
        Simulation s(std::move(scene));
        RunOptions ro;
        ro.progress = false;
        ro.writeFiles = false;
        s.run(ro);
        auto p = planeLayout(s.world(), "p");
        const auto modes = angularModes(*p, s.world().domain);
        int best = 2;
        for (int m = 2; m <= 8; ++m)
            if (modes[m] > modes[best]) best = m;
        std::ostringstream os;
        for (int m = 1; m <= 8; ++m) os << " m" << m << "=" << modes[m];
        INFO("j=" << j << " angular modes:" << os.str());
        CHECK(best == j);
        for (int m = 2; m <= 8; ++m)
            if (m != j && m != 2 * j) CHECK(modes[j] > 3.0 * modes[m]);
    }
}

TEST_CASE("Same seed gives bit-identical files with 1 and 2 threads", "[fast][phase_field][determinism]")
{
    const std::string scene = std::string(kSmallScene) + "noise = 0.01\n";
    std::string files[2];
    std::string paths[2];
    int idx = 0;
    for (int threads : {1, 2}) {
        auto sim = makeSim(scene, {"scene.steps_per_frame=150"});
        RunOptions ro;
        ro.progress = false;
        ro.threads = threads;
        ro.outDir = tempDir("det" + std::to_string(threads));
        auto sum = sim.run(ro);
        REQUIRE(!sum.files.empty());
        paths[idx] = ro.outDir + "/small.0001.vdb";
        files[idx] = readFile(paths[idx]);
        ++idx;
    }
    REQUIRE(files[0].size() > 1000);
    std::string why;
    CHECK(sameVdbContent(paths[0], paths[1], &why));
    INFO(why);
    // A different seed gives a different result (the noise is really used).
    auto other = makeSim(scene, {"scene.steps_per_frame=150", "scene.seed=2"});
    RunOptions ro;
    ro.progress = false;
    ro.outDir = tempDir("det_other");
    other.run(ro);
    CHECK(!sameVdbContent(ro.outDir + "/small.0001.vdb", paths[0]));
}

TEST_CASE("Explicit stability limit is reported and a larger dt is refused", "[fast][phase_field]")
{
    KobayashiParams k;
    const Lattice lat(LatticeKind::Square, 3.0 / 64.0);
    const double limit = k.explicitStabilityLimit(lat.stencil(false));
    // Monotone update: dt (eps_max^2 |w0| + max|n'|) <= tau; here it is below the heat bound h^2/4.
    double growth, decay;
    k.reactionSlopeBounds(growth, decay);
    const double h = 3.0 / 64.0, epsMax = k.epsBar * (1 + k.delta);
    CHECK(decay == Approx(0.5 + 0.45).epsilon(1e-3)); // |n'| at p = 0 with m = -alpha/2
    CHECK(limit == Approx(k.tau / (epsMax * epsMax * 4.0 / (h * h) + decay)));
    CHECK(limit < h * h / 4.0);
    CHECK_NOTHROW(makeSim(kSmallScene, {"phase_field.dt=" + std::to_string(limit * 0.99)}));
    try {
        makeSim(kSmallScene, {"phase_field.dt=" + std::to_string(limit * 1.1)});
        FAIL("dt above the limit was accepted");
    } catch (const std::exception& e) {
        const std::string msg = e.what();
        CHECK(msg.find("phase_field.dt") != std::string::npos);
        CHECK(msg.find("stability limit") != std::string::npos);
    }
}

TEST_CASE("A solver that leaves its bounds stops naming field, voxel, step and time, and writes no file",
          "[fast][phase_field][guard]")
{
    // Forward Euler is bounded below its limit (kobayashiEuler's limiter), and so is lw_cn with
    // its Gauss-Seidel solve (positive rows); BiCGSTAB stopped at tolerance 1 is not a positive
    // scheme: at delta 0.5, K 5 p reaches -0.26 in step 363.
    auto sim = makeSim(kSmallScene, {"phase_field.delta=0.5", "phase_field.latent_heat=5", "phase_field.scheme=\"lw_cn\"",
                                     "phase_field.solver=\"bicgstab\"", "phase_field.precision=\"custom\"",
                                     "phase_field.solver_tolerance=1.0", "phase_field.max_iterations=1",
                                     "phase_field.dt=0.0009", "scene.frames=1", "scene.steps_per_frame=400"});
    RunOptions ro;
    ro.progress = false;
    ro.outDir = tempDir("guard");
    try {
        sim.run(ro);
        FAIL("the unstable run was not stopped");
    } catch (const SimulationError& e) {
        const std::string msg = e.what();
        CHECK(msg.find("p (ice)") != std::string::npos);
        CHECK(msg.find("at voxel [") != std::string::npos);
        CHECK(msg.find("in step ") != std::string::npos);
        CHECK(msg.find("t = ") != std::string::npos);
    }
    // No frame is written; run.json records the failure (and no file).
    CHECK(frameFilesIn(ro.outDir).empty());
    const std::string json = readFile(ro.outDir + "/run.json");
    const auto j = nlohmann::json::parse(json);
    CHECK(j["status"] == "failed");
    CHECK(j["files"] == nlohmann::json::array());
}

TEST_CASE("Hexagonal D6 forms of eps and eps' equal the trigonometric ones", "[fast][phase_field]")
{
    // hexEpsilonD6 evaluates cos and sin of 6 theta from the projections of the gradient on the
    // three lattice directions; it must be the same function as Anisotropy's for any gradient.
    KobayashiParams k;
    k.anisotropyMode = 6;
    k.delta = 0.2;
    const Anisotropy an(k);
    const Lattice lat(LatticeKind::Hexagonal, 0.03);
    const int W = 8;
    FlatStencil st(lat.stencil(false), W, 0);
    useD6Forms(st, an);
    REQUIRE(st.d6);
    std::vector<float> u(size_t(W) * W, 0.f);
    const size_t i = size_t(3) * W + 3;
    double worst = 0;
    for (int trial = 0; trial < 200; ++trial) {
        const double gx = std::cos(0.1 * trial * 1.7) * (1 + trial % 5), gy = std::sin(0.1 * trial * 2.3) * (2 - trial % 3);
        // A linear field in axial coordinates: value at (a, b) = g . (a + b/2, b sqrt3/2) h.
        for (int b = -1; b <= 1; ++b)
            for (int a = -1; a <= 1; ++a)
                u[i + size_t(b * W + a)] = float((gx * (a + 0.5 * b) + gy * b * std::sqrt(3.0) / 2.0) * 0.03);
        double U[3], e1, p1, e2, p2;
        hexProjections(u.data(), i, st, U);
        hexEpsilonD6(U, st, an, e1, p1);
        // The same gradient as the generic central difference sees it.
        double sx = 0, sy = 0;
        for (int q = 0; q < st.n; ++q) {
            const double d = st.wGrad[q] * (double(u[i + st.off[q]]) - u[i]);
            sx += d * st.ex[q];
            sy += d * st.ey[q];
        }
        an(sx, sy, e2, p2);
        worst = std::max({worst, std::fabs(e1 - e2), std::fabs(p1 - p2)});
    }
    CHECK(worst < 1e-12);
}
