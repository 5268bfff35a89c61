#pragma once
/// @file Random.h
/// @brief Counter-based random numbers: every draw is a pure function of (seed, stream, counter),
/// so results are bit-identical for a given seed whatever the thread count or the order in which
/// threads visit voxels, walkers or cells.
///
/// The mixer is SplitMix64's finaliser applied in a chain (a keyed hash, not a sequential
/// generator): draw(seed, a, b, c) = mix(mix(mix(seed ^ K0) ^ a) ^ b) ^ c ...
#include <cstdint>

namespace frostvdb {

inline uint64_t mix64(uint64_t z)
{
    z += 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/// A 64-bit hash of up to four counters under a seed.
inline uint64_t hashCounters(uint64_t seed, uint64_t a, uint64_t b = 0, uint64_t c = 0, uint64_t d = 0)
{
    uint64_t h = mix64(seed ^ 0x6A09E667F3BCC909ull);
    h = mix64(h ^ a);
    h = mix64(h ^ (b + 0x3C6EF372FE94F82Bull));
    h = mix64(h ^ (c + 0xA54FF53A5F1D36F1ull));
    return mix64(h ^ (d + 0x510E527FADE682D1ull));
}

/// Uniform double in [0, 1) from the top 53 bits.
inline double toUnit(uint64_t h) { return double(h >> 11) * (1.0 / 9007199254740992.0); }

/// A small stream for one logical entity (a walker, a cell, a voxel) at one step: successive
/// next() calls are hashCounters(seed, stream, step, k) for k = 0, 1, 2, ...
class CounterRng {
public:
    CounterRng(uint64_t seed, uint64_t stream, uint64_t step = 0)
        : mKey(hashCounters(seed, stream, step)) {}
    uint64_t next() { return mix64(mKey ^ mix64(++mCounter)); }
    double uniform() { return toUnit(next()); }
    /// Uniform integer in [0, n).
    uint32_t below(uint32_t n) { return uint32_t((next() >> 32) * n >> 32); }

private:
    uint64_t mKey;
    uint64_t mCounter = 0;
};

/// Packs a voxel coordinate into one 64-bit counter (21 bits per axis, offset to be unsigned).
inline uint64_t coordKey(int32_t i, int32_t j, int32_t k)
{
    const uint64_t m = (1ull << 21) - 1;
    return ((uint64_t(i + (1 << 20)) & m) << 42) | ((uint64_t(j + (1 << 20)) & m) << 21) |
           (uint64_t(k + (1 << 20)) & m);
}

} // namespace frostvdb
