#pragma once
/// @file FuzzTargets.h
/// @brief What the libFuzzer harnesses run on each input, shared with the regression test
/// (tests/fuzz_regression_test.cpp replays every file of tests/fuzz_regressions/ through the
/// same functions in the normal suite). Each returns "" when the input kept the contract (it
/// was accepted, or refused with a SceneError: a one-line message, exit 2), else what went wrong.
/// Crashes and sanitizer reports need no return value: they stop the process.
#include <frostvdb/core/Domain.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Simulation.h>
#include <frostvdb/ice/Crystal.h>

#include <cmath>
#include <cstdint>
#include <exception>
#include <fstream>
#include <string>
#include <unistd.h>

namespace frostvdb::fuzz {

template <typename Fn>
std::string cleanRefusal(Fn&& fn)
{
    try {
        fn();
    } catch (const SceneError&) {
    } catch (const std::exception& e) {
        return std::string("escaped exception (not a SceneError): ") + e.what();
    } catch (...) {
        return "escaped non-standard exception";
    }
    return {};
}

/// Writes the input to a scratch file of this process (tmpfs when available) and returns its path.
inline std::string scratchFile(const uint8_t* data, size_t size, const std::string& ext)
{
    static const std::string dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
    const std::string path = dir + "/frostvdb_fuzz_" + std::to_string(getpid()) + "." + ext;
    std::ofstream(path, std::ios::binary | std::ios::trunc)
        .write(reinterpret_cast<const char*>(data), std::streamsize(size));
    return path;
}

/// Scene text -> Scene::fromString -> Simulation construction (every section and key validated,
/// effects created), without running a step.
inline std::string sceneTarget(const uint8_t* data, size_t size)
{
    const std::string text(reinterpret_cast<const char*>(data), size);
    return cleanRefusal([&] {
        // a memory budget bounds the work an input can ask for: effects estimate their
        // allocations from the scene and refuse what exceeds it (a shipped shell scene builds its
        // whole band when its walkers are created: 11 s under ASan at -O0, past the timeout; 16
        // MiB of estimate is at most a few seconds of such work)
        Scene scene = Scene::fromString(text, "fuzz.toml");
        scene.applyOverride("run.memory_limit=0.015625");
        Simulation sim(std::move(scene));
        (void)sim.effects().size();
    });
}

/// Samples a map file over a small plane as [crystal] does; values must land in [0, 1].
inline std::string mapTarget(const std::string& path, bool indexSpace)
{
    static const Domain domain = makePlaneDomain(Lattice(), openvdb::Coord(24, 16, 1), 1e-3);
    ice::MapSource src;
    src.path = path;
    src.stretch = true; // any aspect ratio: reach the sampler too
    src.indexSpace = indexSpace;
    src.key = "crystal.melt_map";
    bool inRange = true;
    std::string r = cleanRefusal([&] {
        ice::sampleMap(domain, src, true, [&](const openvdb::Coord&, float v) {
            if (!(v >= 0.f && v <= 1.f)) inRange = false;
        });
    });
    if (r.empty() && !inRange) r = "a map value outside [0, 1] reached the simulation";
    return r;
}

/// PNG bytes -> the map reader (readPngGray, aspect check, bilinear sampling).
inline std::string pngTarget(const uint8_t* data, size_t size) { return mapTarget(scratchFile(data, size, "png"), false); }

/// VDB bytes -> the map reader (grid listing, metadata, readGrid, range check, sampling in world
/// and in index space).
inline std::string vdbTarget(const uint8_t* data, size_t size)
{
    const std::string path = scratchFile(data, size, "vdb");
    std::string r = mapTarget(path, false);
    return r.empty() ? mapTarget(path, true) : r;
}

} // namespace frostvdb::fuzz
