#pragma once
/// @file ParticleHash.h
/// @brief The sparse acceleration structure of [dla3d]: a hierarchy of hashed uniform grids over
/// the aggregate's particles, answering "how far is the nearest particle at least, and which one
/// is it when it is close" for walkers jumping through empty space.
///
/// Level 0 (cell size h) keeps the particles of each occupied cell as a linked list. Level k >= 1
/// (cell size h 2^k) keeps one flag per cell: "some particle lies in the 3^d block of cells around
/// this one". A point whose level-k cell is not flagged is at least h 2^k from every particle, and
/// the flags are monotone in k, so a query climbs or descends a few levels from a hint and, near
/// the aggregate, scans the 3^d level-0 cells exactly. Inserts are serial; queries are read-only
/// and run from many threads at once between inserts.
#include <openvdb/openvdb.h>

#include <cstdint>
#include <vector>

namespace frostvdb::dla3d {

class ParticleHash {
public:
    /// @param cellSize level-0 cell size (must be >= the contact test distance)
    /// @param dimension 2 (z ignored, cells only at z = 0) or 3
    ParticleHash(double cellSize, int dimension);

    /// Adds particle @a id at @a p (ids must be the indices into the positions passed to query).
    void insert(uint32_t id, const openvdb::Vec3d& p);

    struct Result {
        double distance;  ///< exact nearest distance when nearest >= 0, else a lower bound
        int32_t nearest;  ///< index of the nearest particle if it is closer than the level-0 block's clearance (>= cellSize()), else -1
    };
    /// @param levelHint in/out: the level the previous query of this walker ended on
    Result query(const openvdb::Vec3d& p, const std::vector<openvdb::Vec3d>& positions, int& levelHint) const;

    double cellSize() const { return mCell; }
    static constexpr int kLevels = 22;
    size_t memoryBytes() const;
    size_t entries() const { return mCount; }

private:
    uint64_t key(int level, int64_t x, int64_t y, int64_t z) const;
    /// Slot of @a k or -1.
    int64_t find(uint64_t k) const;
    /// Slot of @a k, inserting it (value 0) when absent.
    size_t findOrInsert(uint64_t k);
    void grow();
    bool nearFlag(int level, const openvdb::Vec3d& p) const;
    double blockClearance(const openvdb::Vec3d& p, double h) const;

    double mCell;
    int mDim;
    struct Slot {
        uint64_t key = 0;  ///< 0 = empty slot
        int32_t value = 0; ///< level 0: head particle id + 1; level k: bit 0 occupied, bit 1 near
    };
    std::vector<Slot> mSlots; ///< open addressing, linear probing, load <= 0.6
    std::vector<int32_t> mNext;   ///< per particle: next particle in its level-0 cell, -1 ends
    size_t mCount = 0;
    size_t mMask = 0;
};

} // namespace frostvdb::dla3d
