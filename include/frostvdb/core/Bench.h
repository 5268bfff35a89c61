#pragma once
/// @file Bench.h
/// @brief `frostvdb bench NAME`: named benchmarks registered from the module they measure.
/// A benchmark prints its figures and, where asked, writes them to docs/.
#include <chrono>
#include <functional>
#include <string>
#include <vector>

namespace frostvdb {

struct BenchArgs {
    std::vector<std::string> args; ///< extra words after the benchmark name
    int threads = 0;               ///< 0: all cores
    std::string docsDir = "docs";  ///< where a benchmark may write its report
    bool quick = false;            ///< smaller sizes (for smoke tests)
};

using BenchFn = std::function<int(const BenchArgs&)>;

struct BenchInfo {
    std::string name;
    std::string summary;
    BenchFn run;
};

class BenchRegistry {
public:
    static void add(BenchInfo info);
    static const BenchInfo* find(const std::string& name);
    static std::vector<const BenchInfo*> all();
};

struct BenchRegistrar {
    BenchRegistrar(const std::string& name, const std::string& summary, BenchFn fn)
    { BenchRegistry::add({name, summary, std::move(fn)}); }
};

/// What benchmarks measure, one definition for all of them.
namespace bench {
using Clock = std::chrono::steady_clock;
inline double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
double cpuSeconds();   ///< user + system CPU of this process
double peakRssMiB();   ///< peak resident memory (VmHWM) since start or the last resetPeakRss()
void resetPeakRss();   ///< starts a new VmHWM peak (Linux clear_refs 5)
} // namespace bench

} // namespace frostvdb

#define FROSTVDB_REGISTER_BENCH(ID, NAME, SUMMARY, FN) \
    static ::frostvdb::BenchRegistrar frostvdbBenchRegistrar_##ID(NAME, SUMMARY, FN)
