// Production file options and the machine-readable command line: [output] precision (half
// floats) and compression, `frostvdb info` showing both, `run --progress json`, `run --estimate`.
#include <frostvdb/BuildPaths.h>
#include "test_util.h"

#include <frostvdb/io/VdbIO.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <map>
#include <regex>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

const char* kScene = "[scene]\nname = \"opt\"\nframes = 2\nsteps_per_frame = 120\nseed = 3\n"
                     "[domain]\nsize = [96, 96]\nvoxel_size = 0.001\n[output]\npreview = \"none\"\n"
                     "displacement_png = false\n[phase_field]\n";

/// Runs kScene with @a overrides into a fresh folder; returns the last frame's path.
std::string runWith(const std::string& tag, const std::vector<std::string>& overrides)
{
    auto sim = makeSim(kScene, overrides);
    RunOptions ro;
    ro.progress = false;
    ro.outDir = tempDir("options_" + tag);
    sim.run(ro);
    return ro.outDir + "/opt.0002.vdb";
}

std::map<std::string, openvdb::FloatGrid::Ptr> floatGrids(const std::string& path)
{
    std::map<std::string, openvdb::FloatGrid::Ptr> out;
    const auto grids = readVdb(path); // kept: a range-for over *readVdb(...) would dangle
    for (auto& g : *grids)
        if (auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(g)) out[g->getName()] = f;
    return out;
}

/// One line per JSON object: a crude but strict check of the shape `{"key":value,...}`.
bool looksLikeJsonObject(const std::string& line)
{
    static const std::regex form(R"(^\{"[a-z_]+":.*\}$)");
    return std::regex_match(line, form);
}

std::vector<std::string> lines(const std::string& text)
{
    std::vector<std::string> out;
    std::istringstream is(text);
    for (std::string l; std::getline(is, l);) out.push_back(l);
    return out;
}

/// The number after "key": in a JSON line (-1 if absent).
double jsonNumber(const std::string& line, const std::string& key)
{
    const auto at = line.find("\"" + key + "\":");
    if (at == std::string::npos) return -1;
    return std::stod(line.substr(at + key.size() + 3));
}

} // namespace

TEST_CASE("Output precision: half files are smaller and hold the float values to half precision", "[fast][io][output]")
{
    const std::string full = runWith("float", {"output.precision=float"});
    const std::string half = runWith("half", {"output.precision=half"});
    const auto fullBytes = std::filesystem::file_size(full), halfBytes = std::filesystem::file_size(half);
    INFO("float " << fullBytes << " bytes, half " << halfBytes << " bytes");
    CHECK(halfBytes < fullBytes);
    CHECK(double(halfBytes) / double(fullBytes) < 0.9); // 0.86 on this small plane: metadata and topology weigh

    // Read back as float grids with the same topology; every value within half's rounding:
    // 2^-11 relative for normal numbers, 2^-25 absolute below half's smallest normal (6.1e-5).
    const auto a = floatGrids(full), b = floatGrids(half);
    REQUIRE(a.size() == b.size());
    REQUIRE(a.count("ice") == 1);
    for (const auto& [name, fg] : a) {
        REQUIRE(b.count(name) == 1);
        const auto& hg = b.at(name);
        CHECK(hg->tree().hasSameTopology(fg->tree()));
        double worst = 0, nonzero = 0;
        auto acc = hg->getConstAccessor();
        for (auto it = fg->cbeginValueOn(); it; ++it) {
            const double f = *it, h = acc.getValue(it.getCoord());
            const double tol = std::max(std::fabs(f) * std::ldexp(1.0, -11), std::ldexp(1.0, -25));
            worst = std::max(worst, std::fabs(h - f) / tol);
            if (h != f) ++nonzero;
        }
        INFO(name << ": worst error " << worst << " of the tolerance, " << nonzero << " values rounded");
        CHECK(worst <= 1.0);
        CHECK(nonzero > 0); // really stored as halves, not a float copy
    }
    // Every float grid is stored as halves (the descriptors say so), also with the older key.
    for (const std::string& p : {half, runWith("legacy", {"output.half_float=true"})})
        for (const auto& span : validateVdb(p, readWholeFile(p)).grids) {
            INFO(p << ": " << span.name << " " << span.type);
            CHECK(span.half);
        }
    for (const auto& span : validateVdb(full, readWholeFile(full)).grids) CHECK(!span.half);
}

TEST_CASE("Output compression: blosc, zip and none are lossless, stored as asked and shown by info", "[fast][io][output]")
{
    std::map<std::string, std::string> path;
    for (const char* c : {"blosc", "zip", "none"}) path[c] = runWith(c, {std::string("output.compression=") + c});
    CHECK(std::filesystem::file_size(path["none"]) > std::filesystem::file_size(path["blosc"]));
    const auto ref = floatGrids(path["blosc"]);
    for (const char* c : {"zip", "none"}) {
        const auto g = floatGrids(path[c]);
        for (const auto& [name, grid] : ref) CHECK(maxAbsDiff(*grid, *g.at(name)) == 0.0);
    }
    // The flags each grid was written with (OpenVDB drops zip for fog volumes and level sets).
    auto flagsOf = [&](const std::string& p) {
        std::map<std::string, int64_t> out;
        for (const auto& s : validateVdb(p, readWholeFile(p)).grids) out[s.name] = s.compression;
        return out;
    };
    using namespace openvdb::io;
    for (const auto& [name, f] : flagsOf(path["blosc"])) CHECK(f == (COMPRESS_BLOSC | COMPRESS_ACTIVE_MASK));
    for (const auto& [name, f] : flagsOf(path["none"])) CHECK(f == COMPRESS_NONE);
    const auto zip = flagsOf(path["zip"]);
    CHECK(zip.at("growth") == (COMPRESS_ZIP | COMPRESS_ACTIVE_MASK)); // an unknown-class grid keeps zip
    CHECK(zip.at("ice") == COMPRESS_ACTIVE_MASK);                     // a fog volume: OpenVDB drops zip

    const std::string dir = tempDir("options_info");
    REQUIRE(runCommand(std::string(FROSTVDB_BINARY) + " info " + path["none"], dir + "/none") == 0);
    CHECK(lines(readFile(dir + "/none")).at(0).find("precision float, compression none") != std::string::npos);
    const std::string half = runWith("half_info", {"output.precision=half"});
    REQUIRE(runCommand(std::string(FROSTVDB_BINARY) + " info " + half, dir + "/half") == 0);
    const std::string info = readFile(dir + "/half");
    CHECK(lines(info).at(0).find("precision half, compression blosc + active mask") != std::string::npos);
    CHECK(info.find("precision half (16-bit), compression blosc + active mask") != std::string::npos);
}

TEST_CASE("Output options: a bad value is one line naming the key and the choices", "[fast][io][output]")
{
    const std::string e = errorOf(kScene, {"output.precision=double"});
    CHECK(e.find("output.precision") != std::string::npos);
    CHECK(e.find("half") != std::string::npos);
    CHECK(errorOf(kScene, {"output.compression=lzma"}).find("output.compression") != std::string::npos);
    CHECK(errorOf(kScene, {"output.precision=float", "output.half_float=true"}).find("output.half_float") !=
          std::string::npos);
}

TEST_CASE("Output: a displacement raster wider than 10 UDIM tiles is refused at load, naming the key",
          "[fast][io][output]")
{
    // 700 pixels in tiles of 64: 11 across. Refused before anything runs (it used to fail at the
    // first frame with ice, after the whole simulation, naming a key that does not exist).
    const std::string e = errorOf(kScene, {"domain.size=[700, 8]", "output.displacement_png=true",
                                           "output.displacement_tile=64"});
    CHECK(e.find("output.displacement_tile") != std::string::npos);
    CHECK(e.find("11 UDIM tiles") != std::string::npos);
    CHECK(e.find("at least 70") != std::string::npos);
    CHECK(e.find('\n') == std::string::npos);
    CHECK(errorOf(kScene, {"domain.size=[700, 8]", "output.displacement_png=true", "output.displacement_tile=70"})
              .empty());
    CHECK(errorOf(kScene, {"domain.size=[700, 8]", "output.displacement_tile=64"}).empty()); // no maps asked
}

TEST_CASE("run --progress json: one JSON object per line on stderr, frames and the end reported", "[fast][cli][output]")
{
    const std::string dir = tempDir("progress_json");
    const std::string scene = dir + "/s.toml";
    std::ofstream(scene) << kScene;
    const std::string bin = FROSTVDB_BINARY;
    const int rc = std::system((bin + " run " + scene + " --out " + dir + "/out --progress json > " + dir + "/out.txt 2> " +
                                dir + "/err").c_str());
    REQUIRE(rc == 0);
    const auto ls = lines(readFile(dir + "/err"));
    REQUIRE(ls.size() >= 4);
    double lastStep = 0;
    int frames = 0;
    for (const auto& l : ls) {
        INFO(l);
        CHECK(looksLikeJsonObject(l));
        CHECK(jsonNumber(l, "steps") == 240);
        for (const char* k : {"phase", "step", "frame", "elapsed"}) CHECK(l.find(std::string("\"") + k + "\":") != std::string::npos);
        if (l.find("\"event\":\"progress\"") != std::string::npos) {
            CHECK(jsonNumber(l, "step") >= lastStep);
            CHECK(l.find("\"eta\":") != std::string::npos);
            lastStep = jsonNumber(l, "step");
        }
        if (l.find("\"event\":\"frame\"") != std::string::npos) {
            ++frames;
            CHECK(l.find("opt.000" + std::to_string(frames) + ".vdb") != std::string::npos);
        }
    }
    CHECK(lastStep == 240);
    CHECK(frames == 2);
    CHECK(ls.back().find("\"event\":\"done\"") != std::string::npos);

    // A failure: the one-line message, then the same as a JSON error event; exit code 2.
    std::ofstream(dir + "/bad.toml") << "[domain]\nsize = [32, 32]\n[phase_field]\nanisotropy_mode = 40\n";
    CHECK(runCommand(bin + " run " + dir + "/bad.toml --out " + dir + "/bad --progress json", dir + "/bad.txt") == 2);
    const auto bad = lines(readFile(dir + "/bad.txt"));
    REQUIRE(bad.size() == 2);
    CHECK(bad[0].find("bad.toml:4: phase_field.anisotropy_mode") != std::string::npos);
    CHECK(looksLikeJsonObject(bad[1]));
    CHECK(bad[1].find("\"event\":\"error\"") != std::string::npos);
    CHECK(bad[1].find("\"exit_code\":2") != std::string::npos);
    CHECK(!std::filesystem::exists(dir + "/bad"));
}

TEST_CASE("run --estimate: memory and time, nothing written", "[fast][cli][output]")
{
    const std::string dir = tempDir("estimate");
    const std::string scene = dir + "/s.toml";
    std::ofstream(scene) << kScene;
    const std::string bin = FROSTVDB_BINARY;
    REQUIRE(runCommand(bin + " run " + scene + " --out " + dir + "/out --estimate=0.2", dir + "/text") == 0);
    const std::string text = readFile(dir + "/text");
    CHECK(text.find("memory: about") != std::string::npos);
    CHECK(text.find("time: about") != std::string::npos);
    CHECK(text.find("240 steps and 2 frame(s)") != std::string::npos);
    REQUIRE(runCommand(bin + " run " + scene + " --out " + dir + "/out --estimate=0.2 --progress json", dir + "/json") == 0);
    const std::string json = readFile(dir + "/json");
    INFO(json);
    REQUIRE(lines(json).size() == 1);
    CHECK(looksLikeJsonObject(lines(json)[0]));
    CHECK(jsonNumber(json, "steps") == 240);
    CHECK(jsonNumber(json, "memory_bytes") >= 0); // sparse effects estimate nothing up front
    CHECK(jsonNumber(json, "peak_rss_bytes") > 0);
    CHECK(jsonNumber(json, "seconds") > 0);
    CHECK(jsonNumber(json, "probe_steps") >= 1);
    CHECK(!std::filesystem::exists(dir + "/out"));
    CHECK(runCommand(bin + " run " + scene + " --estimate=-1", dir + "/neg") == 2);
}
