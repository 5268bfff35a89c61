#pragma once
/// @file ShellTexture.h
/// @brief Seeds and melt maps from a UV texture on a shell (issue 11 item 6): `[domain]
/// seed_texture` / `melt_texture`, PNG files read as luminance (io/Png), looked up at each band
/// voxel's closest point through the barycentric UVs of its triangle (the mesh's first UV set,
/// through Assimp). Same semantics as `vertex_colours`: seed = ice where the luminance exceeds
/// 1/2, melt = T_e scale (0 keeps a patch clear; with [dla], the sticking probability).
#include <frostvdb/core/Domain.h>
#include <frostvdb/io/Mesh.h>
#include <frostvdb/shell/ShellBand.h>

#include <string>
#include <vector>

namespace frostvdb::shell {

/// Per band voxel, empty when not given.
struct SurfaceTextures {
    std::vector<float> seed, melt;
};

/// A greyscale image in [0, 1], row 0 at the top, sampled bilinearly with wrap-around at (u, v)
/// (v = 0 at the bottom, as UVs are).
struct Texture {
    int width = 0, height = 0;
    std::vector<float> values;
    double sample(double u, double v) const;
};

/// Reads a PNG as luminance; throws std::runtime_error naming the file.
Texture loadTexture(const std::string& path);

/// The texture at each band voxel's closest point through @a mesh's per-vertex UVs (the mesh the
/// band was built from, in world metres). Throws when the mesh has no UVs.
std::vector<float> sampleTexture(const ShellBand& band, const TriangleMesh& mesh, const Texture& texture);

/// The shell's melt map per band voxel: the melt field (@a meltField, may be null) times the
/// vertex-colour melt map (vertex_colours = "melt") times melt_texture; empty when none applies.
std::vector<float> meltMap(const ShellBand& band, const openvdb::FloatGrid* meltField, const SurfaceTextures* textures);

/// The shell domain's texture maps, or null (no shell, or no texture).
const SurfaceTextures* texturesOf(const Domain& domain);

} // namespace frostvdb::shell
