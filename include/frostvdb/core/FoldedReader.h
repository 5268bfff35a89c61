#pragma once
/// @file FoldedReader.h
/// @brief A folded plane field (core/PlaneFold.h) read as its plane layout, in place.
#include <frostvdb/core/PlaneFold.h>

#include <openvdb/openvdb.h>

namespace frostvdb {
namespace plane {

/// A folded plane field read as its plane layout (plane::unfoldGrid's result) by plane index,
/// without making that copy: a plane cell reads its folded cell when its 8 x 8 chunk holds an
/// active voxel (unfoldGrid makes a plane leaf only there) and the background elsewhere, as do
/// cells off layer 0. The folded tree has no active tiles. Samplers take it as a tree
/// (getValue, probeValue, isValueOn); one per thread (it holds an accessor).
class FoldedReader {
public:
    using ValueType = float;
    using TreeType = openvdb::FloatTree;
    explicit FoldedReader(const openvdb::FloatGrid& folded) : mAcc(folded.tree()), mBg(folded.background()) {}
    bool probeValue(const openvdb::Coord& c, float& v) const
    {
        const openvdb::FloatTree::LeafNodeType* leaf = chunkLeaf(c);
        if (!leaf) {
            v = mBg;
            return false;
        }
        const openvdb::Index n = offset(c);
        v = leaf->getValue(n);
        return leaf->isValueOn(n);
    }
    float getValue(const openvdb::Coord& c) const
    {
        float v;
        probeValue(c, v);
        return v;
    }
    bool isValueOn(const openvdb::Coord& c) const
    {
        const openvdb::FloatTree::LeafNodeType* leaf = chunkLeaf(c);
        return leaf && leaf->isValueOn(offset(c));
    }

private:
    static openvdb::Index offset(const openvdb::Coord& c) { return openvdb::Index(((c.y() & 7) << 6) | (c.x() & 63)); }
    const openvdb::FloatTree::LeafNodeType* chunkLeaf(const openvdb::Coord& c) const
    {
        if (c.z() != 0) return nullptr;
        const auto* leaf = mAcc.probeConstLeaf(fold(c));
        if (!leaf) return nullptr;
        const int g = (c.x() >> 3) & 7;
        const auto& m = leaf->getValueMask();
        uint64_t any = 0;
        for (openvdb::Index w = 0; w < 8; ++w) any |= m.template getWord<uint64_t>(w);
        return ((any >> (g * 8)) & 0xffu) ? leaf : nullptr;
    }
    mutable openvdb::tree::ValueAccessor<const openvdb::FloatTree> mAcc;
    float mBg;
};

/// The plane leaves (origins) unfoldGrid would make of @a folded: one per 8 x 8 chunk of a folded
/// leaf that holds an active voxel, in the folded leaves' order, each with the bit mask of its
/// active columns and its first and last active rows.
struct PlaneChunk {
    openvdb::Coord origin;
    uint8_t columns = 0; ///< bit dx: column dx has an active voxel
    int y0 = 8, y1 = -1; ///< first and last rows with an active voxel
};
template <typename LeafT>
inline int chunksOf(const LeafT& leaf, PlaneChunk out[8])
{
    const auto& m = leaf.getValueMask();
    int n = 0;
    for (int g = 0; g < 8; ++g) {
        PlaneChunk c;
        for (int dy = 0; dy < 8; ++dy) {
            const uint64_t row = (m.template getWord<uint64_t>(openvdb::Index(dy)) >> (g * 8)) & 0xffu;
            c.columns = uint8_t(c.columns | row);
            if (row) {
                if (c.y0 > dy) c.y0 = dy;
                c.y1 = dy;
            }
        }
        if (!c.columns) continue;
        c.origin = planeLeafOfChunk(leaf.origin(), g);
        out[n++] = c;
    }
    return n;
}

} // namespace plane
} // namespace frostvdb
