/// @file GasModels.cpp
/// @brief Ebert's gas models and their scene keys (no OpenVDB here: fast to compile).
#include <frostvdb/gas/GasModels.h>

#include <frostvdb/core/Params.h>

#include <cmath>
#include <cstdio>
#include <limits>

namespace frostvdb::gas {

namespace {

constexpr double kBig = 1e6;

V3 toV3(const std::vector<double>& v) { return {v.at(0), v.at(1), v.at(2)}; }

std::string numText(double v)
{
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.4g", v);
    return buf;
}

/// A unit vector perpendicular to @a n.
V3 anyPerpendicular(const V3& n)
{
    const V3 a = std::fabs(n.x) < 0.9 ? V3(1, 0, 0) : V3(0, 1, 0);
    return normalize(cross(n, a));
}

V3 readUnit(ParamDict& d, const std::string& key, const V3& def, const std::string& doc)
{
    const V3 v = toV3(d.getFloatArray(key, {def.x, def.y, def.z}, {3}, -kBig, kBig, "", doc));
    if (length(v) <= 0) d.fail(key, "must be a non-zero vector");
    return normalize(v);
}

V3 readPoint(ParamDict& d, const std::string& key, const V3& def, const std::string& unit,
             const std::string& doc)
{
    return toV3(d.getFloatArray(key, {def.x, def.y, def.z}, {3}, -kBig, kBig, unit, doc));
}

StrengthRamp readStrength(ParamDict& d, double defMax)
{
    StrengthRamp s;
    auto st = d.getFloatArray("strength", {0.0, defMax}, {2}, 0.0, 1.0, "",
                              "[minimum, maximum] strength (percent to use, 0-1), animated over ramp_frames");
    auto fr = d.getFloatArray("ramp_frames", {0.0, 0.0}, {2}, -kBig, kBig, "frame",
                              "[start, end] frames over which the strength rises from minimum to maximum "
                              "(equal: maximum from the start frame on)");
    s.minStrength = st[0];
    s.maxStrength = st[1];
    s.startFrame = fr[0];
    s.endFrame = fr[1];
    return s;
}

AngleLimit readAngle(ParamDict& d, const V3& defAxis)
{
    AngleLimit a;
    a.axis = readUnit(d, "axis", defAxis, "axis of the angle limit (the cone opens around it)");
    a.halfAngleDeg = d.getFloat("angle", 180.0, 0.0, 180.0, "deg",
                                "half-angle of the cone of influence around axis; 180 = all directions");
    a.edgeDeg = d.getFloat("angle_edge", 10.0, 0.0, 180.0, "deg",
                           "soft edge of the cone: cosine falloff over this many degrees inside the half-angle");
    return a;
}

/// Smooth 0 -> 1 from a face to @a edge inside.
double faceRamp(double d, double edge)
{
    if (d <= 0) return 0.0;
    if (edge <= 0 || d >= edge) return 1.0;
    return 1.0 - cosineRamp(d / edge);
}

/// Axis-aligned extent of a cylinder (base point b, axis u, length h, radius r).
void cylinderBounds(const V3& b, const V3& u, double h, double r, V3& lo, V3& hi)
{
    const V3 top = b + u * h;
    const double ex = r * std::sqrt(std::max(0.0, 1 - u.x * u.x));
    const double ey = r * std::sqrt(std::max(0.0, 1 - u.y * u.y));
    const double ez = r * std::sqrt(std::max(0.0, 1 - u.z * u.z));
    lo = V3(std::min(b.x, top.x) - ex, std::min(b.y, top.y) - ey, std::min(b.z, top.z) - ez);
    hi = V3(std::max(b.x, top.x) + ex, std::max(b.y, top.y) + ey, std::max(b.z, top.z) + ez);
}

} // namespace

// ---------------------------------------------------------------------------------------------
// GasModel

GasModel::GasModel(const GasCommon& common)
    : mC(common), mNoise(common.seed), mPower(common.maxDensity, common.exponent, common.powerTable)
{
    mC.up = normalize(mC.up);
    mE1 = anyPerpendicular(mC.up);
    mE2 = cross(mC.up, mE1);
}

V3 GasModel::displacementAt(const V3& x, const FlowTime& t, const FlowList* flows) const
{
    V3 D = mC.up * (mC.riseSpeed * t.seconds) + mC.wind * t.seconds;
    if (mC.swirlPeriod > 0) {
        // the phase within the current turn: frame / period itself overflows to inf (cos(inf) is
        // NaN) for periods below about 1e-305 frames; fmod is exact and stays below the period
        const double theta = 2.0 * kPi * (std::fmod(t.frame, mC.swirlPeriod) / mC.swirlPeriod);
        D += mE1 * (mC.swirlRadius[0] * (std::cos(theta) - 1.0)) + mE2 * (mC.swirlRadius[1] * std::sin(theta));
    }
    if (flows)
        for (const auto& f : *flows) f->blend(x, t, D);
    return D;
}

V3 GasModel::displacement(const V3& x, const GasContext& ctx) const
{
    return displacementAt(x, ctx.time, ctx.flows);
}

V3 GasModel::staticWarp(const V3& x) const
{
    V3 W(0, 0, 0);
    if (mC.pathNoise == 0 && mC.turbulenceGrowth == 0) return W;
    const V3 p = x / mC.noiseScale + mC.noiseOffset;
    if (mC.pathNoise != 0) {
        const double n = mNoise(p + V3(101.3, 57.1, 13.7));
        W += V3(n, n, n) * mC.pathNoise; // Ebert: the same noise on every component
    }
    if (mC.turbulenceGrowth != 0) {
        const double h = heightAboveBase(x) / mC.growthHeight;
        const double hr = ease(std::clamp(h, 0.0, 1.0), 0.4, 0.6);
        if (hr > 0) {
            const V3 q = p * 1.3;
            W += V3(fbm(mNoise, q + V3(211.1, 0, 0), mC.pathOctaves),
                    fbm(mNoise, q + V3(0, 307.7, 0), mC.pathOctaves),
                    fbm(mNoise, q + V3(0, 0, 401.9), mC.pathOctaves)) *
                 (mC.turbulenceGrowth * hr);
        }
    }
    return W;
}

V3 GasModel::solidPoint(const V3& x, const GasContext& ctx) const
{
    return (x - displacement(x, ctx) - staticWarp(x)) / mC.noiseScale + mC.noiseOffset;
}

V3 GasModel::velocity(const V3& x, const GasContext& ctx) const
{
    const double hf = 0.25; // frames
    FlowTime a = ctx.time, b = ctx.time;
    a.frame -= hf;
    b.frame += hf;
    a.seconds = a.frame / mC.fps;
    b.seconds = b.frame / mC.fps;
    return (displacementAt(x, b, ctx.flows) - displacementAt(x, a, ctx.flows)) / (b.seconds - a.seconds);
}

// ---------------------------------------------------------------------------------------------
// Steam

double SteamModel::maxShift(const GasContext& ctx) const
{
    double s = 0;
    if (ctx.flows)
        for (const auto& f : *ctx.flows) s += f->maxEnvelopeShift();
    return s;
}

V3 SteamModel::shiftAt(double h, const GasContext& ctx) const
{
    V3 s(0, 0, 0);
    if (ctx.flows)
        for (const auto& f : *ctx.flows) s += f->envelopeShift(center, mC.up, h, ctx.time);
    return s;
}

void SteamModel::bounds(const GasContext& ctx, V3& lo, V3& hi) const
{
    cylinderBounds(center, mC.up, height, radius + maxShift(ctx), lo, hi);
}

bool SteamModel::mayHold(const V3& c, double r, const GasContext& ctx) const
{
    const V3 rel = c - center;
    const double h = dot(rel, mC.up);
    if (h + r < 0) return false;
    const double rho = length(rel - mC.up * h);
    const double reff = radius + maxShift(ctx);
    const double a = std::max(0.0, rho - r) / reff;
    const double b = std::max(0.0, std::fabs(h) - r) / height;
    return a * a + b * b < 1.0;
}

double SteamModel::envelope(const V3& x, const GasContext& ctx) const
{
    const V3 rel = x - center;
    const double h = dot(rel, mC.up);
    if (h < 0) return 0.0; // the slab starts at the liquid surface
    const V3 shifted = rel - shiftAt(h, ctx);
    const V3 hor = shifted - mC.up * dot(shifted, mC.up);
    double off = 0;
    if (falloffNoise > 0)
        off = 0.5 * (1.0 + mNoise(x * (2.0 / mC.noiseScale) + V3(5.5, 77.7, 33.3)));
    const double distSq = dot(hor, hor) / (radius * radius) + (h * h) / (height * height) + falloffNoise * off;
    if (distSq >= 1.0) return 0.0;
    const double sph = sphericalRampOff(distSq);
    const double vert = verticalRampOff(h / height + 0.1 * falloffNoise * off);
    return sph * vert;
}

void SteamModel::evaluate(const V3& x, const GasContext& ctx, GasSample& out) const
{
    out.density = 0;
    const double env = envelope(x, ctx);
    if (env <= 0) return;
    const double turb = turbulence(mNoise, solidPoint(x, ctx), mC.octaves);
    out.density = mC.densityScale * mPower(turb) * env;
}

// ---------------------------------------------------------------------------------------------
// Fire

void FireModel::bounds(const GasContext& ctx, V3& lo, V3& hi) const
{
    cylinderBounds(center, mC.up, height, radius, lo, hi);
}

bool FireModel::mayHold(const V3& c, double r, const GasContext& ctx) const
{
    const V3 rel = c - center;
    const double h = dot(rel, mC.up);
    if (h + r < 0 || h - r > height) return false;
    const double rho = length(rel - mC.up * h);
    const double a = std::max(0.0, rho - r) / radius;
    const double b = std::max(0.0, std::fabs(h - 0.5 * height) - r) / (0.5 * height);
    return a * a + b * b < 1.0;
}

void FireModel::evaluate(const V3& x, const GasContext& ctx, GasSample& out) const
{
    out = GasSample();
    const V3 rel = x - center;
    const double h = dot(rel, mC.up);
    if (h < 0 || h > height) return;
    const double half = 0.5 * height;
    const V3 hor = rel - mC.up * h;
    double off = 0;
    if (falloffNoise > 0) off = 0.5 * (1.0 + mNoise(x * (2.0 / mC.noiseScale) + V3(9.1, 3.3, 71.7)));
    const double dv = (h - half) / half;
    const double distSq = dot(hor, hor) / (radius * radius) + dv * dv + falloffNoise * off;
    if (distSq >= 1.0) return;
    const double sph = sphericalRampOff(distSq);

    // flame shape: several sine waves across the two horizontal solid-space coordinates
    const V3 q = solidPoint(x, ctx);
    const double turb = turbulence(mNoise, q, mC.octaves);
    const double shape = flameShape(dot(q, mE1), dot(q, mE2), turb, flameFrequency);
    double d = mPower(shape) * sph; // (shape * max_density)^exponent

    // vertical ramp-off above the centre (Ebert: 2 (y - cy)/rad, clamped to 1)
    double v = std::min(1.0, std::max(0.0, dv) + falloffNoise * off * 0.1);
    if (dv > 0) d *= verticalRampOff(v);
    if (d < cutoff) d = 0;

    // continuous base fire below base_height, eased into the flames above it
    const double baseTop = baseHeight * height;
    const double baseMin = minDensity * sph;
    if (d < baseMin) {
        if (h <= baseTop) d = baseMin;
        else {
            const double blend = std::max(1e-9, 0.5 * baseTop);
            const double e = ease(std::min(1.0, (h - baseTop) / blend), 0.4, 0.6);
            d = std::max(d, (1.0 - e) * baseMin);
        }
    }
    const double md = mC.maxDensity > 0 ? mC.maxDensity : 1.0;
    out.flame = std::clamp(1.5 * d / md, 0.0, 1.0);
    out.colour = fireColour(d, md);
    out.density = mC.densityScale * d;
}

// ---------------------------------------------------------------------------------------------
// Soft box, fog, basic gas

double SoftBox::factor(const V3& x) const
{
    if (x.x < lo.x || x.y < lo.y || x.z < lo.z || x.x > hi.x || x.y > hi.y || x.z > hi.z) return 0.0;
    return faceRamp(x.x - lo.x, edge) * faceRamp(hi.x - x.x, edge) * faceRamp(x.y - lo.y, edge) *
           faceRamp(hi.y - x.y, edge) * faceRamp(x.z - lo.z, edge) * faceRamp(hi.z - x.z, edge);
}

bool SoftBox::mayHold(const V3& c, double r) const
{
    return c.x + r > lo.x && c.y + r > lo.y && c.z + r > lo.z && c.x - r < hi.x && c.y - r < hi.y &&
           c.z - r < hi.z;
}

void FogModel::evaluate(const V3& x, const GasContext& ctx, GasSample& out) const
{
    out.density = 0;
    double f = box.factor(x);
    if (f <= 0) return;
    if (layerHeight > 0) f *= std::exp(-std::max(0.0, heightAboveBase(x)) / layerHeight);
    const double turb = turbulence(mNoise, solidPoint(x, ctx), mC.octaves);
    out.density = mC.densityScale * mC.maxDensity * fogOpacity(turb) * f;
}

void BasicGasModel::evaluate(const V3& x, const GasContext& ctx, GasSample& out) const
{
    out.density = 0;
    const double f = box.factor(x);
    if (f <= 0) return;
    const V3 q = solidPoint(x, ctx);
    double d = 0;
    switch (shape) {
    case Shape::Power: d = mPower(turbulence(mNoise, q, mC.octaves)); break;
    case Shape::Veins: d = mPower(veins(turbulence(mNoise, q, mC.octaves))); break;
    case Shape::MoltenMarble: {
        const double tp = marbleTurbPercent(ctx.time.frame, formStart, formEnd);
        const double turb = tp > 0 ? turbulence(mNoise, q, mC.octaves) : 0.0;
        const double m = marbleValue(dot(q, mC.up) * bandFrequency, turb, tp);
        d = moltenMarbleDensity(m, mC.exponent, mC.maxDensity, sharpness);
        break;
    }
    }
    out.density = mC.densityScale * d * f;
}

// ---------------------------------------------------------------------------------------------
// Scene keys

void readCommon(ParamDict& d, GasCommon& c, const GasCommon& def, bool pathKeys)
{
    c.fps = d.getFloat("fps", def.fps, 1e-3, 1e4, "1/s",
                       "frames per second: frame N is evaluated at time N/fps");
    c.seed = uint64_t(d.getInt("seed", int64_t(def.seed), 0, std::numeric_limits<int64_t>::max(), "",
                               "noise seed (the same seed gives the same gas on every machine)"));
    c.noiseScale = d.getFloat("noise_scale", def.noiseScale, 1e-6, kBig, "m",
                              "size of the largest turbulence feature (world metres per noise unit)");
    c.octaves.count = int(d.getInt("octaves", def.octaves.count, 1, 12, "", "turbulence octaves"));
    c.octaves.lacunarity = d.getFloat("lacunarity", def.octaves.lacunarity, 1.01, 8.0, "",
                                      "frequency ratio between octaves");
    c.octaves.gain = d.getFloat("gain", def.octaves.gain, 0.0, 0.99, "",
                                "amplitude ratio between octaves (0.5: Perlin's 1/f turbulence, range [0,2))");
    c.noiseOffset = readPoint(d, "noise_offset", def.noiseOffset, "",
                              "offset of the turbulence space (noise units): picks another piece of gas");
    c.maxDensity = d.getFloat("max_density", def.maxDensity, 0.0, 10.0, "",
                              "Ebert's maximum density (parms[1]) of the power shaping (turb*max)^exponent");
    c.exponent = d.getFloat("exponent", def.exponent, 0.0, 50.0, "",
                            "power-function exponent (parms[2]): higher = more contrast, separate plumes");
    c.powerTable = d.getBool("power_table", def.powerTable,
                             "use Ebert's 10 000-entry precomputed power table (false: exact pow)");
    c.densityScale = d.getFloat("density_scale", def.densityScale, 0.0, 1e6, "",
                                "multiplier of the output density (renderer units per metre)");
    c.threshold = d.getFloat("threshold", def.threshold, 0.0, 1e6, "",
                             "voxels with output density at or below this stay inactive (sparse output)");
    c.velocity = d.getBool("velocity", def.velocity, "write the `vel` motion-vector grid (m/s)");
    c.up = readUnit(d, "up", def.up, "world up direction (z-up like Blender; [0,1,0] for Houdini/Maya)");
    if (!pathKeys) return;
    c.riseSpeed = d.getFloat("rise_speed", def.riseSpeed, -kBig, kBig, "m/s",
                             "speed of the gas along up (Ebert's downward path through the solid space)");
    c.wind = readPoint(d, "wind", def.wind, "m/s", "constant drift of the gas (fog rolling by)");
    c.swirlPeriod = d.getFloat("swirl_period", def.swirlPeriod, 0.0, kBig, "frames",
                               "frames per full turn of the helical path (Ebert's SWIRL_FRAMES); 0: no swirl");
    auto sr = d.getFloatArray("swirl_radius", {def.swirlRadius[0], def.swirlRadius[1]}, {2}, 0.0, kBig, "m",
                              "the two radii of the elliptical swirl (Ebert's RAD1, RAD2)");
    c.swirlRadius[0] = sr[0];
    c.swirlRadius[1] = sr[1];
    c.pathNoise = d.getFloat("path_noise", def.pathNoise, 0.0, kBig, "m",
                             "amplitude of the noise added to the path (less regular motion)");
    c.turbulenceGrowth = d.getFloat("turbulence_growth", def.turbulenceGrowth, 0.0, kBig, "m",
                                    "path turbulence at growth_height above the base, none at the base (air currents)");
    c.growthHeight = d.getFloat("growth_height", def.growthHeight, 1e-6, kBig, "m",
                                "height over which the path turbulence grows to its full amount");
    c.pathOctaves.count = int(d.getInt("path_octaves", def.pathOctaves.count, 1, 8, "",
                                       "octaves of the path turbulence"));
}

namespace {

double turbulenceMax(const GasCommon& c)
{
    // the table's last entry stands for turbulence 2 and beyond; exact pow reaches the bound
    return c.powerTable ? std::min(2.0, c.octaves.bound()) : c.octaves.bound();
}

/// The largest density the power shaping (s max_density)^exponent can give, times
/// density_scale, for shaped values s up to @a shapeMax. Above a float's range (3.4e38) the grid
/// would hold inf (and the build stop on it); refused before the run, naming the exponent.
void checkDensityRange(ParamDict& d, const GasCommon& c, double shapeMax)
{
    const double turbMax = shapeMax;
    const double peak = c.densityScale * std::pow(turbMax * c.maxDensity, c.exponent);
    if (!(peak <= 1e38))
        d.fail("exponent", "(" + numText(turbMax) + " x max_density " + numText(c.maxDensity) + ")^exponent " +
                               numText(c.exponent) + " x density_scale " + numText(c.densityScale) +
                               " reaches " + numText(peak) +
                               ", beyond a 32-bit float grid (3.4e38): lower exponent, max_density or density_scale");
}

} // namespace

std::unique_ptr<SteamModel> readSteam(ParamDict& d)
{
    GasCommon def;
    def.maxDensity = 0.57;
    def.exponent = 6.0;
    def.noiseScale = 0.02;
    def.densityScale = 40.0;
    def.threshold = 0.01;
    def.riseSpeed = 0.04;
    def.swirlPeriod = 126;
    def.swirlRadius[0] = 0.01;
    def.swirlRadius[1] = 0.008;
    def.pathNoise = 0.004;
    def.turbulenceGrowth = 0.01;
    def.growthHeight = 0.15;
    GasCommon c;
    readCommon(d, c, def);
    checkDensityRange(d, c, turbulenceMax(c));
    auto m = std::make_unique<SteamModel>(c);
    m->center = readPoint(d, "center", {0, 0, 0}, "m", "centre of the liquid surface the steam rises from");
    m->radius = d.getFloat("radius", 0.04, 1e-6, kBig, "m", "cup radius: no steam outside it");
    m->height = d.getFloat("height", 0.2, 1e-6, kBig, "m",
                           "plume height: vertical semi-axis of the slab and length of the vertical ramp-off");
    m->falloffNoise = d.getFloat("falloff_noise", 0.3, 0.0, 10.0, "",
                                 "randomness added to the ramp-offs (Ebert's parms[3]); only shrinks the plume");
    return m;
}

std::unique_ptr<FireModel> readFire(ParamDict& d)
{
    GasCommon def;
    def.maxDensity = 0.9;
    def.exponent = 2.0;
    def.noiseScale = 0.08;
    def.densityScale = 20.0;
    def.threshold = 0.01;
    def.riseSpeed = 0.5;
    def.swirlPeriod = 48;
    def.swirlRadius[0] = 0.02;
    def.swirlRadius[1] = 0.015;
    def.pathNoise = 0.01;
    def.turbulenceGrowth = 0.06;
    def.growthHeight = 0.3;
    GasCommon c;
    readCommon(d, c, def);
    checkDensityRange(d, c, 1.0); // the flame shape lies in [0, 1]
    auto m = std::make_unique<FireModel>(c);
    m->center = readPoint(d, "center", {0, 0, 0}, "m", "centre of the base of the fire");
    m->radius = d.getFloat("radius", 0.15, 1e-6, kBig, "m", "radius of the fire");
    m->height = d.getFloat("height", 0.5, 1e-6, kBig, "m", "height of the fire");
    m->falloffNoise = d.getFloat("falloff_noise", 0.2, 0.0, 10.0, "", "randomness in the ramp-off (parms[3])");
    m->cutoff = d.getFloat("cutoff", 0.0, 0.0, 10.0, "",
                           "shaped density below this is removed (Ebert's parms[4], before density_scale)");
    m->baseHeight = d.getFloat("base_height", 0.25, 0.0, 1.0, "",
                               "fraction of the height holding the continuous base fire (parms[6])");
    m->minDensity = d.getFloat("min_density", 0.05, 0.0, 10.0, "",
                               "minimum shaped density of the base fire (parms[7])");
    m->flameFrequency = d.getFloat("flame_frequency", 3.0, 0.0, 100.0, "",
                                   "sine multiplier of the flames (parms[8]): more, narrower flames");
    return m;
}

namespace {
void readBox(ParamDict& d, SoftBox& b, const V3& lo, const V3& hi, double edge)
{
    b.lo = readPoint(d, "box_min", lo, "m", "minimum corner of the gas box (world)");
    b.hi = readPoint(d, "box_max", hi, "m", "maximum corner of the gas box (world)");
    if (b.hi.x <= b.lo.x || b.hi.y <= b.lo.y || b.hi.z <= b.lo.z)
        d.fail("box_max", "must be greater than box_min on every axis");
    b.edge = d.getFloat("edge", edge, 0.0, kBig, "m", "soft edge: density ramps from 0 at a face to full at this depth");
}
} // namespace

std::unique_ptr<FogModel> readFog(ParamDict& d)
{
    GasCommon def;
    def.maxDensity = 1.0;
    def.exponent = 1.0;
    def.noiseScale = 0.5;
    def.densityScale = 2.0;
    def.threshold = 0.005;
    def.wind = V3(0.2, 0, 0);
    def.swirlPeriod = 240;
    def.swirlRadius[0] = 0.2;
    def.swirlRadius[1] = 0.1;
    def.pathNoise = 0.1;
    def.octaves.count = 4;
    GasCommon c;
    readCommon(d, c, def);
    auto m = std::make_unique<FogModel>(c);
    readBox(d, m->box, {-2, -2, 0}, {2, 2, 0.6}, 0.3);
    m->layerHeight = d.getFloat("layer_height", 0.3, 0.0, kBig, "m",
                                "fog thins with height as exp(-h/layer_height); 0: uniform");
    return m;
}

std::unique_ptr<BasicGasModel> readBasicGas(ParamDict& d)
{
    GasCommon def;
    def.maxDensity = 0.5;
    def.exponent = 2.0;
    def.noiseScale = 0.1;
    def.densityScale = 10.0;
    def.threshold = 0.01;
    def.riseSpeed = 0.05;
    GasCommon c;
    readCommon(d, c, def);
    auto m = std::make_unique<BasicGasModel>(c);
    const std::string shape = d.getString("shape", "power", {"power", "veins", "molten_marble"},
                                          "power: Ebert's basic_gas; veins: sine veins; molten_marble: hypertexture");
    m->shape = shape == "veins" ? BasicGasModel::Shape::Veins
             : shape == "molten_marble" ? BasicGasModel::Shape::MoltenMarble : BasicGasModel::Shape::Power;
    // veins lie in [0, 1]; molten marble is clamped to [0.2, 1] and needs no check
    if (m->shape == BasicGasModel::Shape::Power) checkDensityRange(d, c, turbulenceMax(c));
    if (m->shape == BasicGasModel::Shape::Veins) checkDensityRange(d, c, 1.0);
    readBox(d, m->box, {-0.25, -0.25, 0}, {0.25, 0.25, 0.5}, 0.05);
    auto fr = d.getFloatArray("form_frames", {1.0, 48.0}, {2}, -kBig, kBig, "frame",
                              "molten_marble: [start, end] frames over which the veins form (turbulence added)");
    m->formStart = fr[0];
    m->formEnd = fr[1];
    m->sharpness = d.getFloat("sharpness", 2.0, 0.0, 100.0, "",
                              "molten_marble: Perlin's hard-surface multiplier (parms[3]*parms[8]/640)");
    m->bandFrequency = d.getFloat("band_frequency", 1.0, 0.0, 100.0, "",
                                  "molten_marble: marble bands per noise unit along up");
    return m;
}

std::shared_ptr<SphericalAttractor> readSphericalAttractor(ParamDict& d, bool repulsor)
{
    auto a = std::make_shared<SphericalAttractor>();
    a->repulsor = repulsor;
    const char* what = repulsor ? "repulsor" : "attractor";
    a->center = readPoint(d, "center", {0, 0, 0.2}, "m", std::string("centre of the ") + what + " at frame 0");
    a->centerVelocity = readPoint(d, "center_velocity", {0, 0, 0}, "m/s",
                                  "the centre moves at this velocity (wake of a moving object)");
    a->distance = d.getFloat("distance", 0.5, 1e-6, kBig, "m", "no effect beyond this distance from the centre");
    a->falloffStart = d.getFloat("falloff_start", 0.25, 0.0, kBig, "m",
                                 "full effect inside; cosine falloff from here to distance");
    if (a->falloffStart > a->distance) d.fail("falloff_start", "must not exceed distance");
    a->speed = d.getFloat("speed", 0.1, 0.0, kBig, "m/s", std::string("speed of the gas ") +
                          (repulsor ? "away from" : "toward") + " the centre");
    a->coreRadius = d.getFloat("core_radius", 0.02, 0.0, kBig, "m",
                               "the speed falls linearly to 0 inside this radius (no tearing at the centre)");
    a->angle = readAngle(d, {1, 0, 0});
    a->strength = readStrength(d, 1.0);
    a->shiftAmount = d.getFloat("envelope_shift", 0.0, -kBig, kBig, "m",
                                "steam envelopes bend this far toward the attractor at full strength (Ebert's breeze)");
    auto sh = d.getFloatArray("envelope_heights", {0.0, 0.1}, {2}, 0.0, kBig, "m",
                              "[low, high] heights above the cup: no shift below low, full shift above high");
    a->shiftLow = sh[0];
    a->shiftHigh = sh[1];
    return a;
}

std::shared_ptr<LinearAttractor> readLinearAttractor(ParamDict& d)
{
    auto a = std::make_shared<LinearAttractor>();
    const std::string geom = d.getString("geometry", "line", {"line", "plane"},
                                         "attract toward a line (perpendicular to it) or a plane (along its normal)");
    a->plane = geom == "plane";
    a->center = readPoint(d, "center", {0, 0, 0}, "m", "a point of the line or plane");
    a->direction = readUnit(d, "direction", {1, 0, 0}, "line direction, or plane normal");
    a->distance = d.getFloat("distance", 0.5, 1e-6, kBig, "m", "no effect farther than this from the line/plane");
    a->falloffStart = d.getFloat("falloff_start", 0.2, 0.0, kBig, "m", "full effect inside; cosine falloff to distance");
    if (a->falloffStart > a->distance) d.fail("falloff_start", "must not exceed distance");
    a->alongDistance = d.getFloat("along_distance", 0.0, 0.0, kBig, "m",
                                  "no effect farther than this from center along the line/plane; 0: unlimited");
    a->alongFalloffStart = d.getFloat("along_falloff_start", 0.0, 0.0, kBig, "m",
                                      "full effect within this distance from center along the line/plane");
    a->speed = d.getFloat("speed", 0.1, 0.0, kBig, "m/s", "speed of the gas toward the line/plane");
    a->coreRadius = d.getFloat("core_radius", 0.01, 0.0, kBig, "m", "speed falls to 0 within this distance of the line/plane");
    a->repulsor = d.getBool("repulsor", false, "push away instead of attracting");
    a->angle = readAngle(d, {-1, 0, 0});
    a->strength = readStrength(d, 1.0);
    return a;
}

std::shared_ptr<Vortex> readVortex(ParamDict& d)
{
    auto v = std::make_shared<Vortex>();
    const std::string kind = d.getString("kind", "sims", {"sims", "angular_momentum"},
                                         "sims: omega = rate/(0.1+0.9 r/distance)^exponent; "
                                         "angular_momentum: omega = rate (core/r)^2 outside the core");
    v->kind = kind == "sims" ? Vortex::Kind::Sims : Vortex::Kind::AngularMomentum;
    v->center = readPoint(d, "center", {0, 0, 0.1}, "m", "a point on the vortex axis");
    v->centerVelocity = readPoint(d, "center_velocity", {0, 0, 0}, "m/s", "the vortex moves at this velocity");
    v->axis = readUnit(d, "axis", {0, 0, 1}, "vortex axis (counter-clockwise about it for a positive rate)");
    v->distance = d.getFloat("distance", 0.3, 1e-6, kBig, "m", "no effect beyond this distance from the centre");
    v->falloffStart = d.getFloat("falloff_start", 0.15, 0.0, kBig, "m", "full effect inside; cosine falloff to distance");
    if (v->falloffStart > v->distance) d.fail("falloff_start", "must not exceed distance");
    v->rate = d.getFloat("rate", 2.0, -kBig, kBig, "rad/s", "angular speed (at the axis for sims, in the core for angular_momentum)");
    v->exponent = d.getFloat("exponent", 1.0, 0.0, 10.0, "", "sims: falloff exponent of the angular speed with distance");
    v->coreRadius = d.getFloat("core_radius", 0.03, 0.0, kBig, "m", "angular_momentum: radius of the solid-body core");
    v->axialSpeed = d.getFloat("axial_speed", 0.0, -kBig, kBig, "m/s", "drift along the axis");
    v->strength = readStrength(d, 1.0);
    return v;
}

VectorFieldSettings readVectorField(ParamDict& d)
{
    VectorFieldSettings s;
    s.file = d.getString("file", "", {}, "a .vdb file holding the velocity table (a vector grid)");
    s.grid = d.getString("grid", "vel", {}, "name of the vector grid in the file");
    s.scale = d.getFloat("scale", 1.0, -kBig, kBig, "", "multiplier of the table's velocities");
    s.percent = d.getFloat("percent", 1.0, 0.0, 1.0, "", "percent to use inside the table");
    s.edge = d.getFloat("edge", 0.0, 0.0, kBig, "m", "cosine falloff of the percent toward the table's faces");
    s.strength = readStrength(d, 1.0);
    return s;
}

} // namespace frostvdb::gas
