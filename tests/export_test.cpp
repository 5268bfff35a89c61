// Export: hexagonal frames resampled to square voxels (or kept with --keep-lattice) and the
// displacement map written as a 16-bit PNG.
#include <frostvdb/BuildPaths.h>
#include "test_util.h"

#include <frostvdb/core/Export.h>
#include <frostvdb/io/Png.h>
#include <frostvdb/io/VdbIO.h>

#include <openvdb/tools/Interpolation.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>

using namespace frostvdb;
using namespace frostvdb::test;
using openvdb::Coord;
using openvdb::Vec3d;

namespace {

const double kH = 0.001;

Domain hexPlane(int n) { return makePlaneDomain(Lattice(LatticeKind::Hexagonal), Coord(n, n, 1), kH); }

/// A smooth blob (fog volume in [0,1]) on the hexagonal lattice, centred in world space.
openvdb::FloatGrid::Ptr hexBlob(const Domain& dom, Vec3d& centre, double sigma)
{
    auto g = openvdb::FloatGrid::create(0.f);
    g->setTransform(dom.transform());
    g->setName("ice");
    g->setGridClass(openvdb::GRID_FOG_VOLUME);
    g->insertMeta("note", openvdb::StringMetadata("kept"));
    centre = dom.transform()->indexToWorld(dom.centre());
    auto acc = g->getAccessor();
    for (auto it = dom.bbox().begin(); it; ++it) {
        const double r2 = (dom.transform()->indexToWorld(*it) - centre).lengthSqr();
        const float v = float(std::exp(-r2 / (2 * sigma * sigma)));
        if (v > 1e-4f) acc.setValue(*it, v);
    }
    return g;
}

double sum(const openvdb::FloatGrid& g)
{
    double s = 0;
    for (auto it = g.cbeginValueOn(); it; ++it) s += *it;
    return s;
}

const char* kHexScene = "[scene]\nname = \"hx\"\nframes = 1\nsteps_per_frame = 20\n"
                        "[domain]\nlattice = \"hexagonal\"\nsize = [48, 40]\nvoxel_size = 0.0001\n[phase_field]\n";

openvdb::GridPtrVecPtr readAll(const std::string& path)
{
    return readVdb(path);
}

openvdb::GridBase::Ptr named(const openvdb::GridPtrVec& grids, const std::string& name)
{
    for (auto& g : grids)
        if (g->getName() == name) return g;
    FAIL("no grid " << name);
    return nullptr;
}

} // namespace

TEST_CASE("Export resamples a hexagonal grid to square voxels at the same world place", "[fast][export]")
{
    const Domain dom = hexPlane(64);
    Vec3d centre;
    const double sigma = 6 * kH;
    auto hex = hexBlob(dom, centre, sigma);
    const auto out = exportGrids({hex}, dom, false);
    REQUIRE(out.size() == 1);
    auto sq = openvdb::gridPtrCast<openvdb::FloatGrid>(out[0]);
    REQUIRE(sq);

    // Uniform linear transform, voxel size h, index 0 at world 0; names, class and metadata kept.
    CHECK(sq->transform().isLinear());
    CHECK(sq->transform().hasUniformScale());
    CHECK(sq->transform() == *openvdb::math::Transform::createLinearTransform(kH));
    CHECK(sq->getName() == "ice");
    CHECK(sq->getGridClass() == openvdb::GRID_FOG_VOLUME);
    CHECK(sq->metaValue<std::string>("note") == "kept");
    CHECK_NOTHROW(checkFinite(*sq));

    // One voxel thick, values in [0,1], equal to the hexagonal grid sampled at the same world
    // positions and close to the blob itself.
    const auto bb = sq->evalActiveVoxelBoundingBox();
    CHECK(bb.min().z() == 0);
    CHECK(bb.max().z() == 0);
    auto hacc = hex->getConstAccessor();
    openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> hs(hacc, hex->transform());
    double worst = 0, worstVsHex = 0;
    for (auto it = sq->cbeginValueOn(); it; ++it) {
        CHECK(*it >= 0.f);
        CHECK(*it <= 1.f);
        const Vec3d w = sq->transform().indexToWorld(it.getCoord());
        const double exact = std::exp(-(w - centre).lengthSqr() / (2 * sigma * sigma));
        worst = std::max(worst, std::fabs(*it - exact));
        worstVsHex = std::max(worstVsHex, double(std::fabs(*it - hs.wsSample(w))));
    }
    CHECK(worstVsHex < 1e-4);
    CHECK(worst < 0.02); // bilinear interpolation error of a blob 6 cells wide
    // Mass: sum * cell area (hexagonal cells are sqrt(3)/2 h^2).
    const double hexMass = sum(*hex) * kH * kH * std::sqrt(3.0) / 2.0;
    const double sqMass = sum(*sq) * kH * kH;
    CHECK(sqMass == Approx(hexMass).epsilon(0.03));
}

TEST_CASE("Export leaves square domains and grids on other transforms alone", "[fast][export]")
{
    const Domain square = makePlaneDomain(Lattice(LatticeKind::Square), Coord(16, 16, 1), kH);
    auto g = openvdb::FloatGrid::create(0.f);
    g->setTransform(square.transform());
    CHECK(exportGrids({g}, square, false)[0] == g);
    const Domain hex = hexPlane(16);
    auto own = openvdb::FloatGrid::create(0.f); // e.g. an effect's own square `ice` raster
    own->setTransform(openvdb::math::Transform::createLinearTransform(kH / 2));
    CHECK(exportGrids({own}, hex, false)[0] == own);
}

TEST_CASE("Hexagonal frames are written square, keep_lattice writes the shear", "[fast][export]")
{
    const double h = 0.0001;
    for (bool keep : {false, true}) {
        const std::string dir = tempDir(keep ? "export_keep" : "export_square");
        auto sim = makeSim(kHexScene, {std::string("output.keep_lattice=") + (keep ? "true" : "false"),
                                       "output.preview=none"});
        RunOptions ro;
        ro.outDir = dir;
        ro.progress = false;
        sim.run(ro);
        auto grids = readAll(dir + "/hx.0001.vdb");
        REQUIRE(grids->size() >= 3);
        for (auto& g : *grids) {
            INFO(g->getName());
            const Vec3d e = g->transform().indexToWorld(Vec3d(0, 1, 0));
            if (keep) {
                CHECK(e.x() == Approx(h / 2));
                CHECK(e.y() == Approx(h * std::sqrt(3.0) / 2));
                CHECK(g->metaValue<std::string>("frostvdb_lattice").find("hexagonal") != std::string::npos);
            } else {
                CHECK(g->transform() == *openvdb::math::Transform::createLinearTransform(h));
                CHECK(g->metaValue<std::string>("frostvdb_lattice").find("square") != std::string::npos);
            }
        }
        CHECK(named(*grids, "ice")->getGridClass() == openvdb::GRID_FOG_VOLUME);
    }
}

TEST_CASE("Command line --keep-lattice writes the sheared transform", "[fast][export][cli]")
{
    const std::string dir = tempDir("export_cli");
    std::ofstream(dir + "/hx.toml") << kHexScene;
    const std::string bin = FROSTVDB_BINARY;
    REQUIRE(runCommand(bin + " run " + dir + "/hx.toml --quiet --keep-lattice --out " + dir + "/out", dir + "/log") == 0);
    auto grids = readAll(dir + "/out/hx.0001.vdb");
    const Vec3d e = named(*grids, "ice")->transform().indexToWorld(Vec3d(0, 1, 0));
    CHECK(e.x() == Approx(0.00005));
}

TEST_CASE("Displacement PNG is 16-bit, raster-sized and follows growth", "[fast][export]")
{
    SECTION("square lattice: one pixel per cell, equal to the growth grid")
    {
        const std::string dir = tempDir("export_disp_sq");
        auto sim = makeSim("[scene]\nname = \"d\"\nframes = 1\nsteps_per_frame = 60\n[domain]\nsize = [40, 24]\n"
                           "[phase_field]\n[output]\npreview = \"none\"\n");
        RunOptions ro;
        ro.outDir = dir;
        ro.progress = false;
        const auto sum = sim.run(ro);
        const std::string png = dir + "/d.0001.displacement.png";
        REQUIRE(std::filesystem::exists(png));
        CHECK(std::find(sum.files.begin(), sum.files.end(), png) != sum.files.end());
        int w = 0, h = 0, bits = 0;
        const auto px = readPngGray(png, w, h, &bits);
        CHECK(bits == 16);
        CHECK(w == 40);
        CHECK(h == 24);
        auto growth = openvdb::gridPtrCast<openvdb::FloatGrid>(named(*readAll(dir + "/d.0001.vdb"), "growth"));
        auto acc = growth->getConstAccessor();
        float mx = 0;
        std::vector<std::pair<float, float>> pairs;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const float g = acc.getValue(Coord(x, h - 1 - y, 0));
                mx = std::max(mx, g);
                pairs.emplace_back(g, px[size_t(y) * w + x]);
                CHECK(px[size_t(y) * w + x] == Approx(g).margin(1.0 / 65535 + 1e-6));
            }
        CHECK(mx == Approx(1.0)); // normalised growth: the PNG spans the full range
        std::sort(pairs.begin(), pairs.end());
        for (size_t i = 1; i < pairs.size(); ++i) CHECK(pairs[i].second >= pairs[i - 1].second);
    }
    SECTION("hexagonal lattice: the square raster around the rhombus")
    {
        const std::string dir = tempDir("export_disp_hex");
        auto sim = makeSim(kHexScene, {"output.preview=none"});
        RunOptions ro;
        ro.outDir = dir;
        ro.progress = false;
        sim.run(ro);
        int w = 0, h = 0, bits = 0;
        readPngGray(dir + "/hx.0001.displacement.png", w, h, &bits);
        CHECK(bits == 16);
        CHECK(w == int(std::floor(47 + 39 / 2.0)) + 1);
        CHECK(h == int(std::floor(39 * std::sqrt(3.0) / 2)) + 1);
    }
    SECTION("off by key, and never for boxes")
    {
        const std::string dir = tempDir("export_disp_off");
        auto sim = makeSim(kHexScene, {"output.preview=none", "output.displacement_png=false"});
        RunOptions ro;
        ro.outDir = dir;
        ro.progress = false;
        sim.run(ro);
        CHECK_FALSE(std::filesystem::exists(dir + "/hx.0001.displacement.png"));
        auto box = makeSim("[scene]\nname = \"b\"\nframes = 1\nsteps_per_frame = 2\n[domain]\nkind = \"box\"\n"
                           "size = [12, 12, 12]\n[phase_field]\ndt = 0.0001\n[output]\npreview = \"none\"\n");
        box.run(ro);
        CHECK(std::filesystem::exists(dir + "/b.0001.vdb"));
        CHECK_FALSE(std::filesystem::exists(dir + "/b.0001.displacement.png"));
    }
}

TEST_CASE("Large displacement maps are UDIM tiles, only those with ice, equal to growth", "[fast][export]")
{
    // 300 x 40 square plane, 128-pixel tiles: 3 tiles across, 1 up; growth in tiles 1001 and 1003
    const Domain dom = makePlaneDomain(Lattice(LatticeKind::Square), Coord(300, 40, 1), kH);
    auto g = openvdb::FloatGrid::create(0.f);
    g->setTransform(dom.transform());
    for (int j = 5; j <= 10; ++j)
        for (int i = 10; i <= 20; ++i) g->tree().setValue(Coord(i, j, 0), 0.5f);
    g->tree().setValue(Coord(260, 30, 0), 1.f);
    const std::string dir = tempDir("export_udim");
    const auto files = writeDisplacementMaps(*g, dom, dir + "/d.0001.displacement", 128);
    REQUIRE(files.size() == 2);
    CHECK(files[0] == dir + "/d.0001.displacement.1001.png");
    CHECK(files[1] == dir + "/d.0001.displacement.1003.png");
    CHECK(!std::filesystem::exists(dir + "/d.0001.displacement.1002.png"));
    int w = 0, h = 0, bits = 0;
    const auto t1 = readPngGray(files[0], w, h, &bits);
    CHECK(w == 128);
    CHECK(h == 128);
    CHECK(bits == 16);
    auto acc = g->getConstAccessor();
    for (int b = 0; b < 40; ++b) // row 0 at the top of the tile: b = 127 - row
        for (int a = 0; a < 128; ++a)
            CHECK(t1[size_t(127 - b) * 128 + a] == Approx(acc.getValue(Coord(a, b, 0))).margin(1.0 / 65535 + 1e-6));
    const auto t3 = readPngGray(files[1], w, h, &bits);
    CHECK(t3[size_t(127 - 30) * 128 + (260 - 256)] == Approx(1.0));
    CHECK(t3[size_t(127 - 30) * 128 + (261 - 256)] == Approx(0.0).margin(1e-6));
    // a raster within one tile stays one image, as before
    const auto one = writeDisplacementMaps(*g, dom, dir + "/e", 4096);
    REQUIRE(one.size() == 1);
    CHECK(one[0] == dir + "/e.png");
}

TEST_CASE("Export clips a large hexagonal plane leaf by leaf to OpenVDB's clip values",
          "[fast][export]")
{
    // A small blob in a 4096^2 plane: the export's own clip to the one-voxel-thick raster (OpenVDB's
    // GridBase::clip refills straddling tiles; 182 MB of a 2048^2 bench scale run) must give the
    // same active voxels and values as OpenVDB's clip, with leaves only near the blob.
    const Domain dom = hexPlane(4096);
    Vec3d centre;
    auto hex = hexBlob(dom, centre, 6 * kH);
    const auto out = exportGrids({hex}, dom, false);
    auto sq = openvdb::gridPtrCast<openvdb::FloatGrid>(out[0]);
    REQUIRE(sq);
    auto ref = openvdb::gridPtrCast<openvdb::FloatGrid>(resampleGrid(*hex, *squareTransform(dom)));
    const SquareRaster sr = squareRaster(dom);
    ref->clip(openvdb::CoordBBox(Coord(sr.a0, sr.b0, 0), Coord(sr.a1, sr.b1, 0)));
    CHECK(sq->activeVoxelCount() == ref->activeVoxelCount());
    CHECK(sq->activeVoxelCount() > 0);
    auto racc = ref->getConstAccessor();
    for (auto it = sq->cbeginValueOn(); it; ++it) {
        CHECK(racc.isValueOn(it.getCoord()));
        CHECK(racc.getValue(it.getCoord()) == *it);
    }
    CHECK(sq->tree().leafCount() <= ref->tree().leafCount()); // leaves only near the blob
    CHECK(sq->tree().leafCount() <= hex->tree().leafCount() * 4);
}

TEST_CASE("Sparse resampling equals the box sampler at every output voxel, isolated voxels at leaf edges",
          "[fast][export]")
{
    // Isolated active voxels (the hardest case for the footprints: a leaf's active box is a
    // single voxel) on leaf faces and corners, on several z layers, some values negative; every
    // output voxel of a box around them must be on exactly when a corner with a positive weight
    // is active, with BoxSampler's value, bit for bit.
    const Domain dom = hexPlane(64);
    auto hex = openvdb::FloatGrid::create(0.f);
    hex->setTransform(dom.transform());
    auto acc = hex->getAccessor();
    uint64_t h = 12345;
    const int edges[] = {0, 1, 6, 7, 8, 15, 16, 23, 31, 32, 40};
    for (int i = 0; i < 60; ++i) {
        h = h * 6364136223846793005ull + 1442695040888963407ull;
        const int x = edges[(h >> 20) % 11] + 8 * int((h >> 30) % 3), y = edges[(h >> 40) % 11] + 8 * int((h >> 50) % 2);
        const int z = int((h >> 60) % 4) == 3 ? 7 : int((h >> 60) % 4);
        acc.setValue(Coord(x, y, z), float(int((h >> 8) % 2001) - 1000) / 977.f);
    }
    const auto target = squareTransform(dom);
    auto out = openvdb::gridPtrCast<openvdb::FloatGrid>(resampleGrid(*hex, *target));
    REQUIRE(out);
    openvdb::CoordBBox box;
    for (int c = 0; c < 8; ++c) {
        const Vec3d ip((c & 1) ? 60 : -4, (c & 2) ? 60 : -4, (c & 4) ? 10 : -3);
        box.expand(target->worldToIndexCellCentered(hex->transform().indexToWorld(ip)));
    }
    const auto hacc = hex->getConstAccessor();
    const auto oacc = out->getConstAccessor();
    int64_t on = 0, mismatches = 0;
    for (auto it = box.begin(); it; ++it) {
        const Vec3d p = hex->transform().worldToIndex(target->indexToWorld(*it));
        const Coord i0 = Coord::floor(p);
        const Vec3d f = p - i0.asVec3d();
        bool expectOn = false;
        for (int k = 0; k < 8; ++k) {
            const double wx = (k & 1) ? f.x() : 1.0 - f.x(), wy = (k & 2) ? f.y() : 1.0 - f.y(),
                         wz = (k & 4) ? f.z() : 1.0 - f.z();
            if (wx * wy * wz > 0.0 && hacc.isValueOn(i0.offsetBy(k & 1 ? 1 : 0, k & 2 ? 1 : 0, k & 4 ? 1 : 0)))
                expectOn = true;
        }
        float want = 0.f;
        openvdb::tools::BoxSampler::sample(hacc, p, want);
        float got = 0.f;
        const bool gotOn = oacc.probeValue(*it, got);
        on += expectOn;
        if (gotOn != expectOn || (expectOn && std::memcmp(&got, &want, sizeof(float)) != 0)) ++mismatches;
    }
    CHECK(on > 100); // about 3 output voxels per isolated input voxel
    CHECK(mismatches == 0);
    CHECK(int64_t(out->activeVoxelCount()) == on);
}
