#include <frostvdb/icephysics/EulerRows.h>

#include <cmath>
#include <cstdlib>
#include <cstring>

#if defined(__x86_64__) || defined(__i386__)
#include <frostvdb/base/VectorLanes.h>
#define FROSTVDB_HAVE_AVX2_ROWS 1
#endif

namespace frostvdb {

namespace {

// Plain rows: one cell at a time, out of line (one copy of the machine code for every caller).
__attribute__((noinline)) void auxRowPlain(const float* p, std::size_t i0, std::size_t i1, const FlatStencil& st,
                                           const Anisotropy& an, float* a, float* cx, float* cy, float* gx,
                                           float* gy, float* gz)
{
    for (std::size_t i = i0; i < i1; ++i) kobayashiAux(p, i, st, an, a, cx, cy, gx, gy, gz);
}

__attribute__((noinline)) void eulerRowPlain(const float* p, const float* T, const float* a, const float* cx,
                                             const float* cy, const float* gx, const float* gy, const float* gz,
                                             std::size_t i0, std::size_t i1, const FlatStencil& st,
                                             const KobayashiParams& k, const float* melt, const double* chi,
                                             float* pOut, float* tOut, double* dpOut)
{
    for (std::size_t i = i0; i < i1; ++i) {
        const double Te = melt ? k.localMeltTemperature(melt[i]) : k.meltTemperature;
        const double dp = kobayashiEuler(p, T, a, cx, cy, gx, gy, gz, i, st, k, Te, chi ? chi[i] : 0.0, pOut[i],
                                         tOut[i]);
        if (dpOut) dpOut[i] = dp;
    }
}

__attribute__((noinline)) void heatRowPlain(const float* T, std::size_t i0, std::size_t i1, const FlatStencil& st,
                                            const KobayashiParams& k, float* tOut)
{
    for (std::size_t i = i0; i < i1; ++i) {
        float pOut;
        kobayashiEulerHeatOnly(T, i, st, k, pOut, tOut[i]);
    }
}

#ifdef FROSTVDB_HAVE_AVX2_ROWS
// Vector rows: kobayashiAux and kobayashiEuler of the 4-tap square plane (no d6 forms, integer
// anisotropy mode), transcribed operation by operation onto 4 lanes of doubles. What keeps the
// bits: every + - * / sqrt is the IEEE operation of the scalar code on the same operands in the
// same order (accumulators start at +0 as there; products keep their association, e.g.
// (eps eps') sx); std::min(a, b) is min_pd(b, a) and std::max(a, b) max_pd(b, a) (both return
// their first argument on ties and NaN, as min_pd/max_pd return their second); the branch on
// |g|^2 is a select whose discarded lane is the scalar code's (1, 0) (multiplying by 1 and adding
// +0 is exact, so w stays (1, +0)); atan is libm's, per lane; float <-> double conversions
// are exact one way and round to nearest the other, as the scalar casts. The target has no FMA,
// so nothing is contracted.
using namespace lanes; // FV_AVX2 and the lane operations (base/VectorLanes.h)


constexpr int kTaps = 4;

__attribute__((noinline)) FV_AVX2 void auxRowAvx2(const float* p, std::size_t i0, std::size_t i1,
                                                  const FlatStencil& st, const Anisotropy& an, float* a, float* cx,
                                                  float* cy, float* gx, float* gy, float* gz)
{
    __m256d wG[kTaps], ex[kTaps], ey[kTaps], ez[kTaps];
    std::ptrdiff_t off[kTaps];
    for (int q = 0; q < kTaps; ++q) {
        wG[q] = splat(st.wGrad[q]);
        ex[q] = splat(st.ex[q]);
        ey[q] = splat(st.ey[q]);
        ez[q] = splat(st.ez[q]);
        off[q] = st.off[q];
    }
    const __m256d zero = _mm256_setzero_pd(), one = splat(1.0), tiny = splat(1e-30);
    const __m256d cj0 = splat(an.cj0), sj0 = splat(an.sj0), epsBar = splat(an.epsBar), delta = splat(an.delta);
    const __m256d epsPrimeScale = splat(an.epsBar * an.delta * an.j); // (eps_bar delta) j, as the scalar code
    const int mode = an.integerMode;
    std::size_t i = i0;
    for (; i + 4 <= i1; i += 4) {
        const __m256d p0 = load4(p + i);
        __m256d sx = zero, sy = zero, sz = zero;
        for (int q = 0; q < kTaps; ++q) {
            const __m256d d = mul(wG[q], sub(load4(p + i + off[q]), p0));
            sx = add(sx, mul(d, ex[q]));
            sy = add(sy, mul(d, ey[q]));
            sz = add(sz, mul(d, ez[q]));
        }
        // Anisotropy, integer mode: w = (g / |g|)^j where |g|^2 > 1e-30, else w = 1.
        const __m256d r2 = add(mul(sx, sx), mul(sy, sy));
        const __m256d big = _mm256_cmp_pd(r2, tiny, _CMP_GT_OQ);
        const __m256d inv = _mm256_div_pd(one, _mm256_sqrt_pd(r2));
        const __m256d zr = _mm256_blendv_pd(one, mul(sx, inv), big);
        const __m256d zi = _mm256_blendv_pd(zero, mul(sy, inv), big);
        __m256d wr = one, wi = zero;
        for (int q = 0; q < mode; ++q) {
            const __m256d t = sub(mul(wr, zr), mul(wi, zi));
            wi = add(mul(wr, zi), mul(wi, zr));
            wr = t;
        }
        const __m256d c = add(mul(cj0, wr), mul(sj0, wi));
        const __m256d s = sub(mul(sj0, wr), mul(cj0, wi));
        const __m256d eps = mul(epsBar, add(one, mul(delta, c)));
        const __m256d epsPrime = mul(epsPrimeScale, s);
        const __m256d ee = mul(eps, epsPrime);
        store4(a + i, mul(eps, eps));
        store4(cx + i, mul(ee, sx));
        store4(cy + i, mul(ee, sy));
        store4(gx + i, sx);
        store4(gy + i, sy);
        store4(gz + i, sz);
    }
    for (; i < i1; ++i) kobayashiAux(p, i, st, an, a, cx, cy, gx, gy, gz);
}

__attribute__((noinline)) FV_AVX2 void eulerRowAvx2(const float* p, const float* T, const float* a,
                                                    const float* cx, const float* cy, const float* gx,
                                                    const float* gy, const float* gz, std::size_t i0,
                                                    std::size_t i1, const FlatStencil& st, const KobayashiParams& k,
                                                    const float* melt, const double* chi, float* pOut, float* tOut,
                                                    double* dpOut)
{
    __m256d wG[kTaps], wL[kTaps], ex[kTaps], nex[kTaps], ey[kTaps], ez[kTaps];
    std::ptrdiff_t off[kTaps];
    for (int q = 0; q < kTaps; ++q) {
        wG[q] = splat(st.wGrad[q]);
        wL[q] = splat(st.wLap[q]);
        ex[q] = splat(st.ex[q]);
        nex[q] = splat(-st.ex[q]);
        ey[q] = splat(st.ey[q]);
        ez[q] = splat(st.ez[q]);
        off[q] = st.off[q];
    }
    const __m256d zero = _mm256_setzero_pd(), one = splat(1.0), half = splat(0.5);
    const __m256d farT = splat(k.farTemperature), meltSpan = splat(k.meltTemperature - k.farTemperature);
    const __m256d meltT = splat(k.meltTemperature), gamma = splat(k.gamma), alphaPi = splat(k.alpha / M_PI);
    const __m256d noise = splat(k.noise), r = splat(k.dt / k.tau), dt = splat(k.dt), K = splat(k.latentHeat);
    std::size_t i = i0;
    for (; i + 4 <= i1; i += 4) {
        const __m256d p0 = load4(p + i), t0 = load4(T + i), a0 = load4(a + i);
        __m256d lo = p0, hi = p0, lapP = zero, lapT = zero;
        __m256d u[kTaps];
        for (int q = 0; q < kTaps; ++q) {
            u[q] = load4(p + i + off[q]);
            lo = vmin(lo, u[q]);
            hi = vmax(hi, u[q]);
        }
        for (int q = 0; q < kTaps; ++q) lapP = add(lapP, mul(wL[q], sub(u[q], p0)));
        for (int q = 0; q < kTaps; ++q) lapT = add(lapT, mul(wL[q], sub(load4(T + i + off[q]), t0)));
        const __m256d cx0 = load4(cx + i), cy0 = load4(cy + i);
        __m256d dax = zero, day = zero, daz = zero, cross = zero;
        for (int q = 0; q < kTaps; ++q) {
            const std::size_t j = i + std::size_t(off[q]);
            const __m256d da = mul(wG[q], sub(load4(a + j), a0));
            dax = add(dax, mul(da, ex[q]));
            day = add(day, mul(da, ey[q]));
            daz = add(daz, mul(da, ez[q]));
            cross = add(cross, mul(wG[q], add(mul(nex[q], sub(load4(cy + j), cy0)),
                                              mul(ey[q], sub(load4(cx + j), cx0)))));
        }
        const __m256d rest =
            add(add(add(mul(dax, load4(gx + i)), mul(day, load4(gy + i))), mul(daz, load4(gz + i))), cross);
        const __m256d Te = melt ? add(farT, mul(load4(melt + i), meltSpan)) : meltT;
        alignas(32) double x[4];
        _mm256_store_pd(x, mul(gamma, sub(Te, t0)));
        for (double& v : x) v = std::atan(v);
        const __m256d m = mul(alphaPi, _mm256_load_pd(x));
        const __m256d ch = chi ? _mm256_loadu_pd(chi + i) : zero;
        const __m256d reaction = mul(mul(p0, sub(one, p0)), add(add(sub(p0, half), m), mul(noise, ch)));
        const __m256d pMono = add(p0, mul(r, add(mul(a0, lapP), reaction)));
        const __m256d pNew = vmin(vmax(pMono, hi), vmax(vmin(pMono, lo), add(pMono, mul(r, rest))));
        const __m256d dp = sub(pNew, p0);
        store4(pOut + i, add(pNew, zero));
        store4(tOut + i, add(add(t0, mul(dt, lapT)), mul(K, dp)));
        if (dpOut) _mm256_storeu_pd(dpOut + i, dp);
    }
    if (i < i1) eulerRowPlain(p, T, a, cx, cy, gx, gy, gz, i, i1, st, k, melt, chi, pOut, tOut, dpOut);
}

// Hexagonal plane, j = 6 (st.d6): kobayashiAux's and kobayashiEuler's D6 forms on 4 lanes.
// canonicalSum of 3 terms is the same min/max network; canonicalProduct3 sorts by magnitude,
// and any order by magnitude gives the scalar product's bits (ties differ only in sign, and the
// product's magnitude and sign do not depend on where a sign sits), so the lanes multiply the
// sorted magnitudes and put the xor of the signs back.
constexpr int kHexTaps = 6;

FV_AVX2 inline __m256d sum3(__m256d v0, __m256d v1, __m256d v2) // canonicalSum(v, 3)
{
    const __m256d a = vmin(v0, v1), b = vmax(v0, v1);
    const __m256d lo = vmin(a, v2), t = vmax(a, v2);
    return add(add(add(_mm256_setzero_pd(), lo), vmin(b, t)), vmax(b, t));
}

FV_AVX2 inline __m256d product3(__m256d a, __m256d b, __m256d c) // canonicalProduct3
{
    const __m256d signBit = splat(-0.0);
    const __m256d ma = _mm256_andnot_pd(signBit, a), mb = _mm256_andnot_pd(signBit, b), mc = _mm256_andnot_pd(signBit, c);
    const __m256d sign = _mm256_and_pd(_mm256_xor_pd(_mm256_xor_pd(a, b), c), signBit);
    const __m256d x = vmin(ma, mb), y = vmax(ma, mb);
    const __m256d m0 = vmin(x, mc), t = vmax(x, mc);
    const __m256d m1 = vmin(y, t), m2 = vmax(y, t);
    return _mm256_or_pd(mul(mul(m0, m1), m2), sign);
}

/// hexProjections on 4 lanes: U[k] from the pair differences of taps 2k, 2k+1.
FV_AVX2 inline void projections(const float* u, std::size_t i, const std::ptrdiff_t* off, __m256d U[3])
{
    __m256d D[3];
    for (int k = 0; k < 3; ++k) D[k] = sub(load4(u + i + off[2 * k]), load4(u + i + off[2 * k + 1]));
    const __m256d h = splat(0.5);
    U[0] = add(D[0], add(mul(h, D[1]), mul(h, D[2])));
    U[1] = add(D[1], sub(mul(h, D[0]), mul(h, D[2])));
    U[2] = add(D[2], sub(mul(h, D[0]), mul(h, D[1])));
}

/// symmetricTapSum with the Laplacian weights on 4 lanes.
FV_AVX2 inline __m256d hexLaplacian(const float* u, std::size_t i, const std::ptrdiff_t* off, const __m256d* wL,
                                    __m256d u0)
{
    __m256d pair[3];
    for (int k = 0; k < 3; ++k)
        pair[k] = add(mul(wL[2 * k], sub(load4(u + i + off[2 * k]), u0)), mul(wL[2 * k + 1], sub(load4(u + i + off[2 * k + 1]), u0)));
    return sum3(pair[0], pair[1], pair[2]);
}

__attribute__((noinline)) FV_AVX2 void auxRowHexAvx2(const float* p, std::size_t i0, std::size_t i1,
                                                     const FlatStencil& st, const Anisotropy& an, float* a, float* cx,
                                                     float* cy, float* gx, float* gy, float* gz)
{
    std::ptrdiff_t off[kHexTaps];
    for (int q = 0; q < kHexTaps; ++q) off[q] = st.off[q];
    const __m256d one = splat(1.0), zero = _mm256_setzero_pd(), signBit = splat(-0.0);
    const __m256d gate = splat((2.0 / 3.0) * (st.wGrad[0] * st.wGrad[0])), tiny = splat(1e-30);
    const __m256d c108 = splat(108.0), c12r3 = splat(12.0 * std::sqrt(3.0));
    const __m256d epsBar = splat(an.epsBar), delta = splat(an.delta), cj0 = splat(an.cj0);
    const __m256d primeScale = splat(an.epsBar * an.delta * 6.0);
    std::size_t i = i0;
    for (; i + 4 <= i1; i += 4) {
        __m256d U[3];
        projections(p, i, off, U);
        const __m256d S = sum3(mul(U[0], U[0]), mul(U[1], U[1]), mul(U[2], U[2])); // sorted, ascending
        const __m256d big = _mm256_cmp_pd(mul(gate, S), tiny, _CMP_GT_OQ);
        const __m256d inv = _mm256_div_pd(one, _mm256_sqrt_pd(S));
        const __m256d n0 = mul(U[0], inv), n1 = mul(U[1], inv), n2 = mul(U[2], inv);
        const __m256d P = product3(n0, n1, n2);
        const __m256d Q = product3(sub(n1, n2), add(n0, n2), add(n0, n1));
        const __m256d c6 = _mm256_blendv_pd(one, sub(mul(c108, mul(P, P)), one), big);
        const __m256d s6 = _mm256_blendv_pd(zero, mul(mul(c12r3, P), Q), big);
        const __m256d eps = mul(epsBar, add(one, mul(delta, mul(cj0, c6))));
        const __m256d epsPrime = mul(primeScale, _mm256_xor_pd(mul(cj0, s6), signBit));
        store4(a + i, mul(eps, eps));
        store4(cx + i, mul(eps, epsPrime));
    }
    for (; i < i1; ++i) kobayashiAux(p, i, st, an, a, cx, cy, gx, gy, gz);
}

__attribute__((noinline)) FV_AVX2 void eulerRowHexAvx2(const float* p, const float* T, const float* a,
                                                       const float* cx, const float* cy, const float* gx,
                                                       const float* gy, const float* gz, std::size_t i0,
                                                       std::size_t i1, const FlatStencil& st,
                                                       const KobayashiParams& k, const float* melt, const double* chi,
                                                       float* pOut, float* tOut, double* dpOut)
{
    __m256d wL[kHexTaps];
    std::ptrdiff_t off[kHexTaps];
    for (int q = 0; q < kHexTaps; ++q) {
        wL[q] = splat(st.wLap[q]);
        off[q] = st.off[q];
    }
    const double w2 = st.wGrad[0] * st.wGrad[0];
    const __m256d cDot = splat((2.0 / 3.0) * w2), cCross = splat((2.0 / (3.0 * std::sqrt(3.0))) * w2);
    const __m256d zero = _mm256_setzero_pd(), one = splat(1.0), half = splat(0.5);
    const __m256d farT = splat(k.farTemperature), meltSpan = splat(k.meltTemperature - k.farTemperature);
    const __m256d meltT = splat(k.meltTemperature), gamma = splat(k.gamma), alphaPi = splat(k.alpha / M_PI);
    const __m256d noise = splat(k.noise), r = splat(k.dt / k.tau), dt = splat(k.dt), K = splat(k.latentHeat);
    std::size_t i = i0;
    for (; i + 4 <= i1; i += 4) {
        const __m256d p0 = load4(p + i), t0 = load4(T + i), a0 = load4(a + i);
        __m256d lo = p0, hi = p0;
        for (int q = 0; q < kHexTaps; ++q) {
            const __m256d u = load4(p + i + off[q]);
            lo = vmin(lo, u);
            hi = vmax(hi, u);
        }
        const __m256d lapP = hexLaplacian(p, i, off, wL, p0), lapT = hexLaplacian(T, i, off, wL, t0);
        __m256d Up[3], Ua[3], Ub[3];
        projections(p, i, off, Up);
        projections(a, i, off, Ua);
        projections(cx, i, off, Ub);
        const __m256d dot = sum3(mul(Ua[0], Up[0]), mul(Ua[1], Up[1]), mul(Ua[2], Up[2]));
        const __m256d cross = sum3(sub(mul(Up[0], Ub[1]), mul(Up[1], Ub[0])), sub(mul(Up[2], Ub[0]), mul(Up[0], Ub[2])),
                                   sub(mul(Up[2], Ub[1]), mul(Up[1], Ub[2])));
        const __m256d rest = add(mul(cDot, dot), mul(cCross, cross));
        const __m256d Te = melt ? add(farT, mul(load4(melt + i), meltSpan)) : meltT;
        alignas(32) double x[4];
        _mm256_store_pd(x, mul(gamma, sub(Te, t0)));
        for (double& v : x) v = std::atan(v);
        const __m256d m = mul(alphaPi, _mm256_load_pd(x));
        const __m256d ch = chi ? _mm256_loadu_pd(chi + i) : zero;
        const __m256d reaction = mul(mul(p0, sub(one, p0)), add(add(sub(p0, half), m), mul(noise, ch)));
        const __m256d pMono = add(p0, mul(r, add(mul(a0, lapP), reaction)));
        const __m256d pNew = vmin(vmax(pMono, hi), vmax(vmin(pMono, lo), add(pMono, mul(r, rest))));
        const __m256d dp = sub(pNew, p0);
        store4(pOut + i, add(pNew, zero));
        store4(tOut + i, add(add(t0, mul(dt, lapT)), mul(K, dp)));
        if (dpOut) _mm256_storeu_pd(dpOut + i, dp);
    }
    if (i < i1) eulerRowPlain(p, T, a, cx, cy, gx, gy, gz, i, i1, st, k, melt, chi, pOut, tOut, dpOut);
}

/// The square plane's Laplacian of u at i .. i + 3, its taps summed in order (eulerRowAvx2's).
FV_AVX2 inline __m256d squareLaplacian(const float* u, std::size_t i, const std::ptrdiff_t* off, const __m256d* wL,
                                       __m256d u0)
{
    __m256d lap = _mm256_setzero_pd();
    for (int q = 0; q < kTaps; ++q) lap = add(lap, mul(wL[q], sub(load4(u + i + off[q]), u0)));
    return lap;
}

/// kobayashiEulerHeatOnly along a row: the Euler rows' T update with dp = 0, the Laplacian summed
/// by @a Laplacian in its lattice's order (the scalar code's), so square and hexagonal share it.
template <int Taps, __m256d (*Laplacian)(const float*, std::size_t, const std::ptrdiff_t*, const __m256d*, __m256d)>
FV_AVX2 inline void heatRowLanes(const float* T, std::size_t i0, std::size_t i1, const FlatStencil& st,
                                 const KobayashiParams& k, float* tOut)
{
    __m256d wL[Taps];
    std::ptrdiff_t off[Taps];
    for (int q = 0; q < Taps; ++q) {
        wL[q] = splat(st.wLap[q]);
        off[q] = st.off[q];
    }
    const __m256d dt = splat(k.dt), latentZero = mul(splat(k.latentHeat), _mm256_setzero_pd());
    std::size_t i = i0;
    for (; i + 4 <= i1; i += 4) {
        const __m256d t0 = load4(T + i);
        store4(tOut + i, add(add(t0, mul(dt, Laplacian(T, i, off, wL, t0))), latentZero));
    }
    if (i < i1) heatRowPlain(T, i, i1, st, k, tOut);
}

/// kobayashiEulerHeatOnly on the 4-tap square plane.
__attribute__((noinline)) FV_AVX2 void heatRowAvx2(const float* T, std::size_t i0, std::size_t i1,
                                                   const FlatStencil& st, const KobayashiParams& k, float* tOut)
{
    heatRowLanes<kTaps, squareLaplacian>(T, i0, i1, st, k, tOut);
}

/// kobayashiEulerHeatOnly on the hexagonal plane (any anisotropy: the heat step has none).
__attribute__((noinline)) FV_AVX2 void heatRowHexAvx2(const float* T, std::size_t i0, std::size_t i1,
                                                      const FlatStencil& st, const KobayashiParams& k, float* tOut)
{
    heatRowLanes<kHexTaps, hexLaplacian>(T, i0, i1, st, k, tOut);
}

#endif

} // namespace

EulerRows plainEulerRows() { return {&auxRowPlain, &eulerRowPlain, false, &heatRowPlain}; }

EulerRows fastestEulerRows(const FlatStencil& st, const Anisotropy& an)
{
#ifdef FROSTVDB_HAVE_AVX2_ROWS
    // read at every call (once per step), so a test can compare both builds in one process
    const char* v = std::getenv("FROSTVDB_NO_VECTOR_ROWS");
    const bool disabled = v && std::strcmp(v, "0") != 0 && *v;
    EulerRows rows = plainEulerRows();
    if (disabled || !cpuHasAvx2()) return rows;
    const bool square = st.n == kTaps && !st.hexagonal, hexagonal = st.n == kHexTaps && st.hexagonal;
    if (square) rows.heat = &heatRowAvx2;
    if (hexagonal) rows.heat = &heatRowHexAvx2;
    if (square && !st.d6 && an.integerMode >= 0) {
        rows.aux = &auxRowAvx2;
        rows.euler = &eulerRowAvx2;
        rows.vector = true;
    } else if (st.d6) {
        rows.aux = &auxRowHexAvx2;
        rows.euler = &eulerRowHexAvx2;
        rows.vector = true;
    }
    return rows;
#else
    (void)st;
    (void)an;
#endif
    return plainEulerRows();
}

} // namespace frostvdb
