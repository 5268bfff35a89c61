#pragma once
/// @file MultigridPoisson.h
/// @brief The pressure Poisson solve of a MAC-grid fluid, as a multigrid-preconditioned conjugate
/// gradient (McAdams, Sifakis & Teran 2010; the shared solver::conjugateGradient) over the active cells of a box, in 2D or 3D.
///
/// Layout (why): the unknowns are stored compactly, one entry per active (fluid) cell in
/// lexicographic order, so the vectors of CG and of every multigrid level cost memory only where
/// there is flow. Neighbours are found through a 32-bit index array over the padded bounding box
/// of each level (4 bytes per box cell against 8 bytes per unknown per vector, and no hashing or
/// tree walks in the inner loops); the box is the domain's, so this index never grows beyond the
/// domain. A VDB tree would give the same sparsity at the price of accessor look-ups in every
/// stencil; the index array keeps each stencil at six loads.
///
/// Operator: the standard 5/7-point Laplacian (unit spacing) with, per neighbour, a coupling to
/// another unknown, a Dirichlet cell (p = 0: outflow, free stream beyond the band) or a Neumann
/// cell (solid obstacle, inflow or closed wall: no coupling). Coarse levels re-discretise on the
/// coarsened cell types (a coarse cell is Dirichlet if any child is, else fluid if any child is,
/// else solid), transfers are cell-centred (bi/tri)linear prolongation and its scaled transpose,
/// smoothing is red-black Gauss-Seidel (red then black before, black then red after, so the
/// V-cycle is a symmetric preconditioner). Every sweep updates one colour at a time and every
/// reduction sums fixed blocks serially, so the result is bit-identical at any thread count.
#include <frostvdb/solver/ConjugateGradient.h>

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

namespace frostvdb {
namespace fluid {

/// What a cell of the box is to the pressure solve.
enum class CellKind : uint8_t { Fluid = 0, Solid = 1, Dirichlet = 2 };

struct PoissonSettings {
    double relativeTolerance = 1e-5; ///< stop when |r|_2 <= this * |b|_2 (0: unused)
    double absoluteTolerance = 0.0;  ///< or when max |r| <= this (0: unused)
    int maxIterations = 200;
    int smoothingSweeps = 2;         ///< red-black sweeps before and after each coarse correction
    bool multigrid = true;           ///< false: the same CG with a Jacobi preconditioner (reference)
};

struct PoissonStats {
    int iterations = 0;
    double relativeResidual = 0; ///< |r|_2 / |b|_2 at the end
    double maxResidual = 0;      ///< max |r| at the end
    bool converged = false;
    int levels = 0;
    size_t unknowns = 0;
};

class MultigridPoisson {
public:
    /// A box of dims cells (dims.z() == 1 and dim == 2 for a plane). @a kind gives each box cell's
    /// kind; @a sideDirichlet says, per side (-x, +x, -y, +y, -z, +z), whether the cells beyond
    /// the box are Dirichlet (outflow) or Neumann (wall, inflow).
    MultigridPoisson(int dim, const openvdb::Coord& dims, const std::function<CellKind(int, int, int)>& kind,
                     const std::array<bool, 6>& sideDirichlet);
    ~MultigridPoisson();

    size_t unknowns() const;
    int levels() const;
    /// Index of box cell (x, y, z) in the unknown vectors, or -1 if it is not fluid.
    int64_t unknownIndex(int x, int y, int z) const;
    /// Box cell of unknown @a k.
    openvdb::Coord cellOf(size_t k) const;
    /// Fast look-up of unknownIndex for cells within one cell of the box (x in -1..n): an inline
    /// read of the fine level's padded index (negative: not an unknown).
    struct IndexView {
        const int32_t* index;
        int64_t sx, sy, sz;
        int64_t at(int x, int y, int z) const { return index[(x + 1) * sx + (y + 1) * sy + (z + 1) * sz]; }
    };
    IndexView indexView() const;

    /// Solves A x = b (A: the positive semi-definite negative Laplacian, unit spacing). @a x holds
    /// the initial guess and receives the solution; both vectors have unknowns() entries.
    PoissonStats solve(const std::vector<double>& b, std::vector<double>& x, const PoissonSettings& settings) const;
    /// out = A in (for tests).
    void apply(const std::vector<double>& in, std::vector<double>& out) const;

    struct Level;

private:
    std::vector<std::unique_ptr<Level>> mLevels;
    int mDim;
    mutable solver::CgWorkspace mWork; ///< CG's vectors, kept across solves
};

} // namespace fluid
} // namespace frostvdb
