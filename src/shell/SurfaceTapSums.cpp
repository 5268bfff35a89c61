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

void surfaceCoefficients(const ShellBand& b, const float* P, const Anisotropy& an, double invH, std::size_t i,
                         SurfaceCoefficients* C, float* gx, float* gy)
{
    const VoxelFrame f = b.frame(i);
    // both derivatives in one pass over the taps (each sum in the taps' order)
    const double p0 = P[i];
    double su = 0, sv = 0;
    for (const SurfaceTap* t = b.tapsBegin(i); t != b.tapsEnd(i); ++t) {
        const double dp = double(P[t->node]) - p0;
        su += double(t->du) * dp;
        sv += double(t->dv) * dp;
    }
    const double gu = su * invH, gv = sv * invH;
    double eps, epsPrime;
    an(gu, gv, eps, epsPrime);
    // n x (gu t + gv b) = gu b - gv t
    const openvdb::Vec3d c = (f.bitangent * gu - f.tangent * gv) * (eps * epsPrime);
    C[i] = SurfaceCoefficients{float(eps * eps), float(c.x()), float(c.y()), float(c.z())};
    gx[i] = float(gu);
    gy[i] = float(gv);
}

TapSums tapSums(const ShellBand& b, const float* P, const float* T, const SurfaceCoefficients* C, std::size_t i)
{
    const VoxelFrame f = b.frame(i);
    const double p0 = P[i], t0v = T[i], a0 = C[i].a;
    const openvdb::Vec3d c0(C[i].cx, C[i].cy, C[i].cz);
    const double ct0 = c0.dot(f.tangent), cb0 = c0.dot(f.bitangent);
    TapSums s;
    for (const SurfaceTap* t = b.tapsBegin(i); t != b.tapsEnd(i); ++t) {
        const std::size_t j = std::size_t(t->node);
        const double dp = double(P[j]) - p0, dT = double(T[j]) - t0v, da = double(C[j].a) - a0;
        s.lapP += t->lap * dp;
        s.lapT += t->lap * dT;
        s.dau += t->du * da;
        s.dav += t->dv * da;
        s.dtu += t->du * dT;
        s.dtv += t->dv * dT;
        const openvdb::Vec3d cj(C[j].cx, C[j].cy, C[j].cz);
        s.divC += t->du * (cj.dot(f.tangent) - ct0) + t->dv * (cj.dot(f.bitangent) - cb0);
    }
    return s;
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

void surfaceUpdate4Plain(const SurfaceUpdateInputs& in, std::size_t i, const TapSums s[4], const double chi[4],
                         float pNew[4], float tNew[4])
{
    for (std::size_t n = 0; n < 4; ++n) surfaceUpdate(in, i + n, s[n], chi[n], pNew[n], tNew[n]);
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

/// The taps of nodes i .. i + 3 slot by slot: tap(k, q) is node k's q-th, or a padding tap
/// where it has fewer.
struct TapGroup {
    const SurfaceTap* first[4];
    int count[4], most = 0;
    SurfaceTap pad[4]; // weight 0 on the node itself: a difference of exactly 0 times 0
    TapGroup(const ShellBand& b, std::size_t i)
    {
        for (int k = 0; k < 4; ++k) {
            first[k] = b.tapsBegin(i + std::size_t(k));
            count[k] = int(b.tapsEnd(i + std::size_t(k)) - first[k]);
            most = std::max(most, count[k]);
            pad[k].node = int32_t(i) + k;
            pad[k].lap = pad[k].du = pad[k].dv = 0.f;
        }
    }
    const SurfaceTap* tap(int k, int q) const { return q < count[k] ? first[k] + q : &pad[k]; }
};

FV_AVX2 void tapSums4Avx2(const ShellBand& b, const float* P, const float* T, const SurfaceCoefficients* C,
                          std::size_t i, TapSums out[4])
{
    static_assert(sizeof(SurfaceTap) == 16 && sizeof(SurfaceCoefficients) == 16, "four floats each");
    const FrameFloats* f[4] = {&b.frameFloats(i), &b.frameFloats(i + 1), &b.frameFloats(i + 2), &b.frameFloats(i + 3)};
    const __m256d t[3] = {lanes(f, &FrameFloats::tangent, 0), lanes(f, &FrameFloats::tangent, 1),
                          lanes(f, &FrameFloats::tangent, 2)};
    const __m256d bt[3] = {lanes(f, &FrameFloats::bitangent, 0), lanes(f, &FrameFloats::bitangent, 1),
                           lanes(f, &FrameFloats::bitangent, 2)};
    const __m256d p0 = _mm256_cvtps_pd(_mm_loadu_ps(P + i)), t0 = _mm256_cvtps_pd(_mm_loadu_ps(T + i));
    // the four nodes' coefficients, transposed: a, cx, cy, cz across the lanes
    __m128 c0 = _mm_loadu_ps(&C[i].a), c1 = _mm_loadu_ps(&C[i + 1].a), c2 = _mm_loadu_ps(&C[i + 2].a),
           c3 = _mm_loadu_ps(&C[i + 3].a);
    _MM_TRANSPOSE4_PS(c0, c1, c2, c3);
    const __m256d a0 = _mm256_cvtps_pd(c0);
    const __m256d ct0 = dot(_mm256_cvtps_pd(c1), _mm256_cvtps_pd(c2), _mm256_cvtps_pd(c3), t);
    const __m256d cb0 = dot(_mm256_cvtps_pd(c1), _mm256_cvtps_pd(c2), _mm256_cvtps_pd(c3), bt);

    const TapGroup g(b, i);
    __m256d lapP = _mm256_setzero_pd(), lapT = lapP, dau = lapP, dav = lapP, divC = lapP, dtu = lapP, dtv = lapP;
    for (int q = 0; q < g.most; ++q) {
        const SurfaceTap* tp[4] = {g.tap(0, q), g.tap(1, q), g.tap(2, q), g.tap(3, q)};
        // the four taps transposed: node indices (as bits), lap, du, dv
        __m128 r0 = _mm_loadu_ps(reinterpret_cast<const float*>(tp[0])),
               r1 = _mm_loadu_ps(reinterpret_cast<const float*>(tp[1])),
               r2 = _mm_loadu_ps(reinterpret_cast<const float*>(tp[2])),
               r3 = _mm_loadu_ps(reinterpret_cast<const float*>(tp[3]));
        _MM_TRANSPOSE4_PS(r0, r1, r2, r3);
        (void)r0;
        const std::size_t j0 = std::size_t(tp[0]->node), j1 = std::size_t(tp[1]->node), j2 = std::size_t(tp[2]->node),
                          j3 = std::size_t(tp[3]->node);
        const __m256d lap = _mm256_cvtps_pd(r1), du = _mm256_cvtps_pd(r2), dv = _mm256_cvtps_pd(r3);
        const __m256d dp = sub(_mm256_cvtps_pd(_mm_set_ps(P[j3], P[j2], P[j1], P[j0])), p0);
        const __m256d dT = sub(_mm256_cvtps_pd(_mm_set_ps(T[j3], T[j2], T[j1], T[j0])), t0);
        __m128 k0 = _mm_loadu_ps(&C[j0].a), k1 = _mm_loadu_ps(&C[j1].a), k2 = _mm_loadu_ps(&C[j2].a),
               k3 = _mm_loadu_ps(&C[j3].a);
        _MM_TRANSPOSE4_PS(k0, k1, k2, k3);
        const __m256d da = sub(_mm256_cvtps_pd(k0), a0);
        lapP = add(lapP, mul(lap, dp));
        lapT = add(lapT, mul(lap, dT));
        dau = add(dau, mul(du, da));
        dav = add(dav, mul(dv, da));
        dtu = add(dtu, mul(du, dT));
        dtv = add(dtv, mul(dv, dT));
        const __m256d cx = _mm256_cvtps_pd(k1), cy = _mm256_cvtps_pd(k2), cz = _mm256_cvtps_pd(k3);
        divC = add(divC, add(mul(du, sub(dot(cx, cy, cz, t), ct0)), mul(dv, sub(dot(cx, cy, cz, bt), cb0))));
    }
    alignas(32) double v[7][4];
    _mm256_store_pd(v[0], lapP);
    _mm256_store_pd(v[1], lapT);
    _mm256_store_pd(v[2], dau);
    _mm256_store_pd(v[3], dav);
    _mm256_store_pd(v[4], divC);
    _mm256_store_pd(v[5], dtu);
    _mm256_store_pd(v[6], dtv);
    for (int k = 0; k < 4; ++k) out[k] = TapSums{v[0][k], v[1][k], v[2][k], v[3][k], v[4][k], v[5][k], v[6][k]};
}

FV_AVX2 void surfaceCoefficients4Avx2(const ShellBand& b, const float* P, const Anisotropy& an, double invH,
                                      std::size_t i, SurfaceCoefficients* C, float* gx, float* gy)
{
    const TapGroup g(b, i);
    const __m256d p0 = _mm256_cvtps_pd(_mm_loadu_ps(P + i));
    __m256d su = _mm256_setzero_pd(), sv = su;
    for (int q = 0; q < g.most; ++q) {
        const SurfaceTap *t0 = g.tap(0, q), *t1 = g.tap(1, q), *t2 = g.tap(2, q), *t3 = g.tap(3, q);
        const __m256d dp =
            sub(_mm256_cvtps_pd(_mm_set_ps(P[t3->node], P[t2->node], P[t1->node], P[t0->node])), p0);
        su = add(su, mul(_mm256_set_pd(t3->du, t2->du, t1->du, t0->du), dp));
        sv = add(sv, mul(_mm256_set_pd(t3->dv, t2->dv, t1->dv, t0->dv), dp));
    }
    const __m256d h = _mm256_set1_pd(invH), gu = mul(su, h), gv = mul(sv, h);
    // Anisotropy, integer mode (the plane's vector rows, EulerRows.cpp): w = (g / |g|)^j where
    // |g|^2 > 1e-30, else w = 1 (a select whose discarded lane multiplies by 1 and adds +0)
    const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0);
    const __m256d r2 = add(mul(gu, gu), mul(gv, gv));
    const __m256d big = _mm256_cmp_pd(r2, _mm256_set1_pd(1e-30), _CMP_GT_OQ);
    const __m256d inv = _mm256_div_pd(one, _mm256_sqrt_pd(r2));
    const __m256d zr = _mm256_blendv_pd(one, mul(gu, inv), big), zi = _mm256_blendv_pd(zero, mul(gv, inv), big);
    __m256d wr = one, wi = zero;
    for (int q = 0; q < an.integerMode; ++q) {
        const __m256d t = sub(mul(wr, zr), mul(wi, zi));
        wi = add(mul(wr, zi), mul(wi, zr));
        wr = t;
    }
    const __m256d cj0 = _mm256_set1_pd(an.cj0), sj0 = _mm256_set1_pd(an.sj0);
    const __m256d c = add(mul(cj0, wr), mul(sj0, wi)), s = sub(mul(sj0, wr), mul(cj0, wi));
    const __m256d eps = mul(_mm256_set1_pd(an.epsBar), add(one, mul(_mm256_set1_pd(an.delta), c)));
    const __m256d epsPrime = mul(_mm256_set1_pd(an.epsBar * an.delta * an.j), s); // ((eps_bar delta) j) s
    const __m256d ee = mul(eps, epsPrime);
    const FrameFloats* f[4] = {&b.frameFloats(i), &b.frameFloats(i + 1), &b.frameFloats(i + 2), &b.frameFloats(i + 3)};
    __m128 out[4] = {_mm256_cvtpd_ps(mul(eps, eps)), {}, {}, {}};
    for (int axis = 0; axis < 3; ++axis) // (b gu - t gv) (eps eps'), per component
        out[1 + axis] = _mm256_cvtpd_ps(mul(sub(mul(lanes(f, &FrameFloats::bitangent, axis), gu),
                                                mul(lanes(f, &FrameFloats::tangent, axis), gv)),
                                            ee));
    _MM_TRANSPOSE4_PS(out[0], out[1], out[2], out[3]); // a, cx, cy, cz per node
    for (int k = 0; k < 4; ++k) _mm_storeu_ps(&C[i + std::size_t(k)].a, out[k]);
    _mm_storeu_ps(gx + i, _mm256_cvtpd_ps(gu));
    _mm_storeu_ps(gy + i, _mm256_cvtpd_ps(gv));
}

/// One member of four TapSums, lane k from s[k].
FV_AVX2 inline __m256d lanes(const TapSums s[4], double TapSums::*m)
{
    return _mm256_set_pd(s[3].*m, s[2].*m, s[1].*m, s[0].*m);
}

FV_AVX2 void surfaceUpdate4Avx2(const SurfaceUpdateInputs& in, std::size_t i, const TapSums s[4], const double chi[4],
                                float pNew[4], float tNew[4])
{
    // surfaceUpdate's operations, in its order, on four lanes
    const KobayashiParams& k = *in.k;
    const __m256d p0 = load4(in.P + i), t0 = load4(in.T + i);
    const __m256d a0 = _mm256_set_pd(in.C[i + 3].a, in.C[i + 2].a, in.C[i + 1].a, in.C[i].a);
    const __m256d invH = splat(in.invH), invH2 = splat(in.invH2);
    const __m256d div =
        add(add(mul(mul(a0, lanes(s, &TapSums::lapP)), invH2),
                mul(add(mul(lanes(s, &TapSums::dau), load4(in.gu + i)), mul(lanes(s, &TapSums::dav), load4(in.gv + i))),
                    invH)),
            mul(lanes(s, &TapSums::divC), invH));
    const __m256d melt = in.melt ? load4(in.melt + i) : splat(1.0);
    const __m256d Te = add(splat(k.farTemperature), mul(melt, splat(k.meltTemperature - k.farTemperature)));
    const __m256d m = mul(splat(k.alpha / M_PI), atanCephes4(mul(splat(k.gamma), sub(Te, t0))));
    const __m256d one = splat(1.0);
    const __m256d reaction = mul(mul(p0, sub(one, p0)), add(add(sub(p0, splat(0.5)), m),
                                                            mul(splat(k.noise), _mm256_loadu_pd(chi))));
    const __m256d dp = mul(splat(k.dt / k.tau), add(div, reaction));
    store4(pNew, add(p0, dp));
    store4(tNew, add(add(t0, mul(splat(k.dt), mul(lanes(s, &TapSums::lapT), invH2))), mul(splat(k.latentHeat), dp)));
}

#endif

} // namespace

void surfaceCoefficients4Plain(const ShellBand& b, const float* P, const Anisotropy& an, double invH, std::size_t i,
                               SurfaceCoefficients* C, float* gx, float* gy)
{
    for (std::size_t k = 0; k < 4; ++k) surfaceCoefficients(b, P, an, invH, i + k, C, gx, gy);
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

void tapSums4Plain(const ShellBand& b, const float* P, const float* T, const SurfaceCoefficients* C, std::size_t i,
                   TapSums out[4])
{
    for (int k = 0; k < 4; ++k) out[k] = tapSums(b, P, T, C, i + std::size_t(k));
}

SurfaceUpdate4 fastestSurfaceUpdate4()
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    if (vectorsAllowed()) return &surfaceUpdate4Avx2;
#endif
    return &surfaceUpdate4Plain;
}

TapSums4 fastestTapSums4()
{
#ifdef FROSTVDB_HAVE_AVX2_TAPS
    if (vectorsAllowed()) return &tapSums4Avx2;
#endif
    return &tapSums4Plain;
}

} // namespace frostvdb::shell
