#pragma once
/// @file SurfaceTapSums.h
/// @brief The surface-node Euler step's two passes over a node's stencil taps
/// (ShellPhaseField::stepSurface) and the update itself.
///  - pass 1 sums w (u_j - u_i) over node i's taps j for u = p and T, with each tap's three
///    weights (Laplace-Beltrami lap, tangent du, bitangent dv): p's derivatives give the
///    tangential gradient, so eps, eps' and C, and every sum of p and T the update reads is done
///    here, where the taps are loaded anyway;
///  - pass 2 sums du (C_j - C_i) and dv (C_j - C_i) over the four coefficients (eps^2 and C's
///    three components), which give grad eps^2 and div C;
///  - the update (without wind, fused with pass 2: the sums stay in lanes from the taps on).
/// The vector versions (AVX2) run one node at a time with a tap's weights or a coefficient's
/// components across the four lanes: no transposes per tap and no padding taps, where four nodes
/// across the lanes needed three 4 x 4 transposes and two gathers per tap and padded every node
/// to its group's largest count (docs/shells.md "The step"). They give the scalar functions'
/// bits: each lane does the scalar code's IEEE operations on the same operands in the same order
/// (no FMA in the target).
#include <frostvdb/icephysics/Kobayashi.h>
#include <frostvdb/shell/ShellBand.h>

#include <cstddef>

namespace frostvdb::shell {

/// Pass 1's coefficients of a node, read by its neighbours' pass 2 (one struct: a cache line
/// holds four nodes' where four arrays took four lines per tap).
struct SurfaceCoefficients {
    float a;          ///< eps^2
    float cx, cy, cz; ///< C = eps eps' (n x grad p), a world vector
};

/// Pass 1's sums of a node that pass 2's update reads (sum over taps j of w (u_j - u_i)).
struct FieldSums {
    double lapP = 0; ///< lap on p
    double lapT = 0; ///< lap on T
};

/// Pass 1's sums of T's tangential derivatives, which only the wind's advection reads (kept apart
/// so that a step without wind neither computes nor stores them).
struct WindSums {
    double dtu = 0; ///< du on T
    double dtv = 0; ///< dv on T
};

/// Pass 1 at node @a i: the taps' sums on p and T (each in the taps' order) into sums[i] (and
/// wind[i] unless @a wind is null); g = (dp/dt, dp/db) = (sum du dp, sum dv dp) / h, eps and eps'
/// of its angle, C = eps eps' (n x g) = eps eps' (g_u b - g_v t) as a world vector; writes c[i]
/// and g[i] = (gu, gv).
void surfaceCoefficients(const ShellBand& band, const float* p, const float* T, const Anisotropy& an, double invH,
                         std::size_t i, SurfaceCoefficients* c, float* gu, float* gv, FieldSums* sums,
                         WindSums* wind);
/// Nodes i .. i + 3, bit for bit surfaceCoefficients of each.
using SurfaceCoefficients4 = void (*)(const ShellBand& band, const float* p, const float* T, const Anisotropy& an,
                                      double invH, std::size_t i, SurfaceCoefficients* c, float* gu, float* gv,
                                      FieldSums* sums, WindSums* wind);
void surfaceCoefficients4Plain(const ShellBand& band, const float* p, const float* T, const Anisotropy& an,
                               double invH, std::size_t i, SurfaceCoefficients* c, float* gu, float* gv,
                               FieldSums* sums, WindSums* wind);
/// The AVX2 version for an integer anisotropy mode (as fastestTapSums4), else the plain one.
SurfaceCoefficients4 fastestSurfaceCoefficients4(const Anisotropy& an);
/// Nodes i .. i + 7 (the same type: a SurfaceCoefficients4 over eight nodes), bit for bit
/// surfaceCoefficients of each. The AVX2 version runs the two groups of four's anisotropy side by
/// side, so that their dependency chains overlap (a fifth of pass 1 in cache, bench shell passes).
void surfaceCoefficients8Plain(const ShellBand& band, const float* p, const float* T, const Anisotropy& an,
                               double invH, std::size_t i, SurfaceCoefficients* c, float* gu, float* gv,
                               FieldSums* sums, WindSums* wind);
SurfaceCoefficients4 fastestSurfaceCoefficients8(const Anisotropy& an);

/// Everything the update reads from the taps: pass 1's sums, and pass 2's grad eps^2 = (dau,
/// dav) and div C = t_i . SU + b_i . SV, where SU = sum du (C_j - C_i), SV = sum dv (C_j - C_i)
/// (node i's frame t, b; the surface divergence of a tangent field is the trace of its
/// derivative on the tangent plane).
struct TapSums {
    double lapP = 0, lapT = 0, dau = 0, dav = 0, divC = 0, dtu = 0, dtv = 0;
};

/// Node @a i's sums (the reference): pass 2's on @a C, and sums[i] and wind[i] from pass 1 (dtu
/// and dtv 0 where @a wind is null).
TapSums tapSums(const ShellBand& band, const SurfaceCoefficients* C, const FieldSums* sums, const WindSums* wind,
                std::size_t i);
/// Nodes i .. i + 3 (band indices), bit for bit tapSums of each.
using TapSums4 = void (*)(const ShellBand& band, const SurfaceCoefficients* C, const FieldSums* sums,
                          const WindSums* wind, std::size_t i, TapSums out[4]);
/// tapSums of each of the four, one after the other.
void tapSums4Plain(const ShellBand& band, const SurfaceCoefficients* C, const FieldSums* sums, const WindSums* wind,
                   std::size_t i, TapSums out[4]);
/// The AVX2 version when the CPU has it and FROSTVDB_NO_VECTOR_ROWS is not set (read at every
/// call, once per step, so a test compares both in one process), else tapSums4Plain.
TapSums4 fastestTapSums4();

/// What pass 2's update of a node reads besides its sums.
struct SurfaceUpdateInputs {
    const float* P = nullptr;
    const float* T = nullptr;
    const SurfaceCoefficients* C = nullptr;
    const float* gu = nullptr; ///< pass 1's tangential gradient
    const float* gv = nullptr;
    const float* melt = nullptr; ///< the melt map per node, or null (1 everywhere)
    const KobayashiParams* k = nullptr;
    double invH = 1, invH2 = 1;
};

/// Node @a i's Euler update (the plane's kobayashiEuler with the surface sums):
/// tau dp/dt = eps^2 lap p + grad eps^2 . g + div C + p (1 - p) (p - 1/2 + m(T) + a chi), m by
/// atanCephes; T' = T + dt lap T + K dp. @a chi is the node's noise draw (0 without noise).
/// @a windHeat, where a wind blows: its terms of dT/dt (advection and the upwind diffusion),
/// added to lap T / h^2; null without wind (nothing is added, so no zero changes its sign).
void surfaceUpdate(const SurfaceUpdateInputs& in, std::size_t i, const TapSums& s, double chi, float& pNew,
                   float& tNew, const double* windHeat = nullptr);
/// Pass 2 without wind for nodes i .. i + 3: their tapSums and surfaceUpdate, bit for bit (the
/// vector version keeps the sums in lanes from the taps to the update).
using SurfacePass2 = void (*)(const ShellBand& band, const SurfaceUpdateInputs& in, const FieldSums* sums,
                              std::size_t i, const double chi[4], float pNew[4], float tNew[4]);
void surfacePass2Plain(const ShellBand& band, const SurfaceUpdateInputs& in, const FieldSums* sums, std::size_t i,
                       const double chi[4], float pNew[4], float tNew[4]);
/// The AVX2 version (as fastestTapSums4), else the plain one.
SurfacePass2 fastestSurfacePass2();
/// Pass 2 for nodes i .. i + 7 (the same type over eight nodes: chi, pNew and tNew hold eight),
/// bit for bit surfacePass2Plain of each four; the AVX2 version runs the two groups' updates side
/// by side (as fastestSurfaceCoefficients8).
void surfacePass2x8Plain(const ShellBand& band, const SurfaceUpdateInputs& in, const FieldSums* sums, std::size_t i,
                         const double chi[8], float pNew[8], float tNew[8]);
SurfacePass2 fastestSurfacePass2x8();

/// The accumulated growth (positive dp) and the time p first exceeded 1/2, after a step.
inline void recordGrowth(float& growth, float& freeze, float dp, float p, float time)
{
    if (dp > 0.f) growth += dp;
    if (freeze == 0.f && p > 0.5f) freeze = time;
}

/// Stage 3: the update's new values (pn, tn) become the fields p and T; growth sums p's positive
/// changes and freeze takes @a time where it is 0 and p now exceeds 1/2, except on ghost nodes
/// (ghosts set and lateral > 1/2, ShellBand::ghost).
struct SurfaceCommit {
    float *p = nullptr, *t = nullptr, *growth = nullptr, *freeze = nullptr;
    const float *pn = nullptr, *tn = nullptr, *lateral = nullptr;
    bool ghosts = false;
    float time = 0;
};
/// Nodes [begin, end); returns whether p crossed 1/2 at any of them (the reference).
bool surfaceCommit(const SurfaceCommit& c, std::size_t begin, std::size_t end);
using SurfaceCommitRange = bool (*)(const SurfaceCommit& c, std::size_t begin, std::size_t end);
/// The AVX2 version, eight nodes at a time (as fastestTapSums4: the branchy loop was 5 % of the
/// pane's step), bit for bit surfaceCommit; else surfaceCommit.
SurfaceCommitRange fastestSurfaceCommit();

} // namespace frostvdb::shell
