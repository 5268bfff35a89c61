#pragma once
/// @file SecondOrderRows.h
/// @brief The row kernels of the second-order scheme (lw_cn, Kobayashi.h) over a run of cells
/// [i0, i1) of one flat-array row, in two builds of the same arithmetic (as EulerRows.h does for
/// forward Euler):
///  - plain: one cell at a time, kobayashiEpsSquared and kobayashiSecondOrderRow;
///  - vector: four cells at a time with AVX2, for the hexagonal plane (6 taps, its D6 form of
///    eps^2: j = 6, arms on lattice directions). The same IEEE operations in the same order per
///    cell (no FMA, no reassociation, canonicalSum's min/max network, libmMax/libmMin's operand
///    rules, libm atan per cell), so both builds give the same bits; the tests compare them.
#include <frostvdb/icephysics/Kobayashi.h>

#include <cstddef>

namespace frostvdb {

/// eps^2 of @a u at cells [i0, i1) into @a a (kobayashiEpsSquared).
using EpsSquaredRowFn = void (*)(const float* u, std::size_t i0, std::size_t i1, const FlatStencil& st,
                                 const Anisotropy& an, float* a);

/// Where a row of second-order rows goes: per cell i, diag[i], rhs[i], predictor[i], lapT[i] and
/// the tap coefficients coef[q][i] (kobayashiSecondOrderRow's fields).
struct SecondOrderRowsOut {
    double *diag, *rhs, *predictor, *lapT;
    double* coef[FlatStencil::kMaxTaps];
};

/// kobayashiSecondOrderRow at cells [i0, i1). @a melt: the melt map at the same indices (null:
/// T_e everywhere); @a chi: the noise draws at the same indices (null: none).
using SecondOrderRowFn = void (*)(const float* p, const float* T, const float* pe, const float* te, const float* pf,
                                  const float* a, const float* melt, const double* chi, std::size_t i0, std::size_t i1,
                                  const FlatStencil& st, const KobayashiParams& k, double theta,
                                  const SecondOrderRowsOut& out);

struct SecondOrderRows {
    EpsSquaredRowFn epsSquared;
    SecondOrderRowFn rows;
    bool vector; ///< the AVX2 build
};

/// The plain rows (one cell at a time).
SecondOrderRows plainSecondOrderRows();
/// The vector rows where they apply (CPU with AVX2; the hexagonal plane with j = 6, arms on
/// lattice directions), else the plain ones. FROSTVDB_NO_VECTOR_ROWS=1 forces the plain rows
/// (read at every call).
SecondOrderRows fastestSecondOrderRows(const FlatStencil& st, const Anisotropy& an);

} // namespace frostvdb
