#pragma once
/// @file ConjugateGradient.h
/// @brief The one (preconditioned) conjugate gradient of frostvdb, on a matrix-free
/// LinearOperator (LinearOperator.h) with any Preconditioner (identity, Jacobi, a multigrid
/// V-cycle). Callers choose the stopping rule from the residual's 2-norm and max norm.
///
/// @code
/// solver::CgWorkspace ws;
/// const auto stats = solver::conjugateGradient(A, M, b, x, blocks, maxIterations,
///     [&](const solver::Residual& r) { return r.maxAbs <= tol; }, ws);
/// @endcode
///
/// The iteration (Hestenes-Stiefel with a preconditioner):
///   r = b - A x; stop?; z = M r; p = z; rz = r.z
///   repeat: q = A p; pq = p.q (stop when not > 0: a singular direction); alpha = rz / pq;
///           x += alpha p; r -= alpha q; stop?; z = M r; beta = r.z / rz; p = z + beta p
/// Every vector update runs over the blocks in parallel; every reduction sums blocks serially.
#include <frostvdb/solver/LinearOperator.h>

#include <functional>
#include <vector>

namespace frostvdb {
namespace solver {

/// The residual r = b - A x after an update, as the stopping rule sees it.
struct Residual {
    double sumSquares = 0; ///< r.r, summed over the Blocks
    double maxAbs = 0;     ///< max |r_i|
    int iteration = 0;     ///< updates of x so far
};

struct CgStats {
    int iterations = 0;
    bool converged = false; ///< the stopping rule said yes
    Residual residual;      ///< at exit
};

/// Vectors of the iteration, kept by callers that solve often (no reallocation).
struct CgWorkspace {
    std::vector<double> r, z, p, q;
};

/// Solves A x = b from the guess in @a x. @a stop is asked after the initial residual and after
/// every update; the iteration also ends after @a maxIterations updates or when p.Ap is not
/// positive.
CgStats conjugateGradient(const LinearOperator& A, const Preconditioner& M, const std::vector<double>& b,
                          std::vector<double>& x, const Blocks& blocks, int maxIterations,
                          const std::function<bool(const Residual&)>& stop, CgWorkspace& ws);

/// The same with a workspace of its own.
CgStats conjugateGradient(const LinearOperator& A, const Preconditioner& M, const std::vector<double>& b,
                          std::vector<double>& x, const Blocks& blocks, int maxIterations,
                          const std::function<bool(const Residual&)>& stop);

} // namespace solver
} // namespace frostvdb
