// Output files: every grid and its metadata survive a write/read round trip; the command line
// refuses bad input without writing anything.
#include <frostvdb/io/OutputLock.h>
#include <frostvdb/BuildPaths.h>
#include "test_util.h"

#include <frostvdb/core/PlaneFold.h>

#include <frostvdb/io/Png.h>
#include <frostvdb/io/VdbIO.h>

#include <openvdb/tools/Count.h>
#include <catch2/catch.hpp>

#include <map>

using namespace frostvdb;
using namespace frostvdb::test;

TEST_CASE("Frames round-trip every grid and its metadata", "[fast][io]")
{
    auto sim = makeSim("[scene]\nname = \"rt\"\nframes = 2\nsteps_per_frame = 40\nseed = 77\n"
                       "[domain]\nsize = [48, 48]\nvoxel_size = 0.002\n[phase_field]\n");
    RunOptions ro;
    ro.progress = false;
    ro.outDir = tempDir("roundtrip");
    auto sum = sim.run(ro);
    const std::string path = ro.outDir + "/rt.0002.vdb";
    REQUIRE(std::filesystem::exists(path));
    REQUIRE(std::filesystem::exists(ro.outDir + "/rt.0002.png"));
    REQUIRE(std::filesystem::exists(ro.outDir + "/run.json"));
    const Frame frame = sim.currentFrame(2);

    openvdb::MetaMap::Ptr meta;
    auto grids = readVdb(path, &meta);
    std::vector<std::string> names;
    for (auto& g : *grids) names.push_back(g->getName());
    std::sort(names.begin(), names.end());
    CHECK(names == std::vector<std::string>{"freeze_time", "growth", "ice", "ice_temperature"});
    auto byName = [&](const std::string& n) {
        for (auto& g : *grids)
            if (g->getName() == n) return openvdb::gridPtrCast<openvdb::FloatGrid>(g);
        return openvdb::FloatGrid::Ptr();
    };
    for (auto& g : *grids) {
        auto fg = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
        REQUIRE(fg);
        CHECK(fg->voxelSize()[0] == Approx(0.002));
        for (auto& want : frame.grids)
            if (want->getName() == g->getName())
                CHECK(maxAbsDiff(*fg, *openvdb::gridPtrCast<openvdb::FloatGrid>(want)) == 0.0);
        CHECK(g->metaValue<int64_t>("frostvdb_step") == 80);
    }
    CHECK(byName("ice")->getGridClass() == openvdb::GRID_FOG_VOLUME);
    CHECK(meta->metaValue<int64_t>("seed") == 77);
    CHECK(meta->metaValue<int64_t>("step") == 80);
    CHECK(meta->metaValue<int64_t>("frame") == 2);
    CHECK(meta->metaValue<double>("time") == Approx(80 * 0.0002));
    CHECK(meta->metaValue<std::string>("scene").find("name = \"rt\"") != std::string::npos);
    CHECK(meta->metaValue<std::string>("frostvdb_version") == FROSTVDB_VERSION);
    // The ice is a fog volume in [0,1]; growth normalised to [0,1].
    const auto ice = openvdb::tools::minMax(byName("ice")->tree());
    CHECK(ice.min() >= 0.f);
    CHECK(ice.max() <= 1.f);
    CHECK(openvdb::tools::minMax(byName("growth")->tree()).max() == Approx(1.0f));
    // No temporary files are left behind (the folder's lock file stays: io/OutputLock.h).
    for (auto& e : std::filesystem::directory_iterator(ro.outDir))
        CHECK((e.path().filename().string()[0] != '.' || e.path().filename() == OutputFolderLock::fileName()));
}

TEST_CASE("Non-finite values are never written", "[fast][io]")
{
    auto g = openvdb::FloatGrid::create(0.f);
    g->setName("bad");
    g->tree().setValue(openvdb::Coord(1, 2, 3), std::numeric_limits<float>::quiet_NaN());
    const std::string dir = tempDir("nan");
    const std::string path = dir + "/bad.vdb";
    try {
        writeVdbAtomic(path, {g}, openvdb::MetaMap());
        FAIL("a NaN grid was written");
    } catch (const std::exception& e) {
        CHECK(std::string(e.what()).find("[1, 2, 3]") != std::string::npos);
    }
    CHECK(!std::filesystem::exists(path));
}

TEST_CASE("Streamed frames: the bytes of the one-shot writer and a failure part way leaves the old file", "[fast][io]")
{
    const std::string dir = tempDir("streamed");
    openvdb::GridPtrVec grids;
    for (int i = 0; i < 3; ++i) {
        auto g = openvdb::FloatGrid::create(0.5f * float(i));
        g->setName("grid" + std::to_string(i));
        for (int x = 0; x < 40; x += 3) g->tree().setValue(openvdb::Coord(x, i, -x), float(x * (i + 1)));
        grids.push_back(g);
    }
    openvdb::MetaMap meta;
    meta.insertMeta("scene", openvdb::StringMetadata("streamed"));
    const std::string whole = dir + "/whole.vdb", streamed = dir + "/streamed.vdb";
    writeVdbAtomic(whole, grids, meta);
    std::vector<int> asked;
    writeVdbStreamed(streamed, grids.size(), [&](size_t i) {
        asked.push_back(int(i));
        return grids[i]->deepCopyGrid();
    }, meta);
    CHECK(asked == std::vector<int>{0, 1, 2}); // one at a time, in order
    // Equal bytes but for the header's random UUID (36 characters after the 21-byte prefix).
    std::string a = readFile(whole), b = readFile(streamed);
    REQUIRE(a.size() == b.size());
    for (size_t i = 21; i < 21 + 36; ++i) a[i] = b[i] = '-';
    CHECK(a == b);
    CHECK(sameVdbContent(whole, streamed));

    // A grid that fails part way (a NaN in the second, a throwing producer for the third):
    // the complete file written before stays as it was, and no temporary is left.
    const std::string before = readFile(streamed);
    auto nan = openvdb::FloatGrid::create(0.f);
    nan->setName("nan");
    nan->tree().setValue(openvdb::Coord(7, 8, 9), std::numeric_limits<float>::quiet_NaN());
    CHECK_THROWS_WITH(writeVdbStreamed(streamed, 2, [&](size_t i) -> openvdb::GridBase::Ptr { return i == 0 ? grids[0] : openvdb::GridBase::Ptr(nan); }, meta),
                      Catch::Contains("[7, 8, 9]"));
    CHECK_THROWS_WITH(writeVdbStreamed(streamed, 3, [&](size_t i) -> openvdb::GridBase::Ptr {
        if (i == 2) throw std::runtime_error("export failed");
        return grids[i];
    }, meta), Catch::Contains("export failed"));
    CHECK_THROWS_AS(writeVdbStreamed(streamed, 2, [&](size_t) { return grids[0]; }, meta), std::logic_error);
    CHECK(readFile(streamed) == before);
    for (auto& e : std::filesystem::directory_iterator(dir)) CHECK(e.path().filename().string()[0] != '.');
}

TEST_CASE("A frame kept across steps keeps its values: writers copy the trees it shares", "[fast][io]")
{
    // The frame shares the trees of T and freeze_time (no copy of the largest fields); the
    // phase field and the walkers write them in place, so each must copy a shared tree first.
    Simulation sim = makeSim("[domain]\nsize = [96, 96]\n[dla]\nhumidity = 200\nhits = 2\n[phase_field]\n");
    sim.initialize();
    for (int i = 0; i < 20; ++i) sim.step();
    Frame frame = sim.currentFrame(1);
    std::map<std::string, openvdb::FloatGrid::Ptr> before;
    for (auto& g : frame.grids)
        if (auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(g)) before[g->getName()] = f->deepCopy();
    REQUIRE(before.count("freeze_time"));
    REQUIRE(before.count("ice_temperature"));
    for (int i = 0; i < 30; ++i) sim.step();
    for (auto& g : frame.grids)
        if (auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(g)) {
            INFO(g->getName());
            CHECK(f->tree().hasSameTopology(before[g->getName()]->tree()));
            CHECK(maxAbsDiff(*f, *before[g->getName()]) == 0.0);
        }
    // and the fields did move on
    CHECK(maxAbsDiff(*plane::unfoldGrid(*sim.world().fields.get<openvdb::FloatGrid>("freeze_time")),
                     *before["freeze_time"]) > 0.0); // the field may be folded (core/PlaneFold.h)
    CHECK(maxAbsDiff(*sim.world().fields.get<openvdb::FloatGrid>("T"), *before["ice_temperature"]) > 0.0);
}

TEST_CASE("16-bit greyscale PNG round trip", "[fast][io]")
{
    const std::string path = tempDir("png") + "/g.png";
    std::vector<float> v(6 * 4);
    for (size_t i = 0; i < v.size(); ++i) v[i] = float(i) / float(v.size() - 1);
    writePngGray(path, 6, 4, v, 16);
    int w, h;
    auto back = readPngGray(path, w, h);
    REQUIRE(w == 6);
    REQUIRE(h == 4);
    for (size_t i = 0; i < v.size(); ++i) CHECK(back[i] == Approx(v[i]).margin(1.0 / 65535.0));
}

TEST_CASE("Command line: bad scene gives a one-line error, non-zero exit, nothing written", "[fast][cli]")
{
    const std::string dir = tempDir("cli");
    const std::string scene = dir + "/bad.toml";
    std::ofstream(scene) << "[domain]\nsize = [32, 32]\n[phase_field]\nanisotropy_mode = 40\n";
    const int rc = runCommand(std::string(FROSTVDB_BINARY) + " run " + scene + " --out " + dir + "/out", dir + "/log");
    CHECK(rc == 2);
    const std::string log = readFile(dir + "/log");
    CHECK(log.find("bad.toml:4: phase_field.anisotropy_mode") != std::string::npos);
    CHECK(std::count(log.begin(), log.end(), '\n') == 1);
    CHECK(!std::filesystem::exists(dir + "/out"));

    // An existing good output is not damaged by a failing run into the same folder.
    std::filesystem::create_directories(dir + "/out");
    std::ofstream(dir + "/out/keep.vdb") << "precious";
    runCommand(std::string(FROSTVDB_BINARY) + " run " + scene + " --out " + dir + "/out", dir + "/log2");
    CHECK(readFile(dir + "/out/keep.vdb") == "precious");
}

TEST_CASE("Command line: run, info and preview work end to end", "[fast][cli]")
{
    const std::string dir = tempDir("cli_ok");
    const std::string bin = FROSTVDB_BINARY;
    REQUIRE(runCommand(bin + " run --quiet --out " + dir + " --set scene.frames=2 --set scene.steps_per_frame=50"
                             " --set domain.size=[64,64]", dir + "/log") == 0);
    REQUIRE(std::filesystem::exists(dir + "/dendrite.0002.vdb"));
    REQUIRE(runCommand(bin + " info " + dir + "/dendrite.0002.vdb", dir + "/info") == 0);
    const std::string info = readFile(dir + "/info");
    for (const char* g : {"ice", "ice_temperature", "growth", "freeze_time", "fog volume", "voxel size", "seed"})
        CHECK(info.find(g) != std::string::npos);
    REQUIRE(runCommand(bin + " preview " + dir + "/dendrite.0002.vdb -o " + dir + "/p.png --grid ice_temperature",
                       dir + "/prev") == 0);
    CHECK(std::filesystem::file_size(dir + "/p.png") > 1000);
    CHECK(runCommand(bin + " preview " + dir + "/dendrite.0002.vdb -o " + dir + "/q.png --grid nope", dir + "/prev2") != 0);
}
