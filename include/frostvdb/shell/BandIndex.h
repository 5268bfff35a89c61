#pragma once
/// @file BandIndex.h
/// @brief A shell band's index per voxel (-1 off the band), compact.
///
/// The band is built in 8^3 leaves whose voxels get consecutive indices in offset order
/// (ShellBand::computeLeaf). So a leaf needs only which of its 512 voxels are band voxels (8
/// words of bits), each word's rank and its first index: about 90 bytes, where an Int32Grid
/// leaf took 2 KiB for the 45 nodes a surface leaf holds on average (the windshield at 2 mm:
/// 15.7 MiB for 6,294 leaves, 7 % of the whole run's memory). Leaves are found through a small
/// OpenVDB tree of leaf coordinates (origin / 8), read through a cached accessor.
#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

namespace frostvdb::shell {

class BandIndex {
    /// One leaf: bit (x << 6 | y << 3 | z) of word (offset >> 6) marks a band voxel.
    struct LeafBits {
        std::array<uint64_t, 8> words{};
        std::array<uint16_t, 8> rank{}; ///< band voxels in the words before each
        uint32_t begin = 0;             ///< index of the leaf's first band voxel
    };
    /// Leaf coordinates (origin / 8) -> slot in mLeaves, background -1.
    using SlotTree = openvdb::tree::Tree3<int32_t, 4, 3>::Type;
    static openvdb::Coord leafCoord(const openvdb::Coord& origin)
    {
        return openvdb::Coord(origin.x() >> 3, origin.y() >> 3, origin.z() >> 3);
    }

public:
    static constexpr int kLeafDim = 8;

    BandIndex() : mSlotOf(std::make_shared<SlotTree>(-1)) {}

    /// Adds the leaf at @a origin (a multiple of 8) whose band voxels @a coords, in ascending
    /// offset order, get the indices @a begin, begin + 1, ...
    void addLeaf(const openvdb::Coord& origin, uint32_t begin, const std::vector<openvdb::Coord>& coords);
    size_t memUsage() const { return mSlotOf->memUsage() + mLeaves.capacity() * sizeof(LeafBits); }

    /// Reads indices, keeping the leaf last read (not valid across addLeaf()).
    class Accessor {
    public:
        explicit Accessor(const BandIndex& index) : mIndex(&index), mSlots(*index.mSlotOf) {}
        int32_t getValue(const openvdb::Coord& c)
        {
            const openvdb::Coord origin(c.x() & ~(kLeafDim - 1), c.y() & ~(kLeafDim - 1), c.z() & ~(kLeafDim - 1));
            if (origin != mOrigin) {
                mOrigin = origin;
                const int32_t slot = mSlots.getValue(leafCoord(origin));
                mLeaf = slot < 0 ? nullptr : &mIndex->mLeaves[size_t(slot)];
            }
            if (!mLeaf) return -1;
            const unsigned offset = unsigned(((c.x() & 7) << 6) | ((c.y() & 7) << 3) | (c.z() & 7));
            const uint64_t word = mLeaf->words[offset >> 6], bit = uint64_t(1) << (offset & 63);
            if (!(word & bit)) return -1;
            return int32_t(mLeaf->begin + mLeaf->rank[offset >> 6] + uint32_t(__builtin_popcountll(word & (bit - 1))));
        }

    private:
        const BandIndex* mIndex;
        openvdb::tree::ValueAccessor<const SlotTree, false> mSlots;
        openvdb::Coord mOrigin{std::numeric_limits<int>::max()};
        const LeafBits* mLeaf = nullptr;
    };
    Accessor accessor() const { return Accessor(*this); }
    /// One voxel's index (a fresh look-up; use an Accessor for many).
    int32_t getValue(const openvdb::Coord& c) const { return accessor().getValue(c); }

private:
    SlotTree::Ptr mSlotOf;
    std::vector<LeafBits> mLeaves;
};

inline void BandIndex::addLeaf(const openvdb::Coord& origin, uint32_t begin, const std::vector<openvdb::Coord>& coords)
{
    LeafBits leaf;
    leaf.begin = begin;
    for (const openvdb::Coord& c : coords) {
        const unsigned offset = unsigned(((c.x() & 7) << 6) | ((c.y() & 7) << 3) | (c.z() & 7));
        leaf.words[offset >> 6] |= uint64_t(1) << (offset & 63);
    }
    for (int w = 1; w < 8; ++w) leaf.rank[w] = uint16_t(leaf.rank[w - 1] + __builtin_popcountll(leaf.words[w - 1]));
    mSlotOf->setValue(leafCoord(origin), int32_t(mLeaves.size()));
    mLeaves.push_back(leaf);
}

} // namespace frostvdb::shell
