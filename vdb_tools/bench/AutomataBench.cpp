/// @file AutomataBench.cpp
/// @brief `frostvdb bench automata`: cell updates per second of every rule on a 1001 x 1001
/// hexagonal lattice (radius 500), full computation and 1/12 wedge. No OpenVDB here.
#include <frostvdb/automata/Automata.h>
#include <frostvdb/automata/GG3DEffect.h>
#include <frostvdb/core/Bench.h>

#include <sys/resource.h>

#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
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

double peakRssMB()
{
    struct rusage u;
    getrusage(RUSAGE_SELF, &u);
    return double(u.ru_maxrss) / 1024.0;
}

/// The Gravner-Griffeath 3D rows: the Fig. 14 classic dendrite grown from its seed until the
/// crystal radius reaches the target (400 cells; 60 with --quick), on the 1/24 wedge.
void benchGG3D(const BenchArgs& args)
{
    int target = args.quick ? 60 : 400, layers = 0;
    for (const auto& a : args.args) {
        if (a.rfind("radius=", 0) == 0) target = std::atoi(a.c_str() + 7);
        if (a.rfind("layers=", 0) == 0) layers = std::atoi(a.c_str() + 7);
    }
    const GG3DPreset* p = findGG3DPreset("fig14_classic_dendrite");
    GG3DConfig c;
    c.p = p->p;
    c.domainRadius = int(target / 0.8 + 0.5); // the paper stops at 80 % of the system radius
    c.layers = layers > 0 ? layers : 31; // the dendrite is a few layers thick; vapour comes from 15 above and below
    c.stopRadius = target;
    std::printf("\ngravner_griffeath_3d, Fig. 14 classic dendrite (rho 0.1, beta 1.6/1.5/1.5/1.4, kappa 0.1, mu 0.008)\n");
    std::printf("  domain radius %d, %d layers, reflecting walls, 1/24 wedge, grown until the crystal radius is %d\n",
                c.domainRadius, c.layers, target);
    GG3D a(c);
    const auto t0 = std::chrono::steady_clock::now();
    double lastReport = 0;
    while (!a.stopped()) {
        a.step();
        const double sec = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (sec - lastReport > 30.0) {
            lastReport = sec;
            std::printf("    ... step %lld, radius %d, box radius %d, %.0f s\n", (long long)a.steps(), a.crystalRadius(),
                        a.activeRadius(), sec);
            std::fflush(stdout);
        }
    }
    const double sec = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%-34s %8s %8s %10s %12s %12s\n", "case", "steps", "radius", "seconds", "solver MB", "peak RSS MB");
    std::printf("%-34s %8lld %8d %10.1f %12.1f %12.1f\n", "fig14 classic dendrite", (long long)a.steps(),
                a.crystalRadius(), sec, double(a.peakBytes()) / 1048576.0, peakRssMB());
    std::printf("  attached cells %llu, crystal layers %d..%d, %.2f ns per reduced cell update\n",
                (unsigned long long)a.attachedCount(), a.crystalZMin(), a.crystalZMax(),
                sec * 1e9 / (double(a.cellsPerStep()) * double(a.steps())));
}

int runBench(const BenchArgs& args)
{
    bool onlyGG3D = false;
    for (const auto& a : args.args) onlyGG3D |= a == "gg3d";
    std::unique_ptr<tbb::global_control> gc;
    if (args.threads > 0)
        gc = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                   size_t(args.threads));
    if (onlyGG3D) {
        benchGG3D(args);
        return 0;
    }
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
    benchGG3D(args);
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(automata, "automata",
    "hexagonal automata: cell updates per second per rule at 1001 x 1001, full vs 1/12 wedge; the GG 3D Fig. 14 "
    "dendrite grown to radius 400 (words: gg3d = only that row, radius=N, layers=N)", runBench);

} // namespace automata
} // namespace frostvdb
