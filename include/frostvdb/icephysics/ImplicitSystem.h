#pragma once
/// @file ImplicitSystem.h
/// @brief The sparse linear system of one Crank-Nicolson half of the second-order phase-field
/// scheme, on the active voxels of a VDB topology:
///
///   diag_i x_i - s_i * sum_q w_q x_{i+q} = rhs_i        (w_q: the lattice Laplacian's taps)
///
/// or, when per-row coefficients are given (the phase equation, whose rows also carry the
/// advection), diag_i x_i - sum_q C_iq x_{i+q} = rhs_i with C_iq >= 0 (an M-matrix when
/// diag_i >= sum_q C_iq, so every solver iterate started inside the data's bounds stays there).
///
/// Unknowns live in flat per-leaf slot arrays (64 slots per leaf on a plane, 512 in a box) in
/// the LeafManager's leaf order, so a solver touches neighbours by index arithmetic and one
/// 27-entry neighbour-leaf table per leaf, never through tree accessors. A neighbour outside
/// the topology holds the fixed value @c outside (the far field: Dirichlet).
///
/// Two solvers of the same system:
///  - multi-colour Gauss-Seidel: red-black on the square lattice (5-/7-point stencils are
///    bipartite), three colours (i + 2j + k) mod 3 on the hexagonal one (its triangles are not
///    two-colourable). Voxels of one colour only read the others, so a colour is updated in
///    parallel and the result does not depend on the thread count. On the hexagonal lattice a
///    sweep updates colour 0, then colours 1 and 2 together from the same values (Jacobi between
///    them): a 60-degree rotation or a mirror about a colour-0 cell swaps colours 1 and 2, so this
///    sweep, unlike 0-1-2, commutes with the lattice's symmetries and keeps D6-symmetric data
///    exactly symmetric at any tolerance;
///  - Eigen's BiCGSTAB (diagonal preconditioner) on the same rows, for comparison (the system is
///    not symmetric: s_i varies per row).
/// Both stop when the residual's max norm is at most the tolerance (GS measures the residual
/// of each equation as it updates it; BiCGSTAB's 2-norm criterion is set to imply it).
#include <frostvdb/core/Lattice.h>
#include <frostvdb/icephysics/Kobayashi.h> // canonicalSum

#include <openvdb/openvdb.h>
#include <openvdb/tree/LeafManager.h>

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

namespace frostvdb {

namespace plane {
class PlaneLeaves;
}

enum class LinearSolverKind { GaussSeidel, BiCGSTAB };

struct SolveReport {
    int iterations = 0;
    double residual = 0; ///< max-norm of the residual at exit
    bool converged = false;
};

/// Where the unknowns live: the active voxels of a topology numbered as rows (colour by colour,
/// each colour leaf by leaf in a given order, then voxel order), each row's neighbour rows (the
/// extra row n stands for every neighbour outside the topology). A colour's rows are one
/// contiguous range, so a sweep streams through the row data instead of striding over the other
/// colours' rows (rows of one colour only read the others', so the numbering changes no
/// Gauss-Seidel result). The phase field passes its kernel's leaf groups as the order: a group's
/// rows of a colour are then one run, written as a run by the group's assembly and swept with
/// their neighbours close by. Built once per region topology, shared by the p and T systems.
class SlotLayout {
public:
    /// @a recycle: last step's layout, whose arrays are taken over (the neighbour table is
    /// then not zero-filled and its pages not faulted in again; every entry is written).
    /// @a leafOrder: every leaf index once, the order rows are numbered in (null: leaf order).
    /// @a topology: anything with leafCount() and leaf(i) (origin, value mask, offset to coordinate);
    /// built for a float tree's LeafManager, a mask tree's (a region's plane leaves: no float
    /// topology copy needed) and a folded region's plane-leaf view (plane::PlaneLeaves in the
    /// plane tree's order: the leaves and leaf indices the kernels and the write-back walk).
    template <typename LeavesT>
    SlotLayout(const LeavesT& topology, const Stencil& stencil, bool plane, SlotLayout* recycle = nullptr,
               const std::vector<size_t>* leafOrder = nullptr);

    size_t rowCount() const { return rows; }
    /// Row of active voxel @a c of leaf @a leaf.
    int32_t row(size_t leaf, const openvdb::Coord& c) const
    {
        const openvdb::Index off = openvdb::FloatTree::LeafNodeType::coordToOffset(c);
        return slotRow[leaf * size_t(slots) + (plane ? (off >> 3) : off)];
    }
    /// Row of the active voxel at offset @a off of leaf @a leaf (no coordinate needed).
    int32_t rowAt(size_t leaf, openvdb::Index off) const
    {
        return slotRow[leaf * size_t(slots) + (plane ? (off >> 3) : off)];
    }

    bool plane;
    int slots; ///< 64 per leaf on a plane, 512 in a box
    int colours = 2;
    int taps = 0;
    std::vector<double> weights;          ///< Laplacian weight of each tap
    std::vector<int32_t> slotRow;         ///< per leaf slot: its row, or -1
    size_t rows = 0;                      ///< active voxels (no per-row coordinates or colours are
                                          ///< kept: rebuilt every step where walkers write p, and
                                          ///< nothing reads them)
    std::vector<int32_t> neighbours;      ///< taps per row: neighbour row, or rowCount() outside
    std::vector<size_t> colourStart;      ///< colour c owns rows [colourStart[c], colourStart[c+1])

private:
    /// Red-black on the square lattice, (i + 2j + k) mod 3 on the hexagonal one.
    uint8_t colourOf(const openvdb::Coord& c) const
    {
        return colours == 2 ? uint8_t((c.x() + c.y() + c.z()) & 1) : uint8_t(((c.x() + 2 * c.y() + c.z()) % 3 + 3) % 3);
    }
    template <typename LeafManagerT>
    void build(const LeafManagerT& topology, const Stencil& stencil, SlotLayout* recycle,
               const std::vector<size_t>* leafOrder);
    template <typename LeafManagerT>
    std::vector<size_t> numberRows(const LeafManagerT& topology, const std::vector<size_t>* leafOrder);
    template <typename LeafManagerT>
    void linkNeighbours(const LeafManagerT& topology, const Stencil& stencil);
};

class ImplicitSystem {
public:
    explicit ImplicitSystem(const SlotLayout& layout);
    /// Takes over @a recycle's arrays (last step's system of the same kind, same layout or not)
    /// and sizes them without filling: the caller then sets every row (x, diag or setUniform,
    /// rhs, coef; per-row coefficients stay in use when @a recycle had them).
    /// Saves allocating, zeroing and faulting in ~100 bytes per row every step.
    ImplicitSystem(const SlotLayout& layout, ImplicitSystem& recycle);

    size_t rows() const { return mL.rowCount(); }

    /// Per-row data set by the caller; x has one extra entry, the outside value.
    std::vector<double> x, diag, scale, rhs;
    /// Optional per-row tap coefficients C_iq (rows x taps, row-major); when empty the row's
    /// off-diagonal is scale_i * w_q. useCoefficients() sizes it.
    std::vector<double> coef;
    /// Sizes coef; scale is not read with per-row coefficients and is released.
    void useCoefficients()
    {
        if (mRecycled) coef.resize(rows() * size_t(mL.taps));
        else coef.assign(rows() * size_t(mL.taps), 0.0);
        std::vector<double>().swap(scale);
    }
    /// Every row has the same diag and scale (the temperature system): the sweeps read two
    /// constants instead of two arrays, which are released (a system recycled from this one
    /// stays uniform; call setUniform again for the new step's values).
    void setUniform(double diagValue, double scaleValue)
    {
        std::vector<double>().swap(diag);
        std::vector<double>().swap(scale);
        mUniform = true;
        mUniformDiag = diagValue;
        mUniformScale = scaleValue;
    }
    int taps() const { return mL.taps; }
    void setOutside(double v) { x[rows()] = v; }
    double outside() const { return x[rows()]; }

    SolveReport solve(LinearSolverKind kind, double tolerance, int maxIterations);

    /// max_i |rhs_i - (A x)_i| over the rows.
    double residualMaxNorm() const;

private:
    /// The off-diagonal part sum_q C_iq x_q of row r. Summed as opposite-tap pairs, the pair
    /// sums in a canonical (sorted) order, so that a cell and its mirror or rotated image (whose
    /// taps are the same values in another order) get bit-identical sums: the hexagonal D6 and
    /// square D4 symmetry of the solution is then exact.
    double rowDiag(size_t r) const { return mUniform ? mUniformDiag : diag[r]; }
    double rowScale(size_t r) const { return mUniform ? mUniformScale : scale[r]; }
    double offDiagonal(size_t r) const { return offDiagonal(r, coef.empty() ? rowScale(r) : 1.0); }
    double offDiagonal(size_t r, double rowScale) const
    {
        const int32_t* nb = &mL.neighbours[r * mL.taps];
        double pair[4];
        const int np = mL.taps / 2;
        if (coef.empty()) {
            for (int k = 0; k < np; ++k) pair[k] = mL.weights[2 * k] * x[nb[2 * k]] + mL.weights[2 * k + 1] * x[nb[2 * k + 1]];
            return rowScale * sortedSum(pair, np);
        }
        const double* c = &coef[r * mL.taps];
        for (int k = 0; k < np; ++k) pair[k] = c[2 * k] * x[nb[2 * k]] + c[2 * k + 1] * x[nb[2 * k + 1]];
        return sortedSum(pair, np);
    }
    /// canonicalSum: ascending order, branch-free for 2 and 3 terms (Kobayashi.h).
    static double sortedSum(double* v, int n) { return canonicalSum(v, n); }
    SolveReport gaussSeidel(double tolerance, int maxIterations);
    SolveReport bicgstab(double tolerance, int maxIterations);

    const SlotLayout& mL;
    /// Gauss-Seidel scratch for the hexagonal colours 1 and 2 (kept between steps with the
    /// other arrays: sized and zero-filled once, not every solve)
    std::vector<double> mNext;
    bool mUniform = false, mRecycled = false;
    double mUniformDiag = 1.0, mUniformScale = 0.0;
};

} // namespace frostvdb
