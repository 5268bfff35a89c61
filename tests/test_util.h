#pragma once
// Helpers shared by the tests: build a Simulation from scene text, run it quietly, compare grids.
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Simulation.h>

#include <openvdb/openvdb.h>

#include <openvdb/io/File.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <unistd.h>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

namespace frostvdb::test {

inline Simulation makeSim(const std::string& text, const std::vector<std::string>& overrides = {})
{
    Scene scene = Scene::fromString(text, "test.toml");
    for (auto& o : overrides) scene.applyOverride(o);
    return Simulation(std::move(scene));
}

/// The SceneError message of building @a text (with @a overrides) into a Simulation; "" if none.
inline std::string errorOf(const std::string& text, const std::vector<std::string>& overrides = {})
{
    try {
        makeSim(text, overrides);
    } catch (const SceneError& e) {
        return e.what();
    }
    return "";
}

/// The SceneError message of running @a text without writing files ("" if it ran): for refusals
/// that come at initialisation or during the run (budgets, probes), not only when parsing.
inline std::string refusalOf(const std::string& text)
{
    try {
        auto sim = makeSim(text);
        RunOptions ro;
        ro.progress = false;
        ro.writeFiles = false;
        sim.run(ro);
    } catch (const SceneError& e) {
        return e.what();
    }
    return "";
}

/// A fresh empty folder under the system temp dir, private to this process (test runs of
/// several checkouts at once, or ctest -j, never share one).
/// They are removed when the test process exits (set FROSTVDB_KEEP_TEST_DIRS to keep them).
struct TempDirs {
    std::vector<std::filesystem::path> made;
    pid_t owner = ::getpid();
    ~TempDirs()
    {
        if (::getpid() != owner || std::getenv("FROSTVDB_KEEP_TEST_DIRS")) return; // not in forked children
        std::error_code ec;
        for (const auto& p : made) std::filesystem::remove_all(p, ec);
    }
};
inline TempDirs gTempDirs;

inline std::string tempDir(const std::string& name)
{
    auto p = std::filesystem::temp_directory_path() /
             ("frostvdb_test_" + std::to_string(::getpid()) + "_" + name);
    gTempDirs.made.push_back(p);
    std::filesystem::remove_all(p);
    std::filesystem::create_directories(p);
    return p.string();
}

inline std::string readFile(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

/// Max |a - b| over the union of both grids' active voxels (background where inactive).
inline double maxAbsDiff(const openvdb::FloatGrid& a, const openvdb::FloatGrid& b)
{
    double m = 0;
    auto ba = b.getConstAccessor();
    for (auto it = a.cbeginValueOn(); it; ++it) m = std::max(m, double(std::fabs(*it - ba.getValue(it.getCoord()))));
    auto aa = a.getConstAccessor();
    for (auto it = b.cbeginValueOn(); it; ++it) m = std::max(m, double(std::fabs(*it - aa.getValue(it.getCoord()))));
    return m;
}

/// True when two files hold the same grids (names, topology, every stored value bit for bit,
/// transforms) and the same file metadata apart from the random per-file UUID OpenVDB writes.
inline bool sameVdbContent(const std::string& a, const std::string& b, std::string* why = nullptr)
{
    openvdb::io::File fa(a), fb(b);
    fa.open();
    fb.open();
    auto ga = fa.getGrids(), gb = fb.getGrids();
    auto ma = fa.getMetadata(), mb = fb.getMetadata();
    auto fail = [&](const std::string& w) { if (why) *why = w; return false; };
    if (ga->size() != gb->size()) return fail("grid count");
    if (ma->str() != mb->str()) return fail("file metadata");
    for (size_t i = 0; i < ga->size(); ++i) {
        auto x = openvdb::gridPtrCast<openvdb::FloatGrid>((*ga)[i]);
        auto y = openvdb::gridPtrCast<openvdb::FloatGrid>((*gb)[i]);
        if (!x || !y || x->getName() != y->getName()) return fail("grid names/types");
        if (x->transform() != y->transform()) return fail("transform of " + x->getName());
        if (!x->tree().hasSameTopology(y->tree())) return fail("topology of " + x->getName());
        auto acc = y->getConstAccessor();
        for (auto it = x->cbeginValueAll(); it; ++it)
            if (std::memcmp(&*it, &static_cast<const float&>(acc.getValue(it.getCoord())), sizeof(float)) != 0)
                return fail("value of " + x->getName());
    }
    return true;
}

/// Runs a command line, returning its exit code; output goes to @a outFile.
inline int runCommand(const std::string& cmd, const std::string& outFile)
{
    const int rc = std::system((cmd + " > " + outFile + " 2>&1").c_str());
    return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

/// Ice area (p > 1/2) in square voxels of a plate, sampling @a p (in plate coordinates u, v,
/// centred) every half voxel over an L x L square.
inline double iceArea(const std::function<double(double, double)>& p, double L)
{
    int n = 0;
    for (double v = -L / 2 + 0.25; v < L / 2; v += 0.5)
        for (double u = -L / 2 + 0.25; u < L / 2; u += 0.5) n += p(u, v) > 0.5 ? 1 : 0;
    return n * 0.25;
}

} // namespace frostvdb::test
