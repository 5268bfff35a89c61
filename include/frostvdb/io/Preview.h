#pragma once
/// @file Preview.h
/// @brief PNG previews a person can judge: a shaded top view for flat (one voxel thick) grids and
/// a ray-marched image (tools::VolumeRender) for volumes.
#include <openvdb/openvdb.h>

#include <functional>
#include <string>

namespace frostvdb {

struct PreviewOptions {
    int width = 512;      ///< image width in pixels (height follows the aspect ratio)
    float valueMax = 0.f; ///< colour scale maximum; 0 -> from the data
    bool shade = true;    ///< hill-shade flat grids so structure reads at a glance
};

/// Writes a preview of a scalar grid (FloatGrid) to @a pngPath. A grid whose active voxels span a
/// single z layer is drawn as a shaded top view in world space (hexagonal lattices are resampled);
/// anything thicker is ray-marched with a light from above. Throws on non-scalar grids.
void writePreview(const openvdb::GridBase& grid, const std::string& pngPath,
                  const PreviewOptions& options = {});

/// A flat (one layer) scalar field that is not held as a plane-layout FloatGrid (a folded plane
/// field, core/FoldedReader.h), for writeFlatPreview: what writePreview's top view reads of a grid.
struct FlatPreviewSource {
    openvdb::CoordBBox bbox;                        ///< the active voxels' index box (empty: none)
    float valueMax = 0.f;                           ///< the largest active value
    openvdb::math::Transform::ConstPtr transform;   ///< index to world
    /// A sampler per thread: the field's BoxSampler value at an index-space point.
    std::function<std::function<float(const openvdb::Vec3d&)>()> makeSampler;
};

/// writePreview's shaded top view of @a source: the same PNG as writePreview of the field's
/// plane-layout grid, without that grid.
void writeFlatPreview(const FlatPreviewSource& source, const std::string& pngPath, const PreviewOptions& options = {});

} // namespace frostvdb
