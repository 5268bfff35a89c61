#include <frostvdb/core/Effect.h>

#include <algorithm>

namespace frostvdb {

namespace {
std::map<std::string, EffectInfo>& registry()
{
    static std::map<std::string, EffectInfo> r;
    return r;
}
} // namespace

void EffectRegistry::add(EffectInfo info)
{
    registry()[info.section] = std::move(info);
}

const EffectInfo* EffectRegistry::find(const std::string& section)
{
    auto it = registry().find(section);
    return it == registry().end() ? nullptr : &it->second;
}

std::vector<const EffectInfo*> EffectRegistry::all()
{
    std::vector<const EffectInfo*> v;
    for (auto& [k, info] : registry()) v.push_back(&info);
    return v;
}

} // namespace frostvdb
