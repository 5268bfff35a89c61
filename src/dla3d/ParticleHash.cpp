/// @file ParticleHash.cpp
#include <frostvdb/dla3d/ParticleHash.h>

#include <frostvdb/core/Random.h>

#include <cmath>
#include <limits>

namespace frostvdb::dla3d {

ParticleHash::ParticleHash(double cellSize, int dimension) : mCell(cellSize), mDim(dimension)
{
    mSlots.assign(1 << 12, Slot{});
    mMask = mSlots.size() - 1;
}

uint64_t ParticleHash::key(int level, int64_t x, int64_t y, int64_t z) const
{
    constexpr uint64_t m = (1ull << 19) - 1;
    return (1ull << 63) | (uint64_t(level) << 57) | ((uint64_t(x) & m) << 38) | ((uint64_t(y) & m) << 19) |
           (uint64_t(z) & m);
}

int64_t ParticleHash::find(uint64_t k) const
{
    size_t s = mix64(k) & mMask;
    while (true) {
        const uint64_t e = mSlots[s].key;
        if (e == k) return int64_t(s);
        if (e == 0) return -1;
        s = (s + 1) & mMask;
    }
}

size_t ParticleHash::findOrInsert(uint64_t k)
{
    if ((mCount + 1) * 10 > mSlots.size() * 6) grow();
    size_t s = mix64(k) & mMask;
    while (true) {
        const uint64_t e = mSlots[s].key;
        if (e == k) return s;
        if (e == 0) {
            mSlots[s] = Slot{k, 0};
            ++mCount;
            return s;
        }
        s = (s + 1) & mMask;
    }
}

void ParticleHash::grow()
{
    std::vector<Slot> slots(mSlots.size() * 2, Slot{});
    const size_t mask = slots.size() - 1;
    for (const Slot& e : mSlots) {
        if (!e.key) continue;
        size_t s = mix64(e.key) & mask;
        while (slots[s].key) s = (s + 1) & mask;
        slots[s] = e;
    }
    mSlots.swap(slots);
    mMask = mask;
}

void ParticleHash::insert(uint32_t id, const openvdb::Vec3d& p)
{
    // level 0: push onto the cell's list
    const double inv = 1.0 / mCell;
    int64_t c[3] = {int64_t(std::floor(p.x() * inv)), int64_t(std::floor(p.y() * inv)),
                    mDim == 3 ? int64_t(std::floor(p.z() * inv)) : 0};
    if (mNext.size() <= id) mNext.resize(size_t(id) + 1, -1);
    const size_t s0 = findOrInsert(key(0, c[0], c[1], c[2]));
    mNext[id] = mSlots[s0].value - 1;
    mSlots[s0].value = int32_t(id) + 1;
    // coarser levels: flag the 3^d block once per newly occupied cell
    const int dz = mDim == 3 ? 1 : 0;
    for (int level = 1; level < kLevels; ++level) {
        for (auto& v : c) v = v >> 1; // floor division by 2 (arithmetic shift)
        const size_t s = findOrInsert(key(level, c[0], c[1], c[2]));
        if (mSlots[s].value & 1) break; // occupied already: this and all coarser blocks are flagged
        mSlots[s].value |= 1;
        for (int64_t i = -1; i <= 1; ++i)
            for (int64_t j = -1; j <= 1; ++j)
                for (int64_t k = -dz; k <= dz; ++k) mSlots[findOrInsert(key(level, c[0] + i, c[1] + j, c[2] + k))].value |= 2;
    }
}

bool ParticleHash::nearFlag(int level, const openvdb::Vec3d& p) const
{
    const double inv = 1.0 / std::ldexp(mCell, level);
    const int64_t s = find(key(level, int64_t(std::floor(p.x() * inv)), int64_t(std::floor(p.y() * inv)),
                               mDim == 3 ? int64_t(std::floor(p.z() * inv)) : 0));
    return s >= 0 && (mSlots[s].value & 2);
}

/// Distance from @a p to the outside of the 3^d block of cells (size @a h) around its own cell:
/// between h and 1.5 h.
double ParticleHash::blockClearance(const openvdb::Vec3d& p, double h) const
{
    double m = h;
    for (int a = 0; a < mDim; ++a) {
        const double f = p[a] / h - std::floor(p[a] / h);
        m = std::min(m, std::min(f, 1.0 - f) * h);
    }
    return h + m;
}

ParticleHash::Result ParticleHash::query(const openvdb::Vec3d& p, const std::vector<openvdb::Vec3d>& positions,
                                         int& levelHint) const
{
    // smallest flagged level k (flags are monotone in k)
    int k = std::min(std::max(levelHint, 1), kLevels - 1);
    if (nearFlag(k, p)) {
        while (k > 1 && nearFlag(k - 1, p)) --k;
    } else {
        while (k < kLevels - 1 && !nearFlag(k + 1, p)) ++k;
        ++k;
        if (k >= kLevels) { // beyond the coarsest level: the bound of the coarsest
            levelHint = kLevels - 1;
            return {blockClearance(p, std::ldexp(mCell, kLevels - 1)), -1};
        }
    }
    levelHint = k;
    if (k > 1) return {blockClearance(p, std::ldexp(mCell, k - 1)), -1};
    // exact scan of the 3^d level-0 block, skipping cells farther than the answer can be
    const double inv = 1.0 / mCell;
    const double fx = p.x() * inv, fy = p.y() * inv, fz = mDim == 3 ? p.z() * inv : 0.0;
    const int64_t cx = int64_t(std::floor(fx)), cy = int64_t(std::floor(fy)), cz = int64_t(std::floor(fz));
    const double off[3] = {fx - double(cx), fy - double(cy), fz - double(cz)};
    const double clear = blockClearance(p, mCell);
    const double clear2 = clear * clear;
    const int dz = mDim == 3 ? 1 : 0;
    double best2 = clear2;
    int32_t best = -1;
    auto gap = [&](int a, int64_t d) { // distance (cells) along axis a from p to the neighbour cell d
        return d < 0 ? off[a] : d > 0 ? 1.0 - off[a] : 0.0;
    };
    for (int64_t i = -1; i <= 1; ++i) {
        const double gx = gap(0, i);
        for (int64_t j = -1; j <= 1; ++j) {
            const double gy = gap(1, j);
            for (int64_t kk = -dz; kk <= dz; ++kk) {
                const double gz = mDim == 3 ? gap(2, kk) : 0.0;
                if ((gx * gx + gy * gy + gz * gz) * mCell * mCell >= best2) continue;
                const int64_t s = find(key(0, cx + i, cy + j, cz + kk));
                if (s < 0) continue;
                for (int32_t id = mSlots[s].value - 1; id >= 0; id = mNext[id]) {
                    const double d2 = (positions[id] - p).lengthSqr();
                    if (d2 < best2 || (d2 == best2 && id < best)) { best2 = d2; best = id; }
                }
            }
        }
    }
    // anything outside the block is at least `clear` away: a found particle nearer is the nearest
    if (best >= 0) return {std::sqrt(best2), best};
    return {clear, -1};
}

size_t ParticleHash::memoryBytes() const
{
    return mSlots.capacity() * sizeof(Slot) +
           mNext.capacity() * sizeof(int32_t);
}

} // namespace frostvdb::dla3d
