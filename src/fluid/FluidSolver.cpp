// The dense MAC-grid stable-fluid solver of [fluid] (Stam 1999 with Bridson's staggered layout):
// semi-Lagrangian self-advection, implicit viscosity and the pressure projection, each linear
// system solved by the shared Jacobi-preconditioned conjugate gradient (solver/), warm-started from the
// previous step. Every reduction is summed row by row and then serially, so the result does not
// depend on the thread count.
#include <frostvdb/core/Stopwatch.h>
#include <frostvdb/fluid/Fluid.h>
#include <frostvdb/fluid/MultigridPoisson.h>
#include <frostvdb/solver/ConjugateGradient.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace frostvdb {
namespace ice {

namespace {

using Clock = SteadyClock;

/// Rows in parallel, about 16k cells per task (small grids run serially: a parallel_for per
/// vector operation costs more than it saves below that).
template <typename F>
void forRows(int rows, int width, const F& f)
{
    const int grain = std::max(1, 16384 / std::max(1, width));
    tbb::parallel_for(tbb::blocked_range<int>(0, rows, grain), [&](const tbb::blocked_range<int>& r) {
        for (int j = r.begin(); j != r.end(); ++j) f(j);
    });
}

/// A W x H array of unknowns; entries with invDiag == 0 are not unknowns and stay 0 in every
/// search direction. applyRow(in, out, j) writes out = A in on row j (unknowns only).
struct Grid2 {
    int W, H;
    size_t size() const { return size_t(W) * H; }
};

/// The rows' operator as a solver::LinearOperator: out = A in, rows in parallel.
template <typename ApplyRow>
class RowOperator final : public solver::LinearOperator {
public:
    RowOperator(const Grid2& g, const ApplyRow& applyRow) : mG(g), mApplyRow(applyRow) {}
    size_t size() const override { return mG.size(); }
    void apply(const std::vector<double>& in, std::vector<double>& out) const override
    {
        forRows(mG.H, mG.W, [&](int j) { mApplyRow(in, out, j); });
    }

private:
    Grid2 mG;
    const ApplyRow& mApplyRow;
};

/// Jacobi-preconditioned CG (the shared solver::conjugateGradient) from the initial guess in
/// @a x; stops when max |b - A x| <= tol. Reductions sum each row, then the rows in order.
template <typename ApplyRow>
int conjugateGradient(const Grid2& g, const std::vector<double>& invDiag, const ApplyRow& applyRow,
                      const std::vector<double>& b, std::vector<double>& x, double tol, int maxIt,
                      double& residual, bool& converged)
{
    const RowOperator<ApplyRow> A(g, applyRow);
    const solver::JacobiPreconditioner M(invDiag);
    const solver::CgStats st = solver::conjugateGradient(A, M, b, x, solver::Blocks{g.size(), size_t(g.W)}, maxIt,
                                                         [tol](const solver::Residual& r) { return r.maxAbs <= tol; });
    residual = st.residual.maxAbs;
    converged = st.converged;
    return st.iterations;
}

/// Bilinear sample of a W x H array whose entry (a, b) sits at (a + ox, b + oy), clamped.
double bilinear(const std::vector<double>& f, int W, int H, double x, double y)
{
    x = std::min(std::max(x, 0.0), double(W - 1));
    y = std::min(std::max(y, 0.0), double(H - 1));
    const int i0 = std::min(int(x), W - 2), j0 = std::min(int(y), H - 2);
    const double tx = x - i0, ty = y - j0;
    const size_t k = size_t(j0) * W + i0;
    const double a = f[k] + tx * (f[k + 1] - f[k]);
    const double c = f[k + W] + tx * (f[k + W + 1] - f[k + W]);
    return a + ty * (c - a);
}

} // namespace

StableFluid2D::StableFluid2D(const FluidParams& params, int nx, int ny, double h)
    : mParams(params), mNx(std::max(nx, 2)), mNy(std::max(ny, 2)), mH(h)
{
    const SideKind side = params.closedWalls ? SideKind::Wall : SideKind::Outflow;
    for (auto& w : mWalls) w = side;
    const int in = int(params.inflowEdge);
    mWalls[in] = SideKind::Inflow;
    mWalls[in ^ 1] = SideKind::Outflow; // opposite edge (Left<->Right, Bottom<->Top)
    mU.assign(size_t(mNx + 1) * mNy, 0.0);
    mV.assign(size_t(mNx) * (mNy + 1), 0.0);
    mPhi.assign(size_t(mNx) * mNy, 0.0);
    mSolid.assign(size_t(mNx) * mNy, 0);
}

StableFluid2D::~StableFluid2D() = default;

double StableFluid2D::profile(double s) const
{
    const double U = mParams.inflowSpeed;
    switch (mParams.profile) {
    case Profile::Uniform: return U;
    case Profile::Linear: return s * U;
    case Profile::Quadratic: return s * s * U;
    case Profile::Parabolic: return 4.0 * s * (1.0 - s) * U;
    }
    return U;
}

void StableFluid2D::setSolid(std::vector<uint8_t> solid)
{
    solid.resize(size_t(mNx) * mNy, 0);
    mSolid = std::move(solid);
}

bool StableFluid2D::uFixed(int i, int j, double& value) const
{
    if ((i > 0 && isSolid(i - 1, j)) || (i < mNx && isSolid(i, j))) { value = 0; return true; }
    if (i != 0 && i != mNx) return false;
    const FluidEdge e = i == 0 ? FluidEdge::Left : FluidEdge::Right;
    switch (mWalls[int(e)]) {
    case SideKind::Outflow: return false;
    case SideKind::Wall: value = 0; return true;
    case SideKind::Inflow:
        value = profile((j + 0.5) / mNy) * (i == 0 ? 1.0 : -1.0);
        return true;
    }
    return false;
}

bool StableFluid2D::vFixed(int i, int j, double& value) const
{
    if ((j > 0 && isSolid(i, j - 1)) || (j < mNy && isSolid(i, j))) { value = 0; return true; }
    if (j != 0 && j != mNy) return false;
    const FluidEdge e = j == 0 ? FluidEdge::Bottom : FluidEdge::Top;
    switch (mWalls[int(e)]) {
    case SideKind::Outflow: return false;
    case SideKind::Wall: value = 0; return true;
    case SideKind::Inflow:
        value = profile((i + 0.5) / mNx) * (j == 0 ? 1.0 : -1.0);
        return true;
    }
    return false;
}

void StableFluid2D::applyBoundaries()
{
    forRows(mNy, mNx + 1, [&](int j) {
        double val;
        for (int i = 0; i <= mNx; ++i)
            if (uFixed(i, j, val)) u(i, j) = val;
    });
    forRows(mNy + 1, mNx, [&](int j) {
        double val;
        for (int i = 0; i < mNx; ++i)
            if (vFixed(i, j, val)) v(i, j) = val;
    });
}

void StableFluid2D::setFreeStream()
{
    const FluidEdge e = mParams.inflowEdge;
    const bool horizontal = e == FluidEdge::Left || e == FluidEdge::Right;
    const double sign = (e == FluidEdge::Left || e == FluidEdge::Bottom) ? 1.0 : -1.0;
    std::fill(mU.begin(), mU.end(), 0.0);
    std::fill(mV.begin(), mV.end(), 0.0);
    if (horizontal) {
        for (int j = 0; j < mNy; ++j)
            for (int i = 0; i <= mNx; ++i) u(i, j) = sign * profile((j + 0.5) / mNy);
    } else {
        for (int j = 0; j <= mNy; ++j)
            for (int i = 0; i < mNx; ++i) v(i, j) = sign * profile((i + 0.5) / mNx);
    }
    applyBoundaries();
}

openvdb::Vec2d StableFluid2D::sample(double x, double y) const
{
    // u(i, j) sits at (i - 1/2, j); v(i, j) at (i, j - 1/2).
    return {bilinear(mU, mNx + 1, mNy, x + 0.5, y), bilinear(mV, mNx, mNy + 1, x, y + 0.5)};
}

double StableFluid2D::divergence(int i, int j) const
{
    if (isSolid(i, j)) return 0.0;
    return (u(i + 1, j) - u(i, j) + v(i, j + 1) - v(i, j)) / mH;
}

double StableFluid2D::maxDivergence() const
{
    double m = 0;
    for (int j = 0; j < mNy; ++j)
        for (int i = 0; i < mNx; ++i) m = std::max(m, std::fabs(divergence(i, j)));
    return m;
}

void StableFluid2D::advect(double dt)
{
    const double s = dt / mH; // cells per unit velocity per step
    std::vector<double> un(mU.size()), vn(mV.size());
    forRows(mNy, mNx + 1, [&](int j) {
        double val;
        for (int i = 0; i <= mNx; ++i) {
            const size_t k = size_t(j) * (mNx + 1) + i;
            if (uFixed(i, j, val)) { un[k] = val; continue; }
            const double x = i - 0.5, y = j;
            const openvdb::Vec2d vel = sample(x, y);
            un[k] = bilinear(mU, mNx + 1, mNy, x - s * vel.x() + 0.5, y - s * vel.y());
        }
    });
    forRows(mNy + 1, mNx, [&](int j) {
        double val;
        for (int i = 0; i < mNx; ++i) {
            const size_t k = size_t(j) * mNx + i;
            if (vFixed(i, j, val)) { vn[k] = val; continue; }
            const double x = i, y = j - 0.5;
            const openvdb::Vec2d vel = sample(x, y);
            vn[k] = bilinear(mV, mNx, mNy + 1, x - s * vel.x(), y - s * vel.y() + 0.5);
        }
    });
    mU.swap(un);
    mV.swap(vn);
}

void StableFluid2D::diffuse(double dt)
{
    const double c = mParams.viscosity * dt / (mH * mH);
    const double tol = mParams.tolerance * (mParams.inflowSpeed > 0 ? mParams.inflowSpeed : 1.0);
    mStats.viscosityIterations = 0;
    // One component at a time: W x H faces, fixed faces are known values moved to the right-hand
    // side, faces beyond the grid are zero-gradient (left out of the stencil).
    auto solve = [&](std::vector<double>& f, int W, int H, auto fixed) {
        const Grid2 g{W, H};
        std::vector<double> invDiag(g.size(), 0.0), b(g.size(), 0.0);
        std::vector<uint8_t> isFree(g.size(), 0);
        forRows(H, W, [&](int j) {
            double val;
            for (int i = 0; i < W; ++i) isFree[size_t(j) * W + i] = !fixed(i, j, val);
        });
        forRows(H, W, [&](int j) {
            for (int i = 0; i < W; ++i) {
                const size_t k = size_t(j) * W + i;
                if (!isFree[k]) continue;
                int count = 0;
                double rhs = f[k];
                const int nb[4][2] = {{i - 1, j}, {i + 1, j}, {i, j - 1}, {i, j + 1}};
                for (auto& q : nb) {
                    if (q[0] < 0 || q[0] >= W || q[1] < 0 || q[1] >= H) continue;
                    ++count;
                    const size_t kn = size_t(q[1]) * W + q[0];
                    if (!isFree[kn]) rhs += c * f[kn];
                }
                invDiag[k] = 1.0 / (1.0 + c * count);
                b[k] = rhs;
            }
        });
        auto apply = [&](const std::vector<double>& in, std::vector<double>& out, int j) {
            for (int i = 0; i < W; ++i) {
                const size_t k = size_t(j) * W + i;
                if (!isFree[k]) { out[k] = 0; continue; }
                double sum = 0;
                int count = 0;
                const int nb[4][2] = {{i - 1, j}, {i + 1, j}, {i, j - 1}, {i, j + 1}};
                for (auto& q : nb) {
                    if (q[0] < 0 || q[0] >= W || q[1] < 0 || q[1] >= H) continue;
                    ++count;
                    const size_t kn = size_t(q[1]) * W + q[0];
                    if (isFree[kn]) sum += in[kn];
                }
                out[k] = (1.0 + c * count) * in[k] - c * sum;
            }
        };
        std::vector<double> x(f);
        forRows(H, W, [&](int j) {
            for (int i = 0; i < W; ++i)
                if (!isFree[size_t(j) * W + i]) x[size_t(j) * W + i] = 0;
        });
        double res;
        bool ok;
        mStats.viscosityIterations += conjugateGradient(g, invDiag, apply, b, x, tol, mParams.maxIterations, res, ok);
        for (size_t k = 0; k < f.size(); ++k)
            if (isFree[k]) f[k] = x[k];
    };
    solve(mU, mNx + 1, mNy, [this](int i, int j, double& v) { return uFixed(i, j, v); });
    solve(mV, mNx, mNy + 1, [this](int i, int j, double& v) { return vFixed(i, j, v); });
}

void StableFluid2D::project()
{
    applyBoundaries();
    const Grid2 g{mNx, mNy};
    // Per cell: which of the four faces couple to a neighbour cell (bit), and the diagonal.
    // A fixed face (obstacle, inflow, closed wall) is Neumann; a free face on the grid edge
    // (outflow) is Dirichlet phi = 0 beyond it.
    std::vector<uint8_t> link(g.size(), 0);
    std::vector<double> invDiag(g.size(), 0.0), b(g.size(), 0.0);
    forRows(mNy, mNx + 1, [&](int j) {
        double val;
        for (int i = 0; i < mNx; ++i) {
            const size_t k = size_t(j) * mNx + i;
            if (isSolid(i, j)) { mPhi[k] = 0; continue; }
            int diag = 0;
            uint8_t bits = 0;
            if (!uFixed(i, j, val)) { ++diag; if (i > 0) bits |= 1; }
            if (!uFixed(i + 1, j, val)) { ++diag; if (i + 1 < mNx) bits |= 2; }
            if (!vFixed(i, j, val)) { ++diag; if (j > 0) bits |= 4; }
            if (!vFixed(i, j + 1, val)) { ++diag; if (j + 1 < mNy) bits |= 8; }
            link[k] = bits;
            if (diag == 0) { mPhi[k] = 0; continue; } // boxed in: nothing to solve
            invDiag[k] = 1.0 / diag;
            b[k] = -(u(i + 1, j) - u(i, j) + v(i, j + 1) - v(i, j));
        }
    });
    const int W = mNx;
    auto apply = [&](const std::vector<double>& in, std::vector<double>& out, int j) {
        for (int i = 0; i < W; ++i) {
            const size_t k = size_t(j) * W + i;
            if (invDiag[k] == 0) { out[k] = 0; continue; }
            const uint8_t bits = link[k];
            double s = in[k] / invDiag[k];
            if (bits & 1) s -= in[k - 1];
            if (bits & 2) s -= in[k + 1];
            if (bits & 4) s -= in[k - W];
            if (bits & 8) s -= in[k + W];
            out[k] = s;
        }
    };
    const double tol = mParams.tolerance * (mParams.inflowSpeed > 0 ? mParams.inflowSpeed : 1.0);
    if (mParams.multigrid) {
        // Cells that couple to nothing (boxed in by fixed faces) are left out, like above.
        std::vector<uint8_t> out(g.size(), 0);
        for (size_t k = 0; k < g.size(); ++k) out[k] = invDiag[k] == 0;
        if (!mPoisson || out != mPoissonSolid) {
            const int W0 = mNx;
            mPoisson = std::make_unique<fluid::MultigridPoisson>(
                2, openvdb::Coord(mNx, mNy, 1),
                [&out, W0](int i, int j, int) {
                    return out[size_t(j) * W0 + i] ? fluid::CellKind::Solid : fluid::CellKind::Fluid;
                },
                std::array<bool, 6>{mWalls[0] == SideKind::Outflow, mWalls[1] == SideKind::Outflow,
                                    mWalls[2] == SideKind::Outflow, mWalls[3] == SideKind::Outflow, false, false});
            mPoissonSolid = std::move(out);
        }
        const size_t n = mPoisson->unknowns();
        std::vector<double> bb(n), xx(n);
        for (size_t k = 0; k < n; ++k) {
            const openvdb::Coord c = mPoisson->cellOf(k);
            const size_t idx = size_t(c.y()) * mNx + c.x();
            bb[k] = b[idx];
            xx[k] = mPhi[idx];
        }
        fluid::PoissonSettings ps;
        ps.relativeTolerance = 0;
        ps.absoluteTolerance = tol;
        ps.maxIterations = mParams.maxIterations;
        const fluid::PoissonStats st = mPoisson->solve(bb, xx, ps);
        for (size_t k = 0; k < n; ++k) {
            const openvdb::Coord c = mPoisson->cellOf(k);
            mPhi[size_t(c.y()) * mNx + c.x()] = xx[k];
        }
        mStats.pressureIterations = st.iterations;
        mStats.pressureConverged = st.converged;
    } else {
        double res = 0;
        bool ok = true;
        mStats.pressureIterations = conjugateGradient(g, invDiag, apply, b, mPhi, tol, mParams.maxIterations, res, ok);
        mStats.pressureConverged = ok;
    }
    // Subtract the gradient on every free face.
    auto phi = [&](int i, int j) {
        return (i < 0 || j < 0 || i >= mNx || j >= mNy) ? 0.0 : mPhi[size_t(j) * mNx + i];
    };
    forRows(mNy, mNx + 1, [&](int j) {
        double val;
        for (int i = 0; i <= mNx; ++i)
            if (!uFixed(i, j, val)) u(i, j) -= phi(i, j) - phi(i - 1, j);
    });
    forRows(mNy + 1, mNx, [&](int j) {
        double val;
        for (int i = 0; i < mNx; ++i)
            if (!vFixed(i, j, val)) v(i, j) -= phi(i, j) - phi(i, j - 1);
    });
    mStats.pressureResidual = maxDivergence() * mH;
}

void StableFluid2D::step(double dt)
{
    auto t0 = Clock::now();
    applyBoundaries();
    advect(dt);
    applyBoundaries();
    advectSeconds += secondsSince(t0);
    t0 = Clock::now();
    if (mParams.viscosity > 0) diffuse(dt);
    viscositySeconds += secondsSince(t0);
    t0 = Clock::now();
    project();
    projectSeconds += secondsSince(t0);
}

} // namespace ice
} // namespace frostvdb
