#include <frostvdb/core/Params.h>
#include <frostvdb/core/Error.h>

#include <charconv>
#include <cmath>
#include <sstream>

namespace frostvdb {

namespace {

std::string numText(double v)
{
    std::ostringstream os;
    os.precision(10);
    os << v;
    return os.str();
}

std::string rangeText(double lo, double hi)
{
    return "[" + numText(lo) + ", " + numText(hi) + "]";
}

const char* typeName(const ParamValue& v)
{
    switch (v.index()) {
    case 0: return "a boolean";
    case 1: return "an integer";
    case 2: return "a float";
    case 3: return "a string";
    default: return "an array";
    }
}

} // namespace

void ParamDict::set(const std::string& key, ParamValue value, ParamOrigin origin)
{
    mTables.erase(key);
    mEntries[key] = Entry{std::move(value), std::move(origin), false};
}

void ParamDict::setTables(const std::string& key, std::vector<ParamDict> tables, ParamOrigin origin)
{
    for (size_t i = 0; i < tables.size(); ++i) tables[i].mSection = qualified(key) + "#" + std::to_string(i + 1);
    mEntries.erase(key);
    mTables[key] = TableEntry{std::move(tables), std::move(origin), false};
}

const ParamOrigin* ParamDict::origin(const std::string& key) const
{
    auto it = mEntries.find(key);
    if (it != mEntries.end()) return &it->second.origin;
    auto t = mTables.find(key);
    return t == mTables.end() ? nullptr : &t->second.origin;
}

const ParamDict::Entry* ParamDict::find(const std::string& key) const
{
    auto it = mEntries.find(key);
    if (it == mEntries.end()) return nullptr;
    it->second.read = true;
    return &it->second;
}

std::string ParamDict::qualified(const std::string& key) const
{
    return mSection.empty() ? key : mSection + "." + key;
}

void ParamDict::record(ParamSpec spec)
{
    for (auto& s : mSpecs)
        if (s.key == spec.key) return;
    mSpecs.push_back(std::move(spec));
}

std::string ParamDict::canonicalText(const std::vector<std::string>& skip) const
{
    std::ostringstream os;
    auto num = [&](double v) { // shortest text that reads back to the same double
        char buf[64];
        const auto r = std::to_chars(buf, buf + sizeof(buf), v);
        os.write(buf, r.ptr - buf);
    };
    auto skipped = [&](const std::string& k) {
        for (auto& s : skip)
            if (s == k) return true;
        return false;
    };
    for (const auto& [key, e] : mEntries) {
        if (skipped(key)) continue;
        os << qualified(key) << " = ";
        std::visit([&](const auto& v) {
            using V = std::decay_t<decltype(v)>;
            if constexpr (std::is_same_v<V, std::vector<double>>) {
                os << "[";
                for (size_t i = 0; i < v.size(); ++i) {
                    if (i) os << ", ";
                    num(v[i]);
                }
                os << "]";
            } else if constexpr (std::is_same_v<V, std::string>) {
                os << '"' << v << '"';
            } else if constexpr (std::is_same_v<V, bool>) {
                os << (v ? "true" : "false");
            } else if constexpr (std::is_same_v<V, double>) {
                num(v);
            } else {
                os << v;
            }
        }, e.value);
        os << "\n";
    }
    for (const auto& [key, t] : mTables) {
        if (skipped(key)) continue;
        for (size_t i = 0; i < t.tables.size(); ++i) // a marker line: an empty table counts too
            os << qualified(key) << "#" << (i + 1) << "\n" << t.tables[i].canonicalText();
    }
    return os.str();
}

void ParamDict::onlyWhen(bool applies, const std::string& key, const std::string& option) const
{
    if (!applies && has(key)) fail(key, "does not apply with " + option + " (remove the key or change that option)");
}

void ParamDict::fail(const std::string& key, const std::string& what) const
{
    const ParamOrigin* o = origin(key);
    if (!o) o = &mSectionOrigin;
    throw SceneError(o->file, o->line, qualified(key), what);
}

double ParamDict::getFloat(const std::string& key, double def, double lo, double hi,
                           const std::string& unit, const std::string& doc)
{
    record({key, "float", numText(def), rangeText(lo, hi), unit, doc});
    const Entry* e = find(key);
    if (!e) return def;
    double v;
    if (auto d = std::get_if<double>(&e->value)) v = *d;
    else if (auto i = std::get_if<int64_t>(&e->value)) v = double(*i);
    else fail(key, std::string("expected a number, got ") + typeName(e->value));
    if (!std::isfinite(v) || v < lo || v > hi)
        fail(key, numText(v) + " is out of range " + rangeText(lo, hi) + (unit.empty() ? "" : " " + unit));
    return v;
}

int64_t ParamDict::getInt(const std::string& key, int64_t def, int64_t lo, int64_t hi,
                          const std::string& unit, const std::string& doc)
{
    record({key, "int", std::to_string(def),
            "[" + std::to_string(lo) + ", " + std::to_string(hi) + "]", unit, doc});
    const Entry* e = find(key);
    if (!e) return def;
    int64_t v;
    if (auto i = std::get_if<int64_t>(&e->value)) v = *i;
    else if (auto d = std::get_if<double>(&e->value); d && std::floor(*d) == *d && std::fabs(*d) < 9e15)
        v = int64_t(*d);
    else fail(key, std::string("expected an integer, got ") + typeName(e->value));
    if (v < lo || v > hi)
        fail(key, std::to_string(v) + " is out of range [" + std::to_string(lo) + ", " +
                      std::to_string(hi) + "]" + (unit.empty() ? "" : " " + unit));
    return v;
}

bool ParamDict::getBool(const std::string& key, bool def, const std::string& doc)
{
    record({key, "bool", def ? "true" : "false", "true | false", "", doc});
    const Entry* e = find(key);
    if (!e) return def;
    if (auto b = std::get_if<bool>(&e->value)) return *b;
    fail(key, std::string("expected true or false, got ") + typeName(e->value));
}

std::string ParamDict::getString(const std::string& key, const std::string& def,
                                 const std::vector<std::string>& choices, const std::string& doc)
{
    std::string allowed;
    for (size_t i = 0; i < choices.size(); ++i) allowed += (i ? " | " : "") + choices[i];
    record({key, "string", "\"" + def + "\"", choices.empty() ? "any text" : allowed, "", doc});
    const Entry* e = find(key);
    if (!e) return def;
    auto s = std::get_if<std::string>(&e->value);
    if (!s) fail(key, std::string("expected a string, got ") + typeName(e->value));
    if (!choices.empty()) {
        for (auto& c : choices)
            if (c == *s) return *s;
        fail(key, "\"" + *s + "\" is not one of " + allowed);
    }
    return *s;
}

std::vector<double> ParamDict::getFloatArray(const std::string& key, const std::vector<double>& def,
                                             std::vector<size_t> counts, double lo, double hi,
                                             const std::string& unit, const std::string& doc)
{
    std::string defText = "[";
    for (size_t i = 0; i < def.size(); ++i) defText += (i ? ", " : "") + numText(def[i]);
    defText += "]";
    std::string countText;
    for (size_t i = 0; i < counts.size(); ++i) countText += (i ? " or " : "") + std::to_string(counts[i]);
    record({key, counts.empty() ? "float[]" : "float[" + countText + "]", defText,
            rangeText(lo, hi), unit, doc});
    const Entry* e = find(key);
    if (!e) return def;
    std::vector<double> v;
    if (auto a = std::get_if<std::vector<double>>(&e->value)) v = *a;
    else fail(key, std::string("expected an array of numbers, got ") + typeName(e->value));
    if (v.empty()) fail(key, "expected at least one number");
    if (!counts.empty()) {
        bool ok = false;
        for (size_t c : counts) ok = ok || (v.size() == c);
        if (!ok) fail(key, "expected " + countText + " numbers, got " + std::to_string(v.size()));
    }
    for (double x : v)
        if (!std::isfinite(x) || x < lo || x > hi)
            fail(key, "element " + numText(x) + " is out of range " + rangeText(lo, hi) +
                          (unit.empty() ? "" : " " + unit));
    return v;
}

std::vector<ParamDict>& ParamDict::getTables(const std::string& key, const std::string& doc,
                                             const ParamDict& elementSchema)
{
    record({key, "table[]", "none", "array of tables, keys " + key + "[].*", "", doc});
    for (const auto& s : elementSchema.specs()) {
        ParamSpec sub = s;
        sub.key = key + "[]." + s.key;
        record(std::move(sub));
    }
    if (auto e = mEntries.find(key); e != mEntries.end()) {
        e->second.read = true;
        fail(key, "expected an array of tables ([[" + qualified(key) + "]] entries)");
    }
    auto t = mTables.find(key);
    if (t == mTables.end()) {
        mNoTables.clear();
        return mNoTables;
    }
    t->second.read = true;
    return t->second.tables;
}

void ParamDict::checkAllRead() const
{
    for (auto& [key, t] : mTables) {
        if (t.read) {
            for (auto& d : t.tables) d.checkAllRead();
            continue;
        }
        std::string known;
        for (auto& s : mSpecs) known += (known.empty() ? "" : ", ") + s.key;
        fail(key, "unknown key in section [" + mSection + "] (known keys: " +
                      (known.empty() ? "none" : known) + ")");
    }
    for (auto& [key, entry] : mEntries) {
        if (entry.read) continue;
        std::string known;
        for (auto& s : mSpecs) known += (known.empty() ? "" : ", ") + s.key;
        fail(key, "unknown key in section [" + mSection + "] (known keys: " +
                      (known.empty() ? "none" : known) + ")");
    }
}

} // namespace frostvdb
