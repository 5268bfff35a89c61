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

void Effect::saveState(const World&, StateWriter&) const
{
    if (needsHistory())
        throw CheckpointError("[" + name() + "] keeps state from step to step but cannot save it yet, so this scene "
                              "cannot be checkpointed or resumed (run it without --checkpoint-every/--resume)");
}

void Effect::loadState(World&, const StateReader&)
{
    if (needsHistory())
        throw CheckpointError("[" + name() + "] keeps state from step to step but cannot restore it, so this scene "
                              "cannot be resumed");
}

const char* stageName(Stage s)
{
    switch (s) {
    case Stage::Sources: return "sources";
    case Stage::Walkers: return "walkers";
    case Stage::PhaseField: return "phase field";
    case Stage::ObstacleCopy: return "obstacle copy";
    case Stage::Fluid: return "fluid";
    case Stage::HeatAdvection: return "heat advection";
    }
    return "?";
}

std::vector<std::string> Effect::fieldsWritten() const
{
    std::vector<std::string> names;
    for (const auto& u : declaration().uses)
        if (u.key->role == FieldRole::Field && (u.access & (kInitialises | kWrites))) names.push_back(u.key->name);
    return names;
}

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
