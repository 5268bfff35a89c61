#pragma once
/// @file Params.h
/// @brief One scene section's parameters: typed, range-checked look-ups that remember which
/// keys were read, so keys nobody read are reported as errors (the pbrt-v4 way).
///
/// The same look-ups double as the schema: a ParamDict with no values returns the defaults and
/// records every key's type, default, unit, range and description, which is how
/// `frostvdb keys` and docs/scene-reference.md are produced from the code itself.
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <variant>
#include <vector>

namespace frostvdb {

/// A value as written in a scene: TOML scalars and flat arrays of numbers.
using ParamValue = std::variant<bool, int64_t, double, std::string, std::vector<double>>;

/// Where a value came from, for error messages.
struct ParamOrigin {
    std::string file; ///< scene path, or "--set" for command-line overrides
    int line = 0;
};

/// What the code declares about a key when it reads it.
struct ParamSpec {
    std::string key;          ///< without the section prefix
    std::string type;         ///< "float", "int", "bool", "string", "float[N]"
    std::string defaultText;  ///< default as text
    std::string range;        ///< allowed range or choices as text
    std::string unit;         ///< unit, "" if dimensionless
    std::string doc;          ///< one-line description
};

class ParamDict {
public:
    explicit ParamDict(std::string section = {}) : mSection(std::move(section)) {}

    const std::string& section() const { return mSection; }
    /// Where the section starts (scene file, line of its header): the origin of messages about
    /// keys the scene does not give (a default that does not fit the rest of the scene).
    void setSectionOrigin(ParamOrigin o) { mSectionOrigin = std::move(o); }
    void set(const std::string& key, ParamValue value, ParamOrigin origin);
    /// Stores an array of tables (TOML `[[section.key]]` or `key = [{...}, {...}]`); each element
    /// is a ParamDict of its own whose section reads "section.key#N" (N from 1) in messages.
    void setTables(const std::string& key, std::vector<ParamDict> tables, ParamOrigin origin);
    bool has(const std::string& key) const { return mEntries.count(key) > 0 || mTables.count(key) > 0; }
    const ParamOrigin* origin(const std::string& key) const;

    /// Typed look-ups. Each records the spec and throws SceneError (file, line, key, allowed
    /// range) on a wrong type or out-of-range value.
    double getFloat(const std::string& key, double def, double lo, double hi,
                    const std::string& unit, const std::string& doc);
    int64_t getInt(const std::string& key, int64_t def, int64_t lo, int64_t hi,
                   const std::string& unit, const std::string& doc);
    bool getBool(const std::string& key, bool def, const std::string& doc);
    std::string getString(const std::string& key, const std::string& def,
                          const std::vector<std::string>& choices, const std::string& doc);
    /// A numeric array; an empty @a counts accepts any length >= 1, otherwise the length must be
    /// one of @a counts.
    std::vector<double> getFloatArray(const std::string& key, const std::vector<double>& def,
                                      std::vector<size_t> counts, double lo, double hi,
                                      const std::string& unit, const std::string& doc);

    /// An array of tables: returns its elements (empty when absent) and records the key, plus one
    /// spec per element key ("key[].sub") taken from @a elementSchema, a ParamDict the caller
    /// filled by reading an empty element (so the element reader must accept an empty table).
    /// The elements' unread keys are reported by checkAllRead.
    std::vector<ParamDict>& getTables(const std::string& key, const std::string& doc,
                                      const ParamDict& elementSchema);

    /// A key that does not apply under the options chosen: when the scene gives @a key although
    /// @a applies is false, throws SceneError naming the key and @a option, the setting that
    /// excludes it (e.g. `scheme = "euler"`), like an unknown key. Call it after the key's
    /// look-up, which documents the key whatever the options.
    void onlyWhen(bool applies, const std::string& key, const std::string& option) const;

    /// Throws SceneError naming the first key that no look-up read (in arrays of tables too).
    void checkAllRead() const;

    /// Throws a SceneError about @a key with the origin of that key (if it was given).
    [[noreturn]] void fail(const std::string& key, const std::string& what) const;

    const std::vector<ParamSpec>& specs() const { return mSpecs; }

    /// Every value given (file and --set), one "key = value" line each in key order, numbers
    /// with all their digits: two dicts with the same text hold the same parameters (checkpoints
    /// compare it to refuse resuming another scene). Keys in @a skip are left out.
    std::string canonicalText(const std::vector<std::string>& skip = {}) const;

private:
    struct Entry {
        ParamValue value;
        ParamOrigin origin;
        mutable bool read = false;
    };
    struct TableEntry {
        std::vector<ParamDict> tables;
        ParamOrigin origin;
        bool read = false;
    };
    const Entry* find(const std::string& key) const;
    void record(ParamSpec spec);
    std::string qualified(const std::string& key) const;

    std::string mSection;
    ParamOrigin mSectionOrigin;
    std::map<std::string, Entry> mEntries;
    std::map<std::string, TableEntry> mTables;
    std::vector<ParamDict> mNoTables; ///< what getTables returns for an absent key
    std::vector<ParamSpec> mSpecs;
};

} // namespace frostvdb
