#include <frostvdb/core/StepOrder.h>
#include <frostvdb/core/Error.h>

#include <cstring>
#include <functional>
#include <map>
#include <set>

namespace frostvdb {

bool sameMeaning(const FieldKey& a, const FieldKey& b)
{
    return std::strcmp(a.name, b.name) == 0 && a.type == b.type && a.role == b.role &&
           std::strcmp(a.unit, b.unit) == 0 && std::strcmp(a.meaning, b.meaning) == 0;
}

namespace {

std::string describe(const FieldKey& k)
{
    std::string s = k.meaning;
    if (*k.unit) s += std::string(" [") + k.unit + "]";
    return s;
}

/// Refuses two different keys of one name and role.
void checkMeanings(const std::vector<DeclaredEffect>& fx, const std::string& label)
{
    struct Seen { const FieldKey* key; size_t effect; };
    std::map<std::pair<int, std::string>, Seen> seen;
    auto check = [&](const FieldKey& k, size_t e) {
        const auto id = std::make_pair(int(k.role), std::string(k.name));
        auto it = seen.find(id);
        if (it == seen.end()) { seen[id] = {&k, e}; return; }
        if (sameMeaning(*it->second.key, k)) return;
        const std::string what = k.role == FieldRole::Output ? "output grid" : k.role == FieldRole::State ? "state" : "field";
        throw SceneError(label, 0, "[" + fx[it->second.effect].section + "] and [" + fx[e].section + "]",
                         "both write the " + what + " '" + k.name + "' with different meanings: [" +
                             fx[it->second.effect].section + "]: " + describe(*it->second.key) + "; [" + fx[e].section +
                             "]: " + describe(k) + " (one name means one thing: see docs/outputs.md)");
    };
    for (size_t e = 0; e < fx.size(); ++e) {
        for (const auto& u : fx[e].declaration.uses) check(*u.key, e);
        for (const auto* o : fx[e].declaration.outputs) check(*o, e);
    }
}

/// Kahn's algorithm: @a before[i] lists the nodes that must precede i; ties by @a rank.
std::vector<size_t> topological(size_t n, const std::vector<std::set<size_t>>& before,
                                const std::function<std::pair<int, size_t>(size_t)>& rank,
                                const std::vector<DeclaredEffect>& fx, const std::string& label, const std::string& what)
{
    std::vector<size_t> order;
    std::vector<bool> done(n, false);
    while (order.size() < n) {
        size_t best = n;
        for (size_t i = 0; i < n; ++i) {
            if (done[i]) continue;
            bool ready = true;
            for (size_t b : before[i]) ready = ready && done[b];
            if (ready && (best == n || rank(i) < rank(best))) best = i;
        }
        if (best == n) {
            std::string cycle;
            for (size_t i = 0; i < n; ++i)
                if (!done[i]) cycle += (cycle.empty() ? "[" : ", [") + fx[i].section + "]";
            throw SceneError(label, 0, cycle, "these effects need each other's " + what + " first (circular declarations)");
        }
        done[best] = true;
        order.push_back(best);
    }
    return order;
}

} // namespace

EffectOrder deriveEffectOrder(const std::vector<DeclaredEffect>& fx, const std::string& label)
{
    checkMeanings(fx, label);
    const size_t n = fx.size();
    auto uses = [&](size_t e, const std::string& name, unsigned access) {
        for (const auto& u : fx[e].declaration.uses)
            if ((u.access & access) && name == u.key->name) return true;
        return false;
    };
    std::set<std::string> names;
    for (const auto& f : fx)
        for (const auto& u : f.declaration.uses) names.insert(u.key->name);

    EffectOrder order;
    // initialisation: initialisers of a key before its readers at initialisation
    std::vector<std::set<size_t>> initBefore(n), stepBefore(n);
    for (const auto& name : names)
        for (size_t a = 0; a < n; ++a)
            for (size_t b = 0; b < n; ++b) {
                if (a == b) continue;
                if (uses(a, name, kInitialises) && uses(b, name, kReadsAtInit) && !uses(b, name, kInitialises))
                    initBefore[b].insert(a);
                // steps: within one stage, writers before readers
                if (fx[a].declaration.stage == fx[b].declaration.stage && uses(a, name, kWrites) &&
                    uses(b, name, kReads) && !uses(b, name, kWrites))
                    stepBefore[b].insert(a);
            }
    auto rank = [&](size_t i) { return std::make_pair(int(fx[i].declaration.stage), i); };
    order.initialize = topological(n, initBefore, rank, fx, label, "initialisation");
    order.step = topological(n, stepBefore, rank, fx, label, "step results");
    return order;
}

} // namespace frostvdb
