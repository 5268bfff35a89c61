#pragma once
/// @file VectorLanes.h
/// @brief The AVX2 lane operations shared by the vector rows (icephysics/EulerRows.cpp,
/// SecondOrderRows.cpp, ImplicitSystem.cpp's relaxation) and the shell's tap sums
/// (shell/SurfaceTapSums.cpp). Each is one IEEE operation of the scalar code on 4 doubles, so a
/// lane keeps the scalar code's bits when the caller keeps its order: vmin(a, b) is std::min(a, b)
/// and vmax(a, b) std::max(a, b) (min_pd/max_pd return their second operand on ties and NaN, so
/// the operands are swapped). The target has no FMA, so nothing is contracted.
#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>

#define FV_AVX2 __attribute__((target("avx2")))

namespace frostvdb::lanes {

/// Whether this CPU runs AVX2 (asked once).
inline bool cpuHasAvx2()
{
    static const bool has = __builtin_cpu_supports("avx2");
    return has;
}

FV_AVX2 inline __m256d load4(const float* p) { return _mm256_cvtps_pd(_mm_loadu_ps(p)); }
FV_AVX2 inline void store4(float* p, __m256d v) { _mm_storeu_ps(p, _mm256_cvtpd_ps(v)); }
FV_AVX2 inline __m256d vmin(__m256d a, __m256d b) { return _mm256_min_pd(b, a); } // std::min(a, b)
FV_AVX2 inline __m256d vmax(__m256d a, __m256d b) { return _mm256_max_pd(b, a); } // std::max(a, b)
FV_AVX2 inline __m256d add(__m256d a, __m256d b) { return _mm256_add_pd(a, b); }
FV_AVX2 inline __m256d sub(__m256d a, __m256d b) { return _mm256_sub_pd(a, b); }
FV_AVX2 inline __m256d mul(__m256d a, __m256d b) { return _mm256_mul_pd(a, b); }
FV_AVX2 inline __m256d splat(double v) { return _mm256_set1_pd(v); }

} // namespace frostvdb::lanes
#endif
