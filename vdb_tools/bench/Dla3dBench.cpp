/// @file Dla3dBench.cpp
/// @brief `frostvdb bench dla3d [N ...] [dim=2|3] [stick=S] [threads via --threads]`: grows free
/// aggregates of N particles (default 10,000, 100,000 and 1,000,000; --quick: 10,000) and prints
/// wall time, peak memory (process high-water mark, sizes run in increasing order), particles per
/// second, walk statistics and the fractal dimension. Default parameters match fogleman/dlaf's
/// (spacing 1, attraction distance 3: radius 0.5, stick distance 2); dlaf's published figures
/// on this machine kind are printed beside them.
#include <frostvdb/core/Bench.h>
#include <frostvdb/dla3d/Aggregate.h>
#include <frostvdb/dla3d/Fractal.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>

namespace frostvdb::dla3d {
namespace {

double dlafSeconds(size_t n)
{
    // fogleman/dlaf (Boost R-tree, one core), as published in issue 13 for this machine kind
    if (n == 10000) return 0.29;
    if (n == 100000) return 5.79;
    if (n == 1000000) return 102.6;
    return 0;
}

int benchDla3d(const BenchArgs& args)
{
    std::unique_ptr<tbb::global_control> gc;
    if (args.threads > 0)
        gc = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, args.threads);
    std::vector<size_t> sizes;
    DlaSettings base;
    base.radius = 0.5;
    base.stickDistance = 2.0;
    for (const auto& a : args.args) {
        if (a.rfind("dim=", 0) == 0) base.dimension = std::stoi(a.substr(4));
        else if (a.rfind("stick=", 0) == 0) base.stickDistance = std::stod(a.substr(6));
        else if (a.rfind("seed=", 0) == 0) base.seed = std::stoull(a.substr(5));
        else if (a.rfind("cell=", 0) == 0) base.cellFactor = std::stod(a.substr(5));
        else if (a.rfind("batch=", 0) == 0) base.maxBatch = std::stoi(a.substr(6));
        else sizes.push_back(size_t(std::stod(a)));
    }
    if (sizes.empty()) sizes = args.quick ? std::vector<size_t>{10000} : std::vector<size_t>{10000, 100000, 1000000};
    std::sort(sizes.begin(), sizes.end());
    std::printf("dla3d: %dD, radius %.3g, stick distance %.3g (touch at %.3g), threads %d\n", base.dimension,
                base.radius, base.stickDistance, base.contact() + base.stickDistance, args.threads);
    std::printf("%10s %9s %9s %9s %12s %9s %9s %10s %8s %8s %10s %9s\n", "particles", "wall s", "cpu s", "peak MB",
                "particles/s",
                "steps/p", "walk/p", "conflicts", "D(Rg)", "D(N(r))", "dlaf s", "speedup");
    for (size_t n : sizes) {
        const auto t0 = std::chrono::steady_clock::now();
        const std::clock_t c0 = std::clock(); // CPU of all threads: comparable on a loaded machine
        Aggregate agg(base);
        agg.growTo(n);
        const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        const double cpu = double(std::clock() - c0) / CLOCKS_PER_SEC;
        const auto& st = agg.stats();
        const auto g = gyrationDimension(agg.positions(), std::max<size_t>(100, n / 1000));
        const auto m = massRadiusDimension(agg.positions(), agg.centre(), 10 * agg.settings().contact(),
                                           0.3 * agg.radius());
        const double dl = base.dimension == 3 && base.stickDistance == 2.0 && base.radius == 0.5 ? dlafSeconds(n) : 0;
        std::printf("%10zu %9.2f %9.2f %9.1f %12.0f %9.1f %9.2f %10llu %8.3f %8.3f %10s %9s\n", n, wall, cpu, bench::peakRssMiB(),
                    double(n) / wall, double(st.steps) / double(n), double(st.walkers) / double(n),
                    (unsigned long long)st.conflicts, g.dimension, m.dimension,
                    dl > 0 ? std::to_string(dl).substr(0, 6).c_str() : "-",
                    dl > 0 ? (std::to_string(dl / wall).substr(0, 5) + "x").c_str() : "-");
        std::fflush(stdout);
    }
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(dla3d, "dla3d",
                        "off-lattice 3D DLA: wall time, peak memory, particles/s at 10k/100k/1M vs fogleman/dlaf",
                        benchDla3d);

} // namespace frostvdb::dla3d
