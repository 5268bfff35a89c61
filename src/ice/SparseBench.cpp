// `frostvdb bench sparse`: what the sparse engine buys. For one 2D domain it times a phase-field
// step in sparse and dense mode at several ice fractions, then the kernel's voxel-update rate with
// the whole domain active against the plain dense-array loop of the same stencil (same run).
#include <frostvdb/core/Bench.h>
#include <frostvdb/ice/PhaseFieldSolver.h>

#include <tbb/global_control.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>

namespace frostvdb {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

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

    std::printf("frostvdb bench sparse: %dx%d plane, Kobayashi phase field (forward Euler), %d timed steps after %d warm-up\n\n",
                n, n, steps, 2);
    std::printf("| ice fraction | active region | sparse step (ms) | dense step (ms) | dense / sparse |\n");
    std::printf("|---:|---:|---:|---:|---:|\n");
    for (double fraction : {0.002, 0.01, 0.03, 0.10, 0.30}) {
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
