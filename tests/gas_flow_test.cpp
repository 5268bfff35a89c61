// Flow functions: attractor, repulsor, linear attractor, vortex and vector-field table:
// directions and falloff at sample points.
#include <frostvdb/gas/Flow.h>
#include <frostvdb/gas/GasModels.h>

#include <catch2/catch.hpp>

#include <cmath>

using namespace frostvdb::gas;

namespace {
FlowTime at(double frame, double fps = 24) { return {frame, frame / fps}; }
V3 unit(const V3& v) { return normalize(v); }
} // namespace

TEST_CASE("Spherical attractor pulls toward its centre with a cosine falloff", "[fast][gas]")
{
    SphericalAttractor a;
    a.center = V3(1, 2, 3);
    a.distance = 1.0;
    a.falloffStart = 0.4;
    a.speed = 0.5;
    a.coreRadius = 0.0;
    const V3 x = a.center + V3(0.3, 0, 0);
    const V3 D = a.displacement(x, at(24));  // one second
    CHECK(D.x == Approx(-0.5));
    CHECK(D.y == Approx(0).margin(1e-12));
    // falloff: 1 inside start, 0.5 half way, 0 beyond distance
    CHECK(a.percent(a.center + V3(0, 0.39, 0), at(10)) == Approx(1.0));
    CHECK(a.percent(a.center + V3(0, 0, 0.7), at(10)) == Approx(0.5));
    CHECK(a.percent(a.center + V3(1.01, 0, 0), at(10)) == 0.0);
    // blend: with percent 0.5 the path is half way between default and attractor paths
    V3 Dd(0, 0, 1);
    const V3 y = a.center + V3(0, 0, 0.7);
    a.blend(y, at(24), Dd);
    CHECK(Dd.z == Approx(0.5 * 1 + 0.5 * -0.5));
    // repulsor: away
    SphericalAttractor r = a;
    r.repulsor = true;
    CHECK(r.displacement(x, at(24)).x == Approx(0.5));
}

TEST_CASE("Attractor strength animates and the angle limit cuts a cone", "[fast][gas]")
{
    SphericalAttractor a;
    a.distance = 2;
    a.falloffStart = 1;
    a.strength.minStrength = 0.1;
    a.strength.maxStrength = 0.3;
    a.strength.startFrame = 10;
    a.strength.endFrame = 30;
    const V3 x(0.5, 0, 0);
    CHECK(a.percent(x, at(0)) == Approx(0.1));
    CHECK(a.percent(x, at(20)) == Approx(0.2));
    CHECK(a.percent(x, at(50)) == Approx(0.3));
    a.angle.axis = V3(-1, 0, 0);
    a.angle.halfAngleDeg = 90;
    a.angle.edgeDeg = 10;
    CHECK(a.percent(V3(-0.5, 0, 0), at(50)) == Approx(0.3));     // inside the half-space
    CHECK(a.percent(V3(0.5, 0, 0), at(50)) == 0.0);              // behind: no effect
    CHECK(a.percent(unit(V3(-std::cos(85 * kPi / 180), std::sin(85 * kPi / 180), 0)) * 0.5, at(50)) ==
          Approx(0.3 * 0.5));                                        // middle of the soft edge
    // a moving attractor
    a.centerVelocity = V3(0, 1, 0);
    CHECK(a.centerAt(at(48)).y == Approx(2.0));
}

TEST_CASE("Envelope shift bends steam toward the attractor above its low height", "[fast][gas]")
{
    SphericalAttractor a;
    a.center = V3(1, 0, 0.3);
    a.shiftAmount = 0.05;
    a.shiftLow = 0.02;
    a.shiftHigh = 0.1;
    a.strength.maxStrength = 0.3;
    const V3 up(0, 0, 1), base(0, 0, 0);
    CHECK(length(a.envelopeShift(base, up, 0.01, at(5))) == 0.0);
    const V3 s = a.envelopeShift(base, up, 0.2, at(5));
    CHECK(s.x == Approx(0.3 * 0.05));
    CHECK(s.z == Approx(0).margin(1e-12));
    CHECK(a.envelopeShift(base, up, 0.06, at(5)).x == Approx(0.5 * 0.3 * 0.05));
}

TEST_CASE("Linear and planar attractors pull perpendicular to the line or plane", "[fast][gas]")
{
    LinearAttractor l;
    l.center = V3(0, 0, 0);
    l.direction = V3(1, 0, 0);
    l.distance = 1;
    l.falloffStart = 0.5;
    l.speed = 1;
    l.coreRadius = 0;
    const V3 D = l.displacement(V3(3, 0.2, 0), at(24));
    CHECK(D.x == Approx(0).margin(1e-12));
    CHECK(D.y == Approx(-1.0));
    CHECK(l.percent(V3(3, 0.2, 0), at(1)) == Approx(1.0));
    CHECK(l.percent(V3(3, 0.75, 0), at(1)) == Approx(0.5));
    l.alongDistance = 2;
    l.alongFalloffStart = 1;
    CHECK(l.percent(V3(1.5, 0.2, 0), at(1)) == Approx(0.5));
    CHECK(l.percent(V3(3, 0.2, 0), at(1)) == 0.0);
    LinearAttractor p;
    p.plane = true;
    p.direction = V3(0, 0, 1);
    p.coreRadius = 0;
    p.speed = 1;
    CHECK(p.displacement(V3(5, 5, 0.3), at(24)).z == Approx(-1.0));
    CHECK(p.displacement(V3(5, 5, -0.3), at(24)).z == Approx(1.0));
}

TEST_CASE("Vortices turn the gas counter-clockwise about the axis and fall off", "[fast][gas]")
{
    Vortex v;
    v.center = V3(0, 0, 0);
    v.axis = V3(0, 0, 1);
    v.distance = 1.0;
    v.falloffStart = 0.5;
    v.rate = 0.1;
    v.exponent = 1.0;
    const V3 x(0.4, 0, 0);
    const V3 D = v.displacement(x, at(1));  // small angle: D ~ theta (axis x r)
    CHECK(D.y > 0);
    CHECK(std::fabs(D.x) < 0.01 * D.y);  // (1 - cos t) r vs sin t r
    const double omega = 0.1 / (0.1 + 0.9 * 0.4);
    CHECK(length(D) == Approx(2 * 0.4 * std::sin(omega / 24 / 2)).epsilon(1e-9));
    // inner points turn faster (Sims)
    CHECK(v.angularSpeed(0.1) > v.angularSpeed(0.8));
    CHECK(v.percent(V3(0.3, 0, 0), at(1)) == Approx(1.0));
    CHECK(v.percent(V3(0.75, 0, 0), at(1)) == Approx(0.5));
    CHECK(v.percent(V3(1.5, 0, 0), at(1)) == 0.0);
    // angular momentum: omega r^2 constant outside the core
    Vortex m = v;
    m.kind = Vortex::Kind::AngularMomentum;
    m.coreRadius = 0.1;
    CHECK(m.angularSpeed(0.2) * 0.04 == Approx(m.angularSpeed(0.4) * 0.16));
    CHECK(m.angularSpeed(0.05) == Approx(m.rate));
    // negative rate turns clockwise; axial drift along the axis
    m.rate = -1;
    m.axialSpeed = 0.2;
    const V3 Dm = m.displacement(V3(0.3, 0, 0), at(2));
    CHECK(Dm.y < 0);
    CHECK(Dm.z == Approx(0.2 * 2 / 24.0));
}

TEST_CASE("Vector-field table interpolates trilinearly", "[fast][gas]")
{
    // v = (x, 2y, 0) on a 4^3 lattice of spacing 0.5 from the origin: linear, so trilinear is exact
    std::vector<V3> vals;
    for (int k = 0; k < 4; ++k)
        for (int j = 0; j < 4; ++j)
            for (int i = 0; i < 4; ++i) vals.emplace_back(i * 0.5, 2 * j * 0.5, 0);
    auto t = VectorFieldTable::fromLattice(V3(0, 0, 0), 0.5, 4, 4, 4, vals);
    const V3 s = t->sample(V3(0.6, 0.8, 0.3));
    CHECK(s.x == Approx(0.6));
    CHECK(s.y == Approx(1.6));
    t->scale = 2.0;
    CHECK(t->displacement(V3(0.6, 0.8, 0.3), at(48)).x == Approx(0.6 * 2 * 2));
    CHECK(t->percent(V3(0.6, 0.8, 0.3), at(1)) == Approx(1.0));
    CHECK(t->percent(V3(5, 0.8, 0.3), at(1)) == 0.0);
}
