// Multigrid-preconditioned CG over the active cells of a box (see fluid/MultigridPoisson.h).
#include <frostvdb/fluid/MultigridPoisson.h>
#include <frostvdb/solver/ConjugateGradient.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace frostvdb {
namespace fluid {

namespace {

constexpr int32_t kSolid = -1;
constexpr int32_t kDirichlet = -2;
constexpr size_t kBlock = 4096; // reduction block: fixed, so sums do not depend on threads

/// f(begin, end) over [0, n) in fixed blocks, in parallel.
template <typename F>
void forBlocks(size_t n, const F& f)
{
    const size_t blocks = (n + kBlock - 1) / kBlock;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, blocks), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b != r.end(); ++b) f(b * kBlock, std::min(n, (b + 1) * kBlock));
    });
}

/// Sum over fixed blocks, then serially: the same bits at any thread count.
template <typename F>
double blockSum(size_t n, const F& partial)
{
    const size_t blocks = (n + kBlock - 1) / kBlock;
    std::vector<double> part(blocks, 0.0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, blocks), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b != r.end(); ++b) part[b] = partial(b * kBlock, std::min(n, (b + 1) * kBlock));
    });
    double s = 0;
    for (double p : part) s += p;
    return s;
}

} // namespace

struct MultigridPoisson::Level {
    int dim = 3;
    int n[3] = {1, 1, 1};
    int64_t stride[3] = {1, 0, 0};
    std::array<bool, 6> side{};
    std::vector<int32_t> index;   ///< padded box: unknown index, kSolid or kDirichlet
    std::vector<uint32_t> lin;    ///< padded linear position of each unknown (32 bits: less to stream per sweep)
    std::vector<uint8_t> diag;    ///< non-solid neighbours of each unknown
    std::vector<int32_t> colour[2];
    double scale = 1;             ///< operator scale (1/4 per coarsening)
    mutable std::vector<double> x, b, r;
    int64_t offsets[6] = {0, 0, 0, 0, 0, 0};

    int64_t padLin(int i, int j, int k) const
    {
        return int64_t(i + 1) * stride[0] + int64_t(j + 1) * stride[1] + (dim == 3 ? int64_t(k + 1) * stride[2] : 0);
    }
    openvdb::Coord coordOf(int64_t p) const
    {
        const int k = dim == 3 ? int(p / stride[2]) - 1 : 0;
        if (dim == 3) p %= stride[2];
        return {int(p % stride[1]) - 1, int(p / stride[1]) - 1, k};
    }
    size_t size() const { return lin.size(); }

    /// Fills the index from @a kindAt over the box, numbering fluid cells row by row.
    template <typename KindAt>
    void build(const KindAt& kindAt)
    {
        const int nz = dim == 3 ? n[2] : 1;
        stride[0] = 1;
        stride[1] = n[0] + 2;
        stride[2] = dim == 3 ? stride[1] * (n[1] + 2) : 0;
        const size_t padded = size_t(stride[1]) * (n[1] + 2) * (dim == 3 ? n[2] + 2 : 1);
        if (padded >= (size_t(1) << 32)) throw std::invalid_argument("MultigridPoisson: box too large (32-bit positions)");
        index.assign(padded, kSolid);
        const int rows = n[1] * nz;
        std::vector<int64_t> count(size_t(rows) + 1, 0);
        tbb::parallel_for(tbb::blocked_range<int>(0, rows), [&](const tbb::blocked_range<int>& r) {
            for (int row = r.begin(); row != r.end(); ++row) {
                const int j = row % n[1], k = row / n[1];
                int64_t c = 0;
                for (int i = 0; i < n[0]; ++i) {
                    const CellKind kd = kindAt(i, j, k);
                    int32_t& v = index[size_t(padLin(i, j, k))];
                    v = kd == CellKind::Fluid ? 0 : kd == CellKind::Dirichlet ? kDirichlet : kSolid;
                    c += kd == CellKind::Fluid;
                }
                count[size_t(row) + 1] = c;
            }
        });
        for (int row = 0; row < rows; ++row) count[size_t(row) + 1] += count[size_t(row)];
        lin.assign(size_t(count[size_t(rows)]), 0);
        tbb::parallel_for(tbb::blocked_range<int>(0, rows), [&](const tbb::blocked_range<int>& r) {
            for (int row = r.begin(); row != r.end(); ++row) {
                const int j = row % n[1], k = row / n[1];
                int64_t next = count[size_t(row)];
                for (int i = 0; i < n[0]; ++i) {
                    const int64_t p = padLin(i, j, k);
                    if (index[size_t(p)] != 0) continue;
                    index[size_t(p)] = int32_t(next);
                    lin[size_t(next++)] = uint32_t(p);
                }
            }
        });
        // The padding: per side, Dirichlet (outflow) or solid (walls, inflow).
        for (int k = (dim == 3 ? -1 : 0); k <= (dim == 3 ? n[2] : 0); ++k)
            for (int j = -1; j <= n[1]; ++j)
                for (int i = -1; i <= n[0]; ++i) {
                    int s = -1;
                    if (i < 0) s = 0;
                    else if (i >= n[0]) s = 1;
                    else if (j < 0) s = 2;
                    else if (j >= n[1]) s = 3;
                    else if (dim == 3 && k < 0) s = 4;
                    else if (dim == 3 && k >= n[2]) s = 5;
                    if (s < 0) { i = n[0] - 1; continue; } // skip the interior
                    index[size_t(padLin(i, j, k))] = side[size_t(s)] ? kDirichlet : kSolid;
                }
        const int64_t off[6] = {-stride[0], stride[0], -stride[1], stride[1], -stride[2], stride[2]};
        std::copy(off, off + 6, offsets);
        const int nb = 2 * dim;
        diag.assign(lin.size(), 0);
        colour[0].clear();
        colour[1].clear();
        for (size_t u = 0; u < lin.size(); ++u) {
            int d = 0;
            for (int q = 0; q < nb; ++q) d += index[size_t(lin[u] + offsets[q])] != kSolid;
            diag[u] = uint8_t(d);
            const openvdb::Coord c = coordOf(lin[u]);
            colour[(c.x() + c.y() + c.z()) & 1].push_back(int32_t(u));
        }
        x.assign(lin.size(), 0.0);
        b.assign(lin.size(), 0.0);
        r.assign(lin.size(), 0.0);
    }

    CellKind kindOf(int i, int j, int k) const
    {
        const int32_t v = index[size_t(padLin(i, j, k))];
        return v >= 0 ? CellKind::Fluid : v == kDirichlet ? CellKind::Dirichlet : CellKind::Solid;
    }

    /// out = scale (diag in - sum of unknown neighbours).
    void apply(const std::vector<double>& in, std::vector<double>& out) const
    {
        const int nb = 2 * dim;
        forBlocks(size(), [&](size_t a, size_t e) {
            for (size_t u = a; u < e; ++u) {
                double s = diag[u] * in[u];
                for (int q = 0; q < nb; ++q) {
                    const int32_t v = index[size_t(lin[u] + offsets[q])];
                    if (v >= 0) s -= in[size_t(v)];
                }
                out[u] = scale * s;
            }
        });
    }

    /// One Gauss-Seidel half sweep over the cells of colour @a c.
    void relax(std::vector<double>& xv, const std::vector<double>& bv, int c) const
    {
        const int nb = 2 * dim;
        const auto& list = colour[c];
        const double inv = 1.0 / scale;
        forBlocks(list.size(), [&](size_t a, size_t e) {
            for (size_t t = a; t < e; ++t) {
                const size_t u = size_t(list[t]);
                if (diag[u] == 0) continue;
                double s = bv[u] * inv;
                for (int q = 0; q < nb; ++q) {
                    const int32_t v = index[size_t(lin[u] + offsets[q])];
                    if (v >= 0) s += xv[size_t(v)];
                }
                xv[u] = s / diag[u];
            }
        });
    }

    void residual(const std::vector<double>& xv, const std::vector<double>& bv, std::vector<double>& rv) const
    {
        apply(xv, rv);
        forBlocks(size(), [&](size_t a, size_t e) {
            for (size_t u = a; u < e; ++u) rv[u] = bv[u] - rv[u];
        });
    }
};

namespace {

using Level = MultigridPoisson::Level;

/// f(u, coordinates of unknown u) for u in [a, e), in order; the coordinates are stepped along a
/// row (unknowns of a row are consecutive in the padded layout), so the divisions of coordOf are
/// paid once per row run, not per unknown.
template <typename F>
inline void forCoords(const Level& L, size_t a, size_t e, const F& f)
{
    int64_t prev = -2;
    openvdb::Coord c;
    for (size_t u = a; u < e; ++u) {
        const int64_t p = L.lin[u];
        if (p == prev + 1) c.x() += 1;
        else c = L.coordOf(p);
        prev = p;
        f(u, c);
    }
}

/// Cell-centred linear weights of fine offsets -1, 0, 1, 2 around a coarse cell (times 4).
constexpr double kW[4] = {0.25, 0.75, 0.75, 0.25};

/// coarse.b = P^T r / 2^dim (gather over the 4^dim fine cells each coarse cell touches). The
/// padded index covers fine cells -1..n, whose padding entries are not unknowns, so only a tap
/// past the padding (2c + 2 = n + 1 on an odd axis) needs a bounds test.
void restrictResidual(const Level& fine, const std::vector<double>& r, const Level& coarse, std::vector<double>& bc)
{
    const int dim = fine.dim;
    const double norm = dim == 3 ? 1.0 / 8.0 : 1.0 / 4.0;
    const int64_t sy = fine.stride[1], sz = fine.stride[2];
    forBlocks(coarse.size(), [&](size_t a, size_t e) {
        forCoords(coarse, a, e, [&](size_t u, const openvdb::Coord& c) {
            const int nx = std::min(4, fine.n[0] + 2 - 2 * c.x()), ny = std::min(4, fine.n[1] + 2 - 2 * c.y());
            const int kz0 = dim == 3 ? 0 : 1, kz1 = dim == 3 ? std::min(4, fine.n[2] + 2 - 2 * c.z()) : 2;
            // padded position of fine cell (2c - 1) along each axis
            const int64_t base = int64_t(2 * c.x()) + int64_t(2 * c.y()) * sy + (dim == 3 ? int64_t(2 * c.z()) * sz : 0);
            double s = 0;
            for (int dz = kz0; dz < kz1; ++dz) {
                const double wz = dim == 3 ? kW[dz] : 1.0;
                const int64_t bz = base + (dim == 3 ? dz * sz : 0);
                for (int dy = 0; dy < ny; ++dy) {
                    const int64_t by = bz + dy * sy;
                    for (int dx = 0; dx < nx; ++dx) {
                        const int32_t v = fine.index[size_t(by + dx)];
                        if (v >= 0) s += wz * kW[dy] * kW[dx] * r[size_t(v)];
                    }
                }
            }
            bc[u] = s * norm;
        });
    });
}

/// x += P xc (each fine cell from its parent, weight 3/4 per axis, and the next coarse cell on
/// its side, 1/4 per axis; coarse cells that are not unknowns, padding included, count as 0).
void prolongAdd(const Level& coarse, const std::vector<double>& xc, const Level& fine, std::vector<double>& x)
{
    const int dim = fine.dim;
    forBlocks(fine.size(), [&](size_t a, size_t e) {
        forCoords(fine, a, e, [&](size_t u, const openvdb::Coord& f) {
            int64_t off[3][2];
            double w[3][2];
            for (int ax = 0; ax < 3; ++ax) {
                const int p = ax < dim ? f[ax] >> 1 : 0;
                const int q = ax < dim ? ((f[ax] & 1) ? p + 1 : p - 1) : 0;
                const int64_t st = coarse.stride[ax];
                off[ax][0] = int64_t(p + 1) * st;
                off[ax][1] = int64_t(q + 1) * st;
                w[ax][0] = ax < dim ? 0.75 : 1.0;
                w[ax][1] = ax < dim ? 0.25 : 0.0;
            }
            double s = 0;
            for (int kz = 0; kz < (dim == 3 ? 2 : 1); ++kz)
                for (int ky = 0; ky < 2; ++ky)
                    for (int kx = 0; kx < 2; ++kx) {
                        const int32_t v = coarse.index[size_t(off[2][kz] + off[1][ky] + off[0][kx])];
                        if (v >= 0) s += w[2][kz] * w[1][ky] * w[0][kx] * xc[size_t(v)];
                    }
            x[u] += s;
        });
    });
}

/// x = V-cycle(b) on level L (x starts at 0).
void vcycle(const std::vector<std::unique_ptr<Level>>& levels, size_t L, const std::vector<double>& b,
            std::vector<double>& x, int sweeps)
{
    const Level& lv = *levels[L];
    std::fill(x.begin(), x.end(), 0.0);
    if (L + 1 == levels.size()) {
        for (int s = 0; s < 20; ++s) { // the coarsest level: symmetric sweeps to near convergence
            lv.relax(x, b, 0);
            lv.relax(x, b, 1);
            lv.relax(x, b, 1);
            lv.relax(x, b, 0);
        }
        return;
    }
    for (int s = 0; s < sweeps; ++s) {
        lv.relax(x, b, 0);
        lv.relax(x, b, 1);
    }
    lv.residual(x, b, lv.r);
    const Level& co = *levels[L + 1];
    restrictResidual(lv, lv.r, co, co.b);
    vcycle(levels, L + 1, co.b, co.x, sweeps);
    prolongAdd(co, co.x, lv, x);
    for (int s = 0; s < sweeps; ++s) {
        lv.relax(x, b, 1);
        lv.relax(x, b, 0);
    }
}

} // namespace

MultigridPoisson::MultigridPoisson(int dim, const openvdb::Coord& dims,
                                   const std::function<CellKind(int, int, int)>& kind,
                                   const std::array<bool, 6>& sideDirichlet)
    : mDim(dim)
{
    if (dim != 2 && dim != 3) throw std::invalid_argument("MultigridPoisson: dim must be 2 or 3");
    auto fine = std::make_unique<Level>();
    fine->dim = dim;
    fine->n[0] = std::max(1, dims.x());
    fine->n[1] = std::max(1, dims.y());
    fine->n[2] = dim == 3 ? std::max(1, dims.z()) : 1;
    fine->side = sideDirichlet;
    fine->build(kind);
    // An enclosed pocket of fluid (no Dirichlet cell reachable: ice all round) makes the system
    // singular, and round-off in its right-hand side would be amplified by the smoothers. Pin
    // the pressure of one cell per pocket (its first in order) to 0: the pocket's equations then
    // hold exactly when its fluxes sum to zero, as they do for an enclosed region.
    {
        const Level& f = *fine;
        const int nb = 2 * dim;
        std::vector<uint8_t> seen(f.size(), 0);
        std::vector<int32_t> stack;
        auto flood = [&](size_t start) {
            stack.push_back(int32_t(start));
            seen[start] = 1;
            while (!stack.empty()) {
                const size_t u = size_t(stack.back());
                stack.pop_back();
                for (int q = 0; q < nb; ++q) {
                    const int32_t v = f.index[size_t(f.lin[u] + f.offsets[q])];
                    if (v >= 0 && !seen[size_t(v)]) { seen[size_t(v)] = 1; stack.push_back(v); }
                }
            }
        };
        for (size_t u = 0; u < f.size(); ++u) {
            if (seen[u]) continue;
            bool open = false;
            for (int q = 0; q < nb && !open; ++q) open = f.index[size_t(f.lin[u] + f.offsets[q])] == kDirichlet;
            if (open) flood(u);
        }
        std::vector<int64_t> pins;
        for (size_t u = 0; u < f.size(); ++u)
            if (!seen[u]) { pins.push_back(f.lin[u]); flood(u); }
        if (!pins.empty()) {
            std::vector<uint8_t> pinned(f.index.size(), 0);
            for (int64_t p : pins) pinned[size_t(p)] = 1;
            auto rebuilt = std::make_unique<Level>();
            rebuilt->dim = dim;
            std::copy(f.n, f.n + 3, rebuilt->n);
            rebuilt->side = sideDirichlet;
            const Level* old = fine.get();
            rebuilt->build([&](int i, int j, int k) {
                return pinned[size_t(old->padLin(i, j, k))] ? CellKind::Dirichlet : old->kindOf(i, j, k);
            });
            fine = std::move(rebuilt);
        }
    }
    mLevels.push_back(std::move(fine));
    // Coarsen all axes together until the box is a few cells across.
    for (int l = 0; l < 16; ++l) {
        const Level& f = *mLevels.back();
        const int maxN = std::max(f.n[0], std::max(f.n[1], dim == 3 ? f.n[2] : 1));
        if (maxN <= 4 || f.size() <= 64) break;
        auto c = std::make_unique<Level>();
        c->dim = dim;
        for (int a = 0; a < 3; ++a) c->n[a] = a < dim ? (f.n[a] + 1) / 2 : 1;
        c->side = f.side;
        c->scale = f.scale * 0.25;
        c->build([&f, dim](int i, int j, int k) {
            bool anyFluid = false;
            for (int dz = 0; dz < (dim == 3 ? 2 : 1); ++dz)
                for (int dy = 0; dy < 2; ++dy)
                    for (int dx = 0; dx < 2; ++dx) {
                        const int x = 2 * i + dx, y = 2 * j + dy, z = dim == 3 ? 2 * k + dz : 0;
                        if (x >= f.n[0] || y >= f.n[1] || z >= f.n[2]) continue;
                        const CellKind kd = f.kindOf(x, y, z);
                        if (kd == CellKind::Dirichlet) return CellKind::Dirichlet;
                        anyFluid |= kd == CellKind::Fluid;
                    }
            return anyFluid ? CellKind::Fluid : CellKind::Solid;
        });
        if (c->size() == 0) break;
        mLevels.push_back(std::move(c));
    }
}

MultigridPoisson::~MultigridPoisson() = default;

size_t MultigridPoisson::unknowns() const { return mLevels[0]->size(); }
int MultigridPoisson::levels() const { return int(mLevels.size()); }

int64_t MultigridPoisson::unknownIndex(int x, int y, int z) const
{
    const Level& l = *mLevels[0];
    if (x < 0 || y < 0 || x >= l.n[0] || y >= l.n[1]) return -1;
    if (mDim == 3 && (z < 0 || z >= l.n[2])) return -1;
    const int32_t v = l.index[size_t(l.padLin(x, y, z))];
    return v >= 0 ? v : -1;
}

MultigridPoisson::IndexView MultigridPoisson::indexView() const
{
    const Level& l = *mLevels[0];
    return {l.index.data(), l.stride[0], l.stride[1], l.dim == 3 ? l.stride[2] : 0};
}

openvdb::Coord MultigridPoisson::cellOf(size_t k) const { return mLevels[0]->coordOf(mLevels[0]->lin[k]); }

void MultigridPoisson::apply(const std::vector<double>& in, std::vector<double>& out) const
{
    out.resize(unknowns());
    mLevels[0]->apply(in, out);
}

namespace {

/// The fine level's operator for the shared CG.
class LevelOperator final : public solver::LinearOperator {
public:
    explicit LevelOperator(const Level& L) : mL(L) {}
    size_t size() const override { return mL.size(); }
    void apply(const std::vector<double>& in, std::vector<double>& out) const override { mL.apply(in, out); }

private:
    const Level& mL;
};

/// z = one V-cycle on r (symmetric: red then black before, black then red after).
class VCyclePreconditioner final : public solver::Preconditioner {
public:
    VCyclePreconditioner(const std::vector<std::unique_ptr<Level>>& levels, int sweeps) : mLevels(levels), mSweeps(sweeps) {}
    void apply(const std::vector<double>& r, std::vector<double>& z) const override { vcycle(mLevels, 0, r, z, mSweeps); }

private:
    const std::vector<std::unique_ptr<Level>>& mLevels;
    int mSweeps;
};

/// The Jacobi reference: z = r / diag (0 where the diagonal is 0).
class DiagonalPreconditioner final : public solver::Preconditioner {
public:
    explicit DiagonalPreconditioner(const Level& L) : mL(L) {}
    void apply(const std::vector<double>& r, std::vector<double>& z) const override
    {
        forBlocks(r.size(), [&](size_t a, size_t e) {
            for (size_t u = a; u < e; ++u) z[u] = mL.diag[u] ? r[u] / mL.diag[u] : 0.0;
        });
    }

private:
    const Level& mL;
};

} // namespace

PoissonStats MultigridPoisson::solve(const std::vector<double>& b, std::vector<double>& x,
                                     const PoissonSettings& settings) const
{
    const Level& L0 = *mLevels[0];
    const size_t n = L0.size();
    PoissonStats st;
    st.levels = int(mLevels.size());
    st.unknowns = n;
    x.resize(n, 0.0);
    if (n == 0) { st.converged = true; return st; }
    const solver::Blocks blocks{n, kBlock};
    const double bNorm = std::sqrt(blockSum(n, [&](size_t a, size_t e) {
        double s = 0;
        for (size_t u = a; u < e; ++u) s += b[u] * b[u];
        return s;
    }));
    auto stop = [&](const solver::Residual& r) {
        st.maxResidual = r.maxAbs;
        st.relativeResidual = bNorm > 0 ? std::sqrt(r.sumSquares) / bNorm : std::sqrt(r.sumSquares);
        const bool rel = settings.relativeTolerance > 0 && st.relativeResidual <= settings.relativeTolerance;
        const bool abs = settings.absoluteTolerance > 0 && st.maxResidual <= settings.absoluteTolerance;
        return rel || abs || st.maxResidual == 0;
    };
    const LevelOperator A(L0);
    const VCyclePreconditioner vc(mLevels, std::max(1, settings.smoothingSweeps));
    const DiagonalPreconditioner jacobi(L0);
    // CG's vectors live as long as the solver (reused from solve to solve).
    const solver::CgStats cg = solver::conjugateGradient(
        A, settings.multigrid ? static_cast<const solver::Preconditioner&>(vc) : jacobi, b, x, blocks,
        settings.maxIterations, stop, mWork);
    st.iterations = cg.iterations;
    st.converged = cg.converged;
    return st;
}

} // namespace fluid
} // namespace frostvdb
