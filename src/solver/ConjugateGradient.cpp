/// @file ConjugateGradient.cpp
/// @brief The shared preconditioned conjugate gradient (see ConjugateGradient.h).
#include <frostvdb/solver/ConjugateGradient.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace frostvdb {
namespace solver {

namespace {

/// f(begin, end) for every block, in parallel (about 16k entries per task).
template <typename F>
void forBlocks(const Blocks& bl, const F& f)
{
    const size_t grain = std::max<size_t>(1, 16384 / std::max<size_t>(1, bl.size));
    tbb::parallel_for(tbb::blocked_range<size_t>(0, bl.count(), grain), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b != r.end(); ++b) f(bl.begin(b), bl.end(b));
    });
}

double dot(const Blocks& bl, const std::vector<double>& a, const std::vector<double>& c)
{
    std::vector<double> part(bl.count(), 0.0);
    forBlocks(bl, [&](size_t s0, size_t e) {
        double s = 0;
        for (size_t u = s0; u < e; ++u) s += a[u] * c[u];
        part[s0 / bl.size] = s;
    });
    double s = 0;
    for (double x : part) s += x; // serial: the same sum whatever the thread count
    return s;
}

Residual measure(const Blocks& bl, const std::vector<double>& r, int iteration)
{
    std::vector<double> part(bl.count(), 0.0), mx(bl.count(), 0.0);
    forBlocks(bl, [&](size_t s0, size_t e) {
        double s = 0, m = 0;
        for (size_t u = s0; u < e; ++u) {
            s += r[u] * r[u];
            m = std::max(m, std::fabs(r[u]));
        }
        part[s0 / bl.size] = s;
        mx[s0 / bl.size] = m;
    });
    Residual res;
    for (double x : part) res.sumSquares += x;
    for (double m : mx) res.maxAbs = std::max(res.maxAbs, m);
    res.iteration = iteration;
    return res;
}

} // namespace

void JacobiPreconditioner::apply(const std::vector<double>& r, std::vector<double>& z) const
{
    const Blocks bl{r.size(), 4096};
    forBlocks(bl, [&](size_t a, size_t e) {
        for (size_t u = a; u < e; ++u) z[u] = r[u] * mInverse[u];
    });
}

CgStats conjugateGradient(const LinearOperator& A, const Preconditioner& M, const std::vector<double>& b,
                          std::vector<double>& x, const Blocks& blocks, int maxIterations,
                          const std::function<bool(const Residual&)>& stop, CgWorkspace& ws)
{
    const size_t n = A.size();
    CgStats st;
    std::vector<double>&r = ws.r, &z = ws.z, &p = ws.p, &q = ws.q;
    for (auto* v : {&r, &z, &p, &q}) v->resize(n);
    A.apply(x, q);
    forBlocks(blocks, [&](size_t a, size_t e) {
        for (size_t u = a; u < e; ++u) r[u] = b[u] - q[u];
    });
    st.residual = measure(blocks, r, 0);
    if ((st.converged = stop(st.residual))) return st;
    M.apply(r, z);
    std::copy(z.begin(), z.end(), p.begin());
    double rz = dot(blocks, r, z);
    while (st.iterations < maxIterations) {
        A.apply(p, q);
        const double pq = dot(blocks, p, q);
        if (!(pq > 0)) break; // a singular direction (an enclosed pocket): nothing more to gain
        const double alpha = rz / pq;
        forBlocks(blocks, [&](size_t a, size_t e) {
            for (size_t u = a; u < e; ++u) {
                x[u] += alpha * p[u];
                r[u] -= alpha * q[u];
            }
        });
        ++st.iterations;
        st.residual = measure(blocks, r, st.iterations);
        if ((st.converged = stop(st.residual))) break;
        M.apply(r, z);
        const double rzNew = dot(blocks, r, z);
        const double beta = rz != 0 ? rzNew / rz : 0.0;
        rz = rzNew;
        forBlocks(blocks, [&](size_t a, size_t e) {
            for (size_t u = a; u < e; ++u) p[u] = z[u] + beta * p[u];
        });
    }
    return st;
}

CgStats conjugateGradient(const LinearOperator& A, const Preconditioner& M, const std::vector<double>& b,
                          std::vector<double>& x, const Blocks& blocks, int maxIterations,
                          const std::function<bool(const Residual&)>& stop)
{
    CgWorkspace ws;
    return conjugateGradient(A, M, b, x, blocks, maxIterations, stop, ws);
}

} // namespace solver
} // namespace frostvdb
