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

/// f(t) for t in [0, n), in parallel (each t writes its own entries only).
template <typename F>
void forList(size_t n, const F& f)
{
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t t = r.begin(); t != r.end(); ++t) f(t);
    });
}

/// Clamped (zero-gradient) cell and weight of coordinate @a y on an axis of @a d samples.
inline void clampAxis(double y, int d, int& i0, double& t)
{
    y = std::min(std::max(y, 0.0), double(d - 1));
    i0 = std::min(int(y), d - 2);
    t = y - i0;
}

/// The box a staggered array lives on (internal linkage, so the samplers below inline into the
/// advection loops instead of being called through the shared library's symbol table).
struct Layout {
    openvdb::Coord n;
    int dim;
};

/// Component c (c < 0: cell-centred) of @a f at x (cell coordinates): tri/bilinear, clamped to the
/// array (zero gradient); @a lo and @a hi, if given, receive the range of the corners used.
inline double sampleArray(const Layout& L, const std::vector<double>& f, int c, const openvdb::Vec3d& x, double* lo,
                          double* hi)
{
    // Component c sits at x - e_c / 2.
    const int dx = L.n.x() + (c == 0), dy = L.n.y() + (c == 1);
    int i, j, k = 0;
    double tx, ty, tz = 0;
    clampAxis(x[0] + (c == 0 ? 0.5 : 0.0), dx, i, tx);
    clampAxis(x[1] + (c == 1 ? 0.5 : 0.0), dy, j, ty);
    const bool z2 = L.dim == 3;
    if (z2) clampAxis(x[2] + (c == 2 ? 0.5 : 0.0), L.n.z() + (c == 2), k, tz);
    const size_t sy = size_t(dx), sz = size_t(dx) * dy;
    const double* p = f.data() + (size_t(k) * dy + j) * dx + i;
    auto lerp = [](double a, double b, double s) { return a + s * (b - a); };
    const double c0 = p[0], c1 = p[1], c2 = p[sy], c3 = p[sy + 1];
    const double a0 = lerp(lerp(c0, c1, tx), lerp(c2, c3, tx), ty);
    if (!z2) {
        if (lo) {
            *lo = std::min(std::min(c0, c1), std::min(c2, c3));
            *hi = std::max(std::max(c0, c1), std::max(c2, c3));
        }
        return a0;
    }
    const double c4 = p[sz], c5 = p[sz + 1], c6 = p[sz + sy], c7 = p[sz + sy + 1];
    if (lo) {
        *lo = std::min(std::min(std::min(c0, c1), std::min(c2, c3)), std::min(std::min(c4, c5), std::min(c6, c7)));
        *hi = std::max(std::max(std::max(c0, c1), std::max(c2, c3)), std::max(std::max(c4, c5), std::max(c6, c7)));
    }
    const double a1 = lerp(lerp(c4, c5, tx), lerp(c6, c7, tx), ty);
    return lerp(a0, a1, tz);
}

inline openvdb::Vec3d velocityAt(const Layout& L, const std::array<std::vector<double>, 3>& u, const openvdb::Vec3d& x)
{
    openvdb::Vec3d v(0.0);
    for (int c = 0; c < L.dim; ++c) v[c] = sampleArray(L, u[size_t(c)], c, x, nullptr, nullptr);
    return v;
}

/// Second-order Runge-Kutta (midpoint) trace back through @a u; dt < 0 traces forward.
inline openvdb::Vec3d backtrace(const Layout& L, const std::array<std::vector<double>, 3>& u, const openvdb::Vec3d& x,
                                double dt)
{
    const openvdb::Vec3d mid = x - 0.5 * dt * velocityAt(L, u, x);
    return x - dt * velocityAt(L, u, mid);
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
    if (double(mN.x() + 1) * (mN.y() + 1) * (mN.z() + 1) >= 4.0e9)
        throw std::invalid_argument("SparseFluid: box too large (face lists are 32-bit)");
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
    listActive();
    applyBoundaries(); // the fixed faces change only here (and in setFreeStream)
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

openvdb::Coord SparseFluid::faceCoord(int c, uint32_t f) const
{
    const openvdb::Coord d = faceDims(c);
    const uint32_t row = f / uint32_t(d.x());
    return {int(f - row * uint32_t(d.x())), int(row % uint32_t(d.y())), int(row / uint32_t(d.y()))};
}

void SparseFluid::listActive()
{
    // Per row of the box, in parallel, then concatenated in order (so the lists do not depend on
    // the thread count).
    auto build = [&](const openvdb::Coord& d, const auto& keep, std::vector<uint32_t>& out) {
        const int rows = d.y() * d.z();
        std::vector<std::vector<uint32_t>> perRow(static_cast<size_t>(rows));
        tbb::parallel_for(tbb::blocked_range<int>(0, rows), [&](const tbb::blocked_range<int>& r) {
            for (int row = r.begin(); row != r.end(); ++row) {
                const int j = row % d.y(), k = row / d.y();
                for (int i = 0; i < d.x(); ++i)
                    if (keep(i, j, k)) perRow[size_t(row)].push_back(uint32_t((size_t(k) * d.y() + j) * d.x() + i));
            }
        });
        out.clear();
        for (auto& v : perRow) out.insert(out.end(), v.begin(), v.end());
        out.shrink_to_fit();
    };
    for (int c = 0; c < mDim; ++c)
        build(faceDims(c), [&](int i, int j, int k) { double v; return !faceFixed(c, i, j, k, v); }, mFaces[size_t(c)]);
    build(mN, [&](int i, int j, int k) { return mCell[cellIndex(i, j, k)] == kFluidCell; }, mCells);
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

openvdb::Vec3d SparseFluid::sample(const openvdb::Vec3d& x) const { return velocityAt(Layout{mN, mDim}, mU, x); }

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
    // The fixed faces already hold their values (applyBoundaries runs when the band changes).
    const size_t n = mPoisson->unknowns();
    mRhs.resize(n);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t u = r.begin(); u != r.end(); ++u) {
            const openvdb::Coord c = mPoisson->cellOf(u);
            mRhs[u] = -divergence(c.x(), c.y(), c.z());
        }
    });
    mStats = mPoisson->solve(mRhs, mPressure, mP.poisson);
    // Faces reach one cell outside the box at most: the padded index answers there (not an unknown).
    const MultigridPoisson::IndexView index = mPoisson->indexView();
    auto p = [&](int i, int j, int k) {
        const int64_t u = index.at(i, j, k);
        return u >= 0 ? mPressure[size_t(u)] : 0.0;
    };
    for (int c = 0; c < mDim; ++c) {
        auto& u = mU[size_t(c)];
        const auto& faces = mFaces[size_t(c)];
        forList(faces.size(), [&](size_t t) {
            const openvdb::Coord q = faceCoord(c, faces[t]);
            u[faces[t]] -= p(q.x(), q.y(), q.z()) - p(q.x() - (c == 0), q.y() - (c == 1), q.z() - (c == 2));
        });
    }
}

void SparseFluid::step(double dt)
{
    auto t0 = Clock::now();
    // Only the listed (non-fixed) faces move; the fixed ones already hold their values.
    const bool mc = mP.advection == Advection::MacCormack;
    const Layout L{mN, mDim};
    for (int c = 0; c < mDim; ++c) {
        const auto& faces = mFaces[size_t(c)];
        const auto& u = mU[size_t(c)];
        auto& fwd = mFwd[size_t(c)];
        fwd = u; // reuses the buffer's capacity
        if (mc) {
            mLo.resize(std::max(mLo.size(), faces.size()));
            mHi.resize(mLo.size());
        }
        auto facePos = [&](size_t t) {
            const openvdb::Coord q = faceCoord(c, faces[t]);
            return openvdb::Vec3d(q.x() - 0.5 * (c == 0), q.y() - 0.5 * (c == 1), q.z() - 0.5 * (c == 2));
        };
        forList(faces.size(), [&](size_t t) {
            fwd[faces[t]] = sampleArray(L, u, c, backtrace(L, mU, facePos(t), dt), mc ? &mLo[t] : nullptr, mc ? &mHi[t] : nullptr);
        });
        if (!mc) continue;
        // MacCormack (Selle et al. 2008): trace the forward result back, correct by half the
        // round-trip error, and fall back to semi-Lagrangian where that leaves the bounds of the
        // cells sampled (so no new extrema, whatever the CFL number). The result goes to mLo[t]
        // (each face reads and writes only its own entry) and then into fwd.
        forList(faces.size(), [&](size_t t) {
            const uint32_t f = faces[t];
            const double back = sampleArray(L, fwd, c, backtrace(L, mU, facePos(t), -dt), nullptr, nullptr);
            const double corr = fwd[f] + 0.5 * (u[f] - back);
            mLo[t] = corr >= mLo[t] && corr <= mHi[t] ? corr : fwd[f];
        });
        forList(faces.size(), [&](size_t t) { fwd[faces[t]] = mLo[t]; });
    }
    for (int c = 0; c < mDim; ++c) mU[size_t(c)].swap(mFwd[size_t(c)]);
    advectSeconds += secondsSince(t0);
    t0 = Clock::now();
    project();
    projectSeconds += secondsSince(t0);
}

void SparseFluid::advectScalar(std::vector<double>& f, double dt) const
{
    const bool mc = mP.advection == Advection::MacCormack;
    const Layout L{mN, mDim};
    const size_t n = mCells.size();
    mScalarFwd = f;
    auto& fwd = mScalarFwd;
    if (mc) {
        mLo.resize(std::max(mLo.size(), n));
        mHi.resize(mLo.size());
    }
    auto cellPos = [&](size_t t) {
        const uint32_t x = mCells[t];
        const uint32_t row = x / uint32_t(mN.x());
        return openvdb::Vec3d(double(x - row * uint32_t(mN.x())), double(row % uint32_t(mN.y())),
                              double(row / uint32_t(mN.y())));
    };
    forList(n, [&](size_t t) {
        fwd[mCells[t]] = sampleArray(L, f, -1, backtrace(L, mU, cellPos(t), dt), mc ? &mLo[t] : nullptr, mc ? &mHi[t] : nullptr);
    });
    if (mc) {
        forList(n, [&](size_t t) {
            const uint32_t x = mCells[t];
            const double back = sampleArray(L, fwd, -1, backtrace(L, mU, cellPos(t), -dt), nullptr, nullptr);
            const double corr = fwd[x] + 0.5 * (f[x] - back);
            mLo[t] = corr >= mLo[t] && corr <= mHi[t] ? corr : fwd[x];
        });
        forList(n, [&](size_t t) { fwd[mCells[t]] = mLo[t]; });
    }
    f.swap(fwd);
}

} // namespace fluid
} // namespace frostvdb
