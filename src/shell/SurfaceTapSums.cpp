#include <frostvdb/shell/SurfaceTapSums.h>

#include <frostvdb/base/Atan.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>

#if defined(__x86_64__) || defined(__i386__)
#include <frostvdb/base/VectorLanes.h>
#define FROSTVDB_HAVE_AVX2_TAPS 1
#endif

namespace frostvdb::shell {

void surfaceCoefficients(const ShellBand& b, const float* P, const float* T, const Anisotropy& an, double invH,
                         std::size_t i, SurfaceCoefficients* C, float* gx, float* gy, FieldSums* sums,
                         WindSums* wind)
{
    const VoxelFrame f = b.frame(i);
    // every sum of p and T in one pass over the taps (each in the taps' order)
    const double p0 = P[i], t0 = T[i];
    double lapP = 0, su = 0, sv = 0, lapT = 0, dtu = 0, dtv = 0;
    for (const SurfaceTap* t = b.tapsBegin(i); t != b.tapsEnd(i); ++t) {
        const double dp = double(P[t->node]) - p0, dT = double(T[t->node]) - t0;
        lapP += double(t->lap) * dp;
        su += double(t->du) * dp;
        sv += double(t->dv) * dp;
        lapT += double(t->lap) * dT;
        dtu += double(t->du) * dT;
        dtv += double(t->dv) * dT;
    }
    sums[i] = FieldSums{lapP, lapT};
    if (wind) wind[i] = WindSums{dtu, dtv};
    const double gu = su * invH, gv = sv * invH;
    double eps, epsPrime;
    an(gu, gv, eps, epsPrime);
    // n x (gu t + gv b) = gu b - gv t
    const openvdb::Vec3d c = (f.bitangent * gu - f.tangent * gv) * (eps * epsPrime);
    C[i] = SurfaceCoefficients{float(eps * eps), float(c.x()), float(c.y()), float(c.z())};
    gx[i] = float(gu);
    gy[i] = float(gv);
}

TapSums tapSums(const ShellBand& b, const SurfaceCoefficients* C, const FieldSums* sums, const WindSums* wind,
                std::size_t i)
{
    const VoxelFrame f = b.frame(i);
    const double a0 = C[i].a, x0 = C[i].cx, y0 = C[i].cy, z0 = C[i].cz;
    double dau = 0, sux = 0, suy = 0, suz = 0, dav = 0, svx = 0, svy = 0, svz = 0;
    for (const SurfaceTap* t = b.tapsBegin(i); t != b.tapsEnd(i); ++t) {
        const SurfaceCoefficients& c = C[t->node];
        const double du = t->du, dv = t->dv;
        const double da = double(c.a) - a0, dx = double(c.cx) - x0, dy = double(c.cy) - y0, dz = double(c.cz) - z0;
        dau += du * da;
        sux += du * dx;
        suy += du * dy;
        suz += du * dz;
        dav += dv * da;
        svx += dv * dx;
        svy += dv * dy;
        svz += dv * dz;
    }
    // div C = t . SU + b . SV (each dot in Vec3d::dot's order)
    const double divC = openvdb::Vec3d(sux, suy, suz).dot(f.tangent) + openvdb::Vec3d(svx, svy, svz).dot(f.bitangent);
    const FieldSums& s = sums[i];
    const WindSums w = wind ? wind[i] : WindSums{};
    return TapSums{s.lapP, s.lapT, dau, dav, divC, w.dtu, w.dtv};
}

void surfaceUpdate(const SurfaceUpdateInputs& in, std::size_t i, const TapSums& s, double chi, float& pNew,
                   float& tNew, const double* windHeat)
{
    const KobayashiParams& k = *in.k;
    const double p0 = in.P[i], t0v = in.T[i], a0 = in.C[i].a;
    const double div = (a0 * s.lapP) * in.invH2 + (s.dau * in.gu[i] + s.dav * in.gv[i]) * in.invH + s.divC * in.invH;
    const double Te = k.localMeltTemperature(in.melt ? double(in.melt[i]) : 1.0);
    const double m = k.alpha / M_PI * atanCephes(k.gamma * (Te - t0v));
    const double reaction = p0 * (1.0 - p0) * (p0 - 0.5 + m + k.noise * chi);
    const double dp = k.dt / k.tau * (div + reaction);
    pNew = float(p0 + dp);
    const double heat = windHeat ? s.lapT * in.invH2 + *windHeat : s.lapT * in.invH2;
    tNew = float(t0v + k.dt * heat + k.latentHeat * dp);
}

void surfacePass2Plain(const ShellBand& b, const SurfaceUpdateInputs& in, const FieldSums* sums, std::size_t i,
                       const double chi[4], float pNew[4], float tNew[4])
{
    for (std::size_t n = 0; n < 4; ++n)
        surfaceUpdate(in, i + n, tapSums(b, in.C, sums, nullptr, i + n), chi[n], pNew[n], tNew[n]);
}

namespace {

#ifdef FROSTVDB_HAVE_AVX2_TAPS
using namespace lanes; // FV_AVX2 and the lane operations (base/VectorLanes.h)

/// x . v per lane in Vec3d::dot's order: (x0 v0 + x1 v1) + x2 v2.
FV_AVX2 inline __m256d dot(__m256d x0, __m256d x1, __m256d x2, const __m256d v[3])
{
    return add(add(mul(x0, v[0]), mul(x1, v[1])), mul(x2, v[2]));
}
/// One component of four frames' vectors, lane k from node k (the band's floats, widened
/// exactly as ShellBand::frame does).
FV_AVX2 inline __m256d lanes(const FrameFloats* const f[4], openvdb::Vec3s FrameFloats::*v, int axis)
{
    return _mm256_cvtps_pd(_mm_set_ps((f[3]->*v)[axis], (f[2]->*v)[axis], (f[1]->*v)[axis], (f[0]->*v)[axis]));
}

/// Four rows of four doubles transposed: r[k] lane q becomes r[q] lane k.
FV_AVX2 inline void transpose4(__m256d r[4])
{
    const __m256d t0 = _mm256_unpacklo_pd(r[0], r[1]), t1 = _mm256_unpackhi_pd(r[0], r[1]);
    const __m256d t2 = _mm256_unpacklo_pd(r[2], r[3]), t3 = _mm256_unpackhi_pd(r[2], r[3]);
    r[0] = _mm256_permute2f128_pd(t0, t2, 0x20);
    r[1] = _mm256_permute2f128_pd(t1, t3, 0x20);
    r[2] = _mm256_permute2f128_pd(t0, t2, 0x31);
    r[3] = _mm256_permute2f128_pd(t1, t3, 0x31);
}

/// A tap's weights as four doubles (0, lap, du, dv): its node index's bits are cleared first, so
/// no integer is ever converted as a float.
FV_AVX2 inline __m256d tapWeights(const SurfaceTap* t)
{
    return _mm256_cvtps_pd(_mm_blend_ps(_mm_loadu_ps(reinterpret_cast<const float*>(t)), _mm_setzero_ps(), 1));
}

/// Pass 1's sums of node i with the wind's: (0, lap p, du p, dv p) and (0, lap T, du T, dv T),
/// each lane the scalar code's sum in the taps' order.
FV_AVX2 inline void fieldSums(const ShellBand& b, const float* P, const float* T, std::size_t i, __m256d& onP,
                              __m256d& onT)
{
    const __m256d p0 = splat(double(P[i])), t0 = splat(double(T[i]));
    __m256d sp = _mm256_setzero_pd(), st = sp;
    for (const SurfaceTap* t = b.tapsBegin(i); t != b.tapsEnd(i); ++t) {
        const __m256d w = tapWeights(t);
        const std::size_t j = std::size_t(t->node);
        sp = add(sp, mul(w, sub(splat(double(P[j])), p0)));
        st = add(st, mul(w, sub(splat(double(T[j])), t0)));
    }
    onP = sp;
    onT = st;
}

/// Pass 1's sums of node i without the wind's, in one vector: (lap T, lap p, du p, dv p). A tap's
/// weights as (lap, lap, du, dv) times the differences (T_j - T_i, p_j - p_i, p_j - p_i, p_j - p_i):
/// each lane the scalar code's products and sum, in the taps' order, at half fieldSums' work.
/// (T_j, p_j, p_j, p_j), widened exactly.
FV_AVX2 inline __m256d tpppAt(const float* P, const float* T, std::size_t j)
{
    return _mm256_cvtps_pd(_mm_blend_ps(_mm_broadcast_ss(P + j), _mm_load_ss(T + j), 1));
}

FV_AVX2 inline __m256d fieldSumsNoWind(const ShellBand& b, const float* P, const float* T, std::size_t i)
{
    const __m256d base = tpppAt(P, T, i);
    __m256d s = _mm256_setzero_pd();
    for (const SurfaceTap* t = b.tapsBegin(i); t != b.tapsEnd(i); ++t) {
        const __m128 raw = _mm_loadu_ps(reinterpret_cast<const float*>(t)); // (node bits, lap, du, dv)
        const __m256d w = _mm256_cvtps_pd(_mm_shuffle_ps(raw, raw, _MM_SHUFFLE(3, 2, 1, 1)));
        s = add(s, mul(w, sub(tpppAt(P, T, std::size_t(t->node)), base)));
    }
    return s;
}

/// Pass 2's sums of four nodes' coefficients: grad eps^2 = (dau, dav) and div C, per lane.
struct CoefficientLanes {
    __m256d dau, dav, divC;
};

FV_AVX2 inline CoefficientLanes coefficientSums4(const ShellBand& b, const SurfaceCoefficients* C, std::size_t i)
{
    static_assert(sizeof(SurfaceTap) == 16 && sizeof(SurfaceCoefficients) == 16, "four floats each");
    // per node: the taps' differences (da, dx, dy, dz) times du and times dv, in the taps' order
    __m256d onU[4], onV[4];
    for (std::size_t k = 0; k < 4; ++k) {
        const __m256d c0 = load4(&C[i + k].a);
        __m256d su = _mm256_setzero_pd(), sv = su;
        for (const SurfaceTap* t = b.tapsBegin(i + k); t != b.tapsEnd(i + k); ++t) {
            // the tap's weights widened once, du and dv spread across the lanes from there (two
            // broadcasts each widened cost a fifth more of this loop, measured)
            const __m256d w = tapWeights(t), d = sub(load4(&C[t->node].a), c0);
            su = add(su, mul(_mm256_permute4x64_pd(w, 0xAA), d));
            sv = add(sv, mul(_mm256_permute4x64_pd(w, 0xFF), d));
        }
        onU[k] = su;
        onV[k] = sv;
    }
    transpose4(onU); // dau, SU's x, y, z across the four nodes
    transpose4(onV); // dav, SV's x, y, z
    const FrameFloats* f[4] = {&b.frameFloats(i), &b.frameFloats(i + 1), &b.frameFloats(i + 2), &b.frameFloats(i + 3)};
    const __m256d t[3] = {lanes(f, &FrameFloats::tangent, 0), lanes(f, &FrameFloats::tangent, 1),
                          lanes(f, &FrameFloats::tangent, 2)};
    const __m256d bt[3] = {lanes(f, &FrameFloats::bitangent, 0), lanes(f, &FrameFloats::bitangent, 1),
                           lanes(f, &FrameFloats::bitangent, 2)};
    return {onU[0], onV[0], add(dot(onU[1], onU[2], onU[3], t), dot(onV[1], onV[2], onV[3], bt))};
}

FV_AVX2 void tapSums4Avx2(const ShellBand& b, const SurfaceCoefficients* C, const FieldSums* sums,
                          const WindSums* wind, std::size_t i, TapSums out[4])
{
    const CoefficientLanes c = coefficientSums4(b, C, i);
    alignas(32) double v[3][4];
    _mm256_store_pd(v[0], c.dau);
    _mm256_store_pd(v[1], c.dav);
    _mm256_store_pd(v[2], c.divC);
    for (std::size_t k = 0; k < 4; ++k) {
        const FieldSums& s = sums[i + k];
        const WindSums w = wind ? wind[i + k] : WindSums{};
        out[k] = TapSums{s.lapP, s.lapT, v[0][k], v[1][k], v[2][k], w.dtu, w.dtv};
    }
}

/// Pass 1's sums of nodes i .. i + 3 (into sums, and wind unless null) and their tangential
/// gradient (gu, gv) across the lanes.
FV_AVX2 inline void gradient4(const ShellBand& b, const float* P, const float* T, double invH, std::size_t i,
                              FieldSums* sums, WindSums* wind, __m256d& gu, __m256d& gv)
{
    static_assert(sizeof(FieldSums) == 16 && sizeof(WindSums) == 16, "two doubles each");
    __m256d onP[4]; // (lap T or 0, lap p, du p, dv p) per node
    for (std::size_t k = 0; k < 4; ++k) {
        if (!wind) {
            onP[k] = fieldSumsNoWind(b, P, T, i + k);
            // (lap p, lap T): lanes 1 and 0 swapped
            _mm_storeu_pd(&sums[i + k].lapP, _mm_permute_pd(_mm256_castpd256_pd128(onP[k]), 0x1));
            continue;
        }
        __m256d onT;
        fieldSums(b, P, T, i + k, onP[k], onT);
        _mm_storeu_pd(&sums[i + k].lapP, _mm_unpackhi_pd(_mm256_castpd256_pd128(onP[k]), _mm256_castpd256_pd128(onT)));
        _mm_storeu_pd(&wind[i + k].dtu, _mm256_extractf128_pd(onT, 1));
    }
    transpose4(onP); // du p and dv p across the four nodes in onP[2] and onP[3]
    const __m256d h = _mm256_set1_pd(invH);
    gu = mul(onP[2], h);
    gv = mul(onP[3], h);
}

/// eps^2 and C of G groups of four nodes (i, i + 4, ...) from their gradients, each operation
/// done for every group before the next, so that the groups' dependency chains (the square root,
/// the division, the power loop) overlap: pass 1 in cache (bench shell passes 16) went from
/// about 25 to 20 ns a node.
template <int G>
FV_AVX2 inline void coefficientsOf(const ShellBand& b, const Anisotropy& an, std::size_t i, const __m256d (&gu)[G],
                                   const __m256d (&gv)[G], SurfaceCoefficients* C, float* gx, float* gy)
{
    // Anisotropy, integer mode (the plane's vector rows, EulerRows.cpp): w = (g / |g|)^j where
    // |g|^2 > 1e-30, else w = 1 (a select whose discarded lane multiplies by 1 and adds +0)
    const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0);
    __m256d zr[G], zi[G], wr[G], wi[G];
    for (int g = 0; g < G; ++g) {
        const __m256d r2 = add(mul(gu[g], gu[g]), mul(gv[g], gv[g]));
        const __m256d big = _mm256_cmp_pd(r2, _mm256_set1_pd(1e-30), _CMP_GT_OQ);
        const __m256d inv = _mm256_div_pd(one, _mm256_sqrt_pd(r2));
        zr[g] = _mm256_blendv_pd(one, mul(gu[g], inv), big);
        zi[g] = _mm256_blendv_pd(zero, mul(gv[g], inv), big);
        wr[g] = one;
        wi[g] = zero;
    }
    for (int q = 0; q < an.integerMode; ++q)
        for (int g = 0; g < G; ++g) {
            const __m256d t = sub(mul(wr[g], zr[g]), mul(wi[g], zi[g]));
            wi[g] = add(mul(wr[g], zi[g]), mul(wi[g], zr[g]));
            wr[g] = t;
        }
    const __m256d cj0 = _mm256_set1_pd(an.cj0), sj0 = _mm256_set1_pd(an.sj0);
    for (int g = 0; g < G; ++g) {
        const std::size_t n = i + 4 * std::size_t(g);
        const __m256d c = add(mul(cj0, wr[g]), mul(sj0, wi[g])), s = sub(mul(sj0, wr[g]), mul(cj0, wi[g]));
        const __m256d eps = mul(_mm256_set1_pd(an.epsBar), add(one, mul(_mm256_set1_pd(an.delta), c)));
        const __m256d epsPrime = mul(_mm256_set1_pd(an.epsBar * an.delta * an.j), s); // ((eps_bar delta) j) s
        const __m256d ee = mul(eps, epsPrime);
        const FrameFloats* f[4] = {&b.frameFloats(n), &b.frameFloats(n + 1), &b.frameFloats(n + 2),
                                   &b.frameFloats(n + 3)};
        __m128 out[4] = {_mm256_cvtpd_ps(mul(eps, eps)), {}, {}, {}};
        for (int axis = 0; axis < 3; ++axis) // (b gu - t gv) (eps eps'), per component
            out[1 + axis] = _mm256_cvtpd_ps(mul(sub(mul(lanes(f, &FrameFloats::bitangent, axis), gu[g]),
                                                    mul(lanes(f, &FrameFloats::tangent, axis), gv[g])),
                                                ee));
        _MM_TRANSPOSE4_PS(out[0], out[1], out[2], out[3]); // a, cx, cy, cz per node
        for (int k = 0; k < 4; ++k) _mm_storeu_ps(&C[n + std::size_t(k)].a, out[k]);
        _mm_storeu_ps(gx + n, _mm256_cvtpd_ps(gu[g]));
        _mm_storeu_ps(gy + n, _mm256_cvtpd_ps(gv[g]));
    }
}

FV_AVX2 void surfaceCoefficients4Avx2(const ShellBand& b, const float* P, const float* T, const Anisotropy& an,
                                      double invH, std::size_t i, SurfaceCoefficients* C, float* gx, float* gy,
                                      FieldSums* sums, WindSums* wind)
{
    __m256d gu[1], gv[1];
    gradient4(b, P, T, invH, i, sums, wind, gu[0], gv[0]);
    coefficientsOf<1>(b, an, i, gu, gv, C, gx, gy);
}

FV_AVX2 void surfaceCoefficients8Avx2(const ShellBand& b, const float* P, const float* T, const Anisotropy& an,
                                      double invH, std::size_t i, SurfaceCoefficients* C, float* gx, float* gy,
                                      FieldSums* sums, WindSums* wind)
{
    __m256d gu[2], gv[2];
    gradient4(b, P, T, invH, i, sums, wind, gu[0], gv[0]);
    gradient4(b, P, T, invH, i + 4, sums, wind, gu[1], gv[1]);
    coefficientsOf<2>(b, an, i, gu, gv, C, gx, gy);
}

/// surfaceUpdate's operations, in its order, on G groups of four lanes of sums (nodes i, i + 4,
/// ...), each operation for every group before the next (as coefficientsOf: atan's divisions
/// and polynomials overlap).
template <int G>
FV_AVX2 void surfaceUpdateLanes(const SurfaceUpdateInputs& in, std::size_t i, const __m256d (&lapP)[G],
                                const __m256d (&lapT)[G], const CoefficientLanes (&cs)[G], const double* chi,
                                float* pNew, float* tNew)
{
    const KobayashiParams& k = *in.k;
    const __m256d invH = splat(in.invH), invH2 = splat(in.invH2);
    __m256d p0[G], t0[G], div[G], x[G];
    for (int g = 0; g < G; ++g) {
        const std::size_t n = i + 4 * std::size_t(g);
        p0[g] = load4(in.P + n);
        t0[g] = load4(in.T + n);
        const __m256d a0 = _mm256_set_pd(in.C[n + 3].a, in.C[n + 2].a, in.C[n + 1].a, in.C[n].a);
        div[g] = add(add(mul(mul(a0, lapP[g]), invH2),
                         mul(add(mul(cs[g].dau, load4(in.gu + n)), mul(cs[g].dav, load4(in.gv + n))), invH)),
                     mul(cs[g].divC, invH));
        const __m256d melt = in.melt ? load4(in.melt + n) : splat(1.0);
        const __m256d Te = add(splat(k.farTemperature), mul(melt, splat(k.meltTemperature - k.farTemperature)));
        x[g] = mul(splat(k.gamma), sub(Te, t0[g]));
    }
    __m256d atanX[G];
    for (int g = 0; g < G; ++g) atanX[g] = atanCephes4(x[g]);
    const __m256d one = splat(1.0);
    for (int g = 0; g < G; ++g) {
        const __m256d m = mul(splat(k.alpha / M_PI), atanX[g]);
        const __m256d reaction = mul(mul(p0[g], sub(one, p0[g])),
                                     add(add(sub(p0[g], splat(0.5)), m), mul(splat(k.noise), _mm256_loadu_pd(chi + 4 * g))));
        const __m256d dp = mul(splat(k.dt / k.tau), add(div[g], reaction));
        store4(pNew + 4 * g, add(p0[g], dp));
        store4(tNew + 4 * g, add(add(t0[g], mul(splat(k.dt), mul(lapT[g], invH2))), mul(splat(k.latentHeat), dp)));
    }
}

/// The four nodes' (lap p, lap T) pairs, (p0, T0, p1, T1) and (p2, T2, p3, T3), into lanes.
FV_AVX2 inline void laplacians4(const FieldSums* sums, std::size_t i, __m256d& lapP, __m256d& lapT)
{
    const __m256d s01 = _mm256_loadu_pd(&sums[i].lapP), s23 = _mm256_loadu_pd(&sums[i + 2].lapP);
    lapP = _mm256_permute4x64_pd(_mm256_unpacklo_pd(s01, s23), 0xD8); // (0, 2, 1, 3) -> in order
    lapT = _mm256_permute4x64_pd(_mm256_unpackhi_pd(s01, s23), 0xD8);
}

FV_AVX2 void surfacePass2Avx2(const ShellBand& b, const SurfaceUpdateInputs& in, const FieldSums* sums,
                              std::size_t i, const double chi[4], float pNew[4], float tNew[4])
{
    __m256d lapP[1], lapT[1];
    laplacians4(sums, i, lapP[0], lapT[0]);
    const CoefficientLanes cs[1] = {coefficientSums4(b, in.C, i)};
    surfaceUpdateLanes<1>(in, i, lapP, lapT, cs, chi, pNew, tNew);
}

FV_AVX2 void surfacePass2x8Avx2(const ShellBand& b, const SurfaceUpdateInputs& in, const FieldSums* sums,
                                std::size_t i, const double chi[8], float pNew[8], float tNew[8])
{
    __m256d lapP[2], lapT[2];
    laplacians4(sums, i, lapP[0], lapT[0]);
    laplacians4(sums, i + 4, lapP[1], lapT[1]);
    const CoefficientLanes cs[2] = {coefficientSums4(b, in.C, i), coefficientSums4(b, in.C, i + 4)};
    surfaceUpdateLanes<2>(in, i, lapP, lapT, cs, chi, pNew, tNew);
}

FV_AVX2 bool surfaceCommitAvx2(const SurfaceCommit& c, std::size_t begin, std::size_t end)
{
    // surfaceCommit's comparisons and its one addition in eight lanes, its branches as selects
    const __m256 half = _mm256_set1_ps(0.5f), zero = _mm256_setzero_ps(), time = _mm256_set1_ps(c.time);
    const __m256 allLive = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
    int crossed = 0;
    std::size_t i = begin;
    for (; i + 8 <= end; i += 8) {
        const __m256 now = _mm256_loadu_ps(c.pn + i), before = _mm256_loadu_ps(c.p + i);
        const __m256 d = _mm256_sub_ps(now, before);
        const __m256 nowAbove = _mm256_cmp_ps(now, half, _CMP_GT_OQ);
        crossed |= _mm256_movemask_ps(_mm256_xor_ps(nowAbove, _mm256_cmp_ps(before, half, _CMP_GT_OQ)));
        _mm256_storeu_ps(c.p + i, now);
        _mm256_storeu_ps(c.t + i, _mm256_loadu_ps(c.tn + i));
        // live: not (lateral > 1/2), so a NaN is live as in the scalar test
        const __m256 live = c.ghosts ? _mm256_cmp_ps(_mm256_loadu_ps(c.lateral + i), half, _CMP_NGT_UQ) : allLive;
        const __m256 g = _mm256_loadu_ps(c.growth + i), f = _mm256_loadu_ps(c.freeze + i);
        const __m256 grows = _mm256_and_ps(live, _mm256_cmp_ps(d, zero, _CMP_GT_OQ));
        _mm256_storeu_ps(c.growth + i, _mm256_blendv_ps(g, _mm256_add_ps(g, d), grows));
        const __m256 freezes = _mm256_and_ps(live, _mm256_and_ps(_mm256_cmp_ps(f, zero, _CMP_EQ_OQ), nowAbove));
        _mm256_storeu_ps(c.freeze + i, _mm256_blendv_ps(f, time, freezes));
    }
    const bool tail = surfaceCommit(c, i, end);
    return crossed != 0 || tail;
}

#endif

} // namespace

bool surfaceCommit(const SurfaceCommit& c, std::size_t begin, std::size_t end)
{
    bool crossed = false;
    for (std::size_t i = begin; i < end; ++i) {
        const float now = c.pn[i], d = now - c.p[i];
        crossed = crossed || ((now > 0.5f) != (c.p[i] > 0.5f));
        c.p[i] = now;
        c.t[i] = c.tn[i];
        if (c.ghosts && c.lateral[i] > 0.5f) continue; // a ghost: held at the background
        recordGrowth(c.growth[i], c.freeze[i], d, now, c.time);
    }
    return crossed;
}

void surfaceCoefficients4Plain(const ShellBand& b, const float* P, const float* T, const Anisotropy& an, double invH,
                               std::size_t i, SurfaceCoefficients* C, float* gx, float* gy, FieldSums* sums,
                               WindSums* wind)
{
    for (std::size_t k = 0; k < 4; ++k) surfaceCoefficients(b, P, T, an, invH, i + k, C, gx, gy, sums, wind);
}

void surfaceCoefficients8Plain(const ShellBand& b, const float* P, const float* T, const Anisotropy& an, double invH,
                               std::size_t i, SurfaceCoefficients* C, float* gx, float* gy, FieldSums* sums,
                               WindSums* wind)
{
    for (std::size_t k = 0; k < 8; ++k) surfaceCoefficients(b, P, T, an, invH, i + k, C, gx, gy, sums, wind);
}

void surfacePass2x8Plain(const ShellBand& b, const SurfaceUpdateInputs& in, const FieldSums* sums, std::size_t i,
                         const double chi[8], float pNew[8], float tNew[8])
{
    surfacePass2Plain(b, in, sums, i, chi, pNew, tNew);
    surfacePass2Plain(b, in, sums, i + 4, chi + 4, pNew + 4, tNew + 4);
}

namespace {
bool vectorsAllowed()
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    const char* v = std::getenv("FROSTVDB_NO_VECTOR_ROWS");
    return cpuHasAvx2() && !(v && *v && std::strcmp(v, "0") != 0);
#else
    return false;
#endif
}
} // namespace

SurfaceCoefficients4 fastestSurfaceCoefficients4(const Anisotropy& an)
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    if (vectorsAllowed() && an.integerMode >= 0) return &surfaceCoefficients4Avx2;
#endif
    (void)an;
    return &surfaceCoefficients4Plain;
}

void tapSums4Plain(const ShellBand& b, const SurfaceCoefficients* C, const FieldSums* sums, const WindSums* wind,
                   std::size_t i, TapSums out[4])
{
    for (std::size_t k = 0; k < 4; ++k) out[k] = tapSums(b, C, sums, wind, i + k);
}

SurfacePass2 fastestSurfacePass2()
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    if (vectorsAllowed()) return &surfacePass2Avx2;
#endif
    return &surfacePass2Plain;
}

SurfaceCommitRange fastestSurfaceCommit()
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    if (vectorsAllowed()) return &surfaceCommitAvx2;
#endif
    return &surfaceCommit;
}

SurfaceCoefficients4 fastestSurfaceCoefficients8(const Anisotropy& an)
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    if (vectorsAllowed() && an.integerMode >= 0) return &surfaceCoefficients8Avx2;
#endif
    (void)an;
    return &surfaceCoefficients8Plain;
}

SurfacePass2 fastestSurfacePass2x8()
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    if (vectorsAllowed()) return &surfacePass2x8Avx2;
#endif
    return &surfacePass2x8Plain;
}

TapSums4 fastestTapSums4()
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    if (vectorsAllowed()) return &tapSums4Avx2;
#endif
    return &tapSums4Plain;
}

} // namespace frostvdb::shell
