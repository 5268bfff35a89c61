#pragma once
/// @file Flow.h
/// @brief Ebert's flow-field functions (Texturing & Modeling 4.6): the gas is animated by
/// moving each voxel's point through the turbulence space along a path, x_solid = x - D(x, t),
/// where D is the visual displacement of the gas (a downward path in the solid space shows the
/// gas rising). The default path is a helix (HelicalPath); flow functions return their own
/// displacement and a "percent to use" with a cosine falloff, and are blended in turn:
/// @code
///   D = helix(t);  for each flow f:  D = lerp(D, f.displacement(x, t), f.percent(x, t));
/// @endcode
/// Attractors, repulsors and the vortex are infinite-detail functions; VectorFieldTable reads
/// a VDB `vel` grid with trilinear lookup (in VectorFieldTable.cpp, the only OpenVDB part).
#include <frostvdb/gas/Shaping.h>

#include <memory>
#include <string>
#include <vector>

namespace frostvdb::gas {

/// Animated strength (Ebert's ratio_mult): min before the first ramp frame, linear to max at
/// the last, max after.
struct StrengthRamp {
    double minStrength = 0.0, maxStrength = 1.0;
    double startFrame = 0.0, endFrame = 0.0;
    double operator()(double frame) const
    {
        if (endFrame <= startFrame) return frame < startFrame ? minStrength : maxStrength;
        if (frame <= startFrame) return minStrength;
        if (frame >= endFrame) return maxStrength;
        return minStrength + (maxStrength - minStrength) * (frame - startFrame) / (endFrame - startFrame);
    }
};

/// Radial cosine falloff used by every flow function (Ebert's percent_to_use): 1 inside
/// @a falloffStart, (cos(pi (d - start)/(distance - start)) + 1)/2 up to @a distance, 0 beyond.
inline double flowFalloff(double d, double falloffStart, double distance)
{
    if (d > distance) return 0.0;
    if (d <= falloffStart) return 1.0;
    return cosineRamp((d - falloffStart) / (distance - falloffStart));
}

/// Angle limit like a spot light: 1 within (half-angle - edge) of the axis, cosine to 0 at the
/// half-angle; a half-angle >= 180 degrees means no limit.
struct AngleLimit {
    V3 axis{1, 0, 0};
    double halfAngleDeg = 180.0;
    double edgeDeg = 10.0;
    double operator()(const V3& dir) const // dir: unit vector from the centre to the point
    {
        if (halfAngleDeg >= 180.0) return 1.0;
        const double c = std::clamp(dot(dir, axis), -1.0, 1.0);
        const double ang = std::acos(c) * (180.0 / kPi);
        if (ang >= halfAngleDeg) return 0.0;
        const double inner = halfAngleDeg - edgeDeg;
        if (ang <= inner || edgeDeg <= 0) return 1.0;
        return cosineRamp((ang - inner) / edgeDeg);
    }
};

/// One evaluation time: the frame (fractional for the motion-vector difference) and seconds.
struct FlowTime {
    double frame = 0.0;
    double seconds = 0.0;
};

class FlowFunction {
public:
    virtual ~FlowFunction() = default;
    /// Blending weight in [0, 1] at @a x (falloff x angle limit x animated strength).
    virtual double percent(const V3& x, const FlowTime& t) const = 0;
    /// The displacement this function alone gives the gas at @a x by time @a t.
    virtual V3 displacement(const V3& x, const FlowTime& t) const = 0;
    /// D = lerp(D, displacement, percent).
    void blend(const V3& x, const FlowTime& t, V3& D) const
    {
        const double p = percent(x, t);
        if (p <= 0) return;
        D = lerp(D, displacement(x, t), p);
    }
    /// Horizontal shift of a gas envelope at @a height above its base (Ebert's breeze, Fig. 8);
    /// zero for functions that do not move envelopes.
    virtual V3 envelopeShift(const V3& base, const V3& up, double height, const FlowTime& t) const
    { return {}; }
    /// Largest envelope shift (m) this function can produce, for bounding boxes.
    virtual double maxEnvelopeShift() const { return 0.0; }
};

/// Spherical attractor (or repulsor): the gas streams toward (away from) a centre that may move,
/// within an optional cone, with animated strength. Ebert: paths radially away from the centre
/// in the solid space, i.e. visual motion toward it.
class SphericalAttractor : public FlowFunction {
public:
    V3 center{0, 0, 0};
    V3 centerVelocity{0, 0, 0}; ///< m/s: a moving attractor (wake of a moving object)
    double distance = 1.0;      ///< m, no effect beyond
    double falloffStart = 0.5;  ///< m, full effect inside
    double speed = 0.1;         ///< m/s of the gas along the attraction
    double coreRadius = 0.0;    ///< m, speed scales down linearly inside (no tearing at the centre)
    bool repulsor = false;
    AngleLimit angle;
    StrengthRamp strength;
    // Envelope shift (the breeze of Ebert's Fig. 8): shift = (1 - d2) strength(frame) * maxShift,
    // d2 a cosine ramp from 1 at shiftHeights[0] to 0 at shiftHeights[1].
    double shiftAmount = 0.0;
    double shiftLow = 0.0, shiftHigh = 1.0;

    V3 centerAt(const FlowTime& t) const { return center + centerVelocity * t.seconds; }

    double percent(const V3& x, const FlowTime& t) const override
    {
        const V3 r = x - centerAt(t);
        const double d = length(r);
        const double f = flowFalloff(d, falloffStart, distance);
        if (f <= 0) return 0.0;
        const double a = d > 0 ? angle(r / d) : 1.0;
        return f * a * std::clamp(strength(t.frame), 0.0, 1.0);
    }
    V3 displacement(const V3& x, const FlowTime& t) const override
    {
        const V3 r = x - centerAt(t);
        const double d = length(r);
        if (d <= 0) return {};
        const double s = coreRadius > 0 && d < coreRadius ? d / coreRadius : 1.0;
        const V3 dir = repulsor ? r / d : -(r / d);
        return dir * (speed * s * t.seconds);
    }
    V3 envelopeShift(const V3& base, const V3& up, double height, const FlowTime& t) const override
    {
        if (shiftAmount == 0 || height <= shiftLow) return {};
        double d2 = 0;
        if (height <= shiftHigh && shiftHigh > shiftLow)
            d2 = cosineRamp((height - shiftLow) / (shiftHigh - shiftLow)) ; // 1 -> 0
        const V3 toward = centerAt(t) - base;
        V3 h = toward - up * dot(toward, up);
        h = normalize(h);
        if (repulsor) h = -h;
        return h * ((1.0 - d2) * std::clamp(strength(t.frame), 0.0, 1.0) * shiftAmount);
    }
    double maxEnvelopeShift() const override { return std::fabs(shiftAmount); }
};

/// Linear (line) or planar attractor: the gas streams toward a line (perpendicular to it) or a
/// plane (along its normal). Ebert's flow along a wall into a hole. The falloff is by distance
/// from the line/plane; an optional second falloff along the line/plane from the centre
/// (alongFalloffStart, alongDistance) keeps the effect near the wall.
class LinearAttractor : public FlowFunction {
public:
    bool plane = false;
    V3 center{0, 0, 0};
    V3 direction{1, 0, 0}; ///< line direction, or plane normal (unit)
    double distance = 1.0, falloffStart = 0.5;
    double alongFalloffStart = 0.0, alongDistance = 0.0; ///< 0: unlimited along
    double speed = 0.1;
    double coreRadius = 0.0;
    bool repulsor = false;
    AngleLimit angle;
    StrengthRamp strength;

    /// Vector from the point to its closest point on the line/plane, and the along-distance.
    void geometry(const V3& x, V3& toClosest, double& along) const
    {
        const V3 r = x - center;
        if (plane) {
            const double n = dot(r, direction);
            toClosest = -(direction * n);
            along = length(r - direction * n);
        } else {
            along = dot(r, direction);
            toClosest = -(r - direction * along);
            along = std::fabs(along);
        }
    }
    double percent(const V3& x, const FlowTime& t) const override
    {
        V3 tc;
        double along;
        geometry(x, tc, along);
        const double d = length(tc);
        double f = flowFalloff(d, falloffStart, distance);
        if (f <= 0) return 0.0;
        if (alongDistance > 0) f *= flowFalloff(along, alongFalloffStart, alongDistance);
        const V3 r = x - center;
        const double rl = length(r);
        if (rl > 0) f *= angle(r / rl);
        return f * std::clamp(strength(t.frame), 0.0, 1.0);
    }
    V3 displacement(const V3& x, const FlowTime& t) const override
    {
        V3 tc;
        double along;
        geometry(x, tc, along);
        const double d = length(tc);
        if (d <= 0) return {};
        const double s = coreRadius > 0 && d < coreRadius ? d / coreRadius : 1.0;
        const V3 dir = repulsor ? -(tc / d) : tc / d;
        return dir * (speed * s * t.seconds);
    }
};

/// Spiral vortex about an axis through a centre. The gas turns by theta = omega(rho) t about the
/// axis (rho: distance from the axis) and drifts along it:
///   Sims:              omega = rate / (0.1 + 0.9 rho/distance)^exponent
///   angular momentum:  omega = rate (core/max(rho, core))^2   (v rho = const outside the core)
/// D = perp (1 - cos theta) + (axis x perp) sin theta + axialSpeed t axis; counter-clockwise
/// about the axis for a positive rate. Falloff by the distance from the centre (Ebert).
class Vortex : public FlowFunction {
public:
    enum class Kind { Sims, AngularMomentum };
    Kind kind = Kind::Sims;
    V3 center{0, 0, 0};
    V3 centerVelocity{0, 0, 0};
    V3 axis{0, 0, 1};
    double distance = 1.0, falloffStart = 0.5;
    double rate = 1.0;       ///< rad/s
    double exponent = 1.0;   ///< Sims falloff exponent
    double coreRadius = 0.05;///< m (angular-momentum variant)
    double axialSpeed = 0.0; ///< m/s along the axis
    StrengthRamp strength;

    V3 centerAt(const FlowTime& t) const { return center + centerVelocity * t.seconds; }
    double angularSpeed(double rho) const
    {
        if (kind == Kind::Sims) return rate / std::pow(0.1 + 0.9 * rho / distance, exponent);
        const double r = std::max(rho, coreRadius);
        return coreRadius > 0 ? rate * (coreRadius / r) * (coreRadius / r) : rate;
    }
    double percent(const V3& x, const FlowTime& t) const override
    {
        const double d = length(x - centerAt(t));
        return flowFalloff(d, falloffStart, distance) * std::clamp(strength(t.frame), 0.0, 1.0);
    }
    V3 displacement(const V3& x, const FlowTime& t) const override
    {
        const V3 r = x - centerAt(t);
        const V3 perp = r - axis * dot(r, axis);
        const double rho = length(perp);
        const double theta = angularSpeed(rho) * t.seconds;
        return perp * (1.0 - std::cos(theta)) + cross(axis, perp) * std::sin(theta) +
               axis * (axialSpeed * t.seconds);
    }
};

/// A 3D vector-field table (Ebert 4.6.1-4.6.2): velocities stored on a lattice (a VDB `vel`
/// grid), trilinearly interpolated; D = scale * v(x) * t, percent constant inside the table's
/// active bounding box with a cosine falloff over @a edge metres toward its faces.
class VectorFieldTable : public FlowFunction {
public:
    /// Reads @a gridName (a Vec3 float/double grid) from a .vdb file; throws on failure.
    static std::shared_ptr<VectorFieldTable> load(const std::string& path, const std::string& gridName);
    /// Builds a table from values on a regular lattice: origin (world position of entry 0),
    /// spacing (m), dims, and values x-fastest.
    static std::shared_ptr<VectorFieldTable> fromLattice(const V3& origin, double spacing, int nx,
                                                         int ny, int nz, const std::vector<V3>& values);
    ~VectorFieldTable() override;

    double scale = 1.0, maxPercent = 1.0, edge = 0.0;
    StrengthRamp strength;

    /// Trilinear lookup of the stored velocity (m/s) at a world position (zero outside).
    V3 sample(const V3& x) const;
    /// The largest stored speed (m/s); load() refuses tables holding a non-finite value.
    double maxSpeed() const;
    double percent(const V3& x, const FlowTime& t) const override;
    V3 displacement(const V3& x, const FlowTime& t) const override
    {
        return sample(x) * (scale * t.seconds);
    }

    struct Impl; ///< OpenVDB grid and its world bounds (VectorFieldTable.cpp)

private:
    VectorFieldTable();
    std::unique_ptr<Impl> mImpl;
};

/// A set of flows applied in a fixed order (attractor, repulsor, linear, vortex, table).
using FlowList = std::vector<std::shared_ptr<const FlowFunction>>;

} // namespace frostvdb::gas
