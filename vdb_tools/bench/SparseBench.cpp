// `frostvdb bench sparse`: what the sparse engine buys. For one 2D domain it times a phase-field
// step in sparse and dense mode at several ice fractions, then the kernel's voxel-update rate with
// the whole domain active against the plain dense-array loop of the same stencil (same run).
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/core/Bench.h>
#include <frostvdb/icephysics/EulerRows.h>
#include <frostvdb/ice/PhaseFieldSolver.h>

#include <tbb/global_control.h>

#include <chrono>
#include <ctime>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>
#include <algorithm>
#include <memory>

namespace frostvdb {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
/// CPU seconds of the calling thread: with --threads 1 all of a step's work, and unlike wall time
/// not inflated by the scheduler when other processes share the cores.
double threadCpu()
{
    timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

/// Ice discs covering @a fraction of an n x n plane, spread over a few centres (a frost front
/// rather than one blob), p = 1 inside with a one-cell smooth edge.
openvdb::FloatGrid::Ptr iceCover(int n, double fraction)
{
    auto p = openvdb::FloatGrid::create(0.f);
    const int discs = 4;
    const double r = std::sqrt(fraction * n * n / (discs * M_PI));
    auto acc = p->getAccessor();
    for (int d = 0; d < discs; ++d) {
        const double cx = n * (0.25 + 0.5 * (d % 2)), cy = n * (0.25 + 0.5 * (d / 2));
        const int r0 = int(r) + 2;
        for (int j = int(cy) - r0; j <= int(cy) + r0; ++j)
            for (int i = int(cx) - r0; i <= int(cx) + r0; ++i) {
                if (i < 0 || j < 0 || i >= n || j >= n) continue;
                const double dist = std::hypot(i - cx, j - cy);
                const double v = std::clamp(r + 0.5 - dist, 0.0, 1.0);
                if (v > 0) acc.setValue(openvdb::Coord(i, j, 0), float(v));
            }
    }
    return p;
}

/// The realistic case of issue 10: one disc seed on a square plane grown with forward Euler
/// until its heat covers the domain, region tolerance 0, the engine's whole step (region +
/// kernel + truncation, with the growth and freeze-time accumulators of the effect) against the
/// plain dense-array loop of the same equations from the same start, in the same run.
struct RealisticResult {
    double engineSeconds = 0, denseSeconds = 0, fullEngineSeconds = 0, fullDenseSeconds = 0;
    double vectorDenseSeconds = 0, fullVectorDenseSeconds = 0; ///< the dense loop on the engine's vector rows
    double fullEngineCpu = 0, fullDenseCpu = 0, fullVectorDenseCpu = 0; ///< calling thread's CPU seconds
    int64_t fullSteps = 0, rebuilds = 0;
    PhaseFieldStepStats stats, fullStats; ///< all steps; the fully active ones
    double finalFraction = 0;
    double maxDiff = 0;
    double area = 0;
};

RealisticResult realistic(int n, int steps, int rebuildEvery)
{
    KobayashiParams k;
    k.dt = 0.0002;
    k.delta = 0.04;
    k.latentHeat = 1.6;
    const Lattice lat(LatticeKind::Square, 0.03);
    const Domain dom = makePlaneDomain(lat, openvdb::Coord(n, n, 1), 1e-4);
    RegionSettings rs;
    rs.tolerance = 0.0;
    rs.rebuildEvery = rebuildEvery;
    PhaseFieldSolver solver(k, dom, rs);
    solver.setSoleWriter(true); // as in a scene whose only writer of p and T is [phase_field]
    DensePhaseField ref(k, lat, n, n), refVec(k, lat, n, n);
    refVec.setVectorRows(true);
    auto p = openvdb::FloatGrid::create(0.f);
    auto T = openvdb::FloatGrid::create(float(k.farTemperature));
    auto growth = openvdb::FloatGrid::create(0.f), freeze = openvdb::FloatGrid::create(0.f);
    const double c = 0.5 * (n - 1), r = 5.0;
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const double v = std::clamp(r + 0.5 - std::hypot(i - c, j - c), 0.0, 1.0);
            if (v <= 0) continue;
            p->tree().setValue(openvdb::Coord(i, j, 0), float(v));
            ref.p()[ref.index(i, j)] = float(v);
            refVec.p()[refVec.index(i, j)] = float(v);
        }
    // The plane layout a scene has: p, T and the accumulators folded (core/PlaneFold.h) unless
    // FROSTVDB_NO_PLANE_FOLD=1 (the layout before session 13, for comparison).
    if (plane::foldsPlaneFields(dom)) {
        p = plane::foldGrid(*p);
        T = plane::foldGrid(*T);
        plane::markFolded(*growth);
        plane::markFolded(*freeze);
    }
    RealisticResult out;
    // Interleaved step by step so that both see the same machine load; the steps where the
    // engine's region is the whole domain are also summed apart.
    for (int s = 0; s < steps; ++s) {
        PhaseFieldStepStats st;
        auto t0 = Clock::now();
        double c0 = threadCpu();
        solver.step(p, T, growth.get(), freeze.get(), s, s * k.dt, 1, &st);
        const double te = since(t0), ce = threadCpu() - c0;
        t0 = Clock::now();
        c0 = threadCpu();
        ref.step();
        const double td = since(t0), cd = threadCpu() - c0;
        t0 = Clock::now();
        c0 = threadCpu();
        refVec.step();
        const double tv = since(t0), cv = threadCpu() - c0;
        out.engineSeconds += te;
        out.denseSeconds += td;
        out.vectorDenseSeconds += tv;
        if (st.regionVoxels == dom.voxelCount()) {
            out.fullEngineSeconds += te;
            out.fullDenseSeconds += td;
            out.fullVectorDenseSeconds += tv;
            out.fullEngineCpu += ce;
            out.fullDenseCpu += cd;
            out.fullVectorDenseCpu += cv;
            ++out.fullSteps;
            out.fullStats.regionSeconds += st.regionSeconds;
            out.fullStats.kernelSeconds += st.kernelSeconds;
            out.fullStats.truncateSeconds += st.truncateSeconds;
        }
        out.stats.regionSeconds += st.regionSeconds;
        out.stats.kernelSeconds += st.kernelSeconds;
        out.stats.truncateSeconds += st.truncateSeconds;
        out.rebuilds += st.rebuilds;
        out.finalFraction = double(st.regionVoxels) / double(dom.voxelCount());
    }
    const plane::FloatCells pa(*p), ta(*T);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const openvdb::Coord q(i, j, 0);
            out.maxDiff = std::max(out.maxDiff, double(std::fabs(pa.getValue(q) - ref.p()[ref.index(i, j)])));
            out.maxDiff = std::max(out.maxDiff, double(std::fabs(ta.getValue(q) - ref.T()[ref.index(i, j)])));
            out.maxDiff = std::max(out.maxDiff, double(std::fabs(refVec.p()[ref.index(i, j)] - ref.p()[ref.index(i, j)])));
            out.maxDiff = std::max(out.maxDiff, double(std::fabs(refVec.T()[ref.index(i, j)] - ref.T()[ref.index(i, j)])));
            out.area += ref.p()[ref.index(i, j)] > 0.5f;
        }
    return out;
}

/// Which row code the engine runs on this machine for the square plane (EulerRows.h).
std::string rowsName()
{
    KobayashiParams k;
    FlatStencil st(Lattice(LatticeKind::Square, 0.03).stencil(false), 64, 0);
    return fastestEulerRows(st, Anisotropy(k)).vector ? "AVX2 vector" : "plain";
}

void benchRealistic(const BenchArgs& args)
{
    const int steps = args.quick ? 200 : 2000;
    std::printf("Realistic full-domain run (issue 10): square plane, spacing 0.03, forward Euler dt 0.0002, delta 0.04, "
                "K 1.6, one disc seed of radius 5 cells, %d steps, region tolerance 0, threads %s.\n"
                "Engine = PhaseFieldSolver::step (region + kernel + truncation, growth and freeze-time accumulators; "
                "%s row code); dense = DensePhaseField::step, the plain dense-array loop of the same arithmetic "
                "(one cell at a time); dense, vector rows = the same loop on the engine's row code; the three stepped "
                "alternately in the same run. max diff: largest |difference| of p and T between the three at the end.\n\n",
                steps, args.threads > 0 ? std::to_string(args.threads).c_str() : "all", rowsName().c_str());
    std::printf("| size | rebuild_every | engine (s) | region / kernel / truncation (s) | rebuilds | dense loop (s) | "
                "dense / engine | fully active steps | dense / engine there | dense, vector rows / engine there | final region | max diff |\n");
    std::printf("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    std::vector<int> sizes{300, 600};
    if (args.args.size() > 1) sizes = {std::stoi(args.args[1])}; // `bench sparse realistic N`: one size
    for (int n : sizes) {
        for (int every : {1, 0}) {
            if (n != 300 && every == 1) continue; // the old cadence once, at the size
            const RealisticResult r = realistic(n, steps, every);
            std::printf("| %dx%d | %s | %.2f | %.2f / %.2f / %.2f | %lld | %.2f | %.2fx | %lld | %.2fx | %.2fx | %.0f%% | %g |\n", n, n,
                        every == 0 ? "auto" : std::to_string(every).c_str(), r.engineSeconds, r.stats.regionSeconds,
                        r.stats.kernelSeconds, r.stats.truncateSeconds, (long long)r.rebuilds, r.denseSeconds,
                        r.denseSeconds / r.engineSeconds, (long long)r.fullSteps,
                        r.fullSteps ? r.fullDenseSeconds / r.fullEngineSeconds : 0.0,
                        r.fullSteps ? r.fullVectorDenseSeconds / r.fullEngineSeconds : 0.0, 100.0 * r.finalFraction, r.maxDiff);
            std::fflush(stdout);
            if (r.fullSteps)
                std::fprintf(stderr, "  %dx%d fully active steps, per step: region %.3f ms, kernel %.3f ms, truncation %.3f ms; dense loop %.3f ms (vector rows %.3f ms)\n",
                             n, n, 1e3 * r.fullStats.regionSeconds / r.fullSteps, 1e3 * r.fullStats.kernelSeconds / r.fullSteps,
                             1e3 * r.fullStats.truncateSeconds / r.fullSteps, 1e3 * r.fullDenseSeconds / r.fullSteps,
                             1e3 * r.fullVectorDenseSeconds / r.fullSteps);
            if (r.fullSteps && args.threads == 1)
                std::fprintf(stderr, "  %dx%d fully active steps, CPU ms per step: engine %.3f, dense loop %.3f (vector rows %.3f): "
                             "dense / engine %.2fx\n", n, n, 1e3 * r.fullEngineCpu / r.fullSteps, 1e3 * r.fullDenseCpu / r.fullSteps,
                             1e3 * r.fullVectorDenseCpu / r.fullSteps, r.fullDenseCpu / r.fullEngineCpu);
        }
    }
    std::printf("\n");
}

int benchSparse(const BenchArgs& args)
{
    std::unique_ptr<tbb::global_control> gc;
    if (args.threads > 0)
        gc = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, args.threads);
    const int n = args.quick ? 512 : 2048;
    const int steps = args.quick ? 3 : 5;
    KobayashiParams k;
    const Lattice lat(LatticeKind::Square, 3.0 / 64.0);
    const Domain dom = makePlaneDomain(lat, openvdb::Coord(n, n, 1), 1e-4);
    RegionSettings sparse, dense;
    dense.dense = true;

    const std::string only = args.args.empty() ? "" : args.args[0]; // realistic | fractions | kernel
    if (only.empty() || only == "realistic") benchRealistic(args);
    if (only == "realistic") return 0;

    std::printf("frostvdb bench sparse: %dx%d plane, Kobayashi phase field (forward Euler), %d timed steps after %d warm-up\n\n",
                n, n, steps, 2);
    std::printf("| ice fraction | active region | sparse step (ms) | dense step (ms) | dense / sparse |\n");
    std::printf("|---:|---:|---:|---:|---:|\n");
    for (double fraction : {0.002, 0.01, 0.03, 0.10, 0.30}) {
        if (only == "kernel") break;
        double t[2] = {0, 0};
        uint64_t regionVoxels = 0;
        for (int mode = 0; mode < 2; ++mode) {
            PhaseFieldSolver solver(k, dom, mode == 0 ? sparse : dense);
            auto p = iceCover(n, fraction);
            auto T = openvdb::FloatGrid::create(float(k.farTemperature));
            for (int s = 0; s < 2; ++s) solver.step(p, T, nullptr, nullptr, s, s * k.dt, 1);
            PhaseFieldStepStats stats;
            const auto t0 = Clock::now();
            for (int s = 0; s < steps; ++s) solver.step(p, T, nullptr, nullptr, s + 2, (s + 2) * k.dt, 1, &stats);
            t[mode] = since(t0) / steps;
            if (mode == 0) regionVoxels = stats.regionVoxels;
        }
        std::printf("| %.1f%% | %.2f%% | %.1f | %.1f | %.1fx |\n", fraction * 100.0,
                    100.0 * double(regionVoxels) / double(dom.voxelCount()), t[0] * 1e3, t[1] * 1e3, t[1] / t[0]);
        std::fflush(stdout);
    }

    // Kernel throughput with the whole domain active: same arithmetic, padded VDB leaf blocks
    // versus one flat array.
    auto p = iceCover(n, 0.3);
    auto T = openvdb::FloatGrid::create(float(k.farTemperature));
    auto region = openvdb::MaskGrid::create(false);
    region->tree().fill(dom.bbox(), true, true);
    region->tree().voxelizeActiveTiles();
    PhaseFieldSolver solver(k, dom, dense);
    DensePhaseField ref(k, lat, n, n);
    for (auto it = p->cbeginValueOn(); it; ++it) ref.p()[ref.index(it.getCoord().x(), it.getCoord().y())] = *it;
    double best[2] = {1e30, 1e30};
    for (int rep = 0; rep < steps; ++rep) {
        auto pOut = openvdb::FloatGrid::create(0.f), tOut = openvdb::FloatGrid::create(0.f);
        pOut->tree().topologyUnion(region->tree()); // topology outside the timing: kernel only
        tOut->tree().topologyUnion(region->tree());
        auto t0 = Clock::now();
        solver.kernelOnly(*region, *p, *T, *pOut, *tOut);
        best[0] = std::min(best[0], since(t0));
        t0 = Clock::now();
        ref.step();
        best[1] = std::min(best[1], since(t0));
    }
    const double voxels = double(n) * n;
    std::printf("\nKernel voxel-update rate, whole %dx%d domain active (best of %d):\n\n", n, n, steps);
    std::printf("| kernel | Mvoxel updates/s |\n|---|---:|\n");
    std::printf("| sparse VDB kernel (leaf blocks + halo) | %.1f |\n", voxels / best[0] / 1e6);
    std::printf("| plain dense-array loop, same stencil | %.1f |\n", voxels / best[1] / 1e6);
    std::printf("\nsparse / dense-array rate: %.2f (target >= 0.5)\n", best[1] / best[0]);
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(sparse, "sparse",
                        "phase-field step time sparse vs dense at several ice fractions; kernel rate vs a dense-array loop",
                        benchSparse);

} // namespace frostvdb
