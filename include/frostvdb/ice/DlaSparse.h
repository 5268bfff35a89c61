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
        mSlots.assign(16, Slot{kEmpty, V()});
        mSize = 0;
        mShift = 64 - 4;
    }
    size_t size() const { return mSize; }
    size_t bytes() const { return mSlots.size() * sizeof(Slot); }

    /// The value stored for @a key, or null.
    const V* find(uint64_t key) const
    {
        for (size_t i = slot(key);; i = (i + 1) & (mSlots.size() - 1)) {
            const Slot& s = mSlots[i];
            if (s.key == key) return &s.value;
            if (s.key == kEmpty) return nullptr;
        }
    }
    V* find(uint64_t key) { return const_cast<V*>(static_cast<const KeyMap&>(*this).find(key)); }
    bool contains(uint64_t key) const { return find(key) != nullptr; }
    /// Starts loading the slot where a find(@a key) begins (a hint; no effect on results).
    void prefetch(uint64_t key) const { __builtin_prefetch(&mSlots[slot(key)]); }

    /// Inserts @a key with @a value when absent; returns the stored value and whether it was new.
    std::pair<V*, bool> insert(uint64_t key, const V& value = V())
    {
        if ((mSize + 1) * 4 > mSlots.size() * 3) grow();
        for (size_t i = slot(key);; i = (i + 1) & (mSlots.size() - 1)) {
            Slot& s = mSlots[i];
            if (s.key == key) return {&s.value, false};
            if (s.key == kEmpty) {
                s.key = key;
                s.value = value;
                ++mSize;
                return {&s.value, true};
            }
        }
    }

    /// Visits every (key, value) in slot order.
    template <typename F>
    void forEach(F&& f) const
    {
        for (const Slot& s : mSlots)
            if (s.key != kEmpty) f(s.key, s.value);
    }

private:
    /// Key and value side by side: a probe reads one cache line, not one per array (the walkers
    /// probe the brick map and the pyramid at random places, so each probe is a cache miss).
    struct Slot {
        uint64_t key;
        V value;
    };
    size_t slot(uint64_t key) const { return size_t((key * 0x9E3779B97F4A7C15ull) >> mShift); }
    void grow()
    {
        std::vector<Slot> old;
        old.swap(mSlots);
        mSlots.assign(old.size() * 2, Slot{kEmpty, V()});
        --mShift;
        mSize = 0;
        for (const Slot& s : old)
            if (s.key != kEmpty) insert(s.key, s.value);
    }

    std::vector<Slot> mSlots;
    size_t mSize = 0;
    int mShift = 60;
};

} // namespace ice
} // namespace frostvdb
