#include <frostvdb/io/InputFiles.h>
#include <frostvdb/core/Scene.h>
#include <frostvdb/core/Error.h>

#include <toml++/toml.h>

#include <algorithm>
#include <cctype>
#include <fstream>
#include <sstream>

namespace frostvdb {

namespace {

/// Converts one TOML node to a ParamValue; nested tables and mixed arrays are refused.
ParamValue toValue(const toml::node& node, const std::string& file, const std::string& key)
{
    const int line = int(node.source().begin.line);
    if (auto v = node.as_boolean()) return v->get();
    if (auto v = node.as_integer()) return int64_t(v->get());
    if (auto v = node.as_floating_point()) return v->get();
    if (auto v = node.as_string()) return v->get();
    if (auto arr = node.as_array()) {
        std::vector<double> out;
        for (auto& el : *arr) {
            if (auto i = el.as_integer()) out.push_back(double(i->get()));
            else if (auto f = el.as_floating_point()) out.push_back(f->get());
            else throw SceneError(file, line, key, "arrays may hold numbers only");
        }
        return out;
    }
    throw SceneError(file, line, key, "unsupported value (expected a number, boolean, string or array of numbers)");
}

/// True for a non-empty array whose elements are all tables (`[[a.b]]` or `[{...}, {...}]`).
bool isTableArray(const toml::node& node)
{
    auto arr = node.as_array();
    return arr && !arr->empty() && arr->is_array_of_tables();
}

/// Converts an array of tables to ParamDicts; their values follow the rules of toValue.
std::vector<ParamDict> toTables(const toml::node& node, const std::string& file, const std::string& key)
{
    std::vector<ParamDict> out;
    int n = 0;
    for (auto& el : *node.as_array()) {
        ++n;
        ParamDict d;
        for (auto& [kk, value] : *el.as_table()) {
            const std::string sub = key + "#" + std::to_string(n) + "." + std::string(kk.str());
            const int line = int(value.source().begin.line);
            if (value.is_table() || isTableArray(value))
                throw SceneError(file, line, sub, "tables inside an array of tables are not allowed");
            d.set(std::string(kk.str()), toValue(value, file, sub), {file, line});
        }
        out.push_back(std::move(d));
    }
    return out;
}

bool isBareKey(const std::string& s)
{
    if (s.empty() || s.size() > 64) return false;
    for (char c : s)
        if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-')) return false;
    return true;
}

} // namespace

/// The parsed document, kept so overrides can be applied to it and the effective scene printed.
struct Scene::Document {
    toml::table root;
};

std::string Scene::effectiveText() const
{
    if (!mDoc) return mText;
    std::ostringstream os;
    os << mDoc->root;
    return os.str() + "\n";
}

Scene Scene::load(const std::string& path)
{
    try {
        requireRegularFile(path); // a FIFO would block the read forever
    } catch (const std::runtime_error& e) {
        const std::string m = e.what();
        throw SceneError(path, 0, "", m.substr(std::min(m.size(), path.size() + 2)));
    }
    std::ifstream in(path);
    if (!in) throw SceneError(path, 0, "", "cannot open scene file");
    std::stringstream ss;
    ss << in.rdbuf();
    return fromString(ss.str(), path);
}

Scene Scene::fromString(const std::string& text, const std::string& label)
{
    Scene scene;
    scene.mLabel = label;
    scene.mText = text;
    scene.mDoc = std::make_shared<Document>();
    toml::table& root = scene.mDoc->root;
    try {
        root = toml::parse(text, label);
    } catch (const toml::parse_error& err) {
        throw SceneError(label, int(err.source().begin.line), "",
                         "syntax error: " + std::string(err.description()));
    }
    // Sections in file order: toml::table iterates sorted, so order by source line.
    std::vector<std::pair<int, std::string>> ordered;
    for (auto& [k, node] : root) {
        const std::string name(k.str());
        const int line = int(node.source().begin.line);
        auto table = node.as_table();
        if (!table)
            throw SceneError(label, line, name, "top-level keys must be inside a [section]");
        ParamDict dict(name);
        dict.setSectionOrigin({label, line});
        for (auto& [kk, value] : *table) {
            const std::string key(kk.str());
            if (value.is_table())
                throw SceneError(label, int(value.source().begin.line), name + "." + key,
                                 "nested tables are not allowed");
            if (isTableArray(value)) {
                dict.setTables(key, toTables(value, label, name + "." + key),
                               {label, int(value.source().begin.line)});
                continue;
            }
            dict.set(key, toValue(value, label, name + "." + key),
                     {label, int(value.source().begin.line)});
        }
        scene.mSections.emplace(name, std::move(dict));
        scene.mSectionLines[name] = line;
        ordered.emplace_back(line, name);
    }
    std::sort(ordered.begin(), ordered.end());
    for (auto& [line, name] : ordered) scene.mOrder.push_back(name);
    return scene;
}

void Scene::applyOverride(const std::string& assignment)
{
    const std::string where = "--set " + assignment;
    const auto eq = assignment.find('=');
    const auto dot = assignment.find('.');
    if (eq == std::string::npos || dot == std::string::npos || dot > eq || dot == 0 || dot + 1 == eq)
        throw SceneError("--set", 0, assignment, "expected section.key=value");
    const std::string section = assignment.substr(0, dot);
    const std::string key = assignment.substr(dot + 1, eq - dot - 1);
    const std::string valueText = assignment.substr(eq + 1);
    if (!isBareKey(section) || !isBareKey(key))
        throw SceneError("--set", 0, assignment.substr(0, eq),
                         "section and key are names of letters, digits, '_' and '-' (at most 64)");
    for (char c : valueText)
        if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f)
            throw SceneError("--set", 0, section + "." + key, "the value holds a control character (newline, tab, ...); "
                             "give one TOML value on one line");
    ParamValue value;
    std::vector<ParamDict> tables;
    bool isTables = false;
    toml::table t;
    try {
        t = toml::parse("v = " + valueText);
        if (t.size() != 1)
            throw SceneError("--set", 0, section + "." + key, "expected one TOML value, got more ('" + valueText + "')");
        if (isTableArray(*t.get("v"))) {
            tables = toTables(*t.get("v"), "--set", section + "." + key);
            isTables = true;
        } else {
            value = toValue(*t.get("v"), "--set", section + "." + key);
        }
    } catch (const toml::parse_error&) {
        // A bare word such as `lattice=hexagonal` or `file=maps/seed.png`: one word, no spaces.
        if (valueText.empty() ||
            valueText.find_first_not_of("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_.,/:+-") !=
                std::string::npos)
            throw SceneError("--set", 0, section + "." + key,
                             "expected one TOML value (number, boolean, \"string\", [array]) or one bare word, got '" +
                                 valueText + "'");
        value = valueText;
        t = toml::table{};
        t.insert("v", valueText);
    }
    if (mDoc) {
        if (mDoc.use_count() > 1) mDoc = std::make_shared<Document>(*mDoc); // copies of a Scene stay apart
        auto* sec = mDoc->root.get_as<toml::table>(section);
        if (!sec) sec = mDoc->root.insert_or_assign(section, toml::table{}).first->second.as_table();
        t.get("v")->visit([&](auto&& node) { sec->insert_or_assign(key, node); });
    }
    mOverrides.push_back(section + "." + key + "=" + valueText);
    auto it = mSections.find(section);
    if (it == mSections.end()) {
        it = mSections.emplace(section, ParamDict(section)).first;
        it->second.setSectionOrigin({mLabel, 0});
        mOrder.push_back(section);
        mSectionLines[section] = 0;
    }
    if (isTables) it->second.setTables(key, std::move(tables), {"--set", 0});
    else it->second.set(key, std::move(value), {"--set", 0});
}

ParamDict& Scene::section(const std::string& name)
{
    auto it = mSections.find(name);
    if (it == mSections.end()) {
        it = mSections.emplace(name, ParamDict(name)).first;
        it->second.setSectionOrigin({mLabel, 0});
    }
    return it->second;
}

int Scene::sectionLine(const std::string& name) const
{
    auto it = mSectionLines.find(name);
    return it == mSectionLines.end() ? 0 : it->second;
}

const char* Scene::builtinDefaultText()
{
    return R"(# frostvdb built-in default scene: a six-armed dendrite growing in an undercooled melt
# (Kobayashi phase field, the ice paper's Table 1 constants, forward Euler).
[scene]
name = "dendrite"
frames = 8
steps_per_frame = 150

[domain]
kind = "plane"
lattice = "square"
size = [192, 192]
voxel_size = 0.0001     # metres per cell: a 19 mm plate

[phase_field]
scheme = "euler"
dt = 0.0002
anisotropy_mode = 6
)";
}

Scene Scene::builtinDefault()
{
    return fromString(builtinDefaultText(), "<built-in default scene>");
}

} // namespace frostvdb
