// The band-limited MAC stable fluid in 2D/3D (see fluid/SparseFluid.h). Every loop writes its own
// faces or cells only and the pressure solve is deterministic, so a step gives the same bits at
// any thread count.
#include <frostvdb/core/Stopwatch.h>
#include <frostvdb/fluid/SparseFluid.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace frostvdb {
namespace fluid {

namespace {

using Clock = SteadyClock;

/// f(i, j, k) over a box, rows (j, k) in parallel.
template <typename F>
void forBox(const openvdb::Coord& d, const F& f)
{
    const int rows = d.y() * d.z();
    tbb::parallel_for(tbb::blocked_range<int>(0, rows, std::max(1, 4096 / std::max(1, d.x()))),
                      [&](const tbb::blocked_range<int>& r) {
                          for (int row = r.begin(); row != r.end(); ++row) {
                              const int j = row % d.y(), k = row / d.y();
                              for (int i = 0; i < d.x(); ++i) f(i, j, k);
                          }
                      });
}

/// out[x] = any(in[x + lo .. x + hi]) along @a axis, per line, clipped to the box.
std::vector<uint8_t> dilateAlong(const std::vector<uint8_t>& in, const openvdb::Coord& n, int axis, int lo, int hi)
{
    std::vector<uint8_t> out(in.size(), 0);
    const int len = n[axis];
    const size_t stride = axis == 0 ? 1 : axis == 1 ? size_t(n.x()) : size_t(n.x()) * n.y();
    const openvdb::Coord lines(axis == 0 ? 1 : n.x(), axis == 1 ? 1 : n.y(), axis == 2 ? 1 : n.z());
    forBox(lines, [&](int i, int j, int k) {
        const size_t base = (size_t(k) * n.y() + j) * n.x() + i;
        std::vector<int> prefix(size_t(len) + 1, 0);
        for (int t = 0; t < len; ++t) prefix[size_t(t) + 1] = prefix[size_t(t)] + in[base + t * stride];
        for (int t = 0; t < len; ++t) {
            const int a = std::max(0, t + lo), b = std::min(len - 1, t + hi);
            if (a <= b && prefix[size_t(b) + 1] - prefix[size_t(a)] > 0) out[base + t * stride] = 1;
        }
    });
    return out;
}

} // namespace

SparseFluid::SparseFluid(const SparseFluidParams& params, const openvdb::Coord& dims, int dim)
    : mP(params), mN(std::max(2, dims.x()), std::max(2, dims.y()), dim == 3 ? std::max(2, dims.z()) : 1), mDim(dim)
{
    if (dim != 2 && dim != 3) throw std::invalid_argument("SparseFluid: dim must be 2 or 3");
    if (mP.inflowSide < 0 || mP.inflowSide >= 2 * dim) throw std::invalid_argument("SparseFluid: inflow side out of range");
    for (int s = 0; s < 6; ++s)
        mSide[size_t(s)] = mP.sides[size_t(s)] < 0 ? mP.lateral : mP.sides[size_t(s)] == 1 ? SideKind::Wall : SideKind::Outflow;
    mSide[size_t(mP.inflowSide)] = SideKind::Inflow;
    mSide[size_t(mP.inflowSide ^ 1)] = SideKind::Outflow;
    for (int c = 0; c < dim; ++c) mU[size_t(c)].assign(size_t(faceDims(c).x()) * faceDims(c).y() * faceDims(c).z(), 0.0);
    mSolid.assign(size_t(mN.x()) * mN.y() * mN.z(), 0);
    mCell.assign(mSolid.size(), kInactiveCell);
    updateBand();
}

double SparseFluid::freeStream(int c, double i, double j, double k) const
{
    const int a = mP.inflowSide / 2;
    if (c != a) return 0.0;
    const double sign = (mP.inflowSide & 1) ? -1.0 : 1.0;
    int pa = mP.profileAxis;
    if (pa < 0 || pa >= mDim || pa == a) pa = a == 0 ? 1 : 0;
    const double pos[3] = {i, j, k};
    const double s = std::min(1.0, std::max(0.0, (pos[pa] + 0.5) / mN[pa]));
    const double U = mP.inflowSpeed;
    switch (mP.profile) {
    case Profile::Uniform: return sign * U;
    case Profile::Linear: return sign * s * U;
    case Profile::Quadratic: return sign * s * s * U;
    case Profile::Parabolic: return sign * 4.0 * s * (1.0 - s) * U;
    }
    return sign * U;
}

bool SparseFluid::faceFixed(int c, int i, int j, int k, double& value) const
{
    const int q = c == 0 ? i : c == 1 ? j : k;
    const bool hasLo = q > 0, hasHi = q < mN[c];
    const int li = i - (c == 0), lj = j - (c == 1), lk = k - (c == 2);
    const uint8_t lo = hasLo ? mCell[cellIndex(li, lj, lk)] : kInactiveCell;
    const uint8_t hi = hasHi ? mCell[cellIndex(i, j, k)] : kInactiveCell;
    if (lo == kSolidCell || hi == kSolidCell) { value = 0; return true; }
    if (!hasLo || !hasHi) {
        switch (mSide[size_t(2 * c + (hasLo ? 1 : 0))]) {
        case SideKind::Inflow: value = freeStream(c, i, j, k); return true;
        case SideKind::Wall: value = 0; return true;
        case SideKind::Outflow:
            if ((hasLo ? lo : hi) == kInactiveCell) { value = freeStream(c, i, j, k); return true; }
            return false;
        }
    }
    if (lo == kInactiveCell && hi == kInactiveCell) { value = freeStream(c, i, j, k); return true; }
    return false;
}

void SparseFluid::applyBoundaries()
{
    for (int c = 0; c < mDim; ++c) {
        auto& u = mU[size_t(c)];
        forBox(faceDims(c), [&](int i, int j, int k) {
            double v;
            if (faceFixed(c, i, j, k, v)) u[faceIndex(c, i, j, k)] = v;
        });
    }
}

void SparseFluid::updateBand()
{
    std::vector<uint8_t> act;
    if (mP.bandWidth <= 0) {
        act.assign(mSolid.size(), 1);
    } else {
        const int w = int(std::ceil(mP.bandWidth));
        act = mSolid;
        for (int a = 0; a < mDim; ++a) act = dilateAlong(act, mN, a, -w, w);
        const int flow = mP.inflowSide / 2, L = int(std::ceil(std::max(0.0, mP.wakeLength)));
        // Downstream of a band cell is band too: look upstream by up to L cells.
        act = (mP.inflowSide & 1) ? dilateAlong(act, mN, flow, 0, L) : dilateAlong(act, mN, flow, -L, 0);
    }
    std::vector<uint8_t> cell(mSolid.size());
    size_t count = 0;
    for (size_t x = 0; x < cell.size(); ++x) {
        cell[x] = mSolid[x] ? kSolidCell : act[x] ? kFluidCell : kInactiveCell;
        count += cell[x] == kFluidCell;
    }
    if (mPoisson && cell == mCell) return;
    mCell.swap(cell);
    mActive = count;
    std::unique_ptr<MultigridPoisson> old = std::move(mPoisson);
    std::vector<double> oldPressure = std::move(mPressure);
    mPoisson = std::make_unique<MultigridPoisson>(
        mDim, mN,
        [this](int i, int j, int k) {
            const uint8_t c = mCell[cellIndex(i, j, k)];
            return c == kSolidCell ? CellKind::Solid : c == kFluidCell ? CellKind::Fluid : CellKind::Dirichlet;
        },
        std::array<bool, 6>{mSide[0] == SideKind::Outflow, mSide[1] == SideKind::Outflow,
                            mSide[2] == SideKind::Outflow, mSide[3] == SideKind::Outflow,
                            mSide[4] == SideKind::Outflow, mSide[5] == SideKind::Outflow});
    // Keep the warm start where a cell stays an unknown (new cells start at 0).
    mPressure.assign(mPoisson->unknowns(), 0.0);
    if (old)
        for (size_t u = 0; u < mPressure.size(); ++u) {
            const openvdb::Coord c = mPoisson->cellOf(u);
            const int64_t v = old->unknownIndex(c.x(), c.y(), c.z());
            if (v >= 0) mPressure[u] = oldPressure[size_t(v)];
        }
}

double SparseFluid::maxSpeed() const
{
    double m = 0;
    for (int c = 0; c < mDim; ++c)
        for (double v : mU[size_t(c)]) {
            if (!std::isfinite(v)) return std::numeric_limits<double>::quiet_NaN();
            m = std::max(m, std::fabs(v));
        }
    return m;
}

void SparseFluid::setSolid(const std::function<bool(int, int, int)>& solid)
{
    forBox(mN, [&](int i, int j, int k) { mSolid[cellIndex(i, j, k)] = solid(i, j, k) ? 1 : 0; });
    updateBand();
}

void SparseFluid::setFreeStream()
{
    for (int c = 0; c < mDim; ++c) {
        auto& u = mU[size_t(c)];
        forBox(faceDims(c), [&](int i, int j, int k) { u[faceIndex(c, i, j, k)] = freeStream(c, i, j, k); });
    }
    applyBoundaries();
}

double SparseFluid::sampleComponent(const std::vector<double>& f, int c, const openvdb::Vec3d& x, double* lo,
                                    double* hi) const
{
    // Component c (c < 0: cell-centred) sits at x - e_c / 2; clamp to the array (zero gradient).
    const openvdb::Coord d = c < 0 ? mN : faceDims(c);
    int i0[3];
    double t[3];
    for (int a = 0; a < 3; ++a) {
        double y = x[a] + (a == c ? 0.5 : 0.0);
        if (d[a] == 1 || (a == 2 && mDim == 2)) { i0[a] = 0; t[a] = 0; continue; }
        y = std::min(std::max(y, 0.0), double(d[a] - 1));
        i0[a] = std::min(int(y), d[a] - 2);
        t[a] = y - i0[a];
    }
    const size_t sx = 1, sy = size_t(d.x()), sz = size_t(d.x()) * d.y();
    const size_t base = (size_t(i0[2]) * d.y() + i0[1]) * d.x() + i0[0];
    const bool z2 = mDim == 3 && d.z() > 1;
    double corner[8];
    int nc = 0;
    for (int dz = 0; dz < (z2 ? 2 : 1); ++dz)
        for (int dy = 0; dy < 2; ++dy)
            for (int dx = 0; dx < 2; ++dx) corner[nc++] = f[base + dx * sx + dy * sy + dz * sz];
    if (lo) {
        *lo = *std::min_element(corner, corner + nc);
        *hi = *std::max_element(corner, corner + nc);
    }
    auto lerp = [](double a, double b, double s) { return a + s * (b - a); };
    const double a0 = lerp(lerp(corner[0], corner[1], t[0]), lerp(corner[2], corner[3], t[0]), t[1]);
    if (!z2) return a0;
    const double a1 = lerp(lerp(corner[4], corner[5], t[0]), lerp(corner[6], corner[7], t[0]), t[1]);
    return lerp(a0, a1, t[2]);
}

openvdb::Vec3d SparseFluid::velocityAt(const std::array<std::vector<double>, 3>& u, const openvdb::Vec3d& x) const
{
    openvdb::Vec3d v(0.0);
    for (int c = 0; c < mDim; ++c) v[c] = sampleComponent(u[size_t(c)], c, x, nullptr, nullptr);
    return v;
}

openvdb::Vec3d SparseFluid::sample(const openvdb::Vec3d& x) const { return velocityAt(mU, x); }

openvdb::Vec3d SparseFluid::backtrace(const openvdb::Vec3d& x, double dt) const
{
    // Second-order Runge-Kutta (midpoint) through the current velocity; dt < 0 traces forward.
    const openvdb::Vec3d mid = x - 0.5 * dt * velocityAt(mU, x);
    return x - dt * velocityAt(mU, mid);
}

double SparseFluid::divergence(int i, int j, int k) const
{
    double d = 0;
    for (int c = 0; c < mDim; ++c)
        d += face(c, i + (c == 0), j + (c == 1), k + (c == 2)) - face(c, i, j, k);
    return d;
}

double SparseFluid::maxDivergence() const
{
    double m = 0;
    for (int k = 0; k < mN.z(); ++k)
        for (int j = 0; j < mN.y(); ++j)
            for (int i = 0; i < mN.x(); ++i)
                if (mCell[cellIndex(i, j, k)] == kFluidCell) m = std::max(m, std::fabs(divergence(i, j, k)));
    return m;
}

void SparseFluid::project()
{
    applyBoundaries();
    const size_t n = mPoisson->unknowns();
    std::vector<double> b(n);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t u = r.begin(); u != r.end(); ++u) {
            const openvdb::Coord c = mPoisson->cellOf(u);
            b[u] = -divergence(c.x(), c.y(), c.z());
        }
    });
    mStats = mPoisson->solve(b, mPressure, mP.poisson);
    auto p = [&](int i, int j, int k) {
        const int64_t u = mPoisson->unknownIndex(i, j, k);
        return u >= 0 ? mPressure[size_t(u)] : 0.0;
    };
    for (int c = 0; c < mDim; ++c) {
        auto& u = mU[size_t(c)];
        forBox(faceDims(c), [&](int i, int j, int k) {
            double v;
            if (faceFixed(c, i, j, k, v)) return;
            u[faceIndex(c, i, j, k)] -= p(i, j, k) - p(i - (c == 0), j - (c == 1), k - (c == 2));
        });
    }
}

void SparseFluid::step(double dt)
{
    auto t0 = Clock::now();
    applyBoundaries();
    const bool mc = mP.advection == Advection::MacCormack;
    std::array<std::vector<double>, 3> fwd, lo, hi;
    for (int c = 0; c < mDim; ++c) {
        fwd[size_t(c)] = mU[size_t(c)];
        if (mc) {
            lo[size_t(c)].assign(fwd[size_t(c)].size(), 0.0);
            hi[size_t(c)].assign(fwd[size_t(c)].size(), 0.0);
        }
        forBox(faceDims(c), [&](int i, int j, int k) {
            double v;
            if (faceFixed(c, i, j, k, v)) return;
            const size_t f = faceIndex(c, i, j, k);
            const openvdb::Vec3d x(i - 0.5 * (c == 0), j - 0.5 * (c == 1), k - 0.5 * (c == 2));
            fwd[size_t(c)][f] = sampleComponent(mU[size_t(c)], c, backtrace(x, dt), mc ? &lo[size_t(c)][f] : nullptr,
                                                mc ? &hi[size_t(c)][f] : nullptr);
        });
    }
    if (mc) {
        // MacCormack (Selle et al. 2008): trace the forward result back, correct by half the
        // round-trip error, and fall back to semi-Lagrangian where that leaves the bounds of the
        // cells sampled (so no new extrema, whatever the CFL number).
        std::array<std::vector<double>, 3> out;
        for (int c = 0; c < mDim; ++c) {
            out[size_t(c)] = fwd[size_t(c)];
            forBox(faceDims(c), [&](int i, int j, int k) {
                double v;
                if (faceFixed(c, i, j, k, v)) return;
                const size_t f = faceIndex(c, i, j, k);
                const openvdb::Vec3d x(i - 0.5 * (c == 0), j - 0.5 * (c == 1), k - 0.5 * (c == 2));
                const double back = sampleComponent(fwd[size_t(c)], c, backtrace(x, -dt), nullptr, nullptr);
                const double corr = fwd[size_t(c)][f] + 0.5 * (mU[size_t(c)][f] - back);
                if (corr >= lo[size_t(c)][f] && corr <= hi[size_t(c)][f]) out[size_t(c)][f] = corr;
            });
        }
        fwd.swap(out);
    }
    for (int c = 0; c < mDim; ++c) mU[size_t(c)].swap(fwd[size_t(c)]);
    applyBoundaries();
    advectSeconds += secondsSince(t0);
    t0 = Clock::now();
    project();
    projectSeconds += secondsSince(t0);
}

void SparseFluid::advectScalar(std::vector<double>& f, double dt) const
{
    const bool mc = mP.advection == Advection::MacCormack;
    std::vector<double> fwd(f), lo(mc ? f.size() : 0), hi(mc ? f.size() : 0);
    forBox(mN, [&](int i, int j, int k) {
        const size_t x = cellIndex(i, j, k);
        if (mCell[x] != kFluidCell) return;
        fwd[x] = sampleComponent(f, -1, backtrace(openvdb::Vec3d(i, j, k), dt), mc ? &lo[x] : nullptr,
                                 mc ? &hi[x] : nullptr);
    });
    if (!mc) { f.swap(fwd); return; }
    std::vector<double> out(fwd);
    forBox(mN, [&](int i, int j, int k) {
        const size_t x = cellIndex(i, j, k);
        if (mCell[x] != kFluidCell) return;
        const double back = sampleComponent(fwd, -1, backtrace(openvdb::Vec3d(i, j, k), -dt), nullptr, nullptr);
        const double corr = fwd[x] + 0.5 * (f[x] - back);
        if (corr >= lo[x] && corr <= hi[x]) out[x] = corr;
    });
    f.swap(out);
}

} // namespace fluid
} // namespace frostvdb
