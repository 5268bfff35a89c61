#pragma once
/// @file Scene.h
/// @brief A parsed scene: a TOML file with one section per effect (plus the core sections
/// `scene`, `domain`, `region`, `output`), with `--set section.key=value` overrides applied.
/// The simulation never sees text: it reads ParamDicts.
#include <frostvdb/core/Params.h>

#include <map>
#include <memory>
#include <string>
#include <vector>

namespace frostvdb {

class Scene {
public:
    /// Parses a scene file. Throws SceneError with file and line on a syntax error.
    static Scene load(const std::string& path);
    /// Parses scene text; @a label is used as the file name in messages.
    static Scene fromString(const std::string& text, const std::string& label);
    /// The built-in default scene (a growing dendrite).
    static Scene builtinDefault();
    static const char* builtinDefaultText();

    /// Applies "section.key=value"; the value is parsed as TOML (numbers, booleans, strings,
    /// arrays; a bare word is taken as a string).
    void applyOverride(const std::string& assignment);

    const std::string& label() const { return mLabel; }
    /// The file's text as written (comments included).
    const std::string& text() const { return mText; }
    /// The scene after every override, as TOML: what the run actually used.
    std::string effectiveText() const;
    /// The overrides applied, in order, as "section.key=value".
    const std::vector<std::string>& overrides() const { return mOverrides; }
    /// Sections in file order.
    const std::vector<std::string>& sectionNames() const { return mOrder; }
    bool hasSection(const std::string& name) const { return mSections.count(name) > 0; }
    /// The section's parameters; an absent section yields an empty dict (all defaults).
    ParamDict& section(const std::string& name);
    int sectionLine(const std::string& name) const;

private:
    struct Document;
    std::shared_ptr<Document> mDoc;
    std::vector<std::string> mOverrides;
    std::string mLabel;
    std::string mText;
    std::vector<std::string> mOrder;
    std::map<std::string, ParamDict> mSections;
    std::map<std::string, int> mSectionLines;
};

} // namespace frostvdb
