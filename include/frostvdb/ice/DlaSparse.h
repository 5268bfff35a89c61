#pragma once
/// @file DlaSparse.h
/// @brief A flat open-addressing hash map from a 64-bit key to a small value, for the DLA
/// walkers' sparse structures (distance bricks, the occupancy pyramid, hit counts). Memory grows
/// with the keys stored, never with the domain; lookups are one multiply and a short linear probe
/// (a few ns), cheaper than a VDB accessor miss and independent of insertion order for reads.
/// Not thread-safe for writes; concurrent reads are fine while nobody writes.
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace frostvdb {
namespace ice {

template <typename V>
class KeyMap {
public:
    static constexpr uint64_t kEmpty = ~uint64_t(0);

    KeyMap() { clear(); }

    void clear()
    {
        mKeys.assign(16, kEmpty);
        mValues.assign(16, V());
        mSize = 0;
        mShift = 64 - 4;
    }
    size_t size() const { return mSize; }
    size_t bytes() const { return mKeys.size() * (sizeof(uint64_t) + sizeof(V)); }

    /// The value stored for @a key, or null.
    const V* find(uint64_t key) const
    {
        for (size_t i = slot(key);; i = (i + 1) & (mKeys.size() - 1)) {
            if (mKeys[i] == key) return &mValues[i];
            if (mKeys[i] == kEmpty) return nullptr;
        }
    }
    V* find(uint64_t key) { return const_cast<V*>(static_cast<const KeyMap&>(*this).find(key)); }
    bool contains(uint64_t key) const { return find(key) != nullptr; }

    /// Inserts @a key with @a value when absent; returns the stored value and whether it was new.
    std::pair<V*, bool> insert(uint64_t key, const V& value = V())
    {
        if ((mSize + 1) * 4 > mKeys.size() * 3) grow();
        for (size_t i = slot(key);; i = (i + 1) & (mKeys.size() - 1)) {
            if (mKeys[i] == key) return {&mValues[i], false};
            if (mKeys[i] == kEmpty) {
                mKeys[i] = key;
                mValues[i] = value;
                ++mSize;
                return {&mValues[i], true};
            }
        }
    }

    /// Visits every (key, value) in slot order.
    template <typename F>
    void forEach(F&& f) const
    {
        for (size_t i = 0; i < mKeys.size(); ++i)
            if (mKeys[i] != kEmpty) f(mKeys[i], mValues[i]);
    }

private:
    size_t slot(uint64_t key) const { return size_t((key * 0x9E3779B97F4A7C15ull) >> mShift); }
    void grow()
    {
        std::vector<uint64_t> keys;
        std::vector<V> values;
        keys.swap(mKeys);
        values.swap(mValues);
        mKeys.assign(keys.size() * 2, kEmpty);
        mValues.assign(keys.size() * 2, V());
        --mShift;
        mSize = 0;
        for (size_t i = 0; i < keys.size(); ++i)
            if (keys[i] != kEmpty) insert(keys[i], values[i]);
    }

    std::vector<uint64_t> mKeys;
    std::vector<V> mValues;
    size_t mSize = 0;
    int mShift = 60;
};

} // namespace ice
} // namespace frostvdb
