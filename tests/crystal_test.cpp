// [crystal]: seed shapes, PNG and VDB maps, the melt map's background and the error messages.
#include "test_util.h"

#include <frostvdb/core/Error.h>
#include <frostvdb/ice/Crystal.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/io/Png.h>

#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <set>

using namespace frostvdb;
using namespace frostvdb::test;
using openvdb::Coord;

namespace {

using SimPtr = std::unique_ptr<Simulation>;

/// Builds and initialises a scene; returns the simulation (fields allocated, nothing stepped).
SimPtr initSim(const std::string& text, const std::vector<std::string>& overrides = {})
{
    Scene scene = Scene::fromString(text, "test.toml");
    for (auto& o : overrides) scene.applyOverride(o);
    auto sim = std::make_unique<Simulation>(std::move(scene));
    sim->initialize();
    return sim;
}

/// The cells where a grid holds @a value (active or not; the domain box only).
std::set<Coord> cellsWith(const SimPtr& sim, const openvdb::FloatGrid& g, float value)
{
    std::set<Coord> out;
    auto acc = g.getConstAccessor();
    const auto& bb = sim->world().domain.bbox();
    for (auto it = bb.begin(); it; ++it)
        if (acc.getValue(*it) == value) out.insert(*it);
    return out;
}

openvdb::FloatGrid::Ptr field(const SimPtr& sim, const std::string& name)
{
    auto g = sim->world().fields.get<openvdb::FloatGrid>(name);
    REQUIRE(g);
    return g;
}

openvdb::FloatGrid::Ptr field(Simulation& sim, const std::string& name)
{
    auto g = sim.world().fields.get<openvdb::FloatGrid>(name);
    REQUIRE(g);
    return g;
}

/// The SceneError message of building and initialising a scene ("" if none).
std::string initErrorOf(const std::string& text)
{
    try {
        initSim(text);
    } catch (const SceneError& e) {
        return e.what();
    }
    return "";
}

std::string plane(int nx, int ny, const char* lattice = "square")
{
    return "[domain]\nsize = [" + std::to_string(nx) + ", " + std::to_string(ny) + "]\nlattice = \"" + lattice +
           "\"\nvoxel_size = 0.001\n";
}

} // namespace

TEST_CASE("Crystal point seed equals the default crystal", "[fast][crystal]")
{
    auto withDefault = initSim(plane(40, 30) + "[phase_field]\n");
    auto explicitSeed = initSim(plane(40, 30) + "[[crystal.seed]]\nshape = \"point\"\nposition = [0.5, 0.5]\nradius = 3\n"
                                                "[phase_field]\n");
    auto a = field(withDefault, ice::kPhase), b = field(explicitSeed, ice::kPhase);
    CHECK(a->activeVoxelCount() > 20);
    CHECK(maxAbsDiff(*a, *b) == 0.0);
    CHECK(a->tree().hasSameTopology(b->tree()));
}

TEST_CASE("Crystal point, disc, line and edge set exactly their cells", "[fast][crystal]")
{
    SECTION("point off centre: every cell within the radius, no other")
    {
        auto sim = initSim(plane(41, 41) + "[[crystal.seed]]\nposition = [0.25, 0.75]\nradius = 4.5\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        size_t expected = 0;
        for (int j = 0; j < 41; ++j)
            for (int i = 0; i < 41; ++i) {
                const bool in = (i - 10) * (i - 10) + (j - 30) * (j - 30) <= 4.5 * 4.5;
                expected += in;
                if (in) CHECK(on.count(Coord(i, j, 0)) == 1);
            }
        CHECK(on.size() == expected);
    }
    SECTION("disc: radius as a fraction of the smaller side")
    {
        auto sim = initSim(plane(81, 41) + "[[crystal.seed]]\nshape = \"disc\"\nradius_fraction = 0.25\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        size_t expected = 0; // r = 0.25 * 41 = 10.25 around (40, 20)
        for (int j = 0; j < 41; ++j)
            for (int i = 0; i < 81; ++i) expected += (i - 40) * (i - 40) + (j - 20) * (j - 20) <= 10.25 * 10.25;
        CHECK(on.size() == expected);
        CHECK(on.count(Coord(50, 20, 0)) == 1);
        CHECK(on.count(Coord(51, 20, 0)) == 0);
    }
    SECTION("line: a horizontal segment of width 1 is one row")
    {
        auto sim = initSim(plane(41, 41) + "[[crystal.seed]]\nshape = \"line\"\nfrom = [0.1, 0.5]\nto = [0.9, 0.5]\nwidth = 1\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        CHECK(on.size() == 33);
        for (int i = 4; i <= 36; ++i) CHECK(on.count(Coord(i, 20, 0)) == 1);
    }
    SECTION("line: a diagonal keeps its thickness")
    {
        auto sim = initSim(plane(41, 41) + "[[crystal.seed]]\nshape = \"line\"\nfrom = [0.0, 0.0]\nto = [1.0, 1.0]\nwidth = 3\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        for (const Coord& c : on) CHECK(std::fabs(c.x() - c.y()) / std::sqrt(2.0) <= 1.5);
        for (int i = 0; i < 41; ++i) {
            CHECK(on.count(Coord(i, i, 0)) == 1);
            if (i > 0) CHECK(on.count(Coord(i, i - 1, 0)) == 1); // 0.71 cells off the line
            if (i > 2) CHECK(on.count(Coord(i, i - 3, 0)) == 0); // 2.1 cells off
        }
    }
    SECTION("edge: left and top bands of width 2")
    {
        auto sim = initSim(plane(20, 10) + "[[crystal.seed]]\nshape = \"edge\"\nedges = \"left, top\"\nwidth = 2\n");
        auto p = field(sim, ice::kPhase);
        const auto on = cellsWith(sim, *p, 1.f);
        CHECK(on.size() == size_t(2 * 10 + 20 * 2 - 4));
        for (const Coord& c : on) CHECK((c.x() < 2 || c.y() >= 8));
        CHECK(p->tree().activeTileCount() == 0); // dense voxels, no tiles a leaf kernel could miss
    }
    SECTION("edge: all four edges, several seeds are a union")
    {
        auto sim = initSim(plane(17, 17) + "[[crystal.seed]]\nshape = \"edge\"\n"
                                           "[[crystal.seed]]\nposition = [0.5, 0.5]\nradius = 0\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        CHECK(on.size() == size_t(17 * 17 - 13 * 13 + 1));
    }
}

TEST_CASE("Crystal shapes in a box are balls, capsules and slabs", "[fast][crystal]")
{
    const std::string box = "[domain]\nkind = \"box\"\nsize = [17, 17, 17]\nvoxel_size = 0.001\n";
    SECTION("ball")
    {
        auto sim = initSim(box + "[[crystal.seed]]\nposition = [0.5, 0.5, 0.25]\nradius = 3\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        size_t expected = 0;
        for (int k = 0; k < 17; ++k)
            for (int j = 0; j < 17; ++j)
                for (int i = 0; i < 17; ++i) expected += (i - 8) * (i - 8) + (j - 8) * (j - 8) + (k - 4) * (k - 4) <= 9;
        CHECK(on.size() == expected);
    }
    SECTION("capsule along z")
    {
        auto sim = initSim(box + "[[crystal.seed]]\nshape = \"line\"\nfrom = [0.5, 0.5, 0.0]\nto = [0.5, 0.5, 1.0]\nwidth = 1\n");
        CHECK(cellsWith(sim, *field(sim, ice::kPhase), 1.f).size() == 17);
    }
    SECTION("front slab")
    {
        auto sim = initSim(box + "[[crystal.seed]]\nshape = \"edge\"\nedges = \"front\"\nwidth = 1\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        CHECK(on.size() == 17 * 17);
        for (const Coord& c : on) CHECK(c.z() == 0);
    }
}

TEST_CASE("Crystal point on the hexagonal lattice is round in world space", "[fast][crystal]")
{
    auto sim = initSim(plane(40, 40, "hexagonal") + "[[crystal.seed]]\nposition = [0.5, 0.5]\nradius = 5\n");
    auto p = field(sim, ice::kPhase);
    const auto& xf = p->transform();
    const openvdb::Vec3d c = xf.indexToWorld(openvdb::Vec3d(19.5, 19.5, 0));
    const double h = 0.001;
    size_t n = 0;
    for (auto it = p->cbeginValueOn(); it; ++it, ++n)
        CHECK((xf.indexToWorld(it.getCoord()) - c).length() <= 5 * h + 1e-9);
    // A disc of radius 5 holds about pi r^2 / (sqrt(3)/2) hexagonal cells.
    CHECK(double(n) == Approx(M_PI * 25 / (std::sqrt(3.0) / 2)).epsilon(0.15));
}

TEST_CASE("Crystal melt map has background 1 and stores only values below 1", "[fast][crystal]")
{
    SECTION("no melt keys: no melt field")
    {
        auto sim = initSim(plane(16, 16) + "[[crystal.seed]]\n");
        CHECK_FALSE(sim->world().fields.has(ice::kMelt));
    }
    SECTION("a melt edge")
    {
        auto sim = initSim(plane(16, 16) + "[[crystal.melt]]\nshape = \"edge\"\nedges = \"bottom\"\nwidth = 1\nvalue = 0.25\n");
        auto m = field(sim, ice::kMelt);
        CHECK(m->background() == 1.f);
        CHECK(m->activeVoxelCount() == 16);
        CHECK(cellsWith(sim, *m, 0.25f).size() == 16);
        CHECK(cellsWith(sim, *m, 1.f).size() == 16 * 15);
        // No seed given: the ice effects still get the default crystal.
        CHECK_FALSE(sim->world().fields.has(ice::kPhase));
    }
    SECTION("melt_value everywhere, a shape back to 1 is not stored")
    {
        auto sim = initSim(plane(16, 16) + "[crystal]\nmelt_value = 0.5\n[[crystal.melt]]\nshape = \"disc\"\n"
                                           "radius_fraction = 0.25\nvalue = 1.0\n");
        auto m = field(sim, ice::kMelt);
        CHECK(m->background() == 1.f);
        const auto ones = cellsWith(sim, *m, 1.f);
        CHECK(ones.size() > 40);
        CHECK(cellsWith(sim, *m, 0.5f).size() + ones.size() == 256);
        auto acc = m->getConstAccessor();
        for (const Coord& c : ones) CHECK_FALSE(acc.isValueOn(c));
    }
}

TEST_CASE("Crystal PNG maps round-trip", "[fast][crystal]")
{
    const std::string dir = tempDir("crystal_png");
    const int W = 32, H = 16;
    std::vector<float> img(size_t(W) * H);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) img[size_t(y) * W + x] = float(x + 2 * y) / float(W + 2 * H);
    for (int bits : {16, 8}) {
        const std::string path = dir + "/melt" + std::to_string(bits) + ".png";
        writePngGray(path, W, H, img, bits);
        auto sim = initSim(plane(W, H) + "[crystal]\nmelt_map = \"" + path + "\"\n");
        auto acc = field(sim, ice::kMelt)->getConstAccessor();
        const double tol = bits == 16 ? 1e-4 : 0.5 / 255 + 1e-6;
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < W; ++x) // row 0 is the top (+y)
                CHECK(acc.getValue(Coord(x, H - 1 - y, 0)) == Approx(img[size_t(y) * W + x]).margin(tol));
    }
    SECTION("seed map with a threshold, twice the resolution")
    {
        std::vector<float> seed(size_t(2 * W) * 2 * H, 0.f);
        for (int y = 4; y < 12; ++y)     // image rows 4..11 -> cells j = 16 - 1 - (2..5) = 10..13
            for (int x = 8; x < 16; ++x) // image cols 8..15 -> cells i = 4..7
                seed[size_t(y) * 2 * W + x] = 1.f;
        const std::string path = dir + "/seed.png";
        writePngGray(path, 2 * W, 2 * H, seed, 8);
        auto sim = initSim(plane(W, H) + "[crystal]\nseed_map = \"" + path + "\"\nseed_map_threshold = 0.5\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        CHECK(on.size() == 16);
        for (int j = 10; j <= 13; ++j)
            for (int i = 4; i <= 7; ++i) CHECK(on.count(Coord(i, j, 0)) == 1);
    }
    SECTION("relative paths resolve against the scene file's folder")
    {
        std::filesystem::copy_file(dir + "/melt16.png", dir + "/rel.png", std::filesystem::copy_options::overwrite_existing);
        const std::string scenePath = dir + "/scene.toml";
        std::ofstream(scenePath) << plane(W, H) << "[crystal]\nmelt_map = \"rel.png\"\n";
        Simulation sim(Scene::load(scenePath));
        sim.initialize();
        CHECK(field(sim, ice::kMelt)->activeVoxelCount() > 0);
    }
}

TEST_CASE("Crystal VDB maps in world and index space", "[fast][crystal]")
{
    const std::string dir = tempDir("crystal_vdb");
    // A melt grid on the domain's own transform (world sampling hits cell centres exactly).
    auto m = openvdb::FloatGrid::create(1.f);
    m->setName("m");
    m->setTransform(openvdb::math::Transform::createLinearTransform(0.001));
    auto other = openvdb::FloatGrid::create(1.f); // a second grid, on a coarse unrelated transform
    other->setName("other");
    other->setTransform(openvdb::math::Transform::createLinearTransform(0.5));
    {
        auto a = m->getAccessor(), b = other->getAccessor();
        for (int j = 0; j < 16; ++j)
            for (int i = 0; i < 16; ++i) {
                a.setValue(Coord(i, j, 0), float(i) / 16.f);
                b.setValue(Coord(i, j, 0), float(j) / 16.f);
            }
    }
    const std::string path = dir + "/maps.vdb";
    openvdb::io::File(path).write(openvdb::GridPtrVec{m, other});

    auto world = initSim(plane(16, 16) + "[crystal]\nmelt_map = \"" + path + "\"\nmelt_map_grid = \"m\"\n");
    auto index = initSim(plane(16, 16) + "[crystal]\nmelt_map = \"" + path + "\"\nmelt_map_grid = \"other\"\n"
                                         "melt_map_space = \"index\"\n");
    auto shorthand = initSim(plane(16, 16) + "[crystal]\nmelt_map = \"" + path + ":m\"\n");
    CHECK(maxAbsDiff(*field(world, ice::kMelt), *field(shorthand, ice::kMelt)) == 0.0);
    auto wa = field(world, ice::kMelt)->getConstAccessor();
    auto ia = field(index, ice::kMelt)->getConstAccessor();
    for (int j = 0; j < 16; ++j)
        for (int i = 0; i < 16; ++i) {
            CHECK(wa.getValue(Coord(i, j, 0)) == Approx(i / 16.0).margin(1e-6));
            CHECK(ia.getValue(Coord(i, j, 0)) == Approx(j / 16.0).margin(1e-6));
        }

    SECTION("a level set seeds its inside")
    {
        auto ls = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(0.004f, openvdb::Vec3f(0.008f, 0.008f, 0.f),
                                                                           0.001f);
        ls->setName("sphere");
        const std::string lsPath = dir + "/ls.vdb";
        openvdb::io::File(lsPath).write(openvdb::GridPtrVec{ls});
        auto sim = initSim(plane(17, 17) + "[crystal]\nseed_map = \"" + lsPath + "\"\n");
        const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
        size_t expected = 0;
        for (int j = 0; j < 17; ++j)
            for (int i = 0; i < 17; ++i) expected += (i - 8) * (i - 8) + (j - 8) * (j - 8) <= 16;
        CHECK(double(on.size()) == Approx(double(expected)).margin(4));
    }
}

TEST_CASE("Crystal errors name the file and the key", "[fast][crystal]")
{
    const std::string dir = tempDir("crystal_err");
    const std::string png = dir + "/wide.png";
    writePngGray(png, 64, 8, std::vector<float>(64 * 8, 0.5f), 8);
    auto bad = openvdb::FloatGrid::create(0.f);
    bad->setName("hot");
    bad->tree().setValue(Coord(1, 1, 0), 3.f);
    openvdb::io::File(dir + "/bad.vdb").write(openvdb::GridPtrVec{bad});

    SECTION("missing file")
    {
        const auto msg = initErrorOf(plane(16, 16) + "[crystal]\nmelt_map = \"" + dir + "/nope.png\"\n");
        CHECK(msg.find("test.toml:6") != std::string::npos);
        CHECK(msg.find("crystal.melt_map") != std::string::npos);
        CHECK(msg.find("nope.png") != std::string::npos);
    }
    SECTION("wrong size")
    {
        const auto msg = initErrorOf(plane(16, 16) + "[crystal]\nseed_map = \"" + png + "\"\n");
        CHECK(msg.find("crystal.seed_map") != std::string::npos);
        CHECK(msg.find("wide.png") != std::string::npos);
        CHECK(msg.find("64x8") != std::string::npos);
        CHECK(initErrorOf(plane(16, 16) + "[crystal]\nseed_map = \"" + png + "\"\nmap_stretch = true\n").empty());
    }
    SECTION("unknown grid name")
    {
        const auto msg = initErrorOf(plane(16, 16) + "[crystal]\nmelt_map = \"" + dir + "/bad.vdb\"\nmelt_map_grid = \"cold\"\n");
        CHECK(msg.find("crystal.melt_map") != std::string::npos);
        CHECK(msg.find("'cold'") != std::string::npos);
        CHECK(msg.find("hot") != std::string::npos);
    }
    SECTION("value out of [0,1]")
    {
        const auto msg = initErrorOf(plane(16, 16) + "[crystal]\nmelt_map = \"" + dir + "/bad.vdb\"\n");
        CHECK(msg.find("crystal.melt_map") != std::string::npos);
        CHECK(msg.find("bad.vdb") != std::string::npos);
        CHECK(msg.find("[0, 1]") != std::string::npos);
    }
    SECTION("unknown key and a key of another shape, in an array of tables")
    {
        auto msg = initErrorOf(plane(16, 16) + "[[crystal.seed]]\nradus = 3\n");
        CHECK(msg.find("crystal.seed#1.radus") != std::string::npos);
        CHECK(msg.find("test.toml:6") != std::string::npos);
        msg = initErrorOf(plane(16, 16) + "[[crystal.seed]]\n[[crystal.seed]]\nshape = \"line\"\nfrom = [0, 0]\nto = [1, 1]\nradius = 2\n");
        CHECK(msg.find("crystal.seed#2.radius") != std::string::npos);
        CHECK(msg.find("point") != std::string::npos);
        msg = initErrorOf(plane(16, 16) + "[[crystal.seed]]\nshape = \"edge\"\nedges = \"left, front\"\n");
        CHECK(msg.find("crystal.seed#1.edges") != std::string::npos);
        CHECK(msg.find("front") != std::string::npos);
        msg = initErrorOf(plane(16, 16) + "[crystal]\nseed = 3\n");
        CHECK(msg.find("crystal.seed") != std::string::npos);
        msg = initErrorOf(plane(16, 16) + "[[crystal.seed]]\nposition = [0.5, 0.5, 0.5]\n");
        CHECK(msg.find("crystal.seed#1.position") != std::string::npos);
    }
}

TEST_CASE("Crystal seeds can be given on the command line", "[fast][crystal]")
{
    auto sim = initSim(plane(16, 16) + "[crystal]\n",
                       {"crystal.seed=[{shape = \"point\", position = [0.2, 0.2], radius = 1}]"});
    const auto on = cellsWith(sim, *field(sim, ice::kPhase), 1.f);
    CHECK(on.size() == 5); // a plus around (3, 3) = 0.2 * 15
    CHECK(on.count(Coord(3, 3, 0)) == 1);
    CHECK(on.count(Coord(4, 3, 0)) == 1);
}
