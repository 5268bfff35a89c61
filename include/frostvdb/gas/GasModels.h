#pragma once
/// @file GasModels.h
/// @brief The procedural gases of Ebert's chapter 4 as pure functions of (world point, frame):
/// steam over a cup, fog, fire and the basic gas (power, veins, molten marble). No OpenVDB here;
/// GasGrid.h turns a model into sparse grids.
///
/// Every model evaluates density(x) = shape(x) * f(turbulence(solid(x, t))) where
///   solid(x, t) = (x - D(x, t) - W(x)) / noise_scale + noise_offset,
///   D(x, t)     = the helical default path (swirl, rise, wind) blended with the scene's flow
///                 functions (Flow.h),
///   W(x)        = the static path noise and the turbulence that grows with height (Ebert 4.6).
/// The motion vector of the gas is dD/dt (central difference over a quarter frame).
#include <frostvdb/gas/Flow.h>
#include <frostvdb/gas/Noise.h>
#include <frostvdb/gas/Shaping.h>

#include <cstdint>
#include <memory>
#include <string>

namespace frostvdb {
class ParamDict;
}

namespace frostvdb::gas {

/// Settings every gas section shares (noise, shaping, path, output).
struct GasCommon {
    double fps = 24.0;
    uint64_t seed = 1;
    double noiseScale = 0.03; ///< m: size of the largest turbulence feature
    Octaves octaves{5, 2.0, 0.5};
    V3 noiseOffset{0, 0, 0};
    double maxDensity = 0.57;
    double exponent = 6.0;
    bool powerTable = true;
    double densityScale = 1.0;
    double threshold = 1e-3;
    bool velocity = true;
    V3 up{0, 0, 1};
    // default path (helix)
    double riseSpeed = 0.0;       ///< m/s along up (Ebert's downward path in solid space)
    V3 wind{0, 0, 0};             ///< m/s
    double swirlPeriod = 0.0;     ///< frames per turn, 0 = no swirl
    double swirlRadius[2] = {0, 0}; ///< m, the two radii of the elliptical swirl
    double pathNoise = 0.0;       ///< m, noise added to the path
    double turbulenceGrowth = 0.0;///< m of path turbulence at growthHeight above the base
    double growthHeight = 0.1;    ///< m
    Octaves pathOctaves{2, 2.0, 0.5};
};

/// What one voxel evaluation produces.
struct GasSample {
    double density = 0;
    double flame = 0;   ///< fire only, [0, 1]
    V3 colour{0, 0, 0}; ///< fire only
};

/// A frame's evaluation context: the time and the flows of the scene.
struct GasContext {
    FlowTime time;
    const FlowList* flows = nullptr;
    static GasContext at(double frame, double fps, const FlowList* flows)
    {
        GasContext c;
        c.time.frame = frame;
        c.time.seconds = frame / fps;
        c.flows = flows;
        return c;
    }
};

class GasModel {
public:
    explicit GasModel(const GasCommon& common);
    virtual ~GasModel() = default;

    const GasCommon& common() const { return mC; }
    virtual const char* kind() const = 0;
    virtual bool isFire() const { return false; }

    /// World-space box that can hold gas at this time.
    virtual void bounds(const GasContext& ctx, V3& lo, V3& hi) const = 0;
    /// Conservative test: false only if no point of the sphere (centre, radius) holds gas.
    virtual bool mayHold(const V3& centre, double radius, const GasContext& ctx) const = 0;
    /// Density (after shaping and density_scale, before the threshold) and fire extras.
    virtual void evaluate(const V3& x, const GasContext& ctx, GasSample& out) const = 0;
    double density(const V3& x, const GasContext& ctx) const
    {
        GasSample s;
        evaluate(x, ctx, s);
        return s.density;
    }

    /// Height of @a x above the model's base (for turbulence growth).
    virtual double heightAboveBase(const V3& x) const = 0;

    /// The dynamic displacement D(x, t): helix blended with the flows.
    V3 displacement(const V3& x, const GasContext& ctx) const;
    V3 displacementAt(const V3& x, const FlowTime& t, const FlowList* flows) const;
    /// The static warp W(x): path noise and turbulence growing with height.
    V3 staticWarp(const V3& x) const;
    /// The point in the turbulence (solid) space.
    V3 solidPoint(const V3& x, const GasContext& ctx) const;
    /// Motion vector of the gas (m/s): dD/dt by central difference over a quarter frame.
    V3 velocity(const V3& x, const GasContext& ctx) const;

    const GradientNoise& noise() const { return mNoise; }

protected:
    /// Horizontal basis perpendicular to up.
    V3 mE1, mE2;
    GasCommon mC;
    GradientNoise mNoise;
    PowerTable mPower;
};

/// Steam rising from a cup (Ebert 4.3.2, Figs. 6-7, animated 4.6): a slab over the liquid
/// surface, spherical cosine ramp-off from 25% of the radius with a noise offset, exponential
/// vertical ramp-off, envelope bent by the flows' envelope shift (breeze, Fig. 8).
class SteamModel : public GasModel {
public:
    SteamModel(const GasCommon& c) : GasModel(c) {}
    V3 center{0, 0, 0};       ///< centre of the liquid surface (m)
    double radius = 0.04;     ///< m, cup (inner) radius: no steam outside it
    double height = 0.2;      ///< m, plume height (vertical semi-axis and ramp length)
    double falloffNoise = 0.3;///< Ebert's parms[3]: randomness in the ramp-off (>= 0)

    const char* kind() const override { return "steam"; }
    void bounds(const GasContext& ctx, V3& lo, V3& hi) const override;
    bool mayHold(const V3& c, double r, const GasContext& ctx) const override;
    void evaluate(const V3& x, const GasContext& ctx, GasSample& out) const override;
    double heightAboveBase(const V3& x) const override { return dot(x - center, mC.up); }
    /// The envelope factor alone (spherical x vertical ramp-off) at x; 0 outside the cup radius.
    double envelope(const V3& x, const GasContext& ctx) const;
    double maxShift(const GasContext& ctx) const;
    V3 shiftAt(double h, const GasContext& ctx) const;
};

/// Fire (Ebert 4.7.2): a base of near-constant fire below base_height, several sine flames above
/// it shaped by turbulence, spherical and vertical ramp-off, density threshold, colour from
/// density (dense red to thin yellow).
class FireModel : public GasModel {
public:
    FireModel(const GasCommon& c) : GasModel(c) {}
    V3 center{0, 0, 0};    ///< centre of the fire's base (m)
    double radius = 0.1;   ///< m
    double height = 0.3;   ///< m
    double falloffNoise = 0.2;
    double cutoff = 0.0;      ///< Ebert's parms[4]: shaped density below this is 0
    double baseHeight = 0.25; ///< fraction of the height with a continuous base fire
    double minDensity = 0.05; ///< Ebert's parms[7]: minimum (shaped) density of the base fire
    double flameFrequency = 3.0; ///< Ebert's parms[8]: sine multiplier (flames per noise unit)

    const char* kind() const override { return "fire"; }
    bool isFire() const override { return true; }
    void bounds(const GasContext& ctx, V3& lo, V3& hi) const override;
    bool mayHold(const V3& c, double r, const GasContext& ctx) const override;
    void evaluate(const V3& x, const GasContext& ctx, GasSample& out) const override;
    double heightAboveBase(const V3& x) const override { return dot(x - center, mC.up); }
};

/// A box of gas with soft edges (shared by fog and the basic gas).
struct SoftBox {
    V3 lo{-0.5, -0.5, 0}, hi{0.5, 0.5, 0.5};
    double edge = 0.05; ///< m: density ramps from 0 at a face to full at this depth
    double factor(const V3& x) const;
    bool mayHold(const V3& c, double r) const;
};

/// Solid-textured-transparency fog (Ebert 4.5.1, Fig. 2): opacity 1 - (1 - 0.275 t^2)^3 of the
/// turbulence t, moved along a (horizontal) helical path, in a box with soft edges and an
/// optional exponential layer profile.
class FogModel : public GasModel {
public:
    FogModel(const GasCommon& c) : GasModel(c) {}
    SoftBox box;
    double layerHeight = 0.0; ///< m, density *= exp(-height/layer_height); 0: uniform

    const char* kind() const override { return "fog"; }
    void bounds(const GasContext& ctx, V3& lo, V3& hi) const override { lo = box.lo; hi = box.hi; }
    bool mayHold(const V3& c, double r, const GasContext& ctx) const override { return box.mayHold(c, r); }
    void evaluate(const V3& x, const GasContext& ctx, GasSample& out) const override;
    double heightAboveBase(const V3& x) const override { return dot(x - box.lo, mC.up); }
};

/// Ebert's basic gas (4.3.1): power shaping, the sine veins, or the molten-marble hypertexture
/// (4.7.1, the solid space changing over time as the marble forms), in a soft box.
class BasicGasModel : public GasModel {
public:
    enum class Shape { Power, Veins, MoltenMarble };
    BasicGasModel(const GasCommon& c) : GasModel(c) {}
    Shape shape = Shape::Power;
    SoftBox box;
    // molten marble
    double formStart = 1, formEnd = 48; ///< frames over which turbulence is added
    double sharpness = 2.0;             ///< Perlin's hard-surface trick multiplier
    double bandFrequency = 1.0;         ///< marble bands per noise unit along up

    const char* kind() const override { return "gas"; }
    void bounds(const GasContext& ctx, V3& lo, V3& hi) const override { lo = box.lo; hi = box.hi; }
    bool mayHold(const V3& c, double r, const GasContext& ctx) const override { return box.mayHold(c, r); }
    void evaluate(const V3& x, const GasContext& ctx, GasSample& out) const override;
    double heightAboveBase(const V3& x) const override { return dot(x - box.lo, mC.up); }
};

/// Parameter readers (the schema of the scene sections; see docs/gas.md).
void readCommon(ParamDict& d, GasCommon& c, const GasCommon& defaults, bool pathKeys = true);
std::unique_ptr<SteamModel> readSteam(ParamDict& d);
std::unique_ptr<FireModel> readFire(ParamDict& d);
std::unique_ptr<FogModel> readFog(ParamDict& d);
std::unique_ptr<BasicGasModel> readBasicGas(ParamDict& d);

std::shared_ptr<SphericalAttractor> readSphericalAttractor(ParamDict& d, bool repulsor);
std::shared_ptr<LinearAttractor> readLinearAttractor(ParamDict& d);
std::shared_ptr<Vortex> readVortex(ParamDict& d);
/// The [vector_field] keys; the file itself is loaded at initialisation (VectorFieldTable::load).
struct VectorFieldSettings {
    std::string file, grid = "vel";
    double scale = 1.0, percent = 1.0, edge = 0.0;
    StrengthRamp strength;
    void applyTo(VectorFieldTable& t) const
    {
        t.scale = scale;
        t.maxPercent = percent;
        t.edge = edge;
        t.strength = strength;
    }
};
VectorFieldSettings readVectorField(ParamDict& d);

} // namespace frostvdb::gas
