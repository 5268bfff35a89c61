/// @file ShellImplicit.cpp
/// @brief The implicit closest-point band system (see ShellImplicit.h).
#include <frostvdb/shell/ShellImplicit.h>

#include <frostvdb/solver/EigenMatrixFree.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace frostvdb::shell {

namespace {

template <typename Fn>
void forRange(size_t n, const Fn& fn)
{
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) fn(i);
    });
}

/// The tricubic extension at voxel @a q of the values get(node): ShellBand::extend's sum, in
/// double (the solver's precision).
template <typename Get>
inline double gatherExtension(const ShellBand& band, size_t q, const Get& get)
{
    const int32_t* nodes = band.stencilNodes(q);
    const float* w = band.stencilWeights(q).data();
    double sz = 0;
    for (int z = 0; z < 4; ++z) {
        double sy = 0;
        for (int y = 0; y < 4; ++y) {
            const int32_t* row = nodes + 16 * z + 4 * y;
            const double sx = double(w[0]) * get(size_t(row[0])) + double(w[1]) * get(size_t(row[1])) +
                              double(w[2]) * get(size_t(row[2])) + double(w[3]) * get(size_t(row[3]));
            sy += double(w[4 + y]) * sx;
        }
        sz += double(w[8 + z]) * sy;
    }
    return sz;
}

/// The band operator, matrix-free: unknowns scattered to the band, extended by each point's
/// tricubic stencil, combined by the rows' coefficients.
class BandOperator final : public solver::LinearOperator {
public:
    BandOperator(const ShellBand& band, const BandRows& rows, const BandSystem& sys)
        : mBand(band), mRows(rows), mSys(sys), mU(band.size(), 0.0), mE(rows.points(), 0.0)
    {
    }
    size_t size() const override { return mRows.rows(); }
    void apply(const std::vector<double>& x, std::vector<double>& y) const override
    {
        const size_t n = mRows.rows();
        // the unknowns scattered to the band (voxels that are not rows stay 0: their values are
        // in the right-hand side)
        forRange(n, [&](size_t r) { mU[mRows.voxel(r)] = x[r]; });
        forRange(mRows.points(), [&](size_t m) {
            if (mRows.pointFixed(m)) return; // stays 0: its value is in the right-hand side
            mE[m] = gatherExtension(mBand, mRows.pointVoxel(m), [&](size_t j) { return mU[j]; });
        });
        forRange(n, [&](size_t r) {
            const double* c = &mSys.coef[6 * r];
            double s = 0;
            for (int k = 0; k < 6; ++k) s += c[k] * mE[mRows.point(r, k)];
            y[r] = mSys.diag[r] * x[r] - s;
        });
    }

private:
    const ShellBand& mBand;
    const BandRows& mRows;
    const BandSystem& mSys;
    mutable std::vector<double> mU, mE;
};

} // namespace

void BandRows::build(const ShellBand& band, const std::vector<uint32_t>& leafSlots)
{
    mVoxel.clear();
    mPoint.clear();
    mRowOf.assign(band.size(), -1);
    const auto& leaves = band.leaves();
    for (uint32_t s : leafSlots)
        for (uint32_t i = leaves[s].begin; i < leaves[s].end; ++i)
            if (band.inUpdateSet(i)) {
                mRowOf[i] = int32_t(mVoxel.size());
                mVoxel.push_back(i);
            }
    const size_t n = mVoxel.size();
    std::vector<char> stepped(leaves.size(), 0);
    for (uint32_t s : leafSlots) stepped[s] = 1;
    mNb.resize(6 * n);
    mFixed.clear();
    std::vector<int32_t> pointOf(band.size(), -1);
    for (size_t r = 0; r < n; ++r)
        for (int k = 0; k < 6; ++k) {
            const int32_t q = band.neighbour(mVoxel[r], k); // in the band: U's neighbours lie within 4.5
            if (pointOf[size_t(q)] < 0) {
                pointOf[size_t(q)] = int32_t(mPoint.size());
                mPoint.push_back(uint32_t(q));
                // a neighbour in a leaf not stepped keeps its value (as in the explicit step)
                mFixed.push_back(stepped[size_t(band.leafSlot(leafOrigin(band.coord(size_t(q)))))] ? 0 : 1);
            }
            mNb[6 * r + size_t(k)] = uint32_t(pointOf[size_t(q)]);
        }
    mSelf.assign(6 * n, 0.0);
    forRange(n, [&](size_t r) {
        const uint32_t self = mVoxel[r];
        for (int k = 0; k < 6; ++k) {
            const size_t m = mNb[6 * r + size_t(k)];
            if (mFixed[m]) continue;
            mSelf[6 * r + size_t(k)] = gatherExtension(band, mPoint[m], [&](size_t j) { return j == self ? 1.0 : 0.0; });
        }
    });
}

void BandRows::extendAt(const ShellBand& band, const std::vector<float>& u, double background,
                        std::vector<double>& full, std::vector<double>& fixed) const
{
    full.resize(mPoint.size());
    fixed.resize(mPoint.size());
    forRange(mPoint.size(), [&](size_t m) {
        if (mFixed[m]) {
            full[m] = fixed[m] = double(u[mPoint[m]]) - background;
            return;
        }
        // one pass over the stencil for both sums (each in extend()'s order)
        const int32_t* nodes = band.stencilNodes(mPoint[m]);
        const float* w = band.stencilWeights(mPoint[m]).data();
        double fz = 0, gz = 0;
        for (int z = 0; z < 4; ++z) {
            double fy = 0, gy = 0;
            for (int y = 0; y < 4; ++y) {
                const int32_t* row = nodes + 16 * z + 4 * y;
                double fx = 0, gx = 0;
                for (int x = 0; x < 4; ++x) {
                    const size_t j = size_t(row[x]);
                    const double v = double(u[j]) - background;
                    fx += double(w[x]) * v;
                    gx += mRowOf[j] >= 0 ? 0.0 : double(w[x]) * v;
                }
                fy += double(w[4 + y]) * fx;
                gy += double(w[4 + y]) * gx;
            }
            fz += double(w[8 + z]) * fy;
            gz += double(w[8 + z]) * gy;
        }
        full[m] = fz;
        fixed[m] = gz;
    });
}

SolveReport BandSystem::solve(const ShellBand& band, const BandRows& rows, std::vector<double>& x, double tolerance,
                              int maxIterations) const
{
    SolveReport rep;
    const size_t n = rows.rows();
    if (n == 0) {
        rep.converged = true;
        return rep;
    }
    const BandOperator A(band, rows, *this);
    // Jacobi: the operator's true diagonal diag_r - sum_k c_rk w_k(r) (w_k(r): the row's own
    // weight in its neighbour's extension).
    std::vector<double> inverse(n);
    for (size_t r = 0; r < n; ++r) {
        double d = diag[r];
        for (int k = 0; k < 6; ++k) d -= coef[6 * r + size_t(k)] * rows.selfWeight(r, k);
        inverse[r] = d != 0.0 ? 1.0 / d : 1.0;
    }
    const std::vector<double> b(rhs.begin(), rhs.begin() + std::ptrdiff_t(n));
    solver::BiCgStabSettings settings;
    settings.absoluteTolerance = tolerance; // ||r||_2 <= tol implies ||r||_inf <= tol
    settings.maxIterations = maxIterations;
    x.resize(std::max(x.size(), n));
    std::vector<double> sol(x.begin(), x.begin() + std::ptrdiff_t(n));
    const solver::BiCgStabStats st = solver::bicgstab(A, inverse, b, sol, settings);
    std::copy(sol.begin(), sol.end(), x.begin());
    rep.iterations = st.iterations;
    std::vector<double> ax(n);
    A.apply(sol, ax);
    rep.residual = 0;
    for (size_t r = 0; r < n; ++r) rep.residual = std::max(rep.residual, std::fabs(b[r] - ax[r]));
    rep.converged = rep.residual <= tolerance;
    return rep;
}

} // namespace frostvdb::shell
