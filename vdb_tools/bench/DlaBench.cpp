/// @file DlaBench.cpp
/// @brief `frostvdb bench dla [SCENE] [key=value ...]`: runs a [dla] scene with empty-space jumps
/// on and off and prints walkers, steps, jumps, steps saved and the walker time of each.
/// Without a scene it runs scenes/dla_hex.toml (or a quick 128^2 version with --quick).
#include <frostvdb/BuildPaths.h>
#include <frostvdb/core/Bench.h>
#include <frostvdb/core/Simulation.h>
#include <frostvdb/ice/Dla.h>

#include <tbb/global_control.h>

#include <chrono>
#include <cstdio>
#include <ctime>
#include <memory>

namespace frostvdb {
namespace {

double cpuSeconds() { return double(std::clock()) / CLOCKS_PER_SEC; }

int benchDla(const BenchArgs& args)
{
    std::unique_ptr<tbb::global_control> gc;
    if (args.threads > 0)
        gc = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, args.threads);
    std::string path = std::string(FROSTVDB_SOURCE_DIR) + "/scenes/dla_hex.toml";
    std::vector<std::string> overrides;
    bool withPlain = true;
    for (const auto& a : args.args) {
        if (a == "jumps-only") withPlain = false;
        else if (a.find('=') != std::string::npos) overrides.push_back(a);
        else path = a;
    }
    if (args.quick) overrides.push_back("domain.size=[128,128]");
    std::printf("%-6s %10s %12s %14s %12s %10s %10s %10s\n", "jumps", "walkers", "moves", "lattice steps", "jumps",
                "frozen", "walk s", "cpu s");
    double base = 0;
    for (bool jumps : {false, true}) {
        if (!jumps && !withPlain) continue;
        Scene scene = Scene::load(path);
        for (const auto& o : overrides) scene.applyOverride(o);
        scene.applyOverride(std::string("dla.jumps=") + (jumps ? "true" : "false"));
        Simulation sim(std::move(scene));
        const double c0 = cpuSeconds();
        sim.initialize();
        const int64_t steps = sim.world().frames * sim.world().stepsPerFrame;
        for (int64_t s = 0; s < steps; ++s) sim.step();
        const double cpu = cpuSeconds() - c0;
        auto* fx = dynamic_cast<ice::DlaEffect*>(sim.effect("dla"));
        if (!fx) {
            std::fprintf(stderr, "the scene has no [dla] section\n");
            return 1;
        }
        const auto& st = fx->stats();
        std::printf("stuck %llu, conflicts %llu, killed %llu; seconds: walkers %.2f, apply %.2f, distance %.2f, "
                    "tables %.2f\n", (unsigned long long)st.stuck, (unsigned long long)st.conflicts,
                    (unsigned long long)st.killed, st.walkSeconds, st.applySeconds, st.syncSeconds, st.tableSeconds);
        std::printf("%-6s %10llu %12llu %14.4g %12llu %10llu %10.2f %10.2f\n", jumps ? "on" : "off",
                    (unsigned long long)st.released, (unsigned long long)st.moves, st.latticeSteps,
                    (unsigned long long)st.jumps, (unsigned long long)st.frozen, st.walkSeconds, cpu);
        if (!jumps) base = st.walkSeconds;
        else if (st.walkSeconds > 0)
            std::printf("walker speedup %.1fx; %.1f lattice steps per executed move\n", base / st.walkSeconds,
                        st.latticeSteps / double(std::max<uint64_t>(1, st.moves)));
    }
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(dla, "dla", "DLA walkers with and without empty-space jumps: steps, jumps, walker time",
                        benchDla);

} // namespace frostvdb
