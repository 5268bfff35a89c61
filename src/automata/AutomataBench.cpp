/// @file AutomataBench.cpp
/// @brief `frostvdb bench automata`: cell updates per second of every rule on a 1001 x 1001
/// hexagonal lattice (radius 500), full computation and 1/12 wedge. No OpenVDB here.
#include <frostvdb/automata/Automata.h>
#include <frostvdb/core/Bench.h>

#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <chrono>
#include <cstdio>
#include <memory>

namespace frostvdb {
namespace automata {
namespace {

struct BenchResult {
    double fullRate = 0, wedgeRate = 0; // lattice cell updates per second
    double fullSec = 0, wedgeSec = 0;
};

double timeSteps(HexAutomaton& a, int steps)
{
    const auto t0 = std::chrono::steady_clock::now();
    for (int s = 0; s < steps; ++s) a.step();
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

int runBench(const BenchArgs& args)
{
    std::unique_ptr<tbb::global_control> gc;
    if (args.threads > 0)
        gc = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                   size_t(args.threads));
    const int radius = args.quick ? 100 : 500;
    const int steps = args.quick ? 5 : 20;
    const Rule rules[] = {Rule::Packard, Rule::CoxeReiter, Rule::Probabilistic, Rule::Reiter,
                          Rule::GravnerGriffeath, Rule::GravnerGriffeath3D};
    std::printf("frostvdb bench automata: %d x %d hexagonal lattice (radius %d), %d steps per run, %d threads\n",
                2 * radius + 1, 2 * radius + 1, radius, steps,
                int(tbb::this_task_arena::max_concurrency()));
    std::printf("  (rate = lattice cells advanced per second; the wedge run computes 1/12 of them)\n");
    std::printf("%-22s %8s %14s %14s %8s\n", "rule", "layers", "full Mcells/s", "wedge Mcells/s", "speed-up");
    for (Rule r : rules) {
        AutomatonConfig cfg;
        cfg.rule = r;
        cfg.radius = radius;
        cfg.layers = r == Rule::GravnerGriffeath3D ? 4 : 1;
        cfg.cr.background = 0.3; // fast growth: the front is busy during the run
        cfg.reiter.beta = 0.4;
        BenchResult res;
        for (int w = 0; w < 2; ++w) {
            cfg.wedge = w == 1;
            HexAutomaton a(cfg);
            timeSteps(a, 2); // warm-up
            const double sec = timeSteps(a, steps);
            const double rate = double(a.latticeCells()) * steps / sec;
            (w ? res.wedgeRate : res.fullRate) = rate;
            (w ? res.wedgeSec : res.fullSec) = sec;
        }
        std::printf("%-22s %8d %14.1f %14.1f %7.1fx\n", ruleName(r), cfg.layers, res.fullRate * 1e-6,
                    res.wedgeRate * 1e-6, res.wedgeRate / res.fullRate);
    }
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(automata, "automata",
    "hexagonal automata: cell updates per second per rule at 1001 x 1001, full vs 1/12 wedge", runBench);

} // namespace automata
} // namespace frostvdb
