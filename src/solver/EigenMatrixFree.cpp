/// @file EigenMatrixFree.cpp
/// @brief Eigen's BiCGSTAB on a LinearOperator, by the MatrixReplacement pattern of Eigen's
/// documentation (see EigenMatrixFree.h).
#include <frostvdb/solver/EigenMatrixFree.h>

#include <Eigen/Core>
#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>

namespace frostvdb {
namespace solver {
class MatrixReplacement;
} // namespace solver
} // namespace frostvdb

// Eigen's documented matrix-free recipe: the replacement takes the traits of a sparse matrix...
namespace Eigen {
namespace internal {
template <>
struct traits<frostvdb::solver::MatrixReplacement> : public traits<Eigen::SparseMatrix<double>> {};
} // namespace internal
} // namespace Eigen

namespace frostvdb {
namespace solver {

/// A LinearOperator seen by Eigen as a (sparse-shaped) matrix; its products call apply().
class MatrixReplacement : public Eigen::EigenBase<MatrixReplacement> {
public:
    using Scalar = double;
    using RealScalar = double;
    using StorageIndex = int;
    enum { ColsAtCompileTime = Eigen::Dynamic, MaxColsAtCompileTime = Eigen::Dynamic, IsRowMajor = false };

    explicit MatrixReplacement(const LinearOperator& op) : mOp(&op), mIn(op.size()), mOut(op.size()) {}
    Eigen::Index rows() const { return Eigen::Index(mOp->size()); }
    Eigen::Index cols() const { return rows(); }

    template <typename Rhs>
    Eigen::Product<MatrixReplacement, Rhs, Eigen::AliasFreeProduct> operator*(const Eigen::MatrixBase<Rhs>& x) const
    {
        return Eigen::Product<MatrixReplacement, Rhs, Eigen::AliasFreeProduct>(*this, x.derived());
    }

    /// A x into the replacement's scratch (the operator's own vector type), returned by reference.
    template <typename Rhs>
    const std::vector<double>& product(const Rhs& x) const
    {
        for (Eigen::Index i = 0; i < x.size(); ++i) mIn[size_t(i)] = x.coeff(i);
        mOp->apply(mIn, mOut);
        return mOut;
    }

private:
    const LinearOperator* mOp;
    mutable std::vector<double> mIn, mOut;
};

/// The Jacobi preconditioner in the form Eigen's solvers take (compute, solve, info).
class InverseDiagonal {
public:
    InverseDiagonal() = default;
    template <typename M>
    explicit InverseDiagonal(const M&) {}
    void set(const std::vector<double>& inverse) { mInverse = Eigen::Map<const Eigen::VectorXd>(inverse.data(), Eigen::Index(inverse.size())); }
    template <typename M> InverseDiagonal& analyzePattern(const M&) { return *this; }
    template <typename M> InverseDiagonal& factorize(const M&) { return *this; }
    template <typename M> InverseDiagonal& compute(const M&) { return *this; }
    template <typename Rhs>
    Eigen::VectorXd solve(const Eigen::MatrixBase<Rhs>& b) const { return b.cwiseProduct(mInverse); }
    Eigen::ComputationInfo info() const { return Eigen::Success; }

private:
    Eigen::VectorXd mInverse;
};

} // namespace solver
} // namespace frostvdb

// ...and specialises its product with a dense vector. evalTo, addTo and subTo are given too, so
// that y = A x, y += A x and y = b - A x store the operator's values as they are (the generic
// path would first zero y and add alpha * A x).
namespace Eigen {
namespace internal {
template <typename Rhs>
struct generic_product_impl<frostvdb::solver::MatrixReplacement, Rhs, SparseShape, DenseShape, GemvProduct>
    : generic_product_impl_base<frostvdb::solver::MatrixReplacement, Rhs,
                                generic_product_impl<frostvdb::solver::MatrixReplacement, Rhs>> {
    using Lhs = frostvdb::solver::MatrixReplacement;
    using Scalar = typename Product<Lhs, Rhs>::Scalar;

    template <typename Dest>
    static void evalTo(Dest& dst, const Lhs& lhs, const Rhs& rhs)
    {
        const std::vector<double>& y = lhs.product(rhs);
        for (Index i = 0; i < dst.size(); ++i) dst.coeffRef(i) = y[size_t(i)];
    }
    template <typename Dest>
    static void addTo(Dest& dst, const Lhs& lhs, const Rhs& rhs)
    {
        const std::vector<double>& y = lhs.product(rhs);
        for (Index i = 0; i < dst.size(); ++i) dst.coeffRef(i) += y[size_t(i)];
    }
    template <typename Dest>
    static void subTo(Dest& dst, const Lhs& lhs, const Rhs& rhs)
    {
        const std::vector<double>& y = lhs.product(rhs);
        for (Index i = 0; i < dst.size(); ++i) dst.coeffRef(i) -= y[size_t(i)];
    }
    template <typename Dest>
    static void scaleAndAddTo(Dest& dst, const Lhs& lhs, const Rhs& rhs, const Scalar& alpha)
    {
        const std::vector<double>& y = lhs.product(rhs);
        for (Index i = 0; i < dst.size(); ++i) dst.coeffRef(i) += alpha * y[size_t(i)];
    }
};
} // namespace internal
} // namespace Eigen

namespace frostvdb {
namespace solver {

BiCgStabStats bicgstab(const LinearOperator& A, const std::vector<double>& inverseDiagonal,
                       const std::vector<double>& b, std::vector<double>& x, const BiCgStabSettings& settings)
{
    BiCgStabStats st;
    const Eigen::Index n = Eigen::Index(A.size());
    if (n == 0) {
        st.success = true;
        return st;
    }
    const MatrixReplacement M(A);
    Eigen::BiCGSTAB<MatrixReplacement, InverseDiagonal> solver;
    solver.compute(M);
    solver.preconditioner().set(inverseDiagonal);
    const Eigen::Map<const Eigen::VectorXd> bb(b.data(), n);
    double tolerance = settings.relativeTolerance;
    if (settings.absoluteTolerance > 0) {
        const double bn = bb.norm();
        tolerance = bn > 0 ? settings.absoluteTolerance / bn : settings.absoluteTolerance;
    }
    solver.setTolerance(tolerance);
    solver.setMaxIterations(settings.maxIterations);
    Eigen::VectorXd sol = Eigen::Map<const Eigen::VectorXd>(x.data(), n);
    sol = solver.solveWithGuess(bb, sol);
    for (Eigen::Index r = 0; r < n; ++r) x[size_t(r)] = sol[r];
    st.iterations = int(solver.iterations());
    st.estimatedError = solver.error();
    st.success = solver.info() == Eigen::Success;
    return st;
}

} // namespace solver
} // namespace frostvdb
