#include <frostvdb/icephysics/SecondOrderRows.h>

#include <cmath>
#include <cstdlib>
#include <cstring>

#if defined(__x86_64__) || defined(__i386__)
#include <frostvdb/base/VectorLanes.h>
#define FROSTVDB_HAVE_AVX2_SO_ROWS 1
#endif

namespace frostvdb {

namespace {

// Plain rows: one cell at a time, the inline per-cell functions of Kobayashi.h.
__attribute__((noinline)) void epsSquaredRowPlain(const float* u, std::size_t i0, std::size_t i1, const FlatStencil& st,
                                                  const Anisotropy& an, float* a)
{
    for (std::size_t i = i0; i < i1; ++i) a[i] = float(kobayashiEpsSquared(u, i, st, an));
}

__attribute__((noinline)) void secondOrderRowPlain(const float* p, const float* T, const float* pe, const float* te,
                                                   const float* pf, const float* a, const float* melt,
                                                   const double* chi, std::size_t i0, std::size_t i1,
                                                   const FlatStencil& st, const KobayashiParams& k, double theta,
                                                   const SecondOrderRowsOut& out)
{
    for (std::size_t i = i0; i < i1; ++i) {
        const double Te = melt ? k.localMeltTemperature(melt[i]) : k.meltTemperature;
        const SecondOrderRow row =
            kobayashiSecondOrderRow(p, T, pe, te, pf, a, i, st, k, Te, chi ? chi[i] : 0.0, theta);
        out.diag[i] = row.diag;
        out.rhs[i] = row.rhs;
        out.predictor[i] = row.predictor;
        out.lapT[i] = row.lapT;
        for (int q = 0; q < st.n; ++q) out.coef[q][i] = row.coef[q];
    }
}

#ifdef FROSTVDB_HAVE_AVX2_SO_ROWS
// Vector rows of the hexagonal plane: kobayashiEpsSquared's D6 form and kobayashiSecondOrderRow
// (advectionDiffusionCoefficients, symmetricTapSum, kobayashiReactionPart twice) transcribed
// operation by operation onto 4 lanes of doubles, in the scalar code's association order.
// std::min(a, b) is min_pd(b, a), std::max(a, b) max_pd(b, a) (ties and NaN: the first
// argument); libmMax/libmMin are selects on their own conditions; branches are selects whose
// discarded lanes are never used; atan is libm's, per lane (computed once: both reaction parts
// take the same x). The target has no FMA, so nothing is contracted.
using namespace lanes; // FV_AVX2 and the lane operations (base/VectorLanes.h)

FV_AVX2 inline __m256d dvd(__m256d a, __m256d b) { return _mm256_div_pd(a, b); }
FV_AVX2 inline __m256d neg(__m256d a) { return _mm256_xor_pd(a, _mm256_set1_pd(-0.0)); }
FV_AVX2 inline __m256d vabs(__m256d a) { return _mm256_andnot_pd(_mm256_set1_pd(-0.0), a); }
FV_AVX2 inline __m256d sel(__m256d mask, __m256d ifTrue, __m256d ifFalse) { return _mm256_blendv_pd(ifFalse, ifTrue, mask); }
FV_AVX2 inline __m256d lt(__m256d a, __m256d b) { return _mm256_cmp_pd(a, b, _CMP_LT_OQ); }
FV_AVX2 inline __m256d gt(__m256d a, __m256d b) { return _mm256_cmp_pd(a, b, _CMP_GT_OQ); }
/// libmMax(a, b) = (a > b || b != b) ? a : b
FV_AVX2 inline __m256d libmMax4(__m256d a, __m256d b)
{
    return sel(_mm256_or_pd(gt(a, b), _mm256_cmp_pd(b, b, _CMP_UNORD_Q)), a, b);
}
/// libmMin(a, b) = (a < b || b != b) ? a : b
FV_AVX2 inline __m256d libmMin4(__m256d a, __m256d b)
{
    return sel(_mm256_or_pd(lt(a, b), _mm256_cmp_pd(b, b, _CMP_UNORD_Q)), a, b);
}
/// canonicalSum of 3 terms
FV_AVX2 inline __m256d sum3(__m256d v0, __m256d v1, __m256d v2)
{
    const __m256d a = vmin(v0, v1), b = vmax(v0, v1);
    const __m256d lo = vmin(a, v2), t = vmax(a, v2);
    return add(add(add(_mm256_setzero_pd(), lo), vmin(b, t)), vmax(b, t));
}

constexpr int kHexTaps = 6;

__attribute__((noinline)) FV_AVX2 void epsSquaredRowHexAvx2(const float* u, std::size_t i0, std::size_t i1,
                                                            const FlatStencil& st, const Anisotropy& an, float* a)
{
    std::ptrdiff_t off[kHexTaps];
    for (int q = 0; q < kHexTaps; ++q) off[q] = st.off[q];
    const __m256d h = splat(0.5), one = splat(1.0), c108 = splat(108.0), tiny = splat(1e-300);
    const __m256d gradScale = splat((2.0 / 3.0) * (st.wGrad[0] * st.wGrad[0])), sigma2 = splat(st.flatGradient2);
    const __m256d epsBar = splat(an.epsBar), delta = splat(an.delta), cj0 = splat(an.cj0);
    std::size_t i = i0;
    for (; i + 4 <= i1; i += 4) {
        __m256d D[3];
        for (int k = 0; k < 3; ++k) D[k] = sub(load4(u + i + off[2 * k]), load4(u + i + off[2 * k + 1]));
        const __m256d u0 = add(D[0], add(mul(h, D[1]), mul(h, D[2])));
        const __m256d u1 = add(D[1], sub(mul(h, D[0]), mul(h, D[2])));
        const __m256d u2 = add(D[2], sub(mul(h, D[0]), mul(h, D[1])));
        const __m256d q0 = mul(u0, u0), q1 = mul(u1, u1), q2 = mul(u2, u2);
        const __m256d x = vmin(q0, q1), y = vmax(q0, q1);
        const __m256d t = vmax(x, q2);
        const __m256d s0 = vmin(x, q2), s1 = vmin(y, t), s2 = vmax(y, t);
        const __m256d S = add(add(s0, s1), s2);
        const __m256d c6raw = sub(dvd(mul(c108, mul(mul(s0, s1), s2)), mul(mul(S, S), S)), one);
        __m256d c6 = sel(gt(S, tiny), c6raw, one);
        const __m256d g2 = mul(gradScale, S);
        const __m256d f = dvd(g2, add(g2, sigma2));
        c6 = mul(c6, mul(mul(f, f), f));
        const __m256d eps = mul(epsBar, add(one, mul(delta, mul(cj0, c6))));
        store4(a + i, mul(eps, eps));
    }
    for (; i < i1; ++i) a[i] = float(kobayashiEpsSquared(u, i, st, an));
}

/// kobayashiReactionPart on 4 lanes; @a atanX = atan(x) (the same libm value the scalar code takes).
struct Reaction4 {
    __m256d diag, rhs;
};

FV_AVX2 inline Reaction4 reaction4(__m256d p0, __m256d pm, __m256d pf, __m256d x, __m256d atanX, __m256d noiseChi,
                                   const KobayashiParams& k, double theta, __m256d explicitBudget)
{
    const __m256d zero = _mm256_setzero_pd(), one = splat(1.0), half = splat(0.5), two = splat(2.0);
    const __m256d r = splat(k.dt / k.tau);
    const __m256d m = mul(splat(k.alpha / M_PI), atanX);
    const __m256d g = add(add(sub(pm, half), m), noiseChi);
    const __m256d pq = mul(pm, sub(one, pm)); // pm (1 - pm)
    const __m256d n0 = mul(pq, g);
    __m256d s = add(mul(sub(one, mul(two, pm)), g), pq);
    {
        const __m256d neg_s = lt(s, zero);
        const __m256d zeroAt = sub(pm, dvd(n0, s));
        const __m256d above = _mm256_and_pd(neg_s, gt(zeroAt, one));
        const __m256d below = _mm256_andnot_pd(above, _mm256_and_pd(neg_s, lt(zeroAt, zero)));
        s = sel(above, mul(neg(pm), g), s);
        s = sel(below, mul(sub(one, pm), g), s);
    }
    const __m256d thetaV = splat(theta);
    const __m256d stiff = _mm256_and_pd(lt(s, zero), gt(mul(mul(splat(-(1.0 - theta)), r), s), explicitBudget));
    const __m256d thetaR = sel(stiff, add(one, dvd(libmMax4(zero, explicitBudget), mul(r, s))), thetaV);
    const __m256d dmdT = dvd(splat(-k.alpha / M_PI * k.gamma), add(one, mul(x, x)));
    const __m256d w = mul(mul(mul(pq, dmdT), thetaV), splat(k.latentHeat));
    const __m256d rw = mul(r, w);
    Reaction4 out;
    out.diag = sub(mul(mul(neg(thetaR), r), s), rw);
    out.rhs = sub(mul(r, add(sub(n0, mul(s, pm)), mul(mul(s, sub(one, thetaR)), p0))), mul(rw, pf));
    return out;
}

__attribute__((noinline)) FV_AVX2 void secondOrderRowHexAvx2(const float* p, const float* T, const float* pe,
                                                             const float* te, const float* pf, const float* a,
                                                             const float* melt, const double* chi, std::size_t i0,
                                                             std::size_t i1, const FlatStencil& st,
                                                             const KobayashiParams& k, double theta,
                                                             const SecondOrderRowsOut& out)
{
    std::ptrdiff_t off[kHexTaps];
    __m256d wG[kHexTaps], wL[kHexTaps];
    for (int q = 0; q < kHexTaps; ++q) {
        off[q] = st.off[q];
        wG[q] = splat(st.wGrad[q]);
        wL[q] = splat(st.wLap[q]);
    }
    // the other pairs' exact weights in advectionDiffusionCoefficients' order (l ascending, l != k)
    __m256d pd[3][2];
    int po[3][2];
    for (int kk = 0; kk < 3; ++kk) {
        int m = 0;
        for (int l = 0; l < 3; ++l)
            if (l != kk) {
                pd[kk][m] = splat(st.pairDot[kk][l]);
                po[kk][m] = l;
                ++m;
            }
    }
    const double r = k.dt / k.tau;
    const __m256d one = splat(1.0), zero = _mm256_setzero_pd(), rV = splat(r);
    const __m256d thetaR = splat(theta * r), explicitR = splat((1.0 - theta) * r);
    const __m256d farT = splat(k.farTemperature), meltSpan = splat(k.meltTemperature - k.farTemperature);
    const __m256d meltT = splat(k.meltTemperature), gamma = splat(k.gamma), noise = splat(k.noise);
    std::size_t i = i0;
    for (; i + 4 <= i1; i += 4) {
        // advectionDiffusionCoefficients
        __m256d A[3];
        for (int kk = 0; kk < 3; ++kk)
            A[kk] = mul(wG[2 * kk], sub(load4(a + i + off[2 * kk]), load4(a + i + off[2 * kk + 1])));
        __m256d ce[3];
        __m256d aEff = load4(a + i);
        for (int kk = 0; kk < 3; ++kk) {
            const __m256d rest = add(mul(pd[kk][0], A[po[kk][0]]), mul(pd[kk][1], A[po[kk][1]]));
            ce[kk] = add(A[kk], rest);
            aEff = libmMax4(aEff, dvd(mul(vabs(ce[kk]), wG[2 * kk]), wL[2 * kk]));
        }
        __m256d C[kHexTaps], pair[3];
        for (int kk = 0; kk < 3; ++kk) {
            C[2 * kk] = add(mul(aEff, wL[2 * kk]), mul(wG[2 * kk], ce[kk]));
            C[2 * kk + 1] = add(mul(aEff, wL[2 * kk + 1]), mul(wG[2 * kk + 1], neg(ce[kk])));
            pair[kk] = add(C[2 * kk], C[2 * kk + 1]);
        }
        const __m256d sumC = sum3(pair[0], pair[1], pair[2]);
        // symmetricTapSum of p with C, of T with the Laplacian weights
        const __m256d p0 = load4(p + i), t0 = load4(T + i);
        __m256d pp[3], pt[3];
        for (int kk = 0; kk < 3; ++kk) {
            pp[kk] = add(mul(C[2 * kk], sub(load4(p + i + off[2 * kk]), p0)),
                         mul(C[2 * kk + 1], sub(load4(p + i + off[2 * kk + 1]), p0)));
            pt[kk] = add(mul(wL[2 * kk], sub(load4(T + i + off[2 * kk]), t0)),
                         mul(wL[2 * kk + 1], sub(load4(T + i + off[2 * kk + 1]), t0)));
        }
        const __m256d Lp = sum3(pp[0], pp[1], pp[2]);
        const __m256d lapT = sum3(pt[0], pt[1], pt[2]);
        const __m256d Te = melt ? add(farT, mul(load4(melt + i), meltSpan)) : meltT;
        const __m256d x = mul(gamma, sub(Te, load4(te + i)));
        alignas(32) double xs[4];
        _mm256_store_pd(xs, x);
        for (double& v : xs) v = std::atan(v);
        const __m256d atanX = _mm256_load_pd(xs);
        const __m256d noiseChi = mul(noise, chi ? _mm256_loadu_pd(chi + i) : zero);
        const __m256d pm = load4(pe + i), pfv = load4(pf + i);
        for (int q = 0; q < kHexTaps; ++q) _mm256_storeu_pd(out.coef[q] + i, mul(thetaR, C[q]));
        const Reaction4 rp =
            reaction4(p0, pm, pfv, x, atanX, noiseChi, k, theta, sub(one, mul(explicitR, sumC)));
        _mm256_storeu_pd(out.diag + i, add(add(one, mul(thetaR, sumC)), rp.diag));
        _mm256_storeu_pd(out.rhs + i, add(add(p0, mul(explicitR, Lp)), rp.rhs));
        const Reaction4 ex = reaction4(p0, pm, pfv, x, atanX, noiseChi, k, 0.0, one);
        const __m256d guess = sub(add(add(p0, mul(rV, Lp)), ex.rhs), mul(ex.diag, p0));
        _mm256_storeu_pd(out.predictor + i, libmMin4(one, libmMax4(zero, guess)));
        _mm256_storeu_pd(out.lapT + i, lapT);
    }
    if (i < i1) secondOrderRowPlain(p, T, pe, te, pf, a, melt, chi, i, i1, st, k, theta, out);
}

#endif

} // namespace

SecondOrderRows plainSecondOrderRows() { return {&epsSquaredRowPlain, &secondOrderRowPlain, false}; }

SecondOrderRows fastestSecondOrderRows(const FlatStencil& st, const Anisotropy& an)
{
#ifdef FROSTVDB_HAVE_AVX2_SO_ROWS
    const char* v = std::getenv("FROSTVDB_NO_VECTOR_ROWS");
    const bool disabled = v && std::strcmp(v, "0") != 0 && *v;
    bool pairsCoupled = true; // every other pair enters c . e_k (the hexagonal lattice)
    for (int kk = 0; kk < 3; ++kk)
        for (int l = 0; l < 3; ++l)
            if (l != kk && st.pairDot[kk][l] == 0.0) pairsCoupled = false;
    if (!disabled && cpuHasAvx2() && st.hexagonal && st.n == kHexTaps && pairsCoupled && an.integerMode == 6 &&
        an.sj0 == 0.0)
        return {&epsSquaredRowHexAvx2, &secondOrderRowHexAvx2, true};
#else
    (void)st;
    (void)an;
#endif
    return plainSecondOrderRows();
}

} // namespace frostvdb
