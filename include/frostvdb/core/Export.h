#pragma once
/// @file Export.h
/// @brief What a frame looks like to DCC tools. Grids of a hexagonal-lattice domain live on a
/// sheared transform (axial coordinates); most tools expect axis-aligned voxels, so exports
/// resample them to a square grid: voxel size = the lattice spacing h in world units (z keeps
/// its own), the same world placement (index 0 is world 0 on both), trilinear interpolation
/// (tools::BoxSampler, which keeps fog volumes within [0,1]), level sets rebuilt by
/// tools::resampleToMatch. Names, grid class and metadata are kept. `--keep-lattice` /
/// output.keep_lattice writes the sheared grids as they are.
///
/// The displacement map (the paper's accumulated dp/dt, grid `growth`) is also written as a
/// 16-bit greyscale PNG on the same square raster, row 0 at the top (+y), for flat domains.
#include <frostvdb/core/Domain.h>

#include <openvdb/openvdb.h>

#include <functional>
#include <string>
#include <vector>

namespace frostvdb {

/// The square export raster of a flat domain: cells (a, b) at world (a h, b h), a in [a0, a1],
/// b in [b0, b1], covering the centres of every domain cell (a hexagonal domain's rhombus sits in
/// it with background corners).
struct SquareRaster {
    int a0 = 0, a1 = -1, b0 = 0, b1 = -1;
    double h = 1.0;
    int width() const { return a1 - a0 + 1; }
    int height() const { return b1 - b0 + 1; }
};
SquareRaster squareRaster(const Domain& domain);

/// The square transform exports use for @a domain: uniform scale h (z: the domain's z spacing).
openvdb::math::Transform::Ptr squareTransform(const Domain& domain);

/// Resamples one grid onto @a target (float, double and Vec3s grids trilinearly, integer grids by
/// nearest value); other types are returned unchanged. Keeps name, class and all metadata.
openvdb::GridBase::Ptr resampleGrid(const openvdb::GridBase& grid, const openvdb::math::Transform& target);

/// The grids as written: on a hexagonal domain (unless @a keepLattice) every grid on the domain's
/// transform is resampled to squareTransform(); grids on other transforms (e.g. effects that
/// write their own resampled outputs) and every grid of a square domain are passed through.
/// Each grid gains the metadata `frostvdb_lattice` saying which it is.
openvdb::GridPtrVec exportGrids(const openvdb::GridPtrVec& grids, const Domain& domain, bool keepLattice);
/// One grid as exportGrids writes it (a caller that drops each source after its export keeps
/// only one resampled copy more than the sources at a time).
openvdb::GridBase::Ptr exportGrid(const openvdb::GridBase::Ptr& grid, const Domain& domain, bool keepLattice);

/// The frame export in progress on this thread (Simulation::writeFrame holds one while it writes
/// a frame's VDB): a grid a frame makes again for the writer (Frame::addCopy, addDeferred) may
/// then be made already exported, which exportGrid passes through (it is on the square
/// transform). So a folded plane field is resampled in place (exportFolded) instead of through
/// its plane-layout copy.
class ExportScope {
public:
    ExportScope(const Domain& domain, bool keepLattice);
    ~ExportScope();
    ExportScope(const ExportScope&) = delete;
    ExportScope& operator=(const ExportScope&) = delete;
    const Domain& domain() const { return mDomain; }
    bool keepLattice() const { return mKeepLattice; }
    /// The innermost scope on this thread, or null.
    static const ExportScope* current();

private:
    const Domain& mDomain;
    bool mKeepLattice;
    const ExportScope* mPrevious;
};

/// True when a frame's copy of the folded plane field @a folded, made now, is best made exported
/// (exportFolded, in place): inside an ExportScope of its domain (same transform), hexagonal,
/// lattice not kept. Elsewhere the frame holds the plane-layout copy.
bool exportsFoldedInPlace(const openvdb::FloatGrid& folded);

/// exportGrid(plane::unfoldGrid(@a folded) dressed by @a dress (name, class)) bit for bit, for a
/// folded plane field (core/PlaneFold.h): on a hexagonal domain the resampling reads the folded
/// leaves in place, so the plane-layout copy (about 36 bytes per voxel) is never made; otherwise
/// (a square domain, keepLattice) the copy is the export and is made as before.
openvdb::GridBase::Ptr exportFolded(const openvdb::FloatGrid& folded, const Domain& domain, bool keepLattice,
                                    const std::function<void(openvdb::FloatGrid&)>& dress);

/// exportFolded for the VDB writer: where the folded leaves are resampled in place, the grid is a
/// StreamedFloatGrid (io/StreamedGrid.h), its topology made now and its values sampled from
/// @a folded (which it keeps) while the writer writes it, so the exported grid's values (about
/// 32 bytes per voxel of a plane on the square raster) are never held whole. The file holds
/// exportFolded's bits; nothing but the writer may read the grid's values. Elsewhere it is
/// exportFolded's grid.
openvdb::GridBase::Ptr exportFoldedStreamed(const openvdb::FloatGrid::ConstPtr& folded, const Domain& domain,
                                            bool keepLattice, const std::function<void(openvdb::FloatGrid&)>& dress);

/// Writes @a growth (values in [0,1]) as a 16-bit greyscale PNG on squareRaster(domain), sampled
/// in world space (so it works for sheared and resampled grids alike). Flat domains only.
void writeDisplacementPng(const openvdb::FloatGrid& growth, const Domain& domain, const std::string& path);

/// The displacement map of a large domain, cost following the ice: a raster up to @a tileSize
/// pixels on each side is one image `<stem>.png`; a larger one is cut into UDIM tiles of
/// tileSize^2 pixels, `<stem>.<udim>.png`, udim = 1001 + u + 10 v (u: tile column from the
/// raster's left edge, v: tile row from its bottom; pixel = the lattice spacing h, raster origin
/// at the bottom-left corner of tile 1001, padding beyond the raster is background), and only
/// tiles that hold active growth are written. Only pixels within reach of an active voxel are
/// sampled. At most 10 tiles across (the UDIM convention). Returns the files written.
/// The UDIM convention's tiles per row (udim = 1001 + u + 10 v), and the tiles of @a tileSize
/// pixels a raster @a width pixels wide takes across.
constexpr int kUdimTilesAcross = 10;
inline int udimTilesAcross(int width, int tileSize) { return (width + tileSize - 1) / tileSize; }
std::vector<std::string> writeDisplacementMaps(const openvdb::FloatGrid& growth, const Domain& domain,
                                               const std::string& stem, int tileSize);

} // namespace frostvdb
