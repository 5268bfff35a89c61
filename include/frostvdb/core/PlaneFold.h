#pragma once
/// @file PlaneFold.h
/// @brief Plane fields at their true density: the fold.
///
/// A plane field stored as Coord(x, y, 0) uses one z layer of every 8^3 leaf: 64 of 512 values,
/// about 36 bytes per voxel. Folded, plane voxel (x, y) of layer z = 0 is stored at
/// @code
///   Coord(y, x >> 3, x & 7)      // fold()
/// @endcode
/// so an 8^3 leaf is a dense tile of 8 rows (y) by 64 columns (x), rows of x contiguous in the
/// leaf's buffer (offset ((y & 7) << 6) | (x & 63)), every value used: about 4.5 bytes per voxel
/// (`frostvdb bench layout`, docs/performance.md). The grid stays an OpenVDB grid (leaf managers,
/// pruning, checkpoints and I/O unchanged); only coordinates differ.
///
/// A folded grid carries the metadata flag kFoldMeta; every reader and writer of a field that may
/// be folded asks isFolded(grid) once per step and maps plane coordinates with fold() (a
/// PlaneCells accessor does that per cell). So a field restored from an older checkpoint (not
/// folded) is still read right. Frames never hold folded grids: export unfolds (unfoldGrid), a
/// permutation of the values, so a frame's grids keep their world placement and their bits.
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

/// Grid metadata naming a folded plane field (bool true).
inline const char* const kFoldMeta = "frostvdb_plane_fold";

/// Stored coordinate of plane voxel @a c (c.z() must be 0).
inline openvdb::Coord fold(const openvdb::Coord& c)
{
    return openvdb::Coord(c.y(), c.x() >> 3, c.x() & 7);
}
/// Plane voxel of stored coordinate @a f (the inverse of fold()).
inline openvdb::Coord unfold(const openvdb::Coord& f)
{
    return openvdb::Coord(f.y() * 8 + f.z(), f.x(), 0);
}
/// Origin of the folded leaf holding the plane leaf at @a lo (x, y multiples of 8, z 0).
inline openvdb::Coord foldedLeafOrigin(const openvdb::Coord& lo)
{
    return openvdb::Coord(lo.y(), (lo.x() >> 3) & ~7, 0);
}
/// Offset in its folded leaf of the voxel at (dx, dy) in the plane leaf at @a lo.
inline openvdb::Index foldedOffset(const openvdb::Coord& lo, int dx, int dy)
{
    return openvdb::Index((dy << 6) | (lo.x() & 63) | dx);
}

/// The stored box holding the folded cells of the plane box @a planeBox (z 0): what an active
/// tile of a folded field is clipped to before its cells are unfolded.
inline openvdb::CoordBBox foldedBBox(const openvdb::CoordBBox& planeBox)
{
    return openvdb::CoordBBox(openvdb::Coord(planeBox.min().y(), planeBox.min().x() >> 3, 0),
                              openvdb::Coord(planeBox.max().y(), planeBox.max().x() >> 3, 7));
}

/// True when @a g is a folded plane field.
inline bool isFolded(const openvdb::GridBase& g)
{
    const auto m = g.getMetadata<openvdb::BoolMetadata>(kFoldMeta);
    return m && m->value();
}
/// Marks a fresh (empty) grid as folded.
inline void markFolded(openvdb::GridBase& g) { g.insertMeta(kFoldMeta, openvdb::BoolMetadata(true)); }

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
/// @a folded, foldTopology of a plane region that has since lost the plane leaves at @a removed
/// and gained those at @a added (core/RegionOfTopology.h, RegionEdit), edited to be
/// foldTopology(@a planeRegion) node for node: only the changed leaves' folded leaves are touched.
void refoldTopology(openvdb::MaskGrid& folded, const openvdb::MaskGrid& planeRegion,
                    const std::vector<openvdb::Coord>& removed, const std::vector<openvdb::Coord>& added);
/// The plane-layout topology (active voxels only) of a folded grid: what the region rebuild
/// reads of a folded p or T (core/ActiveRegion.h). Active tiles are expanded.
template <typename GridT>
openvdb::MaskGrid::Ptr unfoldTopology(const GridT& folded);

} // namespace plane
} // namespace frostvdb
