// Finite-difference operators of the lattices against analytic fields.
#include <frostvdb/core/Lattice.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <functional>

using namespace frostvdb;

namespace {

/// Applies a stencil's Laplacian and gradient at lattice cell (0,0[,0]) to a field given in the
/// lattice's plane coordinates scaled by h.
struct Applied {
    double lap = 0, gx = 0, gy = 0, gz = 0;
};

Applied apply(const Lattice& lat, bool withZ, const std::function<double(double, double, double)>& f)
{
    const Stencil s = lat.stencil(withZ);
    const double h = lat.spacing();
    const double f0 = f(0, 0, 0);
    Applied a;
    for (const auto& t : s.taps) {
        const auto q = lat.planePosition(t.offset.x(), t.offset.y());
        const double fk = f(q.x() * h, q.y() * h, t.offset.z() * h);
        a.lap += t.wLap * (fk - f0);
        a.gx += t.wGrad * t.ex * (fk - f0);
        a.gy += t.wGrad * t.ey * (fk - f0);
        a.gz += t.wGrad * t.ez * (fk - f0);
    }
    return a;
}

} // namespace

TEST_CASE("Laplacian and gradient are exact on quadratics on every lattice", "[fast][operators]")
{
    // f = 3 + 2x - y + 0.5 z + 1.5 x^2 + 0.75 y^2 + 0.25 z^2 (+ xy on planes): lap = 3 + 1.5 (+ 0.5),
    // grad at 0 = (2, -1, 0.5).
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        for (bool withZ : {false, true}) {
            if (withZ && kind == LatticeKind::Hexagonal) continue;
            for (double h : {1.0, 0.1, 3.0 / 64.0}) {
                Lattice lat(kind, h);
                auto f = [&](double x, double y, double z) {
                    return 3 + 2 * x - y + 0.5 * z + 1.5 * x * x + 0.75 * y * y + 0.25 * z * z + (withZ ? 0 : x * y);
                };
                const Applied a = apply(lat, withZ, f);
                INFO(Lattice::kindName(kind) << (withZ ? " 3D" : " 2D") << " h=" << h);
                CHECK(a.lap == Approx(3.0 + 1.5 + (withZ ? 0.5 : 0.0)).epsilon(1e-9));
                CHECK(a.gx == Approx(2.0).epsilon(1e-9));
                CHECK(a.gy == Approx(-1.0).epsilon(1e-9));
                if (withZ) CHECK(a.gz == Approx(0.5).epsilon(1e-9));
            }
        }
    }
}

TEST_CASE("Laplacian and gradient converge at second order on a smooth field", "[fast][operators]")
{
    // f = sin(1.3x + 0.4) cos(0.7y - 0.2) exp(0.3 z): compare at the origin while halving h.
    auto f = [](double x, double y, double z) { return std::sin(1.3 * x + 0.4) * std::cos(0.7 * y - 0.2) * std::exp(0.3 * z); };
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        for (bool withZ : {false, true}) {
            if (withZ && kind == LatticeKind::Hexagonal) continue;
            const double lapExact = (-1.69 - 0.49 + (withZ ? 0.09 : 0.0)) * f(0, 0, 0);
            const double gxExact = 1.3 * std::cos(0.4) * std::cos(-0.2);
            const double gyExact = -0.7 * std::sin(0.4) * std::sin(-0.2);
            double prevLap = 0, prevGx = 0, prevGy = 0;
            for (int level = 0; level < 5; ++level) {
                const double h = 0.2 / std::pow(2.0, level);
                const Applied a = apply(Lattice(kind, h), withZ, f);
                const double eLap = std::fabs(a.lap - lapExact), eGx = std::fabs(a.gx - gxExact),
                             eGy = std::fabs(a.gy - gyExact);
                if (level > 0) {
                    const double oLap = std::log2(prevLap / eLap), oGx = std::log2(prevGx / eGx),
                                 oGy = std::log2(prevGy / eGy);
                    INFO(Lattice::kindName(kind) << (withZ ? " 3D" : " 2D") << " h=" << h << " observed orders lap "
                                                 << oLap << " gx " << oGx << " gy " << oGy);
                    CHECK(oLap == Approx(2.0).margin(0.15));
                    CHECK(oGx == Approx(2.0).margin(0.15));
                    CHECK(oGy == Approx(2.0).margin(0.15));
                }
                prevLap = eLap;
                prevGx = eGx;
                prevGy = eGy;
            }
        }
    }
}

TEST_CASE("Hexagonal lattice places cells at unit distance in six directions", "[fast][operators]")
{
    Lattice hex(LatticeKind::Hexagonal, 1.0);
    REQUIRE(hex.planeNeighbours().size() == 6);
    for (const auto& c : hex.planeNeighbours()) {
        CHECK(hex.planePosition(c.x(), c.y()).length() == Approx(1.0));
    }
    // The world transform agrees with planePosition.
    auto xf = hex.transform(0.5);
    const auto w = xf->indexToWorld(openvdb::Vec3d(3, 2, 0));
    const auto q = hex.planePosition(3, 2);
    CHECK(w.x() == Approx(0.5 * q.x()));
    CHECK(w.y() == Approx(0.5 * q.y()));
}
