#pragma once
/// @file LinearOperator.h
/// @brief The matrix-free operator interface every iterative solve of frostvdb goes through:
/// a square operator known by its action out = A in, and a preconditioner known by z = M^-1 r.
///
/// Users (issue 26, "one solver module"):
/// - solver::conjugateGradient (ConjugateGradient.h): the DLA first-passage tables, the dense
///   fluid's viscosity and pressure solves, the multigrid-preconditioned pressure solve;
/// - solver::bicgstab (EigenMatrixFree.h): Eigen's BiCGSTAB through its documented matrix-free
///   path, for the shell's implicit closest-point system (not symmetric).
/// Gauss-Seidel smoothers (the phase field's red-black sweeps, multigrid's smoother) stay beside
/// their stencils: they are not operator-level algorithms.
///
/// Determinism: an operator writes every out[i] from in alone, in any order, so its result does
/// not depend on the thread count; the solvers reduce in fixed blocks (Blocks) and sum the block
/// results serially.
#include <cstddef>
#include <vector>

namespace frostvdb {
namespace solver {

/// A square linear operator given by its action.
class LinearOperator {
public:
    virtual ~LinearOperator() = default;
    /// Number of unknowns (rows = columns).
    virtual size_t size() const = 0;
    /// out = A in; both hold size() entries (out is sized by the caller) and are distinct.
    virtual void apply(const std::vector<double>& in, std::vector<double>& out) const = 0;
};

/// A preconditioner given by its action z = M^-1 r.
class Preconditioner {
public:
    virtual ~Preconditioner() = default;
    virtual void apply(const std::vector<double>& r, std::vector<double>& z) const = 0;
};

/// No preconditioning: z = r.
class IdentityPreconditioner final : public Preconditioner {
public:
    void apply(const std::vector<double>& r, std::vector<double>& z) const override { z = r; }
};

/// Jacobi: z_i = r_i * inverse_i (inverse_i = 1 / A_ii, or 0 for an entry that is no unknown).
class JacobiPreconditioner final : public Preconditioner {
public:
    explicit JacobiPreconditioner(const std::vector<double>& inverseDiagonal) : mInverse(inverseDiagonal) {}
    void apply(const std::vector<double>& r, std::vector<double>& z) const override;
    const std::vector<double>& inverse() const { return mInverse; }

private:
    const std::vector<double>& mInverse;
};

/// Fixed reduction blocks over [0, n): block b is [b * size, min(n, (b + 1) * size)). Sums are
/// taken per block, then over the blocks in order, so they do not depend on the thread count.
/// A block of n entries (Blocks::serial) is a plain serial sum.
struct Blocks {
    size_t n = 0;
    size_t size = 4096;
    static Blocks serial(size_t n) { return {n, n > 0 ? n : 1}; }
    size_t count() const { return (n + size - 1) / size; }
    size_t begin(size_t b) const { return b * size; }
    size_t end(size_t b) const { return (b + 1) * size < n ? (b + 1) * size : n; }
};

} // namespace solver
} // namespace frostvdb
