#include <frostvdb/icephysics/ImplicitSystem.h>

#include <frostvdb/core/PlaneFold.h>

#include <Eigen/Sparse>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>

#if defined(__x86_64__) || defined(__i386__)
#include <frostvdb/base/VectorLanes.h>
#define FROSTVDB_HAVE_AVX2_RELAX 1
#endif

namespace frostvdb {

namespace {

#ifdef FROSTVDB_HAVE_AVX2_RELAX
// Vector Gauss-Seidel relaxation: four rows at a time, each lane the scalar code's operations in
// its order (pair products and sums, canonicalSum's min/max network, the division by the
// diagonal, the residual's |v - x| d and std::max), so the bits are the scalar code's. The
// target has no FMA, nothing is contracted. std::min(a, b) is min_pd(b, a), std::max(a, b)
// max_pd(b, a) (ties and NaN: first argument, as the scalar code).
using namespace lanes; // FV_AVX2 and the lane operations (base/VectorLanes.h)


/// canonicalSum of NP (2 or 3) pair sums per lane.
template <int NP>
FV_AVX2 inline __m256d vsorted(const __m256d* v)
{
    const __m256d zero = _mm256_setzero_pd();
    if constexpr (NP == 3) {
        const __m256d a = vmin(v[0], v[1]), b = vmax(v[0], v[1]);
        const __m256d lo = vmin(a, v[2]), t = vmax(a, v[2]);
        return _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(zero, lo), vmin(b, t)), vmax(b, t));
    } else {
        return _mm256_add_pd(_mm256_add_pd(zero, vmin(v[0], v[1])), vmax(v[0], v[1]));
    }
}

/// Rows [begin, end) of a system with NP opposite-tap pairs (2 taps each): per-row coefficients
/// (coef != null) or uniform weights times @a sc; per-row diagonal (diag != null) or @a d.
/// Writes v into out[r - begin], returns max(mx, |v - x_r| d_r).
template <int NP>
FV_AVX2 __attribute__((noinline)) double relaxRowsAvx2(size_t begin, size_t end, const double* x, const double* rhs,
                                                        const double* diag, double d, const double* coef,
                                                        const double* w, double sc, const int32_t* nb, double* out,
                                                        double mx)
{
    constexpr int taps = 2 * NP;
    const __m256d signBit = _mm256_set1_pd(-0.0);
    __m256d wq[taps];
    for (int q = 0; q < taps; ++q) wq[q] = _mm256_set1_pd(coef ? 0.0 : w[q]);
    const __m256d scv = _mm256_set1_pd(sc), dv = _mm256_set1_pd(d);
    __m256d vmx = _mm256_set1_pd(mx);
    size_t i = begin;
    for (; i + 4 <= end; i += 4) {
        const int32_t* nbr = nb + i * taps;
        __m256d xq[taps];
        // scalar loads into lanes (the hardware gathers were slower here: AMD EPYC, measured)
        for (int q = 0; q < taps; ++q)
            xq[q] = _mm256_setr_pd(x[nbr[q]], x[nbr[taps + q]], x[nbr[2 * taps + q]], x[nbr[3 * taps + q]]);
        __m256d pair[NP];
        __m256d off;
        if (coef) {
            const double* cr = coef + i * taps;
            for (int k = 0; k < NP; ++k) {
                const int q0 = 2 * k, q1 = 2 * k + 1;
                const __m256d c0 = _mm256_setr_pd(cr[q0], cr[taps + q0], cr[2 * taps + q0], cr[3 * taps + q0]);
                const __m256d c1 = _mm256_setr_pd(cr[q1], cr[taps + q1], cr[2 * taps + q1], cr[3 * taps + q1]);
                pair[k] = _mm256_add_pd(_mm256_mul_pd(c0, xq[2 * k]), _mm256_mul_pd(c1, xq[2 * k + 1]));
            }
            off = vsorted<NP>(pair);
        } else {
            for (int k = 0; k < NP; ++k)
                pair[k] = _mm256_add_pd(_mm256_mul_pd(wq[2 * k], xq[2 * k]), _mm256_mul_pd(wq[2 * k + 1], xq[2 * k + 1]));
            off = _mm256_mul_pd(scv, vsorted<NP>(pair));
        }
        const __m256d di = diag ? _mm256_loadu_pd(diag + i) : dv;
        const __m256d v = _mm256_div_pd(_mm256_add_pd(_mm256_loadu_pd(rhs + i), off), di);
        const __m256d res = _mm256_mul_pd(_mm256_andnot_pd(signBit, _mm256_sub_pd(v, _mm256_loadu_pd(x + i))), di);
        vmx = vmax(vmx, res);
        _mm256_storeu_pd(out + (i - begin), v);
    }
    alignas(32) double m4[4];
    _mm256_store_pd(m4, vmx);
    // the lanes' maxima, then the tail rows in the scalar code's form
    for (double m : m4) mx = std::max(mx, m);
    for (; i < end; ++i) {
        const int32_t* nbr = nb + i * taps;
        double pair[NP];
        double off;
        if (coef) {
            const double* c = coef + i * taps;
            for (int k = 0; k < NP; ++k) pair[k] = c[2 * k] * x[nbr[2 * k]] + c[2 * k + 1] * x[nbr[2 * k + 1]];
            off = canonicalSum(pair, NP);
        } else {
            for (int k = 0; k < NP; ++k) pair[k] = w[2 * k] * x[nbr[2 * k]] + w[2 * k + 1] * x[nbr[2 * k + 1]];
            off = sc * canonicalSum(pair, NP);
        }
        const double di = diag ? diag[i] : d;
        const double v = (rhs[i] + off) / di;
        mx = std::max(mx, std::fabs(v - x[i]) * di);
        out[i - begin] = v;
    }
    return mx;
}

#endif

/// The vector relaxation applies: AVX2, not switched off by FROSTVDB_NO_VECTOR_ROWS (read at
/// every solve, so one test process compares both builds).
bool vectorRelax()
{
#ifdef FROSTVDB_HAVE_AVX2_RELAX
    const char* v = std::getenv("FROSTVDB_NO_VECTOR_ROWS");
    const bool disabled = v && std::strcmp(v, "0") != 0 && *v;
    return !disabled && cpuHasAvx2();
#else
    return false;
#endif
}
inline int nbIndex(int dx, int dy, int dz) { return (dz + 1) * 9 + (dy + 1) * 3 + (dx + 1); }

/// Leaf origin (in leaf units, origin >> 3) -> leaf index through a dense table over the leaves'
/// bounding box: a few bytes per leaf of the domain, much faster than hashing 27 look-ups per leaf.
struct LeafTable {
    openvdb::Coord lo{std::numeric_limits<int>::max()}, hi{std::numeric_limits<int>::min()}, dim{0};
    std::vector<int32_t> table;
    template <typename LeafManagerT>
    explicit LeafTable(const LeafManagerT& topology)
    {
        const size_t nLeaves = topology.leafCount();
        for (size_t i = 0; i < nLeaves; ++i) {
            lo.minComponent(topology.leaf(i).origin() >> 3);
            hi.maxComponent(topology.leaf(i).origin() >> 3);
        }
        dim = nLeaves ? hi - lo + openvdb::Coord(1) : openvdb::Coord(0);
        table.assign(size_t(dim.x()) * dim.y() * dim.z(), -1);
        for (size_t i = 0; i < nLeaves; ++i) table[cell(topology.leaf(i).origin() >> 3)] = int32_t(i);
    }
    size_t cell(const openvdb::Coord& l) const
    {
        return (size_t(l.z() - lo.z()) * dim.y() + size_t(l.y() - lo.y())) * dim.x() + size_t(l.x() - lo.x());
    }
    /// The index of the leaf at @a l, -1 where there is none.
    int32_t at(const openvdb::Coord& l) const
    {
        if (l.x() < lo.x() || l.y() < lo.y() || l.z() < lo.z() || l.x() > hi.x() || l.y() > hi.y() || l.z() > hi.z())
            return -1;
        return table[cell(l)];
    }
};

/// The active voxels of leaf @a li, word by word over its value mask (the value iterator and its
/// coordinates cost more than the work done per voxel here): f(offset, coordinate).
template <typename LeafManagerT, typename F>
inline void forActive(const LeafManagerT& topology, size_t li, F&& f)
{
    const auto& leaf = topology.leaf(li);
    const auto& mask = leaf.getValueMask();
    for (openvdb::Index w = 0; w < openvdb::FloatTree::LeafNodeType::NodeMaskType::WORD_COUNT; ++w)
        for (uint64_t bits = mask.template getWord<uint64_t>(w); bits; bits &= bits - 1) {
            const openvdb::Index off = w * 64 + openvdb::Index(__builtin_ctzll(bits));
            f(off, leaf.offsetToGlobalCoord(off));
        }
}
} // namespace

template <typename LeavesT>
SlotLayout::SlotLayout(const LeavesT& topology, const Stencil& stencil, bool flat, SlotLayout* recycle,
                       const std::vector<size_t>* leafOrder)
    : plane(flat), slots(flat ? 64 : 512)
{
    build(topology, stencil, recycle, leafOrder);
}

template SlotLayout::SlotLayout(const openvdb::tree::LeafManager<openvdb::FloatTree>&, const Stencil&, bool,
                                SlotLayout*, const std::vector<size_t>*);
template SlotLayout::SlotLayout(const openvdb::tree::LeafManager<const openvdb::MaskTree>&, const Stencil&, bool,
                                SlotLayout*, const std::vector<size_t>*);
template SlotLayout::SlotLayout(const plane::PlaneLeaves&, const Stencil&, bool, SlotLayout*,
                                const std::vector<size_t>*);

template <typename LeafManagerT>
void SlotLayout::build(const LeafManagerT& topology, const Stencil& stencil, SlotLayout* recycle,
                       const std::vector<size_t>* leafOrder)
{
    if (recycle) {
        slotRow.swap(recycle->slotRow);
        neighbours.swap(recycle->neighbours);
    }
    colours = stencil.hexagonal ? 3 : 2;
    taps = int(stencil.taps.size());
    for (const auto& t : stencil.taps) weights.push_back(t.wLap);
    const std::vector<size_t> firstRow = numberRows(topology, leafOrder);
    rows = colourStart[size_t(colours)];
    // sized only: each leaf's slots are set to -1 by the leaf's own task below, and every
    // neighbour entry is written
    const size_t nLeaves = topology.leafCount();
    slotRow.resize(nLeaves * size_t(slots));
    neighbours.resize(rows * size_t(taps));

    // slot of leaf offset off: the offset itself in a box, its (x, y) part on a plane (one z)
    const int slotShift = plane ? 3 : 0;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nLeaves, 16), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t li = r.begin(); li != r.end(); ++li) {
            size_t next[3];
            for (int c = 0; c < colours; ++c) next[c] = firstRow[li * colours + c];
            int32_t* slot = &slotRow[li * size_t(slots)];
            std::fill(slot, slot + slots, -1);
            forActive(topology, li, [&](openvdb::Index off, const openvdb::Coord& c) {
                slot[off >> slotShift] = int32_t(next[colourOf(c)]++);
            });
        }
    });
    linkNeighbours(topology, stencil);
}

/// Rows: colour by colour, each leaf by leaf in @a leafOrder (or leaf order), then voxel order
/// (prefix sums over the leaves' active counts per colour). Sets colourStart; returns each leaf's
/// first row per colour.
template <typename LeafManagerT>
std::vector<size_t> SlotLayout::numberRows(const LeafManagerT& topology, const std::vector<size_t>* leafOrder)
{
    const size_t nLeaves = topology.leafCount();
    std::vector<size_t> firstRow(nLeaves * size_t(colours), 0); // per leaf and colour
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nLeaves, 16), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t li = r.begin(); li != r.end(); ++li)
            forActive(topology, li, [&](openvdb::Index, const openvdb::Coord& c) { ++firstRow[li * colours + colourOf(c)]; });
    });
    colourStart.assign(size_t(colours) + 1, 0);
    size_t row = 0;
    for (int c = 0; c < colours; ++c) {
        colourStart[size_t(c)] = row;
        for (size_t q = 0; q < nLeaves; ++q) {
            const size_t li = leafOrder ? (*leafOrder)[q] : q;
            const size_t count = firstRow[li * colours + c];
            firstRow[li * colours + c] = row;
            row += count;
        }
    }
    colourStart[size_t(colours)] = row;
    return firstRow;
}

/// Neighbour rows. Where each tap of each leaf offset lands is the same for every leaf: which of
/// the 27 leaves around (the leaf itself in the middle) and which slot of it, tabled once; a
/// voxel's neighbour row is then that leaf's slot row.
template <typename LeafManagerT>
void SlotLayout::linkNeighbours(const LeafManagerT& topology, const Stencil& stencil)
{
    const LeafTable leafTable(topology);
    const int slotShift = plane ? 3 : 0;
    const int32_t n = int32_t(rows);
    struct TapTarget {
        uint8_t leaf; ///< nbIndex of the leaf the tap lands in
        uint16_t slot;
    };
    std::vector<TapTarget> target(size_t(512) * size_t(taps));
    for (openvdb::Index off = 0; off < 512; ++off) {
        const int x = int(off >> 6), y = int((off >> 3) & 7), z = int(off & 7);
        for (int q = 0; q < taps; ++q) {
            const openvdb::Coord& t = stencil.taps[size_t(q)].offset;
            const int i = x + t.x(), j = y + t.y(), k = z + t.z();
            auto side = [](int v) { return v < 0 ? -1 : (v > 7 ? 1 : 0); };
            const openvdb::Index noff = openvdb::Index(((i & 7) << 6) | ((j & 7) << 3) | (k & 7));
            target[size_t(off) * taps + q] = {uint8_t(nbIndex(side(i), side(j), side(k))), uint16_t(noff >> slotShift)};
        }
    }
    tbb::parallel_for(tbb::blocked_range<size_t>(0, topology.leafCount(), 16), [&](const tbb::blocked_range<size_t>& r) {
        int32_t nbLeaf[27];
        for (size_t li = r.begin(); li != r.end(); ++li) {
            const openvdb::Coord o = topology.leaf(li).origin() >> 3;
            for (int dz = -1; dz <= 1; ++dz)
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) nbLeaf[nbIndex(dx, dy, dz)] = leafTable.at(o + openvdb::Coord(dx, dy, dz));
            const int32_t* own = &slotRow[li * size_t(slots)];
            forActive(topology, li, [&](openvdb::Index off, const openvdb::Coord&) {
                int32_t* out = &neighbours[size_t(own[off >> slotShift]) * size_t(taps)];
                const TapTarget* tt = &target[size_t(off) * taps];
                for (int q = 0; q < taps; ++q) {
                    const int32_t nl = nbLeaf[tt[q].leaf];
                    const int32_t nr = nl < 0 ? -1 : slotRow[size_t(nl) * size_t(slots) + tt[q].slot];
                    out[q] = nr >= 0 ? nr : n;
                }
            });
        }
    });
}

ImplicitSystem::ImplicitSystem(const SlotLayout& layout) : mL(layout)
{
    const size_t n = layout.rowCount();
    x.assign(n + 1, 0.0);
    diag.assign(n, 1.0);
    scale.assign(n, 0.0);
    rhs.assign(n, 0.0);
}

ImplicitSystem::ImplicitSystem(const SlotLayout& layout, ImplicitSystem& recycle) : mL(layout), mRecycled(true)
{
    const size_t n = layout.rowCount();
    x.swap(recycle.x);
    diag.swap(recycle.diag);
    scale.swap(recycle.scale);
    rhs.swap(recycle.rhs);
    coef.swap(recycle.coef); // kept in use when it was: useCoefficients() sizes it
    mNext.swap(recycle.mNext);
    mUniform = recycle.mUniform;
    mUniformDiag = recycle.mUniformDiag;
    mUniformScale = recycle.mUniformScale;
    x.resize(n + 1);
    rhs.resize(n);
    if (!mUniform) diag.resize(n);
    if (!mUniform && coef.empty()) scale.resize(n);
    if (!coef.empty()) coef.resize(n * size_t(mL.taps));
}

double ImplicitSystem::residualMaxNorm() const
{
    return tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, rows(), 1024), 0.0,
        [&](const tbb::blocked_range<size_t>& r, double m) {
            for (size_t i = r.begin(); i != r.end(); ++i)
                m = std::max(m, std::fabs(rhs[i] - rowDiag(i) * x[i] + offDiagonal(i)));
            return m;
        },
        [](double a, double b) { return std::max(a, b); });
}

SolveReport ImplicitSystem::solve(LinearSolverKind kind, double tolerance, int maxIterations)
{
    return kind == LinearSolverKind::GaussSeidel ? gaussSeidel(tolerance, maxIterations)
                                                 : bicgstab(tolerance, maxIterations);
}

SolveReport ImplicitSystem::gaussSeidel(double tolerance, int maxIterations)
{
    SolveReport rep;
    // Hexagonal: colours 1 and 2 are updated together from the same values (see the header);
    // their rows are adjacent, one range.
    const bool pairLast = mL.colours == 3;
    const auto& cs = mL.colourStart;
    std::vector<double>& next = mNext; // every entry is written before it is read
    if (pairLast && next.size() < cs[3] - cs[1]) next.resize(cs[3] - cs[1]);
    // The update of row i from the current x; returns its residual before the update.
    // Vector rows (AVX2) for the plane stencils (4 and 6 taps); the scalar loop below is their
    // reference and serves everything else.
    const bool vec = vectorRelax() && (mL.taps == 4 || mL.taps == 6) && (mUniform || !coef.empty());
    auto relaxRows = [&](size_t begin, size_t end, double* out, double mx) {
#ifdef FROSTVDB_HAVE_AVX2_RELAX
        if (vec) {
            const double* c = coef.empty() ? nullptr : coef.data();
            const double* dg = mUniform ? nullptr : diag.data();
            const double sc = mUniform ? mUniformScale : 1.0;
            const double d = mUniform ? mUniformDiag : 1.0;
            return mL.taps == 6 ? relaxRowsAvx2<3>(begin, end, x.data(), rhs.data(), dg, d, c, mL.weights.data(), sc,
                                                   mL.neighbours.data(), out, mx)
                                : relaxRowsAvx2<2>(begin, end, x.data(), rhs.data(), dg, d, c, mL.weights.data(), sc,
                                                   mL.neighbours.data(), out, mx);
        }
#endif
        if (mUniform) {
            const double d = mUniformDiag, sc = mUniformScale;
            for (size_t i = begin; i != end; ++i) {
                const double v = (rhs[i] + offDiagonal(i, sc)) / d;
                mx = std::max(mx, std::fabs(v - x[i]) * d);
                out[i - begin] = v;
            }
        } else {
            for (size_t i = begin; i != end; ++i) {
                const double v = (rhs[i] + offDiagonal(i)) / diag[i];
                mx = std::max(mx, std::fabs(v - x[i]) * diag[i]);
                out[i - begin] = v;
            }
        }
        return mx;
    };
    auto maxReduce = [](double a, double b) { return std::max(a, b); };
    for (int it = 0; it < maxIterations; ++it) {
        double worst = 0;
        for (int c = 0; c < mL.colours; ++c) {
            if (pairLast && c == 2) continue;
            const size_t begin = cs[size_t(c)], end = pairLast && c == 1 ? cs[3] : cs[size_t(c) + 1];
            // Rows of one colour only read rows of the others: a parallel update in place.
            // Colours 1 and 2 of the hexagonal lattice: computed into `next`, then written.
            const bool viaNext = pairLast && c == 1;
            auto target = [&](size_t i) { return viaNext ? next.data() + (i - begin) : x.data() + i; };
            const double m = tbb::parallel_reduce(
                tbb::blocked_range<size_t>(begin, end, 1024), 0.0,
                [&](const tbb::blocked_range<size_t>& r, double mx) {
                    return relaxRows(r.begin(), r.end(), target(r.begin()), mx);
                },
                maxReduce);
            if (viaNext)
                tbb::parallel_for(tbb::blocked_range<size_t>(begin, end, 4096), [&](const tbb::blocked_range<size_t>& r) {
                    std::copy(target(r.begin()), target(r.end()), x.data() + r.begin());
                });
            worst = std::max(worst, m);
        }
        rep.iterations = it + 1;
        rep.residual = worst;
        if (worst <= tolerance) {
            rep.converged = true;
            break;
        }
    }
    return rep;
}

SolveReport ImplicitSystem::bicgstab(double tolerance, int maxIterations)
{
    const int64_t n = int64_t(rows());
    SolveReport rep;
    if (n == 0) {
        rep.converged = true;
        return rep;
    }
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(size_t(n) * (mL.taps + 1));
    Eigen::VectorXd b(n), x0(n);
    for (int64_t r = 0; r < n; ++r) {
        double bi = rhs[r];
        trip.emplace_back(r, r, rowDiag(size_t(r)));
        for (int q = 0; q < mL.taps; ++q) {
            const int32_t col = mL.neighbours[size_t(r) * mL.taps + q];
            const double c = coef.empty() ? rowScale(size_t(r)) * mL.weights[q] : coef[size_t(r) * mL.taps + q];
            if (col < n) trip.emplace_back(r, col, -c);
            else bi += c * outside(); // Dirichlet neighbour: right-hand side
        }
        b[r] = bi;
        x0[r] = x[r];
    }
    Eigen::SparseMatrix<double, Eigen::RowMajor> A(n, n);
    A.setFromTriplets(trip.begin(), trip.end());
    Eigen::BiCGSTAB<Eigen::SparseMatrix<double, Eigen::RowMajor>> solver;
    solver.compute(A);
    // ||r||_2 <= tol implies ||r||_inf <= tol; Eigen's criterion is relative to ||b||_2.
    const double bn = b.norm();
    solver.setTolerance(bn > 0 ? tolerance / bn : tolerance);
    solver.setMaxIterations(maxIterations);
    const Eigen::VectorXd sol = solver.solveWithGuess(b, x0);
    for (int64_t r = 0; r < n; ++r) x[r] = sol[r];
    rep.iterations = int(solver.iterations());
    rep.residual = (b - A * sol).lpNorm<Eigen::Infinity>();
    rep.converged = rep.residual <= tolerance;
    return rep;
}

} // namespace frostvdb
