#pragma once
/// @file PlaneFold.h
/// @brief Plane fields at their true density: the fold.
///
/// A plane field stored as Coord(x, y, 0) uses one z layer of every 8^3 leaf: 64 of 512 values,
/// about 36 bytes per voxel. Folded, plane voxel (x, y) of layer z = 0 is stored at
/// @code
///   Coord(y, ((x >> 3) & 127) | ((x >> 14) << 7), (x & 7) | (((x >> 10) & 15) << 3))   // fold()
/// @endcode
/// so an 8^3 leaf is a dense tile of 8 rows (y) by 64 columns (x), rows of x contiguous in the
/// leaf's buffer (offset ((y & 7) << 6) | (x & 63)), every value used: about 4.5 bytes per voxel
/// (`frostvdb bench layout`, docs/performance.md). The grid stays an OpenVDB grid (leaf managers,
/// pruning, checkpoints and I/O unchanged); only coordinates differ.
///
/// Which leaf a tile lands in is chosen so that the trees' internal nodes are used in all three
/// axes: the tile's 1024-column span within a 16384-column band (x bits 10..13) goes to z, so a
/// level-1 node (16^3 leaf slots, 33 KiB whatever it holds) covers a band of 128 rows by 16384
/// columns with every slot usable. (The first fold, Coord(y, x >> 3, x & 7), used one z slab in
/// 16 of every node: with 1000 scattered seeds on a 16384^2 pane each folded tree paid ~30 MiB of
/// nodes; docs/performance.md session 17.) Checkpoints written with that fold are moved to this
/// one when read (upgradeLegacyFold).
///
/// A folded grid carries the metadata kFoldMeta (Int32 kFoldVersion); every reader and writer of a
/// field that may be folded asks isFolded(grid) once per step and maps plane coordinates with
/// fold() (a PlaneCells accessor does that per cell). So a field restored from an older checkpoint
/// (not folded) is still read right. Frames never hold folded grids: export unfolds (unfoldGrid),
/// a permutation of the values, so a frame's grids keep their world placement and their bits.
///
/// Which fields are folded, and when: see foldsPlaneFields() and docs/architecture.md.
#include <frostvdb/core/Domain.h>

#include <openvdb/openvdb.h>

#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

namespace frostvdb {
namespace plane {

/// Grid metadata naming a folded plane field: Int32 kFoldVersion (a bool true marks the first
/// fold, see upgradeLegacyFold).
inline const char* const kFoldMeta = "frostvdb_plane_fold";
inline constexpr int32_t kFoldVersion = 2;

/// Stored y of plane column @a x: columns 8k .. 8k+7 of the 1024-column span, then the band.
inline int foldedY(int x) { return ((x >> 3) & 127) | ((x >> 14) * 128); }
/// Stored z of plane column @a x: its place in the leaf row, then its span within the band.
inline int foldedZ(int x) { return (x & 7) | (((x >> 10) & 15) << 3); }
/// Plane column of stored (y, z) (the inverse of foldedY and foldedZ).
inline int planeX(int fy, int fz) { return (fz & 7) | ((fy & 127) << 3) | (((fz >> 3) & 15) << 10) | ((fy >> 7) * 16384); }

/// Stored coordinate of plane voxel @a c (c.z() must be 0).
inline openvdb::Coord fold(const openvdb::Coord& c)
{
    return openvdb::Coord(c.y(), foldedY(c.x()), foldedZ(c.x()));
}
/// Plane voxel of stored coordinate @a f (the inverse of fold()).
inline openvdb::Coord unfold(const openvdb::Coord& f)
{
    return openvdb::Coord(planeX(f.y(), f.z()), f.x(), 0);
}
/// Origin of the folded leaf holding the plane leaf at @a lo (x, y multiples of 8, z 0).
inline openvdb::Coord foldedLeafOrigin(const openvdb::Coord& lo)
{
    return openvdb::Coord(lo.y(), foldedY(lo.x()) & ~7, foldedZ(lo.x()) & ~7);
}
/// Offset in its folded leaf of the voxel at (dx, dy) in the plane leaf at @a lo.
inline openvdb::Index foldedOffset(const openvdb::Coord& lo, int dx, int dy)
{
    return openvdb::Index((dy << 6) | (lo.x() & 63) | dx);
}
/// Origin of the plane leaf stored as chunk @a g (0..7: its 8 columns of each row) of the folded
/// leaf at @a fo (the inverse of foldedLeafOrigin with the chunk g = (lo.x() >> 3) & 7).
inline openvdb::Coord planeLeafOfChunk(const openvdb::Coord& fo, int g)
{
    return openvdb::Coord(planeX(fo.y() + g, fo.z()), fo.x(), 0);
}
/// True when @a fo can be a folded leaf's origin (a folded plane grid holds no other leaves).
inline bool isFoldedLeafOrigin(const openvdb::Coord& fo) { return fo.z() >= 0 && fo.z() < 128; }

/// A stored box holding the folded cells of the plane box @a planeBox (z 0) (and, where the
/// columns cross a 1024-column span, others: callers keep the cells whose unfold() is inside
/// @a planeBox): what an active tile of a folded field is clipped to before its cells are unfolded.
inline openvdb::CoordBBox foldedBBox(const openvdb::CoordBBox& planeBox)
{
    const int x0 = planeBox.min().x(), x1 = planeBox.max().x();
    if ((x0 >> 10) == (x1 >> 10)) // one span: a box
        return openvdb::CoordBBox(openvdb::Coord(planeBox.min().y(), foldedY(x0), foldedZ(x0) & ~7),
                                  openvdb::Coord(planeBox.max().y(), foldedY(x1), foldedZ(x0) | 7));
    return openvdb::CoordBBox(openvdb::Coord(planeBox.min().y(), (x0 >> 14) * 128, 0),
                              openvdb::Coord(planeBox.max().y(), (x1 >> 14) * 128 + 127, 127));
}

/// True when @a g is a folded plane field.
inline bool isFolded(const openvdb::GridBase& g)
{
    const auto m = g.getMetadata<openvdb::Int32Metadata>(kFoldMeta);
    return m && m->value() == kFoldVersion;
}
/// Marks a fresh (empty) grid as folded.
inline void markFolded(openvdb::GridBase& g) { g.insertMeta(kFoldMeta, openvdb::Int32Metadata(kFoldVersion)); }

/// A grid read from a checkpoint written with the first fold (kFoldMeta a bool true, plane voxel
/// (x, y) at Coord(y, x >> 3, x & 7)): its leaves moved to this fold's origins (their buffers
/// and masks are the same), and marked with kFoldVersion. Other grids are left as they are.
void upgradeLegacyFold(openvdb::GridBase& g);

/// True when @a d's plane fields are folded when created: a flat lattice domain on layer z = 0
/// (planes), unless FROSTVDB_NO_PLANE_FOLD=1 (read at every call: tests compare both layouts
/// in one process).
inline bool foldsPlaneFields(const Domain& d)
{
    if (!d || !d.flat() || d.discretisation() != "lattice") return false;
    if (d.bbox().min().z() != 0 || d.bbox().max().z() != 0) return false;
    const char* off = std::getenv("FROSTVDB_NO_PLANE_FOLD");
    return !(off && *off && std::string(off) != "0");
}

/// Sets bit @a n of a leaf's value mask atomically: with the fold, eight plane leaves share one
/// folded leaf and each of its 64-bit mask words (one row of 64 x), so threads writing
/// neighbouring plane leaves would race on a plain read-modify-write.
template <typename LeafT>
inline void setOnAtomic(LeafT& leaf, openvdb::Index n)
{
    auto& word = leaf.getValueMask().template getWord<uint64_t>(n >> 6);
    __atomic_fetch_or(&word, uint64_t(1) << (n & 63), __ATOMIC_RELAXED);
}
template <typename LeafT>
inline bool isOnAtomic(const LeafT& leaf, openvdb::Index n)
{
    const auto& word = leaf.getValueMask().template getWord<uint64_t>(n >> 6);
    return (__atomic_load_n(&word, __ATOMIC_RELAXED) >> (n & 63)) & 1u;
}

/// Cell access to a field by plane coordinates, folded or not (one flag test per call).
template <typename TreeT>
class PlaneCells {
public:
    using ValueType = typename TreeT::ValueType;
    template <typename GridT>
    explicit PlaneCells(GridT& grid) : mAcc(grid.tree()), mFold(isFolded(grid)) {}
    openvdb::Coord at(const openvdb::Coord& c) const { return mFold ? fold(c) : c; }
    const ValueType& getValue(const openvdb::Coord& c) const { return mAcc.getValue(at(c)); }
    bool isValueOn(const openvdb::Coord& c) const { return mAcc.isValueOn(at(c)); }
    void setValue(const openvdb::Coord& c, const ValueType& v) { mAcc.setValue(at(c), v); }
    void setValueOn(const openvdb::Coord& c, const ValueType& v) { mAcc.setValueOn(at(c), v); }
    void setValueOff(const openvdb::Coord& c, const ValueType& v) { mAcc.setValueOff(at(c), v); }
    bool folded() const { return mFold; }
    openvdb::tree::ValueAccessor<TreeT>& accessor() { return mAcc; }

private:
    openvdb::tree::ValueAccessor<TreeT> mAcc;
    bool mFold;
};
using FloatCells = PlaneCells<openvdb::FloatTree>;
using Int32Cells = PlaneCells<openvdb::Int32Tree>;

/// The plane layout of a folded grid (voxel (x, y) at Coord(x, y, 0)): the same values, active
/// states and leaf buffers' inactive values, name, class, transform and metadata (without the
/// fold flag). A grid that is not folded is returned as a deep copy. Active tiles of the
/// folded grid are expanded to voxels.
template <typename GridT>
typename GridT::Ptr unfoldGrid(const GridT& folded);
/// The folded layout of a plane grid (the inverse; for tests and old checkpoints).
template <typename GridT>
typename GridT::Ptr foldGrid(const GridT& planeGrid);

/// The folded topology of a plane-layout mask @a planeRegion (active voxels only): what a
/// folded field matched to that region has (matchTopology on the result gives it).
openvdb::MaskGrid::Ptr foldTopology(const openvdb::MaskGrid& planeRegion);
/// ORs the layer-0 cells of every leaf of the plane-layout mask @a planeLeaves into their folded
/// leaves in @a folded (touched even when a leaf holds no cell, as foldTopology does).
void foldLeavesInto(openvdb::MaskTree& folded, const openvdb::MaskTree& planeLeaves);
/// Clears the chunks of the plane leaves at @a planeLeafOrigins in the folded mask @a folded and
/// removes the folded leaves left empty (core/RemoveLeaves.h), so the tree is node for node the
/// one foldTopology gives of the plane region without those leaves.
void clearFoldedChunks(openvdb::MaskTree& folded, const std::vector<openvdb::Coord>& planeLeafOrigins);
/// The cells of the plane leaf stored as chunk @a g of a folded leaf's value mask @a words
/// (8 words, one per row): byte dy, bit dx.
inline uint64_t chunkRows(const openvdb::util::NodeMask<3>& words, int g)
{
    uint64_t rows = 0;
    for (int dy = 0; dy < 8; ++dy)
        rows |= ((words.template getWord<uint64_t>(openvdb::Index(dy)) >> (g * 8)) & 0xffu) << (dy * 8);
    return rows;
}

/// A plane leaf of a folded region read as the kernels read a plane-layout mask leaf: its origin,
/// its plane-layout value mask words (word x, bit y << 3: layer 0) and offsets' coordinates.
struct PlaneLeafView {
    openvdb::Coord o;
    uint64_t rows = 0; ///< byte y, bit x

    const openvdb::Coord& origin() const { return o; }
    struct Mask {
        uint64_t rows;
        template <typename WordT>
        WordT getWord(openvdb::Index x) const
        {
            return WordT((rows >> x) & 0x0101010101010101ull);
        }
    };
    Mask getValueMask() const { return {rows}; }
    openvdb::Coord offsetToGlobalCoord(openvdb::Index n) const
    {
        return o + openvdb::Coord(int(n >> 6), int((n >> 3) & 7), int(n & 7));
    }
};

/// The plane leaves of a folded region (a chunk of a folded leaf with a cell), with a
/// LeafManager's interface (leafCount, leaf): what the kernels walk instead of a plane-layout
/// region mask, 24 bytes a leaf against a mask leaf's 100 and its nodes. Order::Folded lists them
/// folded leaf by folded leaf; Order::Plane in the plane-layout tree's leaf order (made through a
/// transient plane-layout mask: the second-order scheme numbers its rows in that order).
class PlaneLeaves {
public:
    enum class Order { Folded, Plane };
    PlaneLeaves(const openvdb::MaskGrid& foldedRegion, Order order);
    size_t leafCount() const { return mLeaves.size(); }
    const PlaneLeafView& leaf(size_t i) const { return mLeaves[i]; }
    uint64_t bytes() const { return mLeaves.capacity() * sizeof(PlaneLeafView); }

private:
    std::vector<PlaneLeafView> mLeaves;
};

/// The plane-layout topology (active voxels only) of a folded grid: what the region rebuild
/// reads of a folded p or T (core/ActiveRegion.h). Active tiles are expanded.
/// A folded region is a MaskGrid (instantiated for FloatGrid and MaskGrid).
template <typename GridT>
openvdb::MaskGrid::Ptr unfoldTopology(const GridT& folded);

} // namespace plane
} // namespace frostvdb
