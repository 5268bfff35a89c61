#pragma once
/// @file State.h
/// @brief The state of a run as named values, for checkpoints: an effect saves what carries its
/// history (counters, clocks, solver buffers, private grids) under keys of its own, and loads the
/// same keys on resume. Values keep their exact bits (doubles are stored as bytes, grids through
/// OpenVDB's lossless stream without half floats or active-mask compression), so a resumed run
/// continues bit for bit.
///
/// @code
///   void MyEffect::saveState(World& w, StateWriter& out) const {
///       out.putDouble("time", mTime);
///       out.putArray("u", mU);               // any std::vector of trivially copyable values
///       out.putGrid("last_dp", mLastDp);     // an OpenVDB grid (may be null)
///   }
///   void MyEffect::loadState(World& w, StateReader& in) {
///       mTime = in.getDouble("time");
///       in.getArray("u", mU);                // checks element size; throws CheckpointError
///       mLastDp = in.getGrid<openvdb::FloatGrid>("last_dp");
///   }
/// @endcode
/// Keys are scoped: the driver hands each effect a writer/reader prefixed with its section.
#include <openvdb/openvdb.h>

#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace frostvdb {

/// A checkpoint that cannot be written, read or applied (missing, truncated, from another scene).
class CheckpointError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// All values of one checkpoint: a flat map from key to typed bytes.
class StateArchive {
public:
    enum class Type : uint8_t { Int = 1, Double = 2, String = 3, Array = 4, Grid = 5 };
    struct Entry {
        Type type = Type::Int;
        uint32_t elementSize = 0; ///< Array: bytes per element
        std::string bytes; ///< Grid: its metadata names, then the grid as an OpenVDB stream
    };

    void put(const std::string& key, Entry e);
    const Entry& get(const std::string& key, Type type) const;
    bool has(const std::string& key) const { return mEntries.count(key) > 0; }
    std::vector<std::string> keys(const std::string& prefix = {}) const;

    /// The whole archive as bytes (magic, version, entries, checksum) and back.
    std::string serialise() const;
    static StateArchive deserialise(const std::string& bytes, const std::string& label);

private:
    std::map<std::string, Entry> mEntries;
};

class StateWriter {
public:
    StateWriter(StateArchive& archive, std::string prefix = {}) : mArchive(&archive), mPrefix(std::move(prefix)) {}
    /// A writer whose keys are prefixed by "name/".
    StateWriter scope(const std::string& name) const { return StateWriter(*mArchive, mPrefix + name + "/"); }

    void putInt(const std::string& key, int64_t v);
    void putDouble(const std::string& key, double v);
    void putString(const std::string& key, const std::string& v);
    template <typename T>
    void putArray(const std::string& key, const std::vector<T>& v)
    {
        static_assert(std::is_trivially_copyable_v<T>, "arrays of trivially copyable values only");
        putBytes(key, v.empty() ? nullptr : v.data(), v.size() * sizeof(T), sizeof(T));
    }
    /// Stores a copy of the grid (tree shared, metadata copied); a null grid is recorded as absent.
    void putGrid(const std::string& key, const openvdb::GridBase::ConstPtr& grid);

private:
    void putBytes(const std::string& key, const void* data, size_t bytes, uint32_t elementSize);
    StateArchive* mArchive;
    std::string mPrefix;
};

class StateReader {
public:
    StateReader(const StateArchive& archive, std::string prefix = {}, std::string label = "checkpoint")
        : mArchive(&archive), mPrefix(std::move(prefix)), mLabel(std::move(label)) {}
    StateReader scope(const std::string& name) const { return StateReader(*mArchive, mPrefix + name + "/", mLabel); }

    bool has(const std::string& key) const { return mArchive->has(mPrefix + key); }
    int64_t getInt(const std::string& key) const;
    double getDouble(const std::string& key) const;
    std::string getString(const std::string& key) const;
    template <typename T>
    void getArray(const std::string& key, std::vector<T>& out) const
    {
        static_assert(std::is_trivially_copyable_v<T>, "arrays of trivially copyable values only");
        const std::string& b = bytes(key, sizeof(T));
        out.resize(b.size() / sizeof(T));
        if (!b.empty()) std::memcpy(static_cast<void*>(out.data()), b.data(), b.size());
    }
    /// The grid stored under @a key (null if it was saved as null); throws if the type differs.
    openvdb::GridBase::Ptr getGridBase(const std::string& key) const;
    template <typename GridT>
    typename GridT::Ptr getGrid(const std::string& key) const
    {
        auto g = getGridBase(key);
        if (!g) return nullptr;
        auto t = openvdb::gridPtrCast<GridT>(g);
        if (!t) fail(key, "holds a " + g->type() + " grid, expected " + GridT::gridType());
        return t;
    }
    /// Names of the keys under this scope (without the prefix).
    std::vector<std::string> keys() const;

    [[noreturn]] void fail(const std::string& key, const std::string& what) const;

private:
    const std::string& bytes(const std::string& key, uint32_t elementSize) const;
    const StateArchive* mArchive;
    std::string mPrefix;
    std::string mLabel;
};

} // namespace frostvdb
