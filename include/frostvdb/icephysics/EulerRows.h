#pragma once
/// @file EulerRows.h
/// @brief The row kernels of forward Euler (Kobayashi.h): pass 1 (kobayashiAux) and pass 2
/// (kobayashiEuler) over a run of cells [i0, i1) of one flat-array row, in two builds of the
/// same arithmetic:
///  - plain: one cell at a time, the inline per-cell functions (DensePhaseField, the dense
///    reference loop, runs these);
///  - vector: four cells at a time with AVX2 (the engine's plane blocks run these where the CPU
///    has AVX2 and the stencil is the square plane's). The same IEEE operations in the same
///    order per cell (no FMA, no reassociation, std::min/max's operand order, libm atan per
///    cell), so both builds give the same bits; the tests compare them bit for bit.
#include <frostvdb/icephysics/Kobayashi.h>

#include <cstddef>

namespace frostvdb {

/// Pass 1 over cells [i0, i1): a, cx, cy, gx, gy, gz at the same indices.
using AuxRowFn = void (*)(const float* p, std::size_t i0, std::size_t i1, const FlatStencil& st,
                          const Anisotropy& an, float* a, float* cx, float* cy, float* gx, float* gy, float* gz);
/// Pass 2 over cells [i0, i1): p', T' (and dp when @a dpOut is not null) at the same indices.
/// @a melt: the melt map at the same indices (null: T_e everywhere); @a chi: the noise draws at
/// the same indices (null: no noise).
using EulerRowFn = void (*)(const float* p, const float* T, const float* a, const float* cx, const float* cy,
                            const float* gx, const float* gy, const float* gz, std::size_t i0, std::size_t i1,
                            const FlatStencil& st, const KobayashiParams& k, const float* melt, const double* chi,
                            float* pOut, float* tOut, double* dpOut);

/// Pass 2 over cells [i0, i1) whose p is exactly 0 within two stencil steps (the heat halo):
/// T' at the same indices, kobayashiEulerHeatOnly's bits (p' is 0 there, dp 0).
using HeatRowFn = void (*)(const float* T, std::size_t i0, std::size_t i1, const FlatStencil& st,
                           const KobayashiParams& k, float* tOut);

struct EulerRows {
    AuxRowFn aux;
    EulerRowFn euler;
    bool vector; ///< the AVX2 build of aux and euler
    HeatRowFn heat; ///< AVX2 on the square and hexagonal planes wherever the CPU has it
};

/// The plain rows (one cell at a time).
EulerRows plainEulerRows();
/// The vector rows where they apply (CPU with AVX2; 4-tap square plane, integer anisotropy
/// mode), else the plain ones. FROSTVDB_NO_VECTOR_ROWS=1 in the environment forces the plain
/// rows (to measure what the vector build buys).
EulerRows fastestEulerRows(const FlatStencil& st, const Anisotropy& an);

} // namespace frostvdb
