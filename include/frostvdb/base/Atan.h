#pragma once
/// @file Atan.h
/// @brief atan as Cephes computes it (S. Moshier's rational approximation: relative error about
/// 1e-16, tests/atan_test.cpp), once for a double and once for four AVX2 lanes. Both do the same
/// IEEE operations in the same order on each value (every branch's candidates are computed and
/// one is selected), so a lane gives the scalar's bits: a kernel that takes four nodes at a time
/// and one that takes them one by one agree exactly. libm's atan, one call per value, was 7 % of
/// a shell step's CPU (docs/shells.md "Kernel").
#include <cmath>
#include <cstdint>

namespace frostvdb {

namespace atan_detail {
constexpr double kP[5] = {-8.750608600031904122785E-1, -1.615753718733365076637E1, -7.500855792314704667340E1,
                          -1.228866684490136173410E2, -6.485021904942025371773E1};
constexpr double kQ[5] = {2.485846490142306297962E1, 1.650270098316988542046E2, 4.328810604912902668951E2,
                          4.853903996359136964868E2, 1.945506571482613964425E2};
constexpr double kTan3Pi8 = 2.41421356237309504880; ///< above it: pi/2 - atan(1/x)
constexpr double kSmall = 0.66;                     ///< at most it: the series at x
constexpr double kPiO2 = 1.57079632679489661923, kPiO4 = 7.85398163397448309616E-1;
constexpr double kMoreBits = 6.123233995736765886130E-17; ///< pi/2 - kPiO2
} // namespace atan_detail

/// atan(x) for finite x (the sign of x carried by its sign bit: atan(-0) = -0).
inline double atanCephes(double x)
{
    using namespace atan_detail;
    const bool negative = std::signbit(x);
    const double a = std::fabs(x);
    double r, base, extra;
    if (a > kTan3Pi8) r = -1.0 / a, base = kPiO2, extra = kMoreBits;
    else if (a <= kSmall) r = a, base = 0.0, extra = 0.0;
    else r = (a - 1.0) / (a + 1.0), base = kPiO4, extra = 0.5 * kMoreBits;
    const double z = r * r;
    const double num = (((kP[0] * z + kP[1]) * z + kP[2]) * z + kP[3]) * z + kP[4];
    const double den = ((((z + kQ[0]) * z + kQ[1]) * z + kQ[2]) * z + kQ[3]) * z + kQ[4];
    double y = (z * num) / den;
    y = r * y + r;
    y = y + extra;
    y = base + y;
    return negative ? -y : y;
}

} // namespace frostvdb

#if defined(__x86_64__) || defined(__i386__)
#include <frostvdb/base/VectorLanes.h>

namespace frostvdb::lanes {

/// atanCephes on four lanes, bit for bit.
FV_AVX2 inline __m256d atanCephes4(__m256d x)
{
    using namespace atan_detail;
    const __m256d signBit = _mm256_set1_pd(-0.0);
    const __m256d sign = _mm256_and_pd(x, signBit);
    const __m256d a = _mm256_andnot_pd(signBit, x);
    const __m256d one = _mm256_set1_pd(1.0);
    const __m256d big = _mm256_cmp_pd(a, _mm256_set1_pd(kTan3Pi8), _CMP_GT_OQ);
    const __m256d small = _mm256_cmp_pd(a, _mm256_set1_pd(kSmall), _CMP_LE_OQ);
    const __m256d rBig = _mm256_div_pd(_mm256_set1_pd(-1.0), a);
    const __m256d rMid = _mm256_div_pd(_mm256_sub_pd(a, one), _mm256_add_pd(a, one));
    const __m256d r = _mm256_blendv_pd(_mm256_blendv_pd(rMid, a, small), rBig, big);
    const __m256d base = _mm256_blendv_pd(_mm256_blendv_pd(_mm256_set1_pd(kPiO4), _mm256_setzero_pd(), small),
                                          _mm256_set1_pd(kPiO2), big);
    const __m256d extra = _mm256_blendv_pd(_mm256_blendv_pd(_mm256_set1_pd(0.5 * kMoreBits), _mm256_setzero_pd(), small),
                                           _mm256_set1_pd(kMoreBits), big);
    const __m256d z = _mm256_mul_pd(r, r);
    __m256d num = _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(kP[0]), z), _mm256_set1_pd(kP[1]));
    num = _mm256_add_pd(_mm256_mul_pd(num, z), _mm256_set1_pd(kP[2]));
    num = _mm256_add_pd(_mm256_mul_pd(num, z), _mm256_set1_pd(kP[3]));
    num = _mm256_add_pd(_mm256_mul_pd(num, z), _mm256_set1_pd(kP[4]));
    __m256d den = _mm256_add_pd(z, _mm256_set1_pd(kQ[0]));
    den = _mm256_add_pd(_mm256_mul_pd(den, z), _mm256_set1_pd(kQ[1]));
    den = _mm256_add_pd(_mm256_mul_pd(den, z), _mm256_set1_pd(kQ[2]));
    den = _mm256_add_pd(_mm256_mul_pd(den, z), _mm256_set1_pd(kQ[3]));
    den = _mm256_add_pd(_mm256_mul_pd(den, z), _mm256_set1_pd(kQ[4]));
    __m256d y = _mm256_div_pd(_mm256_mul_pd(z, num), den);
    y = _mm256_add_pd(_mm256_mul_pd(r, y), r);
    y = _mm256_add_pd(y, extra);
    y = _mm256_add_pd(base, y);
    return _mm256_xor_pd(y, sign); // -y where x had its sign bit
}

} // namespace frostvdb::lanes
#endif
