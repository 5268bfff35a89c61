#include <frostvdb/core/Bench.h>
#include <frostvdb/core/Stopwatch.h>

#include <fstream>
#include <map>
#include <sys/resource.h>

namespace frostvdb {

namespace {
std::map<std::string, BenchInfo>& registry()
{
    static std::map<std::string, BenchInfo> r;
    return r;
}
} // namespace

void BenchRegistry::add(BenchInfo info) { registry()[info.name] = std::move(info); }

const BenchInfo* BenchRegistry::find(const std::string& name)
{
    auto it = registry().find(name);
    return it == registry().end() ? nullptr : &it->second;
}

std::vector<const BenchInfo*> BenchRegistry::all()
{
    std::vector<const BenchInfo*> v;
    for (auto& [k, info] : registry()) v.push_back(&info);
    return v;
}

namespace bench {

double cpuSeconds() { return processCpuSeconds(); } // the run summary's clock (core/Stopwatch.h)

double peakRssMiB()
{
    std::ifstream in("/proc/self/status");
    std::string line;
    while (std::getline(in, line))
        if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
    return 0;
}

void resetPeakRss() { std::ofstream("/proc/self/clear_refs") << "5"; }

} // namespace bench

} // namespace frostvdb
