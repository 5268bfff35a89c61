#pragma once
/// @file EigenMatrixFree.h
/// @brief Eigen's iterative solvers on a matrix-free LinearOperator, through Eigen's documented
/// matrix-free path ("Matrix-free solvers" in Eigen's sparse module documentation: a
/// `MatrixReplacement` deriving EigenBase, whose product with a vector is specialised), not
/// through Eigen's internal solver functions.
///
/// Only this header and EigenMatrixFree.cpp include Eigen's solver headers; callers use
/// solver::bicgstab.
#include <frostvdb/solver/LinearOperator.h>

#include <vector>

namespace frostvdb {
namespace solver {

struct BiCgStabSettings {
    double relativeTolerance = 1e-8; ///< Eigen's criterion: |b - A x|_2 <= this * |b|_2
    /// When > 0, replaces relativeTolerance by this / |b|_2 (this when b = 0): |b - A x|_2 <= this,
    /// which implies max |b - A x| <= this.
    double absoluteTolerance = 0;
    int maxIterations = 100;
};

struct BiCgStabStats {
    int iterations = 0;
    double estimatedError = 0; ///< Eigen's relative residual estimate at exit
    bool success = false;      ///< Eigen's info() == Success
};

/// Solves A x = b from the guess in @a x with Eigen's BiCGSTAB (Eigen::BiCGSTAB on the operator
/// wrapped as a MatrixReplacement), preconditioned by z_i = r_i * inverseDiagonal_i.
BiCgStabStats bicgstab(const LinearOperator& A, const std::vector<double>& inverseDiagonal,
                       const std::vector<double>& b, std::vector<double>& x, const BiCgStabSettings& settings);

} // namespace solver
} // namespace frostvdb
