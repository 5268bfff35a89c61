// Every input the fuzzers of fuzz/ ever crashed on (tests/fuzz_regressions/<target>/), replayed
// through the same target functions in the normal suite: each must now be accepted or refused
// with a SceneError. The shipped scenes go through the scene target too.
#include "../fuzz/FuzzTargets.h"

#include <frostvdb/BuildPaths.h>

#include <catch2/catch.hpp>

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
} // namespace

TEST_CASE("fuzz regressions: every input that once crashed a harness is refused cleanly", "[fuzz]")
{
    const fs::path root = fs::path(FROSTVDB_SOURCE_DIR) / "tests" / "fuzz_regressions";
    const int n = replay(root / "scene", frostvdb::fuzz::sceneTarget) + replay(root / "png", frostvdb::fuzz::pngTarget) +
                  replay(root / "vdb", frostvdb::fuzz::vdbTarget);
    INFO(n << " regression inputs");
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
