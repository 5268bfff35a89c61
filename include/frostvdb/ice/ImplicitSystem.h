#pragma once
/// @file ImplicitSystem.h
/// @brief The sparse linear system of one Crank-Nicolson half of the second-order phase-field
/// scheme, on the active voxels of a VDB topology:
///
///   diag_i x_i - s_i * sum_q w_q x_{i+q} = rhs_i        (w_q: the lattice Laplacian's taps)
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
///    parallel and the result does not depend on the thread count;
///  - Eigen's BiCGSTAB (diagonal preconditioner) on the same rows, for comparison (the system is
///    not symmetric: s_i varies per row).
/// Both stop when the residual's max norm is at most the tolerance (GS measures the residual
/// of each equation as it updates it; BiCGSTAB's 2-norm criterion is set to imply it).
#include <frostvdb/core/Lattice.h>

#include <openvdb/openvdb.h>
#include <openvdb/tree/LeafManager.h>

#include <cstdint>
#include <vector>

namespace frostvdb {

enum class LinearSolverKind { GaussSeidel, BiCGSTAB };

struct SolveReport {
    int iterations = 0;
    double residual = 0; ///< max-norm of the residual at exit
    bool converged = false;
};

/// Where the unknowns live: the active voxels of a topology numbered as rows (leaf order, then
/// voxel order), each row's neighbour rows (the extra row n stands for every neighbour outside
/// the topology), and the rows of each colour. Built once per step, shared by the p and T
/// systems, so that a sweep is a plain indexed loop.
class SlotLayout {
public:
    SlotLayout(openvdb::tree::LeafManager<openvdb::FloatTree>& topology, const Stencil& stencil, bool plane);

    size_t rowCount() const { return rowCoord.size(); }
    /// Row of active voxel @a c of leaf @a leaf.
    int32_t row(size_t leaf, const openvdb::Coord& c) const
    {
        const openvdb::Index off = openvdb::FloatTree::LeafNodeType::coordToOffset(c);
        return slotRow[leaf * size_t(slots) + (plane ? (off >> 3) : off)];
    }

    bool plane;
    int slots; ///< 64 per leaf on a plane, 512 in a box
    int colours = 2;
    int taps = 0;
    std::vector<double> weights;          ///< Laplacian weight of each tap
    std::vector<int32_t> slotRow;         ///< per leaf slot: its row, or -1
    std::vector<openvdb::Coord> rowCoord; ///< per row
    std::vector<int32_t> neighbours;      ///< taps per row: neighbour row, or rowCount() outside
    std::vector<uint8_t> colour;          ///< per row
    std::vector<std::vector<int32_t>> rowsOfColour;
};

class ImplicitSystem {
public:
    explicit ImplicitSystem(const SlotLayout& layout);

    size_t rows() const { return mL.rowCount(); }

    /// Per-row data set by the caller; x has one extra entry, the outside value.
    std::vector<double> x, diag, scale, rhs;
    void setOutside(double v) { x[rows()] = v; }
    double outside() const { return x[rows()]; }

    SolveReport solve(LinearSolverKind kind, double tolerance, int maxIterations);

    /// max_i |rhs_i - (A x)_i| over the rows.
    double residualMaxNorm() const;

private:
    double neighbourSum(size_t r) const
    {
        const int32_t* nb = &mL.neighbours[r * mL.taps];
        double sum = 0;
        for (int q = 0; q < mL.taps; ++q) sum += mL.weights[q] * x[nb[q]];
        return sum;
    }
    SolveReport gaussSeidel(double tolerance, int maxIterations);
    SolveReport bicgstab(double tolerance, int maxIterations);

    const SlotLayout& mL;
};

} // namespace frostvdb
