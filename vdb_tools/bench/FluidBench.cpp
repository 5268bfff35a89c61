// `frostvdb bench fluid [SIZE...]`: the pressure solve of a flow past a ball (a disc in 2D) by
// the multigrid-preconditioned CG, next to the Jacobi-preconditioned CG on the same system and
// OpenVDB's tools::poisson, then what a whole fluid step costs. SIZE is n^2 or n^3 (default
// 256^2 1024^2 128^3 256^3; --quick: 64^2 32^3). "noref" skips the slow reference solvers; "plate"
// runs only the disc-in-wind band rows, so their peak memory is their own.
#include <frostvdb/core/Bench.h>
#include <frostvdb/fluid/MultigridPoisson.h>
#include <frostvdb/fluid/SparseFluid.h>
#include <frostvdb/fluid/Fluid.h>

#include <openvdb/tools/PoissonSolver.h>

#include <tbb/global_control.h>

#include <sys/resource.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>

namespace frostvdb {

namespace {

using bench::Clock;

/// Where the solver's memory goes: allocated 8^3 face blocks of the box's, the face velocities
/// in them, the cell flags (box-sized) and the multigrid index (the band's bounding box).
std::string storage(const fluid::SparseFluid& f)
{
    char buf[200];
    std::snprintf(buf, sizeof buf, "face blocks %zu of %zu (%.1f%%), faces %.0f MiB, cell flags + MG index %.0f MiB", f.faceBlocks(),
                  f.boxBlocks(), 100.0 * double(f.faceBlocks()) / double(f.boxBlocks()), f.faceBytes() / 1048576.0,
                  f.boxBytes() / 1048576.0);
    return buf;
}

/// Starts @a f from the free stream, projected, then times @a steps whole steps: advection and
/// projection seconds per step (both solvers keep these two counters) and the process's CPU
/// seconds per step (all threads; on a shared machine the honest measure of work).
template <typename Solver>
void timeSteps(Solver& f, int steps, double& adv, double& proj, double& cpu)
{
    f.setFreeStream();
    f.project();
    f.advectSeconds = f.projectSeconds = 0;
    const double c0 = bench::cpuSeconds();
    for (int s = 0; s < steps; ++s) f.step(1.0);
    cpu = (bench::cpuSeconds() - c0) / steps;
    adv = f.advectSeconds / steps;
    proj = f.projectSeconds / steps;
}

/// The realistic 3D case: a disc of ice (radius n/4, 2 cells thick) facing the wind, solved only
/// in the default band (8 cells, 24-cell wake), as `[fluid] solver = "sparse"` runs a scene.
void benchPlate(int n, int steps)
{
    bench::resetPeakRss();
    fluid::SparseFluidParams fp;
    fp.inflowSpeed = 1.0;
    fp.bandWidth = 8;
    fp.wakeLength = 24;
    const double c = 0.5 * (n - 1), r = 0.25 * n;
    fluid::SparseFluid f(fp, openvdb::Coord(n), 3);
    f.setSolid([&](int i, int j, int k) {
        return std::fabs(i - c) <= 1.0 && (j - c) * (j - c) + (k - c) * (k - c) <= r * r;
    });
    double adv = 0, proj = 0, cpu = 0;
    timeSteps(f, steps, adv, proj, cpu);
    std::printf("%5d^3 plate | active cells %zu (%.1f%% of the box) | MG it %d | adv %.3f s proj %.3f s step %.3f s "
                "[CPU %.2f s] | peak %.0f MiB | %s\n",
                n, f.activeCells(), 100.0 * double(f.activeCells()) / (double(n) * n * n), f.pressureStats().iterations,
                adv, proj, adv + proj, cpu, bench::peakRssMiB(), storage(f).c_str());
    std::fflush(stdout);
}

struct Problem {
    int dim, n;
    double r;
    bool solid(int i, int j, int k) const
    {
        const double c = 0.5 * (n - 1), dz = dim == 3 ? k - c : 0.0;
        return (i - c) * (i - c) + (j - c) * (j - c) + dz * dz <= r * r;
    }
    /// -div of the free stream (1, 0, 0) with the faces next to the ball closed.
    double rhs(int i, int j, int k) const
    {
        const double uL = solid(i - 1, j, k) ? 0.0 : 1.0, uR = solid(i + 1, j, k) ? 0.0 : 1.0;
        return -(uR - uL);
    }
};

/// tools::poisson boundary: outflow (+x and the four sides) Dirichlet, inflow (-x) Neumann,
/// the ball Neumann; in 2D the z neighbours are Neumann.
struct BallBoundary {
    Problem pb;
    void operator()(const openvdb::Coord& ijk, const openvdb::Coord& nb, double&, double& diag) const
    {
        if (pb.dim == 2 && nb.z() != ijk.z()) return;
        if (nb.x() < 0) return; // inflow wall
        const bool outside = nb.x() >= pb.n || nb.y() < 0 || nb.y() >= pb.n ||
                             (pb.dim == 3 && (nb.z() < 0 || nb.z() >= pb.n));
        if (outside) diag -= 1.0;
    }
};

int benchFluid(const BenchArgs& args)
{
    std::unique_ptr<tbb::global_control> gc;
    if (args.threads > 0)
        gc = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, args.threads);
    std::vector<std::string> sizes;
    bool refs = true; // "noref": skip the Jacobi-CG and tools::poisson references
    bool plateOnly = false;
    for (const std::string& a : args.args) {
        if (a == "noref") refs = false; // step timing only (no Jacobi-CG / tools::poisson)
        else if (a == "plate") plateOnly = true; // only the disc-in-wind band rows (their own peak memory)
        else sizes.push_back(a);
    }
    if (sizes.empty())
        sizes = args.quick ? std::vector<std::string>{"64^2", "32^3"}
                           : std::vector<std::string>{"256^2", "1024^2", "128^3", "256^3"};
    const size_t refLimit = 2200000; // the slow reference solvers only up to 1024^2 / 128^3
    std::printf("fluid bench: pressure solve of a free stream past a ball (r = n/10), outflow on 5 sides, "
                "to relative residual 1e-5; CPU s in brackets\n");
    std::printf("%8s %10s | %5s %8s %8s | %5s %8s | %5s %8s | %9s %9s %9s | %8s\n", "size", "unknowns", "MG it",
                "setup s", "solve s", "JC it", "solve s", "VDB it", "solve s", "adv s", "proj s", "step s",
                "peak MiB");
    for (const std::string& sz : sizes) {
        const auto hat = sz.find('^');
        if (hat == std::string::npos) { std::fprintf(stderr, "bench fluid: size '%s' is not n^2 or n^3\n", sz.c_str()); return 2; }
        Problem pb{std::stoi(sz.substr(hat + 1)), std::stoi(sz.substr(0, hat)), 0};
        if (pb.dim != 2 && pb.dim != 3) { std::fprintf(stderr, "bench fluid: size '%s' is not n^2 or n^3\n", sz.c_str()); return 2; }
        pb.r = 0.1 * pb.n;
        if (plateOnly) {
            if (pb.dim == 3) benchPlate(pb.n, args.quick ? 2 : 3);
            continue;
        }
        bench::resetPeakRss();
        auto t0 = Clock::now();
        double c0 = bench::cpuSeconds();
        auto mg = std::make_unique<fluid::MultigridPoisson>(
            pb.dim, openvdb::Coord(pb.n, pb.n, pb.dim == 3 ? pb.n : 1),
            [&](int i, int j, int k) { return pb.solid(i, j, k) ? fluid::CellKind::Solid : fluid::CellKind::Fluid; },
            std::array<bool, 6>{false, true, true, true, pb.dim == 3, pb.dim == 3});
        const double tSetup = bench::since(t0), cSetup = bench::cpuSeconds() - c0;
        const size_t n = mg->unknowns();
        std::vector<double> b(n), x(n, 0.0);
        for (size_t k = 0; k < n; ++k) {
            const auto c = mg->cellOf(k);
            b[k] = pb.rhs(c.x(), c.y(), c.z());
        }
        fluid::PoissonSettings ps;
        t0 = Clock::now();
        c0 = bench::cpuSeconds();
        const auto st = mg->solve(b, x, ps);
        const double tMg = bench::since(t0), cMg = bench::cpuSeconds() - c0;
        char jc[64] = "    -        -", vdb[64] = "    -        -";
        if (refs && n <= refLimit) {
            ps.multigrid = false;
            ps.maxIterations = 20000;
            std::fill(x.begin(), x.end(), 0.0);
            t0 = Clock::now();
            const auto sj = mg->solve(b, x, ps);
            std::snprintf(jc, sizeof jc, "%5d %8.3f", sj.iterations, bench::since(t0));
            x = std::vector<double>();
            openvdb::DoubleTree source(0.0);
            for (int k = 0; k < (pb.dim == 3 ? pb.n : 1); ++k)
                for (int j = 0; j < pb.n; ++j)
                    for (int i = 0; i < pb.n; ++i)
                        if (!pb.solid(i, j, k)) source.setValue(openvdb::Coord(i, j, k), -pb.rhs(i, j, k));
            auto state = openvdb::math::pcg::terminationDefaults<double>();
            state.iterations = 20000;
            state.relativeError = 1e-5;
            state.absoluteError = 1e-30;
            openvdb::util::NullInterrupter interrupt;
            t0 = Clock::now();
            auto sol = openvdb::tools::poisson::solveWithBoundaryConditions(source, BallBoundary{pb}, state, interrupt);
            std::snprintf(vdb, sizeof vdb, "%5d %8.3f", state.iterations, bench::since(t0));
        }
        // The cold-solve objects go before the steps, and the peak memory column is the steps'.
        mg.reset();
        b = std::vector<double>();
        x = std::vector<double>();
        bench::resetPeakRss();
        // Whole steps: the 2D reference layout with the multigrid projection, or the sparse 3D solver.
        double adv = 0, proj = 0, cpuStep = 0;
        int stepIterations = 0;
        std::string fullStorage;
        const int steps = args.quick ? 2 : 3;
        if (pb.dim == 2) {
            ice::FluidParams fp;
            fp.inflowSpeed = 1.0;
            ice::StableFluid2D f(fp, pb.n, pb.n, 1.0);
            std::vector<uint8_t> solid(size_t(pb.n) * pb.n, 0);
            for (int j = 0; j < pb.n; ++j)
                for (int i = 0; i < pb.n; ++i) solid[size_t(j) * pb.n + i] = pb.solid(i, j, 0);
            f.setSolid(solid);
            timeSteps(f, steps, adv, proj, cpuStep);
            stepIterations = f.stats().pressureIterations;
        } else {
            fluid::SparseFluidParams fp;
            fp.inflowSpeed = 1.0;
            fp.bandWidth = 0; // the whole box: the worst case
            fluid::SparseFluid f(fp, openvdb::Coord(pb.n), 3);
            f.setSolid([&](int i, int j, int k) { return pb.solid(i, j, k); });
            timeSteps(f, steps, adv, proj, cpuStep);
            stepIterations = f.pressureStats().iterations;
            fullStorage = storage(f);
        }
        std::printf("%8s %10zu | %5d %8.3f %8.3f | %s | %s | %9.3f %9.3f %9.3f | %8.0f\n", sz.c_str(), n, st.iterations,
                    tSetup, tMg, jc, vdb, adv, proj, adv + proj, bench::peakRssMiB());
        std::printf("%8s %10s | %5s [%6.2f] [%6.2f]   (MG relative residual %.2e, %d levels; step [CPU %.2f s], "
                    "%d MG iterations in the last step)\n", "", "", "", cSetup, cMg, st.relativeResidual, st.levels, cpuStep,
                    stepIterations);
        if (!fullStorage.empty()) std::printf("%8s full box: %s\n", "", fullStorage.c_str());
        std::fflush(stdout);
        if (pb.dim == 3) benchPlate(pb.n, steps);
    }
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(fluid, "fluid", "[fluid] pressure solve: multigrid PCG vs Jacobi-CG vs tools::poisson; step cost",
                        benchFluid);

} // namespace frostvdb
