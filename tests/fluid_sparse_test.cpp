// [fluid] the band-limited 2D/3D MAC stable fluid (fluid/SparseFluid.h): divergence-free after the
// projection, solids at rest, 3D equal to 2D on a z-invariant set-up, the band converging to the
// full-box solve, MacCormack bounded at CFL 5, the same bits at 1 and 2 threads.
#include <frostvdb/fluid/SparseFluid.h>
#include <frostvdb/fluid/Fluid.h>

#include <catch2/catch.hpp>

#include <tbb/global_control.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <random>

using namespace frostvdb;
using namespace frostvdb::fluid;

namespace {

/// A ball (3D) or disc (2D) of radius r centred in the box.
std::function<bool(int, int, int)> ball(const openvdb::Coord& n, int dim, double r)
{
    const double cx = 0.5 * (n.x() - 1), cy = 0.5 * (n.y() - 1), cz = 0.5 * (n.z() - 1);
    return [=](int i, int j, int k) {
        const double dz = dim == 3 ? k - cz : 0.0;
        return (i - cx) * (i - cx) + (j - cy) * (j - cy) + dz * dz <= r * r;
    };
}

SparseFluidParams tight()
{
    SparseFluidParams p;
    p.poisson.relativeTolerance = 0;
    p.poisson.absoluteTolerance = 1e-7; // max |div| per unit length, velocity scale 1
    p.poisson.maxIterations = 100;
    return p;
}

} // namespace

TEST_CASE("sparse fluid: divergence-free after projection, solids at rest (2D and 3D)", "[fluid]")
{
    for (int dim : {2, 3}) {
        const openvdb::Coord n = dim == 3 ? openvdb::Coord(28, 24, 20) : openvdb::Coord(64, 48, 1);
        SparseFluidParams p = tight();
        p.bandWidth = 6;
        p.wakeLength = 10;
        SparseFluid f(p, n, dim);
        f.setSolid(ball(n, dim, 5));
        f.setFreeStream();
        f.project();
        for (int s = 0; s < 3; ++s) f.step(0.8);
        INFO("dim " << dim << " iterations " << f.pressureStats().iterations);
        CHECK(f.pressureStats().converged);
        CHECK(f.pressureStats().iterations <= 20);
        CHECK(f.maxDivergence() < 1e-5);
        CHECK(f.activeCells() > 0);
        CHECK(f.activeCells() < size_t(n.x()) * n.y() * n.z() * 3 / 4); // a band, not the box
        // Every face of a solid cell is at rest.
        double maxSolid = 0;
        for (int k = 0; k < n.z(); ++k)
            for (int j = 0; j < n.y(); ++j)
                for (int i = 0; i < n.x(); ++i) {
                    if (!f.solid(i, j, k)) continue;
                    for (int c = 0; c < dim; ++c) {
                        maxSolid = std::max(maxSolid, std::fabs(f.face(c, i, j, k)));
                        maxSolid = std::max(maxSolid, std::fabs(f.face(c, i + (c == 0), j + (c == 1), k + (c == 2))));
                    }
                }
        CHECK(maxSolid == 0.0);
        // The flow goes round: slower right in front of the ball than the free stream.
        const auto c = n.asVec3d() * 0.5 - openvdb::Vec3d(0.5);
        CHECK(f.sample(openvdb::Vec3d(c.x() - 6.5, c.y(), dim == 3 ? c.z() : 0)).x() < 0.7);
    }
}

TEST_CASE("sparse fluid: 3D equals 2D on a z-invariant set-up", "[fluid]")
{
    SparseFluidParams p = tight();
    p.poisson.absoluteTolerance = 1e-10;
    p.bandWidth = 0;
    p.lateral = SideKind::Outflow;
    const openvdb::Coord n2(40, 32, 1), n3(40, 32, 6);
    SparseFluid f2(p, n2, 2);
    // 3D: the same disc as a cylinder along z.
    SparseFluidParams p3 = p;
    p3.sides[4] = p3.sides[5] = 1; // walls at +-z: the 2D plane's implicit Neumann
    SparseFluid f3(p3, n3, 3);
    auto disc = ball(n2, 2, 5);
    f2.setSolid(disc);
    f3.setSolid([&](int i, int j, int) { return disc(i, j, 0); });
    f2.setFreeStream();
    f3.setFreeStream();
    for (int s = 0; s < 4; ++s) {
        f2.step(1.0);
        f3.step(1.0);
    }
    double err = 0, wMax = 0;
    for (int k = 0; k < n3.z(); ++k)
        for (int j = 0; j < n2.y(); ++j)
            for (int i = 0; i <= n2.x(); ++i) err = std::max(err, std::fabs(f3.face(0, i, j, k) - f2.face(0, i, j, 0)));
    for (int k = 0; k <= n3.z(); ++k)
        for (int j = 0; j < n2.y(); ++j)
            for (int i = 0; i < n2.x(); ++i) wMax = std::max(wMax, std::fabs(f3.face(2, i, j, k)));
    CHECK(err < 1e-6);
    CHECK(wMax < 1e-6);
}

TEST_CASE("sparse fluid: the band converges to the full-box solve as it widens", "[fluid]")
{
    const openvdb::Coord n(96, 64, 1);
    auto velocityNear = [&](double band) {
        SparseFluidParams p = tight();
        p.bandWidth = band;
        p.wakeLength = 2 * band;
        SparseFluid f(p, n, 2);
        f.setSolid(ball(n, 2, 6));
        f.setFreeStream();
        f.project();
        std::vector<double> v;
        for (int j = 22; j < 42; ++j)
            for (int i = 38; i < 58; ++i) v.push_back(f.face(0, i, j, 0));
        return v;
    };
    const auto full = velocityNear(0);
    double prev = 1e30;
    for (double band : {3.0, 6.0, 12.0, 24.0}) {
        const auto v = velocityNear(band);
        double e = 0;
        for (size_t k = 0; k < v.size(); ++k) e = std::max(e, std::fabs(v[k] - full[k]));
        INFO("band " << band << " error " << e);
        CHECK(e < prev);
        prev = e;
    }
    CHECK(prev < 0.05);
}

TEST_CASE("sparse fluid: MacCormack advection stays within the data at CFL 5", "[fluid][stability]")
{
    const openvdb::Coord n(48, 40, 1);
    SparseFluidParams p = tight();
    p.bandWidth = 0;
    p.inflowSpeed = 5.0; // 5 cells per unit step
    SparseFluid f(p, n, 2);
    f.setSolid(ball(n, 2, 6));
    f.setFreeStream();
    f.project();
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> d(0.0, 1.0);
    // T on a grid offset from the box (cell (i, j) is voxel origin + (i, j)), random in every cell.
    const openvdb::Coord origin(-5, 3, 0);
    auto T = openvdb::FloatGrid::create(0.5f);
    auto acc = T->getAccessor();
    float lo = 1, hi = 0;
    for (int j = 0; j < n.y(); ++j)
        for (int i = 0; i < n.x(); ++i) {
            const float t = float(d(rng));
            acc.setValue(origin + openvdb::Coord(i, j, 0), t);
            lo = std::min(lo, t);
            hi = std::max(hi, t);
        }
    size_t moved = 0;
    for (int s = 0; s < 5; ++s) {
        const auto changes = f.advectScalar(*T, origin, 1.0);
        moved += changes.size();
        for (const auto& ch : changes) acc.setValue(origin + ch.cell, float(ch.value));
    }
    CHECK(moved > 0);
    for (auto it = T->cbeginValueOn(); it; ++it) {
        REQUIRE(*it >= lo);
        REQUIRE(*it <= hi);
    }
    // The velocity too: no face exceeds the largest speed present before the step.
    double before = 0, after = 0;
    for (int j = 0; j < n.y(); ++j)
        for (int i = 0; i <= n.x(); ++i) before = std::max(before, std::fabs(f.face(0, i, j, 0)));
    f.step(1.0);
    for (int j = 0; j < n.y(); ++j)
        for (int i = 0; i <= n.x(); ++i) after = std::max(after, std::fabs(f.face(0, i, j, 0)));
    CHECK(std::isfinite(after));
    CHECK(after < 3 * before); // the projection may redistribute, the advection adds no blow-up
}

TEST_CASE("sparse fluid: 1 and 2 threads give the same bits", "[fluid]")
{
    const openvdb::Coord n(24, 20, 16);
    auto run = [&](int threads) {
        tbb::global_control gc(tbb::global_control::max_allowed_parallelism, threads);
        SparseFluidParams p;
        p.bandWidth = 5;
        SparseFluid f(p, n, 3);
        f.setSolid(ball(n, 3, 4));
        f.setFreeStream();
        for (int s = 0; s < 3; ++s) f.step(1.5);
        std::vector<double> v;
        for (int c = 0; c < 3; ++c)
            for (int k = 0; k < n.z() + (c == 2); ++k)
                for (int j = 0; j < n.y() + (c == 1); ++j)
                    for (int i = 0; i < n.x() + (c == 0); ++i) v.push_back(f.face(c, i, j, k));
        return v;
    };
    const auto a = run(1), b = run(2);
    REQUIRE(a.size() == b.size());
    CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
}

TEST_CASE("sparse fluid over the whole box equals the dense 2D reference solver", "[fluid]")
{
    const openvdb::Coord n(64, 48, 1);
    auto disc = ball(n, 2, 6);
    SparseFluidParams p = tight();
    p.poisson.absoluteTolerance = 1e-9;
    p.bandWidth = 0;
    SparseFluid f(p, n, 2);
    f.setSolid(disc);
    f.setFreeStream();
    f.project();
    ice::FluidParams fp;
    fp.inflowSpeed = 1.0;
    fp.tolerance = 1e-9;
    ice::StableFluid2D d(fp, n.x(), n.y(), 1.0);
    std::vector<uint8_t> mask(size_t(n.x()) * n.y());
    for (int j = 0; j < n.y(); ++j)
        for (int i = 0; i < n.x(); ++i) mask[size_t(j) * n.x() + i] = disc(i, j, 0);
    d.setSolid(mask);
    d.setFreeStream();
    d.project();
    double err = 0;
    for (int j = 0; j < n.y(); ++j)
        for (int i = 0; i <= n.x(); ++i) err = std::max(err, std::fabs(f.face(0, i, j, 0) - d.u(i, j)));
    for (int j = 0; j <= n.y(); ++j)
        for (int i = 0; i < n.x(); ++i) err = std::max(err, std::fabs(f.face(1, i, j, 0) - d.v(i, j)));
    CHECK(err < 1e-6);
}

TEST_CASE("sparse fluid: face storage follows the band, not the box", "[fluid]")
{
    // A disc of ice facing the wind (radius 6, 2 cells thick) in boxes of 64^3 and 128^3: the same
    // band (same place relative to the 8^3 blocks), a box eight times larger.
    auto plate = [](int n) {
        SparseFluidParams p;
        p.bandWidth = 4;
        p.wakeLength = 8;
        auto f = std::make_unique<SparseFluid>(p, openvdb::Coord(n), 3);
        const double c = 0.5 * (n - 1);
        f->setSolid([=](int i, int j, int k) {
            return std::fabs(i - c) <= 1.0 && (j - c) * (j - c) + (k - c) * (k - c) <= 36.0;
        });
        f->setFreeStream();
        return f;
    };
    auto small = plate(64), large = plate(128);
    INFO("face blocks " << small->faceBlocks() << " of " << small->boxBlocks() << ", " << large->faceBlocks() << " of "
                        << large->boxBlocks());
    CHECK(small->activeCells() == large->activeCells());
    CHECK(large->faceBlocks() == small->faceBlocks()); // storage follows the band volume
    CHECK(large->faceBytes() == small->faceBytes());
    CHECK(large->boxBlocks() > 6 * small->boxBlocks());
    CHECK(large->faceBlocks() * 50 < large->boxBlocks()); // under 2 % of the box's blocks
    // Blocks hold the band and its edge: at most 4x the band and the ice, cell for cell.
    CHECK(large->faceBlocks() * 512 < 4 * (large->activeCells() + 6 * 6 * 4 * 3));
    // Faces in no block read as the free stream, also after a step.
    large->step(1.0);
    CHECK(large->face(0, 3, 5, 7) == 1.0);
    CHECK(large->face(1, 120, 100, 2) == 0.0);
    CHECK(large->sample(openvdb::Vec3d(5.3, 110.2, 9.9)).x() == 1.0);
    CHECK(large->maxDivergence() < 1e-3);
    // In blocked storage: 1 and 2 threads give the same faces and the same band-only T advection
    // (T read from a grid, from the blocks inside the band and from the grid where traces leave
    // them), and T stays within its data.
    auto blockedRun = [&](int threads) {
        tbb::global_control gc(tbb::global_control::max_allowed_parallelism, threads);
        auto f = plate(64);
        f->step(2.0);
        auto T = openvdb::FloatGrid::create(0.0f);
        auto acc = T->getAccessor();
        std::mt19937 rng(5);
        std::uniform_real_distribution<float> d(0.0f, 1.0f);
        for (int k = 0; k < 64; ++k)
            for (int j = 0; j < 64; ++j)
                for (int i = 0; i < 64; ++i) acc.setValue(openvdb::Coord(i, j, k), d(rng));
        std::vector<double> out;
        const auto changes = f->advectScalar(*T, openvdb::Coord(0), 2.0);
        CHECK(changes.size() > 1000);
        for (const auto& ch : changes) {
            CHECK((ch.value >= 0.0 && ch.value <= 1.0));
            out.push_back(ch.value);
            out.push_back(ch.cell.x() + 64.0 * (ch.cell.y() + 64.0 * ch.cell.z()));
        }
        for (int c = 0; c < 3; ++c)
            for (int k = 20; k < 44; ++k)
                for (int j = 20; j < 44; ++j)
                    for (int i = 20; i < 64; ++i) out.push_back(f->face(c, i, j, k));
        return out;
    };
    const auto one = blockedRun(1), two = blockedRun(2);
    REQUIRE(one.size() == two.size());
    CHECK(std::memcmp(one.data(), two.data(), one.size() * sizeof(double)) == 0);
    CHECK(small->denseFaces() == false);
    // The whole box (band width 0) allocates every block.
    SparseFluidParams all;
    all.bandWidth = 0;
    SparseFluid f(all, openvdb::Coord(20, 17, 9), 3);
    CHECK(f.faceBlocks() == f.boxBlocks());
    CHECK(f.denseFaces());
}
