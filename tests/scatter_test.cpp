// Scatter seeds (issue 23 item 3): `count` sites spread by area with a `min_distance`, weighted by
// a PNG or a mesh's vertex colours, on planes and on shells.
#include "test_util.h"

#include <frostvdb/ice/Crystal.h>
#include <frostvdb/io/Png.h>

#include <catch2/catch.hpp>

#include <filesystem>

using namespace frostvdb;
using openvdb::Vec3d;

TEST_CASE("Scatter seeds: count, minimum distance, weight map, same sites every time", "[fast][crystal]")
{
    const Domain plane = makePlaneDomain(Lattice(LatticeKind::Square, 3.0 / 64.0), openvdb::Coord(128, 128, 1), 1e-3);
    ice::CrystalShape s;
    s.kind = ice::CrystalShape::Kind::Scatter;
    s.count = 40;
    s.minDistance = 12;
    const auto sites = ice::scatterSites(plane, s);
    REQUIRE(sites.size() == 40);
    double closest = 1e9;
    for (size_t a = 0; a < sites.size(); ++a) {
        CHECK(plane.bbox().isInside(openvdb::Coord::round(sites[a])));
        for (size_t b = a + 1; b < sites.size(); ++b) closest = std::min(closest, (sites[a] - sites[b]).length());
    }
    CHECK(closest >= 12.0);
    CHECK(ice::scatterSites(plane, s) == sites); // a pure function of the shape and the domain
    s.seed = 2;
    CHECK(ice::scatterSites(plane, s) != sites);

    // a map black on the left half (x < 64), white on the right: every site on the right
    const std::string png = (std::filesystem::temp_directory_path() / "frostvdb_scatter_weight.png").string();
    std::vector<float> img(64 * 64);
    for (int j = 0; j < 64; ++j)
        for (int i = 0; i < 64; ++i) img[size_t(j * 64 + i)] = i < 32 ? 0.f : 1.f;
    writePngGray(png, 64, 64, img, 8);
    s.weight = ice::CrystalShape::Weight::Texture;
    s.weightPath = png;
    s.minDistance = 0;
    const auto right = ice::scatterSites(plane, s);
    REQUIRE(right.size() == 40);
    for (const Vec3d& p : right) CHECK(p.x() >= 63.0);
    std::filesystem::remove(png);
}

TEST_CASE("Scatter seeds on a shell lie on the surface, by area", "[fast][crystal][shell]")
{
    auto sim = test::makeSim("[domain]\nkind = \"shell\"\nvoxel_size = 0.0001\nsphere_radius = 0.002\n"
                             "[[crystal.seed]]\nshape = \"scatter\"\ncount = 60\nmin_distance = 5\n[phase_field]\n");
    const Domain& dom = sim.world().domain;
    ice::CrystalShape s;
    s.kind = ice::CrystalShape::Kind::Scatter;
    s.count = 60;
    s.minDistance = 5;
    const auto sites = ice::scatterSites(dom, s);
    REQUIRE(sites.size() == 60);
    int north = 0;
    for (const Vec3d& p : sites) {
        CHECK(std::fabs(p.length() - 20.0) < 0.2); // R = 20 voxels (the icosphere's facets sag 0.2 %)
        north += p.z() > 0 ? 1 : 0;
    }
    CHECK(north > 15); // by area: about half in each hemisphere
    CHECK(north < 45);
    // a scatter with vertex_colours needs a mesh that has them: one line naming the key
    const std::string err = test::errorOf("[domain]\nkind = \"shell\"\nsphere_radius = 0.002\n[[crystal.seed]]\n"
                                          "shape = \"scatter\"\nweight = \"vertex_colours\"\n[phase_field]\n");
    CHECK(err.find("weight") != std::string::npos);
    CHECK(err.find('\n') == std::string::npos);
}
