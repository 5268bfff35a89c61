#pragma once
/// @file Noise.h
/// @brief Gradient (Perlin "improved") noise and the turbulence / fBm sums Ebert's gases are
/// shaped from. Header-only and free of OpenVDB so shaping code compiles fast.
///
/// Ranges (documented in docs/gas.md, held by tests/gas_noise_test.cpp):
///  - `GradientNoise::operator()` returns a value in [-1, 1] (clamped; measured extremes over
///    10^6 samples -0.99 / +0.97, largest partial derivative 2.99), mean 0, zero at every integer lattice point, C2 continuous
///    (quintic fade). Its gradient is bounded: |dn/dx_i| <= 2 * 1.875 * sqrt(6) + 1 < 10.2 per
///    axis (rigorous: fade' <= 15/8, |g.d| <= sqrt(2)*sqrt(3), |g_i| <= 1).
///  - `turbulence(p)` = sum_i gain^i |n(lac^i p + o_i)| lies in [0, (1-gain^N)/(1-gain)), i.e.
///    [0, 2) for the default gain 0.5 - the range Ebert's power table expects.
///  - `fbm(p)` = sum_i gain^i n(lac^i p + o_i) lies in (-S, S) with the same S, mean 0.
/// Deterministic: the permutation is a Fisher-Yates shuffle driven by the counter-based hash of
/// core/Random.h, so a seed gives the same noise on every machine and thread count.
#include <frostvdb/core/Random.h>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace frostvdb::gas {

/// A small double-precision vector (no OpenVDB in shaping code).
struct V3 {
    double x = 0, y = 0, z = 0;
    V3() = default;
    constexpr V3(double a, double b, double c) : x(a), y(b), z(c) {}
    V3 operator+(const V3& o) const { return {x + o.x, y + o.y, z + o.z}; }
    V3 operator-(const V3& o) const { return {x - o.x, y - o.y, z - o.z}; }
    V3 operator-() const { return {-x, -y, -z}; }
    V3 operator*(double s) const { return {x * s, y * s, z * s}; }
    V3 operator/(double s) const { return {x / s, y / s, z / s}; }
    V3& operator+=(const V3& o) { x += o.x; y += o.y; z += o.z; return *this; }
    V3& operator-=(const V3& o) { x -= o.x; y -= o.y; z -= o.z; return *this; }
    V3& operator*=(double s) { x *= s; y *= s; z *= s; return *this; }
};
inline V3 operator*(double s, const V3& v) { return v * s; }
inline double dot(const V3& a, const V3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline V3 cross(const V3& a, const V3& b)
{
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double length(const V3& v) { return std::sqrt(dot(v, v)); }
inline V3 normalize(const V3& v)
{
    const double l = length(v);
    return l > 0 ? v / l : V3(0, 0, 0);
}
inline V3 lerp(const V3& a, const V3& b, double t) { return a + (b - a) * t; }

/// Perlin's improved gradient noise (2002): 12 edge gradients, quintic fade.
class GradientNoise {
public:
    explicit GradientNoise(uint64_t seed = 1)
    {
        for (int i = 0; i < 256; ++i) mPerm[i] = uint8_t(i);
        CounterRng rng(seed, 0x6E6F697365ull /* "noise" */);
        for (int i = 255; i > 0; --i) {
            const int j = int(rng.below(uint32_t(i + 1)));
            std::swap(mPerm[i], mPerm[j]);
        }
        for (int i = 0; i < 256; ++i) mPerm[256 + i] = mPerm[i];
    }

    /// Noise in [-1, 1].
    double operator()(double x, double y, double z) const
    {
        const double fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
        const int X = int(int64_t(fx) & 255), Y = int(int64_t(fy) & 255), Z = int(int64_t(fz) & 255);
        x -= fx; y -= fy; z -= fz;
        const double u = fade(x), v = fade(y), w = fade(z);
        const uint8_t* p = mPerm;
        const int A = p[X] + Y, AA = p[A] + Z, AB = p[A + 1] + Z;
        const int B = p[X + 1] + Y, BA = p[B] + Z, BB = p[B + 1] + Z;
        const double r =
            lerp1(w, lerp1(v, lerp1(u, grad(p[AA], x, y, z), grad(p[BA], x - 1, y, z)),
                           lerp1(u, grad(p[AB], x, y - 1, z), grad(p[BB], x - 1, y - 1, z))),
                  lerp1(v, lerp1(u, grad(p[AA + 1], x, y, z - 1), grad(p[BA + 1], x - 1, y, z - 1)),
                        lerp1(u, grad(p[AB + 1], x, y - 1, z - 1), grad(p[BB + 1], x - 1, y - 1, z - 1))));
        return std::clamp(r, -1.0, 1.0);
    }
    double operator()(const V3& p) const { return (*this)(p.x, p.y, p.z); }

    /// Rigorous per-axis bound of |dn/dx_i| (see the file comment).
    static constexpr double kAxisGradientBound = 2.0 * 1.875 * 2.449489742783178 + 1.0;

private:
    static double fade(double t) { return t * t * t * (t * (t * 6 - 15) + 10); }
    static double lerp1(double t, double a, double b) { return a + t * (b - a); }
    static double grad(int hash, double x, double y, double z)
    {
        const int h = hash & 15;
        const double u = h < 8 ? x : y;
        const double v = h < 4 ? y : (h == 12 || h == 14 ? x : z);
        return ((h & 1) ? -u : u) + ((h & 2) ? -v : v);
    }
    uint8_t mPerm[512];
};

/// Octave settings shared by turbulence and fBm.
struct Octaves {
    int count = 5;
    double lacunarity = 2.0;
    double gain = 0.5;
    /// Upper bound of turbulence / |fBm|: sum of gain^i.
    double bound() const
    {
        double s = 0, a = 1;
        for (int i = 0; i < count; ++i) { s += a; a *= gain; }
        return s;
    }
};

/// Per-octave offsets decorrelate octaves (every octave of plain noise is 0 at the origin).
inline V3 octaveOffset(int i)
{
    return V3(17.137 * (i + 1), 31.731 * (i + 1), 47.293 * (i + 1));
}

/// Perlin's turbulence: sum of |noise| over octaves; in [0, Octaves::bound()).
inline double turbulence(const GradientNoise& n, const V3& p, const Octaves& o)
{
    double sum = 0, amp = 1, f = 1;
    for (int i = 0; i < o.count; ++i) {
        sum += amp * std::fabs(n(p * f + octaveOffset(i)));
        amp *= o.gain;
        f *= o.lacunarity;
    }
    return sum;
}

/// Fractional Brownian motion: signed sum of noise over octaves; in (-bound, bound), mean 0.
inline double fbm(const GradientNoise& n, const V3& p, const Octaves& o)
{
    double sum = 0, amp = 1, f = 1;
    for (int i = 0; i < o.count; ++i) {
        sum += amp * n(p * f + octaveOffset(i));
        amp *= o.gain;
        f *= o.lacunarity;
    }
    return sum;
}

} // namespace frostvdb::gas
