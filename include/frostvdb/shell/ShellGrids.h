#pragma once
/// @file ShellGrids.h
/// @brief Moving shell fields between band arrays and VDB grids, and the shell's frame outputs:
/// `ice` (fog) and `ice_sdf` (level set) of a frost layer grown outward along the normal, with a
/// thickness from the accumulated growth, plus `ice_temperature`, `growth` and `freeze_time` on
/// the band.
#include <frostvdb/shell/ShellBand.h>

#include <openvdb/openvdb.h>

#include <string>
#include <vector>

namespace frostvdb::shell {

/// A grid holding @a values (band order) where they differ from @a background (its background):
/// the band's topology minus the voxels at the background.
openvdb::FloatGrid::Ptr toGrid(const ShellBand& band, const std::vector<float>& values, float background,
                               const std::string& name);
/// The values of @a grid at the band's voxels (its background where it has none). With
/// @a materialise, the band's leaves are first built wherever @a grid differs from its background
/// (seeds stamped into a lazily built band).
void fromGrid(const ShellBand& band, const openvdb::FloatGrid& grid, std::vector<float>& values,
              bool materialise = false);

/// The frost layer as a fog volume: at band voxel x with normal offset s (voxels, along the
/// outward normal at cp) and no lateral offset (x projects inside the surface, so nothing
/// beyond an open mesh's border), ice = clamp(p) * ramp(s + 1/2) * ramp(th - s + 1/2),
/// th = frostThickness * min(1, max(growth, p)) (seeds start as ice with no growth), ramp(v) = clamp(v, 0, 1). Background 0, inactive
/// where 0.
openvdb::FloatGrid::Ptr frostFog(const ShellBand& band, const std::vector<float>& p, const std::vector<float>& growth);
/// The fog's 0.5 iso-surface (OpenVDB volume-to-mesh) as polygons in world space.
void frostMesh(const openvdb::FloatGrid& fog, std::vector<openvdb::Vec3s>& points,
               std::vector<openvdb::Vec3I>& triangles, std::vector<openvdb::Vec4I>& quads);
/// The fog's 0.5 iso-surface as a narrow-band level set (3 voxels each side).
openvdb::FloatGrid::Ptr frostLevelSet(const openvdb::FloatGrid& fog);
/// Surface nodes: the frost layer's level set straight from the nodes (the union of one prism
/// per icy node along its normal, 3 voxels each side), without meshing or sweeping.
openvdb::FloatGrid::Ptr frostLevelSetOnNodes(const ShellBand& band, const std::vector<float>& p,
                                             const std::vector<float>& growth);

} // namespace frostvdb::shell
