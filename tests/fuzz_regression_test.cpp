// Every input the fuzzers of fuzz/ ever crashed on (tests/fuzz_regressions/<target>/), replayed
// in the normal suite: scene texts through the same target function, map files through the real
// program as a [crystal] map under a 2 GB address-space limit (OpenVDB's reader allocates the
// lengths a damaged file claims before it finds the damage, docs/fuzzing.md): each must be
// accepted or refused with one line and exit code 2. The shipped scenes go through the scene target.
#include "../fuzz/FuzzTargets.h"

#include "test_util.h"
#include <frostvdb/BuildPaths.h>

#include <catch2/catch.hpp>

#include <cstdlib>
#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <sstream>

namespace fs = std::filesystem;

namespace {
std::string bytesOf(const fs::path& p)
{
    std::ifstream in(p, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

template <typename Target>
int replay(const fs::path& dir, Target target)
{
    int n = 0;
    if (!fs::exists(dir)) return 0;
    for (auto& e : fs::directory_iterator(dir)) {
        if (!e.is_regular_file() || e.path().filename().string()[0] == '.') continue;
        const std::string b = bytesOf(e.path());
        INFO(e.path().string());
        CHECK(target(reinterpret_cast<const uint8_t*>(b.data()), b.size()) == "");
        ++n;
    }
    return n;
}
/// Runs `frostvdb run` on a tiny scene whose melt map is @a map, memory-limited; returns the exit
/// code and the first line of its output.
int runWithMap(const fs::path& map, std::string& firstLine)
{
    const fs::path dir = fs::path(frostvdb::test::tempDir("fuzz_map"));
    const fs::path copy = dir / ("map" + map.extension().string());
    fs::copy_file(map, copy);
    std::ofstream(dir / "s.toml") << "[scene]\nframes = 1\nsteps_per_frame = 1\n[domain]\nsize = [16, 16]\n"
                                     "[crystal]\nmelt_map = \"" << copy.filename().string() << "\"\n[dla]\nhumidity = 1\n";
    const std::string cmd = "cd " + dir.string() + " && ulimit -v 2000000 && " + FROSTVDB_BINARY +
                            " run s.toml --out o -q > log.txt 2>&1";
    const int rc = std::system(("bash -c '" + cmd + "'").c_str());
    std::ifstream log(dir / "log.txt");
    std::getline(log, firstLine);
    return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}
} // namespace

TEST_CASE("fuzz regressions: every input that once crashed a harness is refused cleanly", "[fuzz]")
{
    const fs::path root = fs::path(FROSTVDB_SOURCE_DIR) / "tests" / "fuzz_regressions";
    int n = replay(root / "scene", frostvdb::fuzz::sceneTarget);
    for (const char* kind : {"png", "vdb"}) {
        if (!fs::exists(root / kind)) continue;
        for (auto& e : fs::directory_iterator(root / kind)) {
            if (e.path().filename().string()[0] == '.') continue;
            std::string line;
            const int rc = runWithMap(e.path(), line);
            INFO(e.path().string() << ": exit " << rc << ": " << line);
            CHECK((rc == 0 || rc == 2));
            if (rc == 2) CHECK(line.find("crystal.melt_map") != std::string::npos);
            ++n;
        }
    }
    INFO(n << " regression inputs");
    CHECK(n >= 1);
    // the shipped scenes are the seed corpus: they must all build
    int scenes = 0;
    for (auto& e : fs::directory_iterator(fs::path(FROSTVDB_SOURCE_DIR) / "scenes")) {
        if (e.path().extension() != ".toml") continue;
        const std::string b = bytesOf(e.path());
        INFO(e.path().string());
        CHECK(frostvdb::fuzz::sceneTarget(reinterpret_cast<const uint8_t*>(b.data()), b.size()) == "");
        ++scenes;
    }
    CHECK(scenes > 20);
}
