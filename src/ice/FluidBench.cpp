// `frostvdb bench fluid`: what one [fluid] step costs on n x n planes with a disc obstacle, and
// the projection solved by the hand-written dense CG against OpenVDB's tools::poisson
// (incomplete-Cholesky and Jacobi preconditioners) on the same system from a zero guess.
#include <frostvdb/core/Bench.h>
#include <frostvdb/ice/Fluid.h>

#include <openvdb/tools/PoissonSolver.h>

#include <tbb/global_control.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>

namespace frostvdb {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

/// The projection's boundary conditions for tools::poisson: solids and non-outflow edges are
/// Neumann (nothing to do), outflow edges Dirichlet phi = 0, the plane's z neighbours Neumann.
struct PlaneBoundary {
    const ice::StableFluid2D* f;
    void operator()(const openvdb::Coord& ijk, const openvdb::Coord& nb, double& source, double& diag) const
    {
        if (nb.z() != ijk.z()) return;
        ice::FluidEdge e;
        if (nb.x() < 0) e = ice::FluidEdge::Left;
        else if (nb.x() >= f->nx()) e = ice::FluidEdge::Right;
        else if (nb.y() < 0) e = ice::FluidEdge::Bottom;
        else if (nb.y() >= f->ny()) e = ice::FluidEdge::Top;
        else return; // a solid cell
        if (f->wall(e) == ice::WallKind::Outflow) diag -= 1.0;
    }
};

int benchFluid(const BenchArgs& args)
{
    std::unique_ptr<tbb::global_control> gc;
    if (args.threads > 0)
        gc = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, args.threads);
    const double h = 3.0 / 64.0, dt = 0.0002;
    std::vector<int> sizes = args.quick ? std::vector<int>{64} : std::vector<int>{128, 256, 512};
    std::printf("fluid bench: n x n plane, disc obstacle r = n/10, inflow 3.5 from the left, dt %.4g, tolerance 1e-5\n", dt);
    std::printf("%6s | %10s %6s | %12s %6s | %12s %6s | %10s %6s\n", "n", "CG cold s", "iters", "poisson IC s",
                "iters", "poisson Jac s", "iters", "step ms", "iters");
    for (int n : sizes) {
        ice::FluidParams fp;
        ice::StableFluid2D f(fp, n, n, h);
        std::vector<uint8_t> solid(size_t(n) * n, 0);
        const double c = 0.5 * (n - 1), r = 0.1 * n;
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i)
                if ((i - c) * (i - c) + (j - c) * (j - c) <= r * r) solid[size_t(j) * n + i] = 1;
        f.setSolid(solid);
        f.setFreeStream();

        // The same projection through tools::poisson (index space, source = the flux out).
        openvdb::DoubleTree source(0.0);
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i)
                if (!solid[size_t(j) * n + i])
                    source.setValue(openvdb::Coord(i, j, 0), f.u(i + 1, j) - f.u(i, j) + f.v(i, j + 1) - f.v(i, j));
        double tIC = 0, tJ = 0;
        int itIC = 0, itJ = 0;
        {
            auto state = openvdb::math::pcg::terminationDefaults<double>();
            state.iterations = 10000;
            state.relativeError = 1e-14;
            state.absoluteError = 1e-5 * fp.inflowSpeed;
            openvdb::util::NullInterrupter interrupt;
            auto t0 = Clock::now();
            auto x = openvdb::tools::poisson::solveWithBoundaryConditions(source, PlaneBoundary{&f}, state, interrupt);
            tIC = since(t0);
            itIC = state.iterations;
            state = openvdb::math::pcg::terminationDefaults<double>();
            state.iterations = 10000;
            state.relativeError = 1e-14;
            state.absoluteError = 1e-5 * fp.inflowSpeed;
            t0 = Clock::now();
            using Pre = openvdb::math::pcg::JacobiPreconditioner<openvdb::tools::poisson::LaplacianMatrix>;
            x = openvdb::tools::poisson::solveWithBoundaryConditionsAndPreconditioner<Pre>(source, PlaneBoundary{&f},
                                                                                          state, interrupt);
            tJ = since(t0);
            itJ = state.iterations;
        }
        auto t0 = Clock::now();
        f.project();
        const double tCold = since(t0);
        const int itCold = f.stats().pressureIterations;
        const int steps = args.quick ? 5 : 20;
        int itSum = 0;
        t0 = Clock::now();
        for (int s = 0; s < steps; ++s) {
            f.step(dt);
            itSum += f.stats().pressureIterations;
        }
        const double tStep = since(t0) / steps;
        std::printf("%6d | %10.4f %6d | %12.4f %6d | %12.4f %6d | %10.3f %6.1f\n", n, tCold, itCold, tIC, itIC, tJ,
                    itJ, tStep * 1e3, double(itSum) / steps);
    }
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(fluid, "fluid", "[fluid] step cost; dense CG projection vs tools::poisson", benchFluid);

} // namespace frostvdb
