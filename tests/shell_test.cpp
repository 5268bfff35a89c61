// Frost on objects: the shell domain (a narrow band around a mesh) and its closest-point
// surface operators.
#include "test_util.h"

#include <frostvdb/geometry/TriangleBvh.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/shell/ShellDomain.h>
#include <frostvdb/shell/ShellGrids.h>
#include <frostvdb/shell/ShellPhaseField.h>

#include <catch2/catch.hpp>

#include <frostvdb/ice/PhaseFieldSolver.h>

#include <openvdb/tools/Interpolation.h>

#include <tbb/global_control.h>

#include <cstring>
#include <random>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <array>
#include <atomic>
#include <algorithm>

#include <cmath>

using namespace frostvdb;
using test::iceArea;
using openvdb::Vec3d;

namespace {

/// Decay rate of the l-th zonal harmonic P_l(cos theta) under closest-point heat steps on a
/// sphere of radius R voxels (spacing 1): fitted amplitude a(t) = exp(-rate t).
double measuredDecayRate(const shell::ShellBand& band, int l, double dt, int steps)
{
    auto Pl = [l](double c) {
        switch (l) {
        case 1: return c;
        case 2: return 0.5 * (3 * c * c - 1);
        default: return 0.5 * (5 * c * c * c - 3 * c);
        }
    };
    std::vector<float> u(band.size()), u0(band.size()), scratch;
    for (size_t i = 0; i < band.size(); ++i) {
        const Vec3d q = band.closestPoint(i);
        u0[i] = u[i] = float(Pl(q.z() / q.length()));
    }
    for (int s = 0; s < steps; ++s) shell::heatStep(band, u, dt, 1.0, scratch);
    // amplitude by projection on P_l minus its band mean: the voxels do not sample the sphere
    // uniformly, so P_2 has a small constant part over them, which does not decay
    double mean = 0;
    for (float v : u0) mean += v;
    mean /= double(u0.size());
    double num = 0, den = 0;
    for (size_t i = 0; i < band.size(); ++i) {
        num += double(u[i]) * (u0[i] - mean);
        den += double(u0[i]) * (u0[i] - mean);
    }
    return -std::log(num / den) / (dt * steps);
}

/// A phase-field run on a square plate of @a L voxels, rotated by @a rx about x then @a ry about
/// y, crystal axis rotated with it, a seed disc of radius 3 at its centre.
struct PlateRun {
    std::shared_ptr<const shell::ShellBand> band;
    std::unique_ptr<shell::ShellPhaseField> pf;
    openvdb::Mat4d placement;
};

/// The seed disc's profile at distance @a r (voxels) from its centre: radius 3, about a voxel wide.
float seedProfile(double r) { return r > 6.0 ? 0.f : float(0.5 * (1.0 - std::tanh((r - 3.0) / 0.7))); }

KobayashiParams plateParams()
{
    KobayashiParams k; // the ice paper's Table 1 with j = 6
    k.dt = 0.0002;
    return k;
}

using Discretisation = shell::BandSettings::Discretisation;
const char* nameOf(Discretisation d) { return d == Discretisation::SurfaceNodes ? "surface nodes" : "closest point"; }

PlateRun runPlate(double L, double rx, double ry, int steps, double seedOffset = 0.0,
                  const Vec3d& plateWind = Vec3d(0.0), const KobayashiParams& params = plateParams(),
                  Discretisation disc = Discretisation::ClosestPoint)
{
    MeshPlacement m;
    m.rotateDegrees = Vec3d(rx, ry, 0);
    TriangleMesh mesh = makePlate(L, int(L / 2));
    mesh.transform(m);
    PlateRun run;
    run.placement = m.matrix();
    shell::BandSettings bs;
    bs.voxelSize = 1.0;
    bs.crystalAxis = run.placement.transform3x3(Vec3d(1, 0, 0));
    bs.secondaryAxis = run.placement.transform3x3(Vec3d(0, 1, 0));
    bs.discretisation = disc;
    run.band = shell::ShellBand::build(mesh, bs);
    run.pf = std::make_unique<shell::ShellPhaseField>(run.band, params, 3.0 / 64.0);
    run.pf->setWind(run.placement.transform3x3(plateWind) + Vec3d(0, 0, 0));
    // the seed: a smooth disc of radius 3 (the same profile as the plane's), set at each voxel
    // from its closest point, so it is closest-point data from the start
    const Vec3d centre = run.placement.transform(Vec3d(seedOffset, 0, 0));
    for (size_t i = 0; i < run.band->size(); ++i)
        run.pf->p()[i] = seedProfile((run.band->closestPoint(i) - centre).length());
    for (int s = 0; s < steps; ++s) run.pf->step((s + 1) * params.dt);
    return run;
}

/// p at plate coordinates (u, v) (voxels from the centre): trilinear at the surface point on a
/// closest-point band; on surface nodes, the value of the node whose closest point is nearest.
struct PlateSampler {
    const PlateRun& run;
    openvdb::FloatGrid::Ptr grid;
    explicit PlateSampler(const PlateRun& r) : run(r), grid(shell::toGrid(*r.band, r.pf->p(), 0.f, "p")) {}
    double operator()(double u, double v) const
    {
        const Vec3d w = run.placement.transform(Vec3d(u, v, 0));
        if (!run.band->surfaceNodes()) return openvdb::tools::BoxSampler::sample(grid->tree(), w);
        const openvdb::Coord c = openvdb::Coord::round(w);
        double best = 1e9, value = 0;
        for (int dz = -1; dz <= 1; ++dz)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) {
                    const int32_t id = run.band->indexOf(c + openvdb::Coord(dx, dy, dz));
                    if (id < 0) continue;
                    const double d = (run.band->closestPoint(size_t(id)) - w).lengthSqr();
                    if (d < best) { best = d; value = run.pf->p()[size_t(id)]; }
                }
        return value;
    }
};

/// Arms: runs of p > 1/2 on a circle of radius @a r about the centre.
int armCount(const std::function<double(double, double)>& p, double r)
{
    const int N = 720;
    std::vector<int> in(N);
    for (int k = 0; k < N; ++k) in[size_t(k)] = p(r * std::cos(2 * M_PI * k / N), r * std::sin(2 * M_PI * k / N)) > 0.5;
    int runs = 0;
    for (int k = 0; k < N; ++k) runs += (in[size_t(k)] && !in[size_t((k + N - 1) % N)]) ? 1 : 0;
    return runs;
}

} // namespace

TEST_CASE("Shell band: memory follows the surface, closest points lie on it", "[fast][shell]")
{
    const double R = 16.0;
    shell::BandSettings bs;
    bs.voxelSize = 1.0;
    auto band = shell::ShellBand::build(makeIcosphere(R, 5), bs);
    const double area = 4 * M_PI * R * R;
    // about 2 x 5.5 voxels thick
    CHECK(double(band->size()) / area > 9.0);
    CHECK(double(band->size()) / area < 13.0);
    double worst = 0;
    for (size_t i = 0; i < band->size(); ++i) {
        worst = std::max(worst, std::fabs(band->closestPoint(i).length() - R));
        REQUIRE(band->distance(i) <= shell::kHalfWidth);
    }
    CHECK(worst < 0.02 * R); // the icosphere's facets sag by R (1 - cos(edge/2R)) < 0.2 %
}

TEST_CASE("Surface nodes: one node per surface cell on the surface, stencils exact for quadratics", "[fast][shell]")
{
    // a sphere (curved) and a plate tilted 30/30 degrees (an irregular layer)
    MeshPlacement m;
    m.rotateDegrees = Vec3d(30, 30, 0);
    TriangleMesh plate = makePlate(48, 24);
    plate.transform(m);
    const double R = 16.0;
    for (int which = 0; which < 2; ++which) {
        shell::BandSettings bs;
        bs.voxelSize = 1.0;
        bs.discretisation = Discretisation::SurfaceNodes;
        auto band = shell::ShellBand::build(which == 0 ? makeIcosphere(R, 5) : plate, bs);
        // the plate's nodes reach half a voxel past its border (as far as a plane's cells do)
        const double area = which == 0 ? 4 * M_PI * R * R : 49.0 * 49.0;
        // (the plate's open border also has one ring of ghost nodes beyond it: not surface cells)
        size_t nodes = 0, ghosts = 0;
        for (size_t i = 0; i < band->size(); ++i) (band->ghost(i) ? ghosts : nodes) += 1;
        INFO((which == 0 ? "sphere" : "plate") << ": " << nodes << " nodes (+" << ghosts << " ghosts) for " << area
                                               << " cells");
        CHECK(std::fabs(double(nodes) / area - 1.0) < 0.05); // the plane's density
        CHECK((which == 0 ? ghosts == 0 : ghosts > 4 * 40));  // a ring around the plate, none on a sphere
        // every node within half a voxel of the surface along its normal; the stencils reproduce
        // the tangent-plane derivatives of a quadratic in the world coordinates at interior nodes
        // of the plate (exactly: a quadratic restricted to a plane is a quadratic in (s, t))
        size_t checked = 0;
        double worstLap = 0, worstGrad = 0;
        for (size_t i = 0; i < band->size(); ++i) {
            REQUIRE(std::fabs(band->normalOffset(i)) <= 0.5f + 1e-5f);
            if (band->ghost(i)) continue; // held at the background, never stepped
            REQUIRE(band->tapsEnd(i) - band->tapsBegin(i) >= 3); // a corner: the ring estimate
            if (which == 0) continue;
            const Vec3d q = band->closestPoint(i);
            if (m.matrix().inverse().transform(q).length() > 20) continue; // away from the border
            const Vec3d g0(0.3, -0.2, 0.1);
            auto f = [&](const Vec3d& x) { return g0.dot(x) + 0.01 * (x.x() * x.x() - 2 * x.y() * x.z() + 0.5 * x.z() * x.z()); };
            double lap = 0, du = 0, dv = 0;
            for (auto* t = band->tapsBegin(i); t != band->tapsEnd(i); ++t) {
                const double d = f(band->closestPoint(size_t(t->node))) - f(q);
                lap += t->lap * d;
                du += t->du * d;
                dv += t->dv * d;
            }
            // exact: grad f . t and trace of the Hessian on the tangent plane
            const auto& fr = band->frame(i);
            const Vec3d grad = g0 + 0.01 * Vec3d(2 * q.x(), -2 * q.z(), -2 * q.y() + q.z());
            auto hess = [&](const Vec3d& a) { return 0.01 * (2 * a.x() * a.x() - 4 * a.y() * a.z() + a.z() * a.z()); };
            worstLap = std::max(worstLap, std::fabs(lap - hess(fr.tangent) - hess(fr.bitangent)));
            worstGrad = std::max({worstGrad, std::fabs(du - grad.dot(fr.tangent)), std::fabs(dv - grad.dot(fr.bitangent))});
            ++checked;
        }
        INFO("worst Laplacian error " << worstLap << ", gradient " << worstGrad << " over " << checked << " nodes");
        CHECK(worstLap < 1e-4);
        CHECK(worstGrad < 1e-4);
    }
}

TEST_CASE("Surface nodes: weak taps are dropped where a layer is tilted, none where it is aligned", "[fast][shell]")
{
    // The stencils keep the taps that carry at least 12 % of an operator's largest weight
    // (ShellBand::surfaceStencil). On a flat axis-aligned plate that is every tap: 8 neighbours,
    // the Laplacian's edges 0.8 and corners 0.1 (1/8 of the largest). On a plate tilted 30/30
    // degrees the full fits averaged 10.1 taps a node (session 16); thinned, fewer than 8.6,
    // and still exact on quadratics (the test above, on the same plate).
    for (const bool tilted : {false, true}) {
        TriangleMesh plate = makePlate(48, 24);
        MeshPlacement m;
        if (tilted) m.rotateDegrees = Vec3d(30, 30, 0);
        plate.transform(m);
        shell::BandSettings bs;
        bs.voxelSize = 1.0;
        bs.discretisation = Discretisation::SurfaceNodes;
        auto band = shell::ShellBand::build(plate, bs);
        size_t interior = 0, taps = 0, notNine = 0;
        for (size_t i = 0; i < band->size(); ++i) {
            if (band->ghost(i)) continue;
            if (m.matrix().inverse().transform(band->closestPoint(i)).length() > 20) continue; // away from the border
            ++interior;
            const size_t n = size_t(band->tapsEnd(i) - band->tapsBegin(i));
            taps += n;
            if (tilted) continue;
            bool nine = n == 8;
            for (auto* t = band->tapsBegin(i); nine && t != band->tapsEnd(i); ++t) {
                const openvdb::Coord d = band->coord(size_t(t->node)) - band->coord(i);
                const bool corner = d.x() != 0 && d.y() != 0;
                nine = std::fabs(t->lap - (corner ? 0.1f : 0.8f)) < 1e-5f;
            }
            notNine += !nine;
        }
        const double mean = double(taps) / double(interior);
        INFO((tilted ? "tilted" : "aligned") << ": " << interior << " interior nodes, " << mean << " taps a node");
        CHECK(interior > 1000);
        if (tilted) {
            CHECK(mean < 8.6);
        } else {
            CHECK(notNine == 0);
        }
    }
}

TEST_CASE("Shell heat: a zonal harmonic on a sphere decays at l(l+1)/R^2 within 2 %", "[fast][shell]")
{
    // R = 20 voxels, dt = 0.1 h^2 (the phase field's ratio); measured -0.06 %, +0.50 %, +0.61 % (docs/shells.md)
    const double R = 20.0;
    const auto disc = GENERATE(Discretisation::ClosestPoint, Discretisation::SurfaceNodes);
    INFO(nameOf(disc));
    shell::BandSettings bs;
    bs.voxelSize = 1.0;
    bs.discretisation = disc;
    auto band = shell::ShellBand::build(makeIcosphere(R, 5), bs);
    for (int l : {1, 2, 3}) {
        const double expected = l * (l + 1) / (R * R);
        const int steps = int(std::ceil(0.25 / expected / 0.1)); // to about exp(-1/4)
        const double rate = measuredDecayRate(*band, l, 0.1, steps);
        INFO("l = " << l << " measured " << rate << " expected " << expected);
        CHECK(std::fabs(rate / expected - 1.0) < 0.02);
    }
}

/// The flat plane reference: the dense 2D loop of the same equations from the same seed, an
/// L x L square, after @a steps steps.
static DensePhaseField flatPlate(const KobayashiParams& k, double L, int steps)
{
    DensePhaseField plane(k, Lattice(LatticeKind::Square, 3.0 / 64.0), int(L), int(L));
    for (int j = 0; j < int(L); ++j)
        for (int i = 0; i < int(L); ++i) {
            const double x = i + 0.5 - L / 2, y = j + 0.5 - L / 2;
            plane.p()[plane.index(i, j)] = seedProfile(std::sqrt(x * x + y * y));
        }
    for (int s = 0; s < steps; ++s) plane.step();
    return plane;
}

TEST_CASE("Shell phase field: a plate at 0, 30 and 45 degrees grows the same crystal as the plane", "[fast][shell]")
{
    const double L = 56;
    const int steps = 300;
    // eps / h = 0.32 (epsBar 0.015): at Table 1's 0.21 the interface is narrower than a voxel and
    // tilted plates grow 8.6 % more ice ([shellexp] "interface width" measures both)
    KobayashiParams k = plateParams();
    k.epsBar = 0.015;
    const auto disc = GENERATE(Discretisation::ClosestPoint, Discretisation::SurfaceNodes);
    INFO(nameOf(disc));
    DensePhaseField plane = flatPlate(k, L, steps); // the flat reference
    auto planeP = [&](double u, double v) {
        const double x = u + L / 2 - 0.5, y = v + L / 2 - 0.5;
        const int i = int(std::floor(x)), j = int(std::floor(y));
        if (i < 0 || j < 0 || i + 1 >= int(L) || j + 1 >= int(L)) return 0.0;
        const double fx = x - i, fy = y - j;
        auto at = [&](int a, int b) { return double(plane.p()[plane.index(a, b)]); };
        return (1 - fy) * ((1 - fx) * at(i, j) + fx * at(i + 1, j)) + fy * ((1 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1));
    };
    const double planeArea = iceArea(planeP, L);
    std::vector<double> areas;
    for (double angle : {0.0, 30.0, 45.0}) {
        PlateRun run = runPlate(L, angle, angle, steps, 0.0, Vec3d(0.0), k, disc);
        PlateSampler ps(run);
        auto p = [&](double u, double v) { return ps(u, v); };
        areas.push_back(iceArea(p, L));
        INFO("angle " << angle << " area " << areas.back() << " plane " << planeArea);
        WARN(nameOf(disc) << ", plate at " << angle << " degrees: ice area " << areas.back() << ", plane " << planeArea);
        // The 5 % (docs/shells.md has the measured figures). At eps / h = 0.21 it is
        // 8.6 %: the interface is narrower than a voxel and a front aligned with the grid is
        // slowed by the lattice, a tilted one is not (not the time step, not the Laplacian).
        CHECK(std::fabs(areas.back() / planeArea - 1.0) < 0.05);
        // the crystal's mirror symmetry about the plate's axes survives the tilt
        const double r = 0.45 * std::sqrt(planeArea);
        CHECK(std::fabs(p(r, 0.0) - p(-r, 0.0)) < 0.05);
        CHECK(std::fabs(p(0.0, r) - p(0.0, -r)) < 0.05);
    }
    // grid-aligned, the closest-point band's 7-point stencil is the plane's 5-point one; surface
    // nodes use a least-squares stencil there too (measured -2.4 %, docs/shells.md)
    if (disc == Discretisation::ClosestPoint) CHECK(std::fabs(areas[0] / planeArea - 1.0) < 0.02);
    CHECK(std::fabs(areas[2] / areas[1] - 1.0) < 0.03);  // 30 and 45 degrees agree (measured 0.2 %)
}

TEST_CASE("Shell phase field: bit-identical at 1 and 2 threads", "[fast][shell]")
{
    std::vector<float> p1, p2, t1, t2;
    const auto disc = GENERATE(Discretisation::ClosestPoint, Discretisation::SurfaceNodes);
    INFO(nameOf(disc));
    KobayashiParams k = plateParams();
    k.noise = 0.01; // the noise is keyed by coordinates: still the same bits
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        PlateRun run = runPlate(32, 30, 30, 40, 0.0, Vec3d(3, 1, 0), k, disc);
        p1 = run.pf->p();
        t1 = run.pf->T();
    }
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
        PlateRun run = runPlate(32, 30, 30, 40, 0.0, Vec3d(3, 1, 0), k, disc);
        p2 = run.pf->p();
        t2 = run.pf->T();
    }
    REQUIRE(p1.size() == p2.size());
    CHECK(std::memcmp(p1.data(), p2.data(), p1.size() * sizeof(float)) == 0);
    CHECK(std::memcmp(t1.data(), t2.data(), t1.size() * sizeof(float)) == 0);
}

TEST_CASE("Shell phase field: a sphere of curvature radius 5 voxels stays bounded", "[fast][shell][stability]")
{
    const auto disc = GENERATE(Discretisation::ClosestPoint, Discretisation::SurfaceNodes);
    INFO(nameOf(disc));
    shell::BandSettings bs;
    bs.voxelSize = 1.0;
    bs.discretisation = disc;
    auto band = shell::ShellBand::build(makeIcosphere(5.0, 4), bs);
    shell::ShellPhaseField pf(band, plateParams(), 3.0 / 64.0);
    for (size_t i = 0; i < band->size(); ++i)
        pf.p()[i] = seedProfile((band->closestPoint(i) - Vec3d(0, 0, 5)).length());
    for (int s = 0; s < 400; ++s) pf.step((s + 1) * 0.0002);
    float lo = 1, hi = 0, tlo = 1e9f, thi = -1e9f;
    size_t ice = 0;
    for (size_t i = 0; i < band->size(); ++i) {
        REQUIRE(std::isfinite(pf.p()[i]));
        REQUIRE(std::isfinite(pf.T()[i]));
        lo = std::min(lo, pf.p()[i]);
        hi = std::max(hi, pf.p()[i]);
        tlo = std::min(tlo, pf.T()[i]);
        thi = std::max(thi, pf.T()[i]);
        ice += pf.p()[i] > 0.5f ? 1 : 0;
    }
    INFO("p in [" << lo << ", " << hi << "], T in [" << tlo << ", " << thi << "], ice voxels " << ice);
    CHECK(lo >= -0.05f);
    CHECK(hi <= 1.05f);
    CHECK(tlo >= -0.05f); // T starts at 0 and only warms (latent heat K dp)
    CHECK(thi <= 1.5f + 0.05f);
    CHECK(ice > 0);
}

TEST_CASE("Shell output: no ice beyond an open mesh's border", "[fast][shell]")
{
    const double L = 32;
    const auto disc = GENERATE(Discretisation::ClosestPoint, Discretisation::SurfaceNodes);
    INFO(nameOf(disc));
    PlateRun run = runPlate(L, 30, 30, 400, /*seedOffset=*/L / 2 - 5, Vec3d(0.0), plateParams(), disc); // grows into the border
    PlateSampler ps(run);
    CHECK(ps(L / 2 - 1, 0) > 0.5); // the ice reached the border
    auto fog = shell::frostFog(*run.band, run.pf->p(), run.pf->growthValues());
    REQUIRE(fog->activeVoxelCount() > 0);
    const openvdb::Mat4d inv = run.placement.inverse();
    double worst = 0;
    for (auto it = fog->cbeginValueOn(); it; ++it) {
        const Vec3d q = inv.transform(Vec3d(it.getCoord().x(), it.getCoord().y(), it.getCoord().z()));
        worst = std::max({worst, std::fabs(q.x()) - L / 2, std::fabs(q.y()) - L / 2});
        CHECK(q.z() > -1.0); // outward (the normal side) only
    }
    // within half a voxel of the border; surface nodes stamp the layer around each node's normal
    // (0.75 voxels), so their frost ends within a voxel of it
    CHECK(worst <= (disc == Discretisation::ClosestPoint ? 0.5 : 1.0) + 1e-6);
}

// The table in docs/shells.md: build/bin/frostvdb_tests "[shellexp]"
TEST_CASE("Shell heat decay rate against R and dt (measurement, not a check)", "[.][slow][shellexp]")
{
    for (double R : {16.0, 20.0, 24.0}) {
        const int sub = 5;
        shell::BandSettings bs;
        bs.voxelSize = 1.0;
        auto band = shell::ShellBand::build(makeIcosphere(R, sub), bs);
        for (int l : {1, 2, 3}) {
            const double expected = l * (l + 1) / (R * R);
            for (double dt : {0.1, 0.15}) {
                const int steps = int(std::ceil(0.5 / expected / dt));
                const double rate = measuredDecayRate(*band, l, dt, steps);
                WARN("sub " << sub << " R " << R << " l " << l << " dt " << dt << " rel " << rate / expected - 1.0);
            }
        }
    }
}

TEST_CASE("Shell domain: a missing, empty or unreadable mesh is a one-line error naming the file", "[fast][shell]")
{
    const std::string missing = test::errorOf("[domain]\nkind = \"shell\"\nmesh = \"no_such_glass.obj\"\n[phase_field]\n");
    CHECK(missing.find("domain.mesh") != std::string::npos);
    CHECK(missing.find("no_such_glass.obj") != std::string::npos);
    CHECK(missing.find('\n') == std::string::npos);
    const auto dir = std::filesystem::temp_directory_path();
    const std::string empty = (dir / "frostvdb_shell_empty.obj").string();
    std::ofstream(empty) << "# no faces\nv 0 0 0\nv 1 0 0\n";
    const std::string e1 = test::errorOf("[domain]\nkind = \"shell\"\nmesh = \"" + empty + "\"\n[phase_field]\n");
    CHECK(e1.find(empty) != std::string::npos);
    const std::string junk = (dir / "frostvdb_shell_junk.ply").string();
    std::ofstream(junk) << "ply\nthis is not a mesh\n";
    const std::string e2 = test::errorOf("[domain]\nkind = \"shell\"\nmesh = \"" + junk + "\"\n[phase_field]\n");
    CHECK(e2.find(junk) != std::string::npos);
    CHECK(e2.find('\n') == std::string::npos);
    std::filesystem::remove(empty);
    std::filesystem::remove(junk);
    // a band that cannot fit is refused before it is allocated
    const std::string huge = test::errorOf("[domain]\nkind = \"shell\"\nvoxel_size = 1e-9\nsphere_radius = 10\n[phase_field]\n");
    CHECK(huge.find("domain.voxel_size") != std::string::npos);
    // walkers on a surface (tests/shell_walkers_test.cpp): a perimeter release needs an open border
    const std::string dla = test::errorOf("[domain]\nkind = \"shell\"\nsphere_radius = 0.001\n[phase_field]\n[dla]\n"
                                          "release = \"perimeter\"\n");
    CHECK(dla.find("dla.release") != std::string::npos);
    // lw_cn's band system is not an M-matrix: Gauss-Seidel is refused by name (BiCGSTAB only)
    const std::string cp = "[domain]\nkind = \"shell\"\nsphere_radius = 0.001\ndiscretisation = \"closest_point\"\n";
    const std::string lw = test::errorOf(cp + "[phase_field]\nscheme = \"lw_cn\"\nsolver = \"gauss_seidel\"\n");
    CHECK(lw.find("phase_field.solver") != std::string::npos);
    CHECK(lw.find('\n') == std::string::npos);
    CHECK(test::errorOf(cp + "[phase_field]\nscheme = \"lw_cn\"\n").empty());
    // lw_cn and the potential flow need the closest-point band: refused on surface nodes, naming
    // the key and the way out
    const std::string sn = "[domain]\nkind = \"shell\"\nsphere_radius = 0.001\n";
    const std::string lwSurface = test::errorOf(sn + "[phase_field]\nscheme = \"lw_cn\"\n");
    CHECK(lwSurface.find("phase_field.scheme") != std::string::npos);
    CHECK(lwSurface.find("closest_point") != std::string::npos);
    const std::string potSurface = test::errorOf(sn + "[phase_field]\nwind = [1, 0, 0]\nwind_model = \"potential\"\n");
    CHECK(potSurface.find("phase_field.wind_model") != std::string::npos);
}

TEST_CASE("Shell domain: the support is the band, the frame follows the surface", "[fast][shell][domain]")
{
    auto sim = test::makeSim("[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.001\n[phase_field]\n");
    const Domain& dom = sim.world().domain;
    CHECK(dom.kind() == "shell");
    CHECK(dom.intrinsicDimension() == 2);
    CHECK(!dom.flat());
    auto band = shell::bandOf(dom);
    REQUIRE(band);
    CHECK(dom.voxelCount() == band->size());
    CHECK(dom.contains(openvdb::Coord(0, 0, 10)));  // on the sphere (radius 10 voxels)
    CHECK(!dom.contains(openvdb::Coord(0, 0, 0)));  // its centre is not in the band
    const VoxelFrame f = dom.frame(openvdb::Coord(10, 0, 0));
    CHECK(f.normal.x() > 0.99);                        // outward
    CHECK(std::fabs(f.tangent.dot(f.normal)) < 1e-9);
    // the active region is clipped to the band
    openvdb::MaskTree m;
    m.fill(openvdb::CoordBBox(openvdb::Coord(-20), openvdb::Coord(20)), true);
    dom.clipToSupport(m);
    CHECK(m.activeVoxelCount() == band->size());
}

TEST_CASE("Shell scene: bit-identical files (ice, ice_sdf, ...) at 1 and 2 threads", "[fast][shell][determinism]")
{
    const std::string scene = "[scene]\nname = \"sh\"\nframes = 1\nsteps_per_frame = 60\n"
                              "[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.0012\n"
                              "[[crystal.seed]]\nshape = \"point\"\nspace = \"world\"\nposition = [0, 0, 0.0012]\n"
                              "radius = 3\n[phase_field]\nnoise = 0.01\n"; // noise too: keyed by voxel, not thread
    std::string paths[2];
    for (int threads : {1, 2}) {
        auto sim = test::makeSim(scene);
        RunOptions ro;
        ro.progress = false;
        ro.threads = threads;
        ro.outDir = test::tempDir("shell_det" + std::to_string(threads));
        auto sum = sim.run(ro);
        REQUIRE(!sum.files.empty());
        paths[threads - 1] = ro.outDir + "/sh.0001.vdb";
    }
    std::string why;
    CHECK(test::sameVdbContent(paths[0], paths[1], &why));
    INFO(why);
    openvdb::io::File f(paths[0]);
    f.open();
    CHECK(f.readGrid("ice")->activeVoxelCount() > 0);
    CHECK(f.readGrid("ice_sdf")->activeVoxelCount() > 0);
}

TEST_CASE("Shell wind: a wind along the plate carries the heat downwind, the ice grows upwind", "[fast][shell]")
{
    const double L = 48;
    auto reach = [&](const PlateRun& run, double sign) {
        PlateSampler ps(run);
        double r = 0;
        for (double u = 0; u < L / 2; u += 0.25)
            if (ps(sign * u, 0.0) > 0.5) r = u;
        return r;
    };
    // wind along the plate's +x, tilted 30 / 30 degrees (the wind is rotated with the plate)
    PlateRun calm = runPlate(L, 30, 30, 250);
    PlateRun windy = runPlate(L, 30, 30, 250, 0.0, Vec3d(40, 0, 0));
    const double up = reach(windy, -1), down = reach(windy, +1);
    INFO("calm " << reach(calm, -1) << " / " << reach(calm, +1) << ", windy upwind " << up << " downwind " << down);
    CHECK(std::fabs(reach(calm, -1) - reach(calm, +1)) < 0.3); // symmetric without wind
    CHECK(up > down + 1.0);
    // a wind along the normal does nothing: it is projected on the tangent plane
    PlateRun normal = runPlate(L, 30, 30, 250, 0.0, Vec3d(0, 0, 40));
    double diff = 0;
    for (size_t i = 0; i < calm.pf->p().size(); ++i)
        diff = std::max(diff, double(std::fabs(normal.pf->p()[i] - calm.pf->p()[i])));
    CHECK(diff < 1e-3); // (the float mesh's normals leave a ~1e-6 tangential part)
}

TEST_CASE("Shell seeds: vertex colours, the open mesh's border, points on the surface", "[fast][shell]")
{
    // a 3 x 3 cm plate of 3 x 3 vertices as ASCII PLY with colours: the left column white
    const std::string ply = (std::filesystem::temp_directory_path() / "frostvdb_shell_colours.ply").string();
    {
        std::ofstream f(ply);
        f << "ply\nformat ascii 1.0\nelement vertex 9\nproperty float x\nproperty float y\nproperty float z\n"
             "property uchar red\nproperty uchar green\nproperty uchar blue\nelement face 8\n"
             "property list uchar int vertex_indices\nend_header\n";
        for (int j = 0; j < 3; ++j)
            for (int i = 0; i < 3; ++i) {
                const int c = i == 0 ? 255 : 0;
                f << 0.015 * (i - 1) << " " << 0.015 * (j - 1) << " 0 " << c << " " << c << " " << c << "\n";
            }
        for (int j = 0; j < 2; ++j)
            for (int i = 0; i < 2; ++i) {
                const int a = j * 3 + i, b = a + 1, c = a + 3, d = c + 1;
                f << "3 " << a << " " << b << " " << d << "\n3 " << a << " " << d << " " << c << "\n";
            }
    }
    const std::string head = "[scene]\nframes = 1\nsteps_per_frame = 1\n[domain]\nkind = \"shell\"\nmesh = \"" + ply +
                             "\"\nvoxel_size = 0.001\n";
    {
        auto sim = test::makeSim(head + "vertex_colours = \"seed\"\n[[crystal.seed]]\nshape = \"point\"\n"
                                        "position = [0.9, 0.9, 0.5]\nradius = 2\n[phase_field]\n");
        RunOptions ro;
        ro.progress = false;
        ro.outDir = test::tempDir("shell_colours");
        sim.run(ro);
        auto p = sim.world().fields.get<openvdb::FloatGrid>("p");
        auto acc = p->getConstAccessor();
        CHECK(acc.getValue(openvdb::Coord(-13, 0, 0)) > 0.5f); // white: a seed
        CHECK(acc.getValue(openvdb::Coord(-2, 0, 0)) < 0.1f);  // black: none
        CHECK(acc.getValue(openvdb::Coord(14, 14, 0)) > 0.5f); // the point seed, moved onto the surface
    }
    {
        auto sim = test::makeSim(head + "[[crystal.seed]]\nshape = \"edge\"\nedges = \"border\"\nwidth = 2\n[phase_field]\n");
        RunOptions ro;
        ro.progress = false;
        ro.outDir = test::tempDir("shell_border");
        sim.run(ro);
        auto acc = sim.world().fields.get<openvdb::FloatGrid>("p")->getConstAccessor();
        CHECK(acc.getValue(openvdb::Coord(-14, 0, 0)) > 0.5f); // at the border
        CHECK(acc.getValue(openvdb::Coord(0, 14, 0)) > 0.5f);
        CHECK(acc.getValue(openvdb::Coord(0, 0, 0)) < 0.1f);   // the middle is bare
    }
    const std::string none = test::errorOf(head + "vertex_colours = \"seed\"\n[phase_field]\n");
    INFO(none);
    CHECK(none.empty());
    std::filesystem::remove(ply);
}

TEST_CASE("Shell orientation against the interface width eps / h (measurement, not a check)", "[.][slow][shellexp]")
{
    // The plate test's 0 / 30 / 45 degree ice areas at a wider interface: does the tilted excess
    // (8.5 % at eps / h = 0.2) shrink when the interface spans more of a voxel?
    const double L = 56;
    for (double eps : {0.01, 0.015, 0.02}) {
        KobayashiParams k = plateParams();
        k.epsBar = eps;
        const int steps = 300;
        double a[3];
        int n = 0;
        for (double angle : {0.0, 30.0, 45.0}) {
            PlateRun run = runPlate(L, angle, angle, steps, 0.0, Vec3d(0.0), k);
            PlateSampler ps(run);
            a[n++] = iceArea([&](double u, double v) { return ps(u, v); }, L);
        }
        DensePhaseField plane = flatPlate(k, L, steps);
        int planeCells = 0; // cell count (the plate test samples bilinearly; close enough here)
        for (int j = 0; j < int(L); ++j)
            for (int i = 0; i < int(L); ++i) planeCells += plane.p()[plane.index(i, j)] > 0.5f ? 1 : 0;
        WARN("eps " << eps << ": plane cells " << planeCells);
        WARN("eps " << eps << " (eps/h " << eps / (3.0 / 64.0) << "): area 0 deg " << a[0] << ", 30 deg " << a[1]
                    << " (" << 100 * (a[1] / a[0] - 1) << " %),\n  45 deg " << a[2] << " (" << 100 * (a[2] / a[0] - 1) << " %)");
    }
}

namespace {

/// A phase field on a tilted plate with a seed disc of radius 3 at its centre, run @a steps with
/// noise, on a whole band (@a lazy false, stepped whole) or a lazily built one stepped around the
/// ice with region tolerance @a tol. Returns p and T by voxel.
struct RegionRun {
    std::map<openvdb::Coord, std::pair<float, float>> values;
    size_t bandVoxels = 0, steppedVoxels = 0;
};

RegionRun runRegion(double L, bool lazy, double tol, int steps)
{
    MeshPlacement m;
    m.rotateDegrees = Vec3d(30, 30, 0);
    TriangleMesh mesh = makePlate(L, int(L / 8));
    mesh.transform(m);
    shell::BandSettings bs;
    bs.voxelSize = 1.0;
    bs.crystalAxis = m.matrix().transform3x3(Vec3d(1, 0, 0));
    auto band = lazy ? shell::ShellBand::buildLazy(mesh, bs) : shell::ShellBand::build(mesh, bs);
    KobayashiParams k = plateParams();
    k.noise = 0.01;
    shell::ShellPhaseField pf(band, k, 3.0 / 64.0);
    pf.setActiveRegion(lazy, tol);
    band->nearSurfacePoint(Vec3d(0.0), 6.0); // builds the seed's leaves on a lazy band
    pf.grow();
    for (size_t i = 0; i < band->size(); ++i) pf.p()[i] = seedProfile(band->closestPoint(i).length());
    for (int s = 0; s < steps; ++s) pf.step((s + 1) * k.dt, s, 7, nullptr);
    RegionRun r;
    for (size_t i = 0; i < band->size(); ++i) r.values[band->coord(i)] = {pf.p()[i], pf.T()[i]};
    r.bandVoxels = band->size();
    r.steppedVoxels = pf.steppedVoxels();
    return r;
}

/// Largest |p - p_ref| and |T - T_ref| over the reference's voxels (a voxel the run did not
/// build counts as background: p 0, T 0).
double maxDifference(const RegionRun& a, const RegionRun& ref)
{
    double d = 0;
    for (const auto& [c, v] : ref.values) {
        const auto it = a.values.find(c);
        const std::pair<float, float> w = it == a.values.end() ? std::make_pair(0.f, 0.f) : it->second;
        d = std::max({d, double(std::fabs(w.first - v.first)), double(std::fabs(w.second - v.second))});
    }
    return d;
}

} // namespace

TEST_CASE("Shell active region: at tolerance 0 the same bits as the whole band, converging as it shrinks",
          "[fast][shell][region]")
{
    const double L = 64;
    const int steps = 60;
    const RegionRun whole = runRegion(L, false, 0.0, steps);
    const RegionRun exact = runRegion(L, true, 0.0, steps);
    INFO("whole band " << whole.bandVoxels << " voxels; lazy band " << exact.bandVoxels << ", stepped "
                       << exact.steppedVoxels);
    CHECK(maxDifference(exact, whole) == 0.0); // bit-identical wherever either has a voxel
    for (const auto& [c, v] : exact.values) REQUIRE(whole.values.count(c) == 1); // the same band
    double last = 1.0;
    for (double tol : {1e-2, 1e-4, 1e-6}) {
        const double d = maxDifference(runRegion(L, true, tol, steps), whole);
        WARN("tolerance " << tol << ": max |difference| " << d);
        CHECK(d <= last);
        CHECK(d <= 10 * tol); // the error stays of the order of what is left out
        last = d;
    }
}

TEST_CASE("Shell active region: a huge plate with a small crystal builds only the band around it",
          "[fast][shell][region]")
{
    // a 4096^2 tilted plate (~190 M band voxels if built whole); 40 steps of a radius-3 seed
    const RegionRun r = runRegion(4096, true, 1e-6, 40);
    WARN("built " << r.bandVoxels << ", stepped " << r.steppedVoxels);
    CHECK(r.bandVoxels < 200000);       // the seed's neighbourhood, not the plate
    CHECK(r.steppedVoxels < r.bandVoxels);
    double pMax = 0;
    for (const auto& [c, v] : r.values) pMax = std::max(pMax, double(v.first));
    CHECK(pMax > 0.9); // the crystal is there
}

TEST_CASE("Shell active region: bit-identical at 1 and 2 threads", "[fast][shell][region][determinism]")
{
    RegionRun r[2];
    for (int t : {1, 2}) {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, size_t(t));
        r[t - 1] = runRegion(64, true, 1e-6, 40);
    }
    CHECK(r[0].values.size() == r[1].values.size());
    CHECK(maxDifference(r[0], r[1]) == 0.0);
    CHECK(maxDifference(r[1], r[0]) == 0.0);
}

TEST_CASE("Shell active region: a run resumed from its fields and region state steps the same bits",
          "[fast][shell][region][determinism]")
{
    const double tol = 1e-3; // a region that leaves small values out, so its state matters
    MeshPlacement m;
    m.rotateDegrees = Vec3d(30, 30, 0);
    TriangleMesh mesh = makePlate(64, 8);
    mesh.transform(m);
    shell::BandSettings bs;
    bs.voxelSize = 1.0;
    bs.crystalAxis = m.matrix().transform3x3(Vec3d(1, 0, 0));
    KobayashiParams k = plateParams();
    k.noise = 0.01;
    struct Run {
        std::shared_ptr<const shell::ShellBand> band;
        std::unique_ptr<shell::ShellPhaseField> pf;
    };
    auto start = [&] {
        Run r;
        r.band = shell::ShellBand::buildLazy(mesh, bs);
        r.pf = std::make_unique<shell::ShellPhaseField>(r.band, k, 3.0 / 64.0);
        r.pf->setActiveRegion(true, tol);
        return r;
    };
    auto steps = [&](Run& r, int from, int to) {
        for (int s = from; s < to; ++s) r.pf->step((s + 1) * k.dt, s, 7, nullptr);
    };
    auto seed = [&](Run& r) {
        r.band->nearSurfacePoint(Vec3d(0.0), 6.0);
        r.pf->grow();
        for (size_t i = 0; i < r.band->size(); ++i) r.pf->p()[i] = seedProfile(r.band->closestPoint(i).length());
    };
    Run a = start();
    seed(a);
    steps(a, 0, 60);
    Run b = start();
    seed(b);
    steps(b, 0, 30);
    // the checkpoint: the fields by voxel and the region state
    std::map<openvdb::Coord, std::array<float, 4>> saved;
    for (size_t i = 0; i < b.band->size(); ++i)
        saved[b.band->coord(i)] = {b.pf->p()[i], b.pf->T()[i], b.pf->growthValues()[i], b.pf->freezeValues()[i]};
    auto boxes = openvdb::Int32Grid::create(0);
    auto stepped = openvdb::MaskGrid::create();
    b.pf->regionState(*boxes, *stepped);
    // resume: a fresh band built where the fields are off their backgrounds, then the region
    Run c = start();
    std::vector<openvdb::Coord> origins;
    for (const auto& [coord, v] : saved)
        if (v[0] != 0.f || v[1] != 0.f) origins.push_back(shell::leafOrigin(coord));
    c.band->materialise(origins);
    c.pf->grow();
    for (size_t i = 0; i < c.band->size(); ++i) {
        const auto it = saved.find(c.band->coord(i));
        if (it == saved.end()) continue;
        c.pf->p()[i] = it->second[0];
        c.pf->T()[i] = it->second[1];
        c.pf->growthValues()[i] = it->second[2];
        c.pf->freezeValues()[i] = it->second[3];
    }
    c.pf->restoreRegion(*boxes, *stepped);
    steps(c, 30, 60);
    CHECK(c.pf->steppedVoxels() == a.pf->steppedVoxels());
    std::map<openvdb::Coord, std::array<float, 4>> ref;
    for (size_t i = 0; i < a.band->size(); ++i)
        ref[a.band->coord(i)] = {a.pf->p()[i], a.pf->T()[i], a.pf->growthValues()[i], a.pf->freezeValues()[i]};
    size_t differ = 0;
    for (size_t i = 0; i < c.band->size(); ++i) {
        const auto it = ref.find(c.band->coord(i));
        const std::array<float, 4> want = it == ref.end() ? std::array<float, 4>{0.f, 0.f, 0.f, 0.f} : it->second;
        const std::array<float, 4> got = {c.pf->p()[i], c.pf->T()[i], c.pf->growthValues()[i], c.pf->freezeValues()[i]};
        differ += got == want ? 0 : 1;
    }
    CHECK(differ == 0);
}

TEST_CASE("Shell scene: the active region at tolerance 0 writes the whole band's ice, seeds on the border too",
          "[fast][shell][region]")
{
    // an open plate (a border) with a point seed and an edge seed: built lazily where they are
    // stamped, against [region] dense = true (the whole band)
    const std::string obj = (std::filesystem::temp_directory_path() / "frostvdb_shell_region_plate.obj").string();
    {
        std::ofstream f(obj);
        f << "v -0.004 -0.003 0\nv 0.004 -0.003 0\nv 0.004 0.003 0\nv -0.004 0.003 0\nf 1 2 3\nf 1 3 4\n";
    }
    const std::string scene = "[scene]\nname = \"rg\"\nframes = 1\nsteps_per_frame = 40\n"
                              "[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nmesh = \"" + obj + "\"\n"
                              "mesh_rotate = [30, 20, 0]\n"
                              "[[crystal.seed]]\nshape = \"point\"\nposition = [0.5, 0.5, 0.5]\nradius = 3\n"
                              "[[crystal.seed]]\nshape = \"edge\"\nedges = \"border\"\nwidth = 1\n"
                              "[phase_field]\nnoise = 0.01\n";
    std::map<openvdb::Coord, float> ice[2];
    for (int dense : {0, 1}) {
        auto sim = test::makeSim(scene + (dense ? "[region]\ndense = true\n" : "[region]\ntolerance = 0\n"));
        RunOptions ro;
        ro.progress = false;
        ro.outDir = test::tempDir("shell_region" + std::to_string(dense));
        sim.run(ro);
        openvdb::io::File f(ro.outDir + "/rg.0001.vdb");
        f.open();
        auto g = openvdb::gridPtrCast<openvdb::FloatGrid>(f.readGrid("ice"));
        for (auto it = g->cbeginValueOn(); it; ++it) ice[dense][it.getCoord()] = *it;
    }
    CHECK(ice[0].size() > 100);
    CHECK(ice[0] == ice[1]);
    std::filesystem::remove(obj);
}

TEST_CASE("Shell run summary: each frame's active voxels are the fields of that frame, not the last one's",
          "[fast][shell]")
{
    // The shell phase field keeps its fields in band arrays and writes them into World's grids
    // only when published (frames, checkpoints); run.json's active_voxels were counted before the
    // frame's publication, so each entry showed the previous frame's fields (the seeds at frame 1).
    const std::string text = "[scene]\nname = \"shav\"\nseed = 3\nframes = 2\nsteps_per_frame = 30\n"
                             "[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.0012\n"
                             "[[crystal.seed]]\nshape = \"point\"\nspace = \"world\"\nposition = [0, 0, 0.0012]\n"
                             "radius = 4\n[phase_field]\n";
    std::vector<uint64_t> expected;
    {
        Simulation sim = test::makeSim(text);
        for (int frame = 0; frame < 2; ++frame) {
            for (int s = 0; s < 30; ++s) sim.step();
            expected.push_back(sim.world().fields.activeVoxels()); // world(): published first
        }
    }
    Simulation sim = test::makeSim(text);
    RunOptions ro;
    ro.progress = false;
    ro.outDir = test::tempDir("shell_active_voxels");
    const RunSummary sum = sim.run(ro);
    REQUIRE(sum.activeVoxels.size() == 2);
    CHECK(expected[0] < expected[1]); // the heat and the ice spread: the counts differ per frame
    for (size_t f = 0; f < 2; ++f) {
        INFO("frame " << f + 1);
        CHECK(sum.activeVoxels[f].first == int64_t(30 * (f + 1)));
        CHECK(sum.activeVoxels[f].second == expected[f]);
    }
}

TEST_CASE("Shell frames: the grids made from the band arrays are those the published fields give",
          "[fast][shell]")
{
    // A shell's frames are made from the phase field's band arrays (Frame::addDeferred), not from
    // World's grids, which a frame no longer publishes (they were held beside the frame's own:
    // 95 MiB of the pane's 317 MiB peak). ice_temperature, growth and freeze_time must still be
    // what ice::addIceFieldOutputs makes of the published p, T, growth_acc and freeze_time.
    const std::string text = "[scene]\nname = \"shfr\"\nseed = 5\nframes = 2\nsteps_per_frame = 40\n"
                             "[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.0012\n"
                             "[[crystal.seed]]\nshape = \"point\"\nspace = \"world\"\nposition = [0, 0, 0.0012]\n"
                             "radius = 4\n[phase_field]\n[dla]\nhumidity = 20\n";
    Simulation run = test::makeSim(text);
    RunOptions ro;
    ro.progress = false;
    ro.outDir = test::tempDir("shell_frame_arrays");
    REQUIRE(run.run(ro).framesWritten == 2);

    Simulation published = test::makeSim(text);
    for (int s = 0; s < 80; ++s) published.step();
    World& w = published.world(); // publishes the band arrays into World's grids
    auto T = w.fields.get<openvdb::FloatGrid>(ice::kTemperature);
    auto growth = w.fields.get<openvdb::FloatGrid>(ice::kGrowth)->deepCopy();
    ice::normaliseGrowth(*growth);
    auto freeze = w.fields.get<openvdb::FloatGrid>(ice::kFreezeTime);
    const std::map<std::string, openvdb::FloatGrid::ConstPtr> expected = {
        {"ice_temperature", T}, {"growth", growth}, {"freeze_time", freeze}};

    openvdb::io::File f(ro.outDir + "/shfr.0002.vdb");
    f.open();
    for (const auto& [name, want] : expected) {
        INFO(name);
        auto got = openvdb::gridPtrCast<openvdb::FloatGrid>(f.readGrid(name));
        REQUIRE(got);
        CHECK(got->activeVoxelCount() > 0);
        CHECK(got->background() == want->background());
        CHECK(got->tree().hasSameTopology(want->tree()));
        auto acc = want->getConstAccessor();
        size_t differ = 0;
        for (auto it = got->cbeginValueOn(); it; ++it) differ += *it != acc.getValue(it.getCoord());
        CHECK(differ == 0);
    }
    CHECK(openvdb::gridPtrCast<openvdb::FloatGrid>(f.readGrid("ice_temperature"))->getGridClass() ==
          openvdb::GRID_UNKNOWN);
}

TEST_CASE("Frame: a deferred grid is a named placeholder until the writer or a PNG asks for it", "[fast][core]")
{
    int made = 0;
    Frame frame;
    frame.add(out::kIce, openvdb::FloatGrid::create());
    frame.addDeferred(out::kGrowth, [&made] {
        ++made;
        auto g = openvdb::FloatGrid::create();
        g->tree().setValue(openvdb::Coord(1, 2, 3), 0.5f);
        return g;
    });
    REQUIRE(frame.grids.size() == 2);
    CHECK(frame.grids[1]->getName() == "growth");
    CHECK(frame.grids[1]->activeVoxelCount() == 0);
    CHECK(made == 0);
    frame.makeNamed("growth"); // a PNG reads it: made once, then kept through dropCopies
    CHECK(made == 1);
    CHECK(frame.grids[1]->activeVoxelCount() == 1);
    CHECK(frame.grids[1]->getName() == "growth");
    frame.dropCopies();
    CHECK(frame.grid(1)->activeVoxelCount() == 1);
    CHECK(made == 1);

    Frame second;
    second.addDeferred(out::kGrowth, [&made] { ++made; return openvdb::FloatGrid::create(); });
    second.dropCopies(); // the writer's path: made when reached
    CHECK(!second.grids[0]);
    CHECK(second.grid(0));
    CHECK(made == 2);
}

TEST_CASE("Surface commit: the vector stage 3 (AVX2) gives the scalar one bit for bit", "[fast][shell]")
{
    // Random new and old p around 1/2 (crossings both ways), growth and freeze times with zeros
    // of both signs, ghosts on and off, every range length 0-40 at every start 0-7: the fields,
    // growth, freeze time and the crossed flag equal the scalar stage's.
    const shell::SurfaceCommitRange fast = shell::fastestSurfaceCommit();
    INFO((fast == &shell::surfaceCommit ? "plain" : "AVX2"));
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> u(0.f, 1.f);
    const size_t n = 64;
    size_t differ = 0, crossings = 0, grown = 0, frozen = 0, runs = 0;
    for (const bool ghosts : {false, true})
        for (size_t begin = 0; begin < 8; ++begin)
            for (size_t length = 0; length <= 40; ++length) {
                std::vector<float> p(n), t(n), g(n), f(n), pn(n), tn(n), lat(n);
                for (size_t i = 0; i < n; ++i) {
                    p[i] = u(rng);
                    pn[i] = u(rng) < 0.3f ? p[i] : u(rng); // some unchanged: d = 0 grows nothing
                    t[i] = u(rng);
                    tn[i] = u(rng);
                    g[i] = u(rng) < 0.5f ? (u(rng) < 0.5f ? -0.f : 0.f) : u(rng);
                    f[i] = u(rng) < 0.5f ? (u(rng) < 0.5f ? -0.f : 0.f) : u(rng);
                    lat[i] = u(rng);
                }
                auto p2 = p, t2 = t, g2 = g, f2 = f;
                const auto g0 = g;
                const shell::SurfaceCommit a{p.data(), t.data(), g.data(), f.data(), pn.data(), tn.data(), lat.data(),
                                             ghosts, 2.5f};
                const shell::SurfaceCommit b{p2.data(), t2.data(), g2.data(), f2.data(), pn.data(), tn.data(),
                                             lat.data(), ghosts, 2.5f};
                const bool c1 = fast(a, begin, begin + length), c2 = shell::surfaceCommit(b, begin, begin + length);
                differ += c1 != c2 || std::memcmp(p.data(), p2.data(), n * 4) != 0 ||
                          std::memcmp(t.data(), t2.data(), n * 4) != 0 || std::memcmp(g.data(), g2.data(), n * 4) != 0 ||
                          std::memcmp(f.data(), f2.data(), n * 4) != 0;
                crossings += c2;
                for (size_t i = begin; i < begin + length; ++i) {
                    grown += g2[i] != g0[i];
                    frozen += f2[i] == 2.5f;
                }
                ++runs;
            }
    CHECK(runs == 2 * 8 * 41);
    CHECK(crossings > 100);
    CHECK(grown > 100);
    CHECK(frozen > 100);
    CHECK(differ == 0);
}

TEST_CASE("Surface tap sums: the vector passes (AVX2) give the scalar passes bit for bit", "[fast][shell]")
{
    // Random fields on a sphere's and a tilted plate's surface nodes (taps of every count, a
    // ghost ring on the plate): pass 1's coefficients, gradients and sums of p and T (with and
    // without a wind), pass 2's sums, and pass 2 through the update, of every group of four (and
    // of eight, two fours side by side) equal the scalar functions' exactly, including the sign of zero sums (half the nodes are flat,
    // where every difference is 0).
    TriangleMesh plate = makePlate(40, 20);
    MeshPlacement m;
    m.rotateDegrees = Vec3d(30, 30, 0);
    plate.transform(m);
    for (int which = 0; which < 2; ++which) {
        shell::BandSettings bs;
        bs.voxelSize = 1.0;
        bs.discretisation = Discretisation::SurfaceNodes;
        auto band = shell::ShellBand::build(which == 0 ? makeIcosphere(12.0, 5) : plate, bs);
        const size_t n = band->size();
        std::mt19937 rng(7 + which);
        std::uniform_real_distribution<float> u(-1.f, 1.f);
        std::vector<float> P(n), T(n);
        std::vector<shell::SurfaceCoefficients> C(n);
        for (size_t i = 0; i < n; ++i) {
            // the nodes at x < 0 flat (p = 0, T = -0.5, C = 0): inside that half the sums are zeros
            const bool flat = band->coord(i).x() < 0;
            P[i] = flat ? 0.f : u(rng);
            T[i] = flat ? -0.5f : u(rng);
            C[i] = flat ? shell::SurfaceCoefficients{0.01f, 0.f, 0.f, 0.f}
                        : shell::SurfaceCoefficients{u(rng), u(rng), u(rng), u(rng)};
        }
        INFO((which == 0 ? "sphere" : "plate"));

        // pass 1: the coefficients and sums, j = 6 and j = 4 (flat nodes take the zero-gradient
        // branch), without a wind and with one (T's derivatives summed too)
        std::vector<shell::FieldSums> sums(n);
        std::vector<shell::WindSums> winds(n);
        for (const size_t group : {4, 8}) // four nodes, or eight (two fours side by side)
        for (const bool withWind : {false, true})
            for (const double j : {6.0, 4.0}) {
                KobayashiParams kp;
                kp.anisotropyMode = j;
                kp.delta = 0.05;
                kp.theta0 = j == 4.0 ? 0.3 : 0.0;
                const Anisotropy an(kp);
                const shell::SurfaceCoefficients4 fastC =
                    group == 4 ? shell::fastestSurfaceCoefficients4(an) : shell::fastestSurfaceCoefficients8(an);
                const bool plain = fastC == &shell::surfaceCoefficients4Plain || fastC == &shell::surfaceCoefficients8Plain;
                INFO((plain ? "plain" : "AVX2") << ", " << group << " nodes, j = " << j << (withWind ? ", wind" : ""));
                std::vector<shell::SurfaceCoefficients> c1(n), c2(n);
                std::vector<float> gu1(n), gv1(n), gu2(n), gv2(n);
                std::vector<shell::FieldSums> s1(n);
                std::vector<shell::WindSums> w1(n);
                size_t coefDiffer = 0, sumsDiffer = 0, flatNodes = 0;
                for (const auto& leaf : band->leaves())
                    for (size_t i = leaf.begin; i + group <= leaf.end; i += group) {
                        fastC(*band, P.data(), T.data(), an, 0.5, i, c1.data(), gu1.data(), gv1.data(), s1.data(),
                              withWind ? w1.data() : nullptr);
                        for (size_t k = 0; k < group; ++k) {
                            shell::surfaceCoefficients(*band, P.data(), T.data(), an, 0.5, i + k, c2.data(),
                                                       gu2.data(), gv2.data(), sums.data(), winds.data());
                            coefDiffer += std::memcmp(&c1[i + k], &c2[i + k], sizeof c1[0]) != 0 ||
                                          std::memcmp(&gu1[i + k], &gu2[i + k], 4) != 0 ||
                                          std::memcmp(&gv1[i + k], &gv2[i + k], 4) != 0;
                            sumsDiffer += std::memcmp(&s1[i + k], &sums[i + k], sizeof sums[0]) != 0 ||
                                          (withWind && std::memcmp(&w1[i + k], &winds[i + k], sizeof winds[0]) != 0);
                            flatNodes += gu2[i + k] == 0.f && gv2[i + k] == 0.f;
                        }
                    }
                CHECK(flatNodes > 0);
                CHECK(coefDiffer == 0);
                CHECK(sumsDiffer == 0);
            }

        // pass 2: the sums of the coefficients, with pass 1's sums passed through
        const shell::TapSums4 fast = shell::fastestTapSums4();
        INFO((fast == &shell::tapSums4Plain ? "plain" : "AVX2"));
        size_t groups = 0, differ = 0, zeros = 0;
        shell::TapSums four[4];
        for (const auto& leaf : band->leaves())
            for (size_t i = leaf.begin; i + 4 <= leaf.end; i += 4, ++groups) {
                fast(*band, C.data(), sums.data(), winds.data(), i, four);
                for (size_t k = 0; k < 4; ++k) {
                    const shell::TapSums ref = shell::tapSums(*band, C.data(), sums.data(), winds.data(), i + k);
                    differ += std::memcmp(&ref, &four[k], sizeof ref) != 0;
                    zeros += ref.lapP == 0.0 && ref.dau == 0.0 && ref.divC == 0.0;
                }
            }
        CHECK(groups > 100);
        CHECK(zeros > 0);
        CHECK(differ == 0);

        // pass 2 without wind, the sums kept in lanes through the update (p across [0, 1] and
        // beyond, T around the melt temperature, with and without a melt map and noise draws)
        const shell::SurfacePass2 pass2 = shell::fastestSurfacePass2(), pass2x8 = shell::fastestSurfacePass2x8();
        INFO((pass2 == &shell::surfacePass2Plain ? "plain" : "AVX2"));
        CHECK((pass2 == &shell::surfacePass2Plain) == (pass2x8 == &shell::surfacePass2x8Plain));
        std::vector<float> Pu(n), Tu(n), gu(n), gv(n), melt(n);
        for (size_t i = 0; i < n; ++i) {
            Pu[i] = 0.5f + 0.7f * u(rng);
            Tu[i] = 0.5f * u(rng);
            gu[i] = 3.f * u(rng);
            gv[i] = 3.f * u(rng);
            melt[i] = 0.5f + 0.5f * u(rng);
        }
        KobayashiParams kp;
        kp.noise = 0.01;
        size_t updated = 0, updateDiffer = 0;
        for (const size_t group : {4, 8})
        for (const bool withMelt : {false, true}) {
            const shell::SurfaceUpdateInputs in{Pu.data(), Tu.data(), C.data(), gu.data(), gv.data(),
                                                withMelt ? melt.data() : nullptr, &kp, 1.0 / 0.03, 1.0 / (0.03 * 0.03)};
            for (const auto& leaf : band->leaves())
                for (size_t i = leaf.begin; i + group <= leaf.end; i += group) {
                    double chi[8];
                    for (size_t k = 0; k < group; ++k) chi[k] = (i / 4 + k / 4) % 2 ? 0.0 : 0.5 * u(rng);
                    float p4[8], t4[8];
                    (group == 4 ? pass2 : pass2x8)(*band, in, sums.data(), i, chi, p4, t4);
                    for (size_t k = 0; k < group; ++k, ++updated) {
                        float p1, t1;
                        shell::surfaceUpdate(in, i + k, shell::tapSums(*band, C.data(), sums.data(), nullptr, i + k),
                                             chi[k], p1, t1);
                        updateDiffer += std::memcmp(&p1, &p4[k], 4) != 0 || std::memcmp(&t1, &t4[k], 4) != 0;
                    }
                }
        }
        CHECK(updated > 800);
        CHECK(updateDiffer == 0);
    }
}

TEST_CASE("Triangle BVH: the closest point among a leaf's candidates is the whole tree's", "[fast][shell]")
{
    // An icosphere of 1280 small triangles (ties between neighbours at shared edges and
    // vertices): for points around it, the search among the triangles whose boxes meet a box
    // within reach gives the tree's point, triangle (lowest index on ties) and distance exactly.
    const TriangleMesh mesh = makeIcosphere(6.0, 3);
    const std::vector<Vec3d> points(mesh.points.begin(), mesh.points.end());
    const geometry::TriangleBvh bvh(points, mesh.triangles);
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-8.0, 8.0);
    const double reach = 2.5;
    size_t found = 0, differ = 0;
    std::vector<uint32_t> cand;
    for (int k = 0; k < 20000; ++k) {
        const Vec3d p(std::round(u(rng)), std::round(u(rng)), u(rng)); // on lattice lines: exact ties
        bvh.query(openvdb::BBoxd(p - Vec3d(reach + 1e-6), p + Vec3d(reach + 1e-6)), cand);
        Vec3d q1(0.0), q2(0.0);
        uint32_t t1 = 0, t2 = 0;
        double d1 = 0, d2 = 0;
        const bool f1 = bvh.closestPointWithin(p, reach * reach, q1, t1, d1);
        const bool f2 = bvh.closestPointAmong(cand, p, reach * reach, q2, t2, d2);
        found += f1;
        differ += f1 != f2 || (f1 && (q1 != q2 || t1 != t2 || d1 != d2));
    }
    CHECK(found > 1000);
    CHECK(differ == 0);
}

TEST_CASE("Slab sweep: every stage runs once, after what it reads, at any thread count", "[fast][shell]")
{
    // A synthetic band of leaves 6 x 3 x 2 (with one empty slab gap): each stage checks that the
    // stages it depends on have run on its leaf's neighbours (origins at most one leaf apart),
    // and that those that depend on it have not. A schedule that ran a stage early would fail.
    std::vector<shell::ShellBand::Leaf> leaves;
    for (int x = 0; x < 30; ++x) {
        if (x == 17) continue;
        for (int y = 0; y < 3; ++y)
            for (int z = 0; z < 2; ++z) {
                shell::ShellBand::Leaf l;
                l.origin = openvdb::Coord(x * 8, y * 8, z * 8);
                l.begin = uint32_t(leaves.size() * 10);
                l.end = l.begin + 10;
                leaves.push_back(l);
            }
    }
    std::vector<uint32_t> slots(leaves.size());
    for (uint32_t s = 0; s < slots.size(); ++s) slots[s] = s;
    std::shuffle(slots.begin(), slots.end(), std::mt19937(3));
    auto neighbours = [&](uint32_t a, uint32_t b) {
        const openvdb::Coord d = leaves[a].origin - leaves[b].origin;
        return std::abs(d.x()) <= 8 && std::abs(d.y()) <= 8 && std::abs(d.z()) <= 8;
    };
    for (const size_t ranges : {size_t(1), size_t(4), size_t(8)}) {
        shell::SlabSweep sweep;
        sweep.build(leaves, slots, ranges);
        INFO("ranges asked " << ranges << ", built " << sweep.ranges());
        CHECK(sweep.axis() == 0);
        CHECK(sweep.slabs() == 29);
        CHECK((ranges == 1 ? sweep.ranges() == 1 : sweep.ranges() >= ranges - 1));
        std::vector<std::atomic<int>> done(leaves.size()); // stages done per leaf
        for (auto& d : done) d = 0;
        std::atomic<size_t> violations{0};
        auto stage = [&](int k) {
            return [&, k](uint32_t s) {
                for (uint32_t o = 0; o < leaves.size(); ++o) {
                    if (!neighbours(s, o)) continue;
                    if (done[o] < k - 1) ++violations; // what this stage reads is not ready
                    if (k < 3 && done[o] == 3) ++violations; // a neighbour already overwrote its input
                }
                if (done[s] != k - 1) ++violations;
                done[s] = k;
            };
        };
        for (const int threads : {1, 2}) {
            tbb::global_control c(tbb::global_control::max_allowed_parallelism, size_t(threads));
            for (auto& d : done) d = 0;
            violations = 0;
            sweep.run(stage(1), stage(2), stage(3));
            size_t notDone = 0;
            for (auto& d : done) notDone += d != 3;
            INFO(threads << " threads");
            CHECK(notDone == 0);
            CHECK(violations == 0);
        }
    }
}

TEST_CASE("Slab sweep: the surface-node Euler step gives the three passes' bits", "[fast][shell][determinism]")
{
    // A tilted plate (ghost ring, wind) and a sphere, with noise: stepped as one sweep of slabs
    // (at 1 and 2 threads) and as three passes; p, T, growth and freeze time compared bit for bit.
    TriangleMesh plate = makePlate(96, 48);
    MeshPlacement m;
    m.rotateDegrees = Vec3d(20, 35, 0);
    plate.transform(m);
    for (int which = 0; which < 2; ++which) {
        shell::BandSettings bs;
        bs.voxelSize = 1.0;
        bs.discretisation = Discretisation::SurfaceNodes;
        auto band = shell::ShellBand::build(which == 0 ? plate : makeIcosphere(30.0, 6), bs);
        KobayashiParams k = plateParams();
        k.noise = 0.01;
        std::vector<std::vector<float>> results[3];
        for (int run = 0; run < 3; ++run) {
            tbb::global_control c(tbb::global_control::max_allowed_parallelism, run == 1 ? 1 : 2);
            shell::ShellPhaseField pf(band, k, 3.0 / 64.0);
            pf.setSlabSweep(run < 2);
            pf.setWind(Vec3d(2, 1, 0));
            const Vec3d seedA = band->closestPoint(band->size() / 3), seedB = band->closestPoint(2 * band->size() / 3);
            for (size_t i = 0; i < band->size(); ++i) {
                const Vec3d c = band->closestPoint(i);
                pf.p()[i] = seedProfile(std::min((c - seedA).length(), (c - seedB).length()));
            }
            for (int s = 0; s < 40; ++s) pf.step((s + 1) * k.dt, s, 11, nullptr);
            results[run] = {pf.p(), pf.T(), pf.growthValues(), pf.freezeValues()};
        }
        INFO((which == 0 ? "plate" : "sphere"));
        size_t frozenish = 0;
        for (float v : results[0][0]) frozenish += v > 0.5f;
        CHECK(frozenish > 20);
        for (int f = 0; f < 4; ++f) {
            INFO("field " << f);
            REQUIRE(results[0][size_t(f)].size() == results[2][size_t(f)].size());
            CHECK(std::memcmp(results[0][size_t(f)].data(), results[2][size_t(f)].data(), results[0][size_t(f)].size() * 4) == 0);
            CHECK(std::memcmp(results[1][size_t(f)].data(), results[2][size_t(f)].data(), results[1][size_t(f)].size() * 4) == 0);
        }
    }
}
