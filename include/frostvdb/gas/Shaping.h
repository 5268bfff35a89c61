#pragma once
/// @file Shaping.h
/// @brief Ebert's density-shaping functions (Texturing & Modeling, ch. 4.3 and 4.7): the power
/// function with its precomputed table, the sine "veins", the spherical cosine ramp-off from 25%
/// of the radius, the exponential vertical ramp-off, solid-textured-transparency fog, the fire
/// flame shape and colour, and the molten-marble hypertexture. Pure functions of their inputs,
/// no OpenVDB. Each carries the formula it implements.
#include <frostvdb/gas/Noise.h>

#include <cmath>
#include <vector>

namespace frostvdb::gas {

constexpr double kPi = 3.14159265358979323846;

/// Ebert's power shaping: density = (turb * max_density)^exponent, for turbulence in [0, 2).
/// With a table (Ebert's `pow_table`, 10 000 entries over turb in [0, 2]) the value is the
/// entry at floor(turb/2 * (N-1)); exact mode calls pow().
class PowerTable {
public:
    PowerTable(double maxDensity = 1.0, double exponent = 1.0, bool useTable = true, int size = 10000)
        : mMax(maxDensity), mExp(exponent), mUseTable(useTable)
    {
        if (mUseTable) {
            mTable.resize(size_t(size));
            for (int i = 0; i < size; ++i)
                mTable[size_t(i)] = float(std::pow(double(i) / (size - 1) * maxDensity * 2.0, exponent));
        }
    }
    double operator()(double turb) const
    {
        if (turb <= 0) return mUseTable ? mTable[0] : (mExp == 0 ? 1.0 : 0.0);
        if (!mUseTable) return std::pow(turb * mMax, mExp);
        const double f = turb * 0.5 * double(mTable.size() - 1);
        const size_t i = f >= double(mTable.size() - 1) ? mTable.size() - 1 : size_t(f);
        return mTable[i];
    }
    double maxDensity() const { return mMax; }
    double exponent() const { return mExp; }

private:
    double mMax, mExp;
    bool mUseTable;
    std::vector<float> mTable;
};

/// Ebert's sine veins: turb' = (1 + sin(5 pi turb)) / 2, in [0, 1].
inline double veins(double turb) { return (1.0 + std::sin(turb * kPi * 5.0)) * 0.5; }

/// Cosine ramp (Ebert's make_ramp_table): 1 at s <= 0, (cos(pi s) + 1)/2, 0 at s >= 1.
inline double cosineRamp(double s)
{
    if (s <= 0) return 1.0;
    if (s >= 1) return 0.0;
    return (std::cos(s * kPi) + 1.0) * 0.5;
}

/// Hermite-style ease with acceleration/deceleration fractions (Ebert's ease(t, a, b)):
/// constant acceleration over [0, a], constant speed, deceleration over [b, 1]; ease(0)=0,
/// ease(1)=1, monotone.
inline double ease(double t, double a, double b)
{
    if (t <= 0) return 0.0;
    if (t >= 1) return 1.0;
    const double rr = 1.0 / (a * -0.5 + b * 0.5 + 0.5); // 2/(1 + b - a)
    const double s = rr;
    if (t < a) return s * t * t / (2 * a);
    if (t <= b) return s * (a * 0.5 + (t - a));
    const double tt = (t - b) / (1 - b);
    return s * (a * 0.5 + (b - a) + (1 - b) * (tt - tt * tt * 0.5));
}

/// Spherical ramp-off of the steam slab (Ebert 4.3.2): @a distSq is the point's squared
/// (ellipsoidal) distance from the centre divided by the radius squared, plus the noise offset.
/// 1 inside 25%, cosine falloff (dist_sq - 0.25) * 4/3 over the rest, 0 at and beyond 1.
inline double sphericalRampOff(double distSq)
{
    if (distSq < 0.25) return 1.0;
    return cosineRamp((distSq - 0.25) * (4.0 / 3.0));
}

/// Exponential vertical ramp-off (Ebert 4.3.2): @a h is the height above the centre divided by
/// the plume height (plus noise). 1 up to 5%, then 1 - (exp((h - 0.05)/0.9) - 1)/(e - 1),
/// reaching 0 at h = 0.95; clamped to [0, 1]. Monotone non-increasing in h.
inline double verticalRampOff(double h)
{
    if (h <= 0.05) return 1.0;
    const double v = 1.0 - (std::exp((h - 0.05) * (1.0 / 0.9)) - 1.0) / 1.718281828459045;
    return v < 0 ? 0.0 : (v > 1 ? 1.0 : v);
}

/// Ebert's solid-textured-transparency fog: transparency = (1 - 0.275 turb^2)^3, returned as
/// opacity 1 - transparency in [0, 1].
inline double fogOpacity(double turb)
{
    double t = 1.0 - turb * turb * 0.275;
    if (t < 0) t = 0;
    return 1.0 - t * t * t;
}

/// Ebert's fire flame shape: several sine waves across the two horizontal noise-space
/// coordinates (a, b), perturbed by the turbulence @a turb; @a freq is parms[8].
/// Returns a value in [0, 1] that feeds the power table.
inline double flameShape(double a, double b, double turb, double freq)
{
    double v = (std::sin(a * freq + turb * freq) + 1.25) * (1.0 / 2.25);
    v *= (std::sin((b + turb) * 2.0 * freq) + 1.0) * 0.5;
    return v;
}

/// Ebert's flame colour: dense flame red, thinning flame yellow.
/// d = clamp(1 - 1.5 density/max_density, 0, 1); rgb = (1, 0.85 d + 0.2(1-d), 0.5 d + 0.2(1-d)).
inline V3 fireColour(double density, double maxDensity)
{
    double d = 1.0 - density * 1.5 / maxDensity;
    d = d < 0 ? 0 : (d > 1 ? 1 : d);
    const double c = 1.0 - d;
    return {1.0, 0.85 * d + 0.2 * c, 0.5 * d + 0.2 * c};
}

/// Marble forming (Ebert 4.5): fraction of turbulence added at @a frame, linear from the start
/// to the end frame, eased (0.3, 0.7).
inline double marbleTurbPercent(double frame, double start, double end)
{
    if (frame <= start) return 0.0;
    if (frame >= end) return 1.0;
    return ease((frame - start) / (end - start), 0.3, 0.7);
}

/// The marble value sin-band in [0, 1]: (sin(pi (y + 3 tp turb - 3 tp)) + 1)/2, where tp is
/// the turbulence percent (the -3 tp displacement keeps the veins forming in place).
inline double marbleValue(double y, double turb, double turbPercent)
{
    const double x = y + turbPercent * 3.0 * turb - 3.0 * turbPercent;
    return (std::sin(x * kPi) + 1.0) * 0.5;
}

/// Molten-marble hypertexture density (Ebert 4.7.1): (m^exp * 0.35 + 0.65) * max_density, then
/// Perlin's hard-surface trick (d - 0.5) * sharpness + 0.5, clamped to [0.2, 1].
inline double moltenMarbleDensity(double marble, double exponent, double maxDensity, double sharpness)
{
    double d = (std::pow(marble, exponent) * 0.35 + 0.65) * maxDensity;
    d = (d - 0.5) * sharpness + 0.5;
    return d < 0.2 ? 0.2 : (d > 1.0 ? 1.0 : d);
}

} // namespace frostvdb::gas
