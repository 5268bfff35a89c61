#pragma once
/// @file ShellImplicit.h
/// @brief The band system of the implicit closest point method (Macdonald & Ruuth 2009), for the
/// shell's lw_cn scheme (ShellPhaseField).
///
/// Unknowns: the update-set voxels (d <= 3.5, every extension node lies there) of the stepped
/// leaves, the "rows". Each row's equation is a 7-point operator whose neighbour values are the
/// closest-point extension of the unknowns, with the centre taken as the unknown itself: their
/// stabilised form (section 2.4), for the Laplacian
///   M u = Delta_h E u - (6 / h^2)(I - E) u,   (M u)_i = (1/h^2) (sum_k (E u)_{nb_k(i)} - 6 u_i),
/// and for any operator sum_k C_k (u_k - u_i) with per-row coefficients the same split:
///   diag_i x_i - sum_k c_ik (E x)_{nb_k(i)} = rhs_i.
/// E (row q: the 64 tricubic weights at cp(q), ShellBand::stencilNodes/stencilWeights) is built
/// into the operator, so no explicit re-extension happens between the implicit solves. The
/// operator is applied matrix-free: one extension gather over the rows' face neighbours, then a
/// 6-term sum per row (about 70 multiply-adds per row; the assembled matrix has ~150 entries per
/// row, since the neighbours' stencils overlap). Eigen's BiCGSTAB (Jacobi-preconditioned with
/// the operator's true diagonal) solves it; every product and update is per row in a fixed order
/// and Eigen's reductions are serial, so the answer does not depend on the thread count.
///
/// Values of nodes that are not rows (update-set voxels of leaves not stepped, which hold the
/// background within the region's tolerance) are fixed: the caller moves them to the right-hand
/// side (extendAt's fixed part).
#include <frostvdb/icephysics/ImplicitSystem.h> // SolveReport
#include <frostvdb/shell/ShellBand.h>

#include <cstdint>
#include <vector>

namespace frostvdb::shell {

class BandRows {
public:
    /// Numbers the update-set voxels of @a leafSlots (in slot order, then voxel order) and lists
    /// the points where the extension is read (their face neighbours, in first-use order).
    void build(const ShellBand& band, const std::vector<uint32_t>& leafSlots);

    size_t rows() const { return mVoxel.size(); }
    /// Band index of row @a r.
    uint32_t voxel(size_t r) const { return mVoxel[r]; }
    /// Row of band voxel @a i, or -1.
    int32_t rowOf(size_t i) const { return i < mRowOf.size() ? mRowOf[i] : -1; }
    /// Extension point of row @a r's face neighbour k (band neighbour order: -x, +x, -y, +y, -z, +z).
    uint32_t point(size_t r, int k) const { return mNb[6 * r + size_t(k)]; }
    size_t points() const { return mPoint.size(); }
    uint32_t pointVoxel(size_t m) const { return mPoint[m]; }
    /// A point in a leaf that is not stepped: its value is fixed (read, not extended).
    bool pointFixed(size_t m) const { return mFixed[m] != 0; }
    /// Weight of row r's own voxel in the extension at its neighbour k (0 when not a node).
    double selfWeight(size_t r, int k) const { return mSelf[6 * r + size_t(k)]; }

    /// (E (u - background)) at every extension point, in double, into @a full (a fixed point: its
    /// own value), and into @a fixed the same with the rows' values taken as 0 (the fixed nodes'
    /// part, for the right-hand side).
    void extendAt(const ShellBand& band, const std::vector<float>& u, double background, std::vector<double>& full,
                  std::vector<double>& fixed) const;

private:
    std::vector<uint32_t> mVoxel, mPoint, mNb;
    std::vector<int32_t> mRowOf;
    std::vector<double> mSelf;
    std::vector<char> mFixed; ///< per point
};

/// One system diag_r x_r - sum_k coef[6 r + k] (E x)_{point(r, k)} = rhs_r on the rows.
struct BandSystem {
    std::vector<double> diag, coef, rhs;
    void resize(size_t rows)
    {
        diag.resize(rows);
        coef.resize(6 * rows);
        rhs.resize(rows);
    }
    /// Solves to a max-norm residual <= @a tolerance (BiCGSTAB, at most @a maxIterations);
    /// @a x holds the first guess and gets the solution.
    SolveReport solve(const ShellBand& band, const BandRows& rows, std::vector<double>& x, double tolerance,
                      int maxIterations) const;
};

} // namespace frostvdb::shell
