#include <frostvdb/core/Bench.h>

#include <map>

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

} // namespace frostvdb
