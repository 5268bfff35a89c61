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

/// Where the unknowns live: per-leaf slots of a topology, their colours and the neighbour-leaf
/// table. Built once per step and shared by the p and T systems.
class SlotLayout {
public:
    SlotLayout(openvdb::tree::LeafManager<openvdb::FloatTree>& topology, const Stencil& stencil, bool plane);

    size_t leafCount() const { return origins.size(); }
    size_t slotCount() const { return active.size(); }
    /// Slot of voxel @a c in leaf @a leaf (c must lie in the leaf).
    size_t slot(size_t leaf, const openvdb::Coord& c) const
    {
        const openvdb::Index off = openvdb::FloatTree::LeafNodeType::coordToOffset(c);
        return leaf * size_t(slots) + (plane ? (off >> 3) : off);
    }

    bool plane;
    int slots; ///< 64 per leaf on a plane, 512 in a box
    int colours = 2;
    std::vector<openvdb::Coord> origins;
    std::vector<uint8_t> active, colour;
    std::vector<int32_t> neighbourLeaf; ///< 27 per leaf, -1 where no leaf
    struct Tap {
        int dx, dy, dz;
        double w;
    };
    std::vector<Tap> taps;
};

class ImplicitSystem {
public:
    explicit ImplicitSystem(const SlotLayout& layout);

    size_t slot(size_t leaf, const openvdb::Coord& c) const { return mL.slot(leaf, c); }
    bool active(size_t s) const { return mL.active[s] != 0; }

    // Per-slot data, set by the caller for active slots.
    std::vector<double> x, diag, scale, rhs;
    double outside = 0; ///< value of every neighbour outside the topology

    SolveReport solve(LinearSolverKind kind, double tolerance, int maxIterations);

    /// max_i |rhs_i - (A x)_i| over the active slots.
    double residualMaxNorm() const;

private:
    double neighbourSum(size_t leaf, int lx, int ly, int lz) const;
    SolveReport gaussSeidel(double tolerance, int maxIterations);
    SolveReport bicgstab(double tolerance, int maxIterations);

    const SlotLayout& mL;
};

} // namespace frostvdb
