#pragma once
/// @file ShellTexture.h
/// @brief Seeds and melt maps from a UV texture on a shell (issue 11 item 6): `[domain]
/// seed_texture` / `melt_texture`, PNG files read as luminance (io/Png), looked up at each band
/// voxel's closest point through the barycentric UVs of its triangle (the mesh's first UV set,
/// through Assimp). Same semantics as `vertex_colours`: seed = ice where the luminance exceeds
/// 1/2, melt = T_e scale (0 keeps a patch clear; with [dla], the sticking probability). On the lazy
/// band the seeds' triangles are built at the start (seedTriangles) and melt values are computed for
/// each leaf when it is built (meltSource), so the active region keeps working with both.
#include <frostvdb/core/Domain.h>
#include <frostvdb/io/Mesh.h>
#include <frostvdb/shell/ShellBand.h>

#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace frostvdb::shell {

/// A greyscale image in [0, 1], row 0 at the top, sampled bilinearly with wrap-around at (u, v)
/// (v = 0 at the bottom, as UVs are).
struct Texture {
    int width = 0, height = 0;
    std::vector<float> values;
    double sample(double u, double v) const;
};

/// The domain's texture maps with the mesh's UVs, sampled per band voxel on demand: the band is
/// built lazily, so a value is computed for a voxel when it is asked for (never stored per voxel
/// at domain creation, which would miss the leaves built later).
struct SurfaceTextures {
    std::shared_ptr<const Texture> seed, melt; ///< null when not given
    std::vector<openvdb::Vec3d> points;        ///< the mesh's vertices, world metres
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec2s> uvs;           ///< per vertex

    /// Keeps @a mesh's geometry and UVs; throws std::runtime_error when it has no UVs.
    explicit SurfaceTextures(const TriangleMesh& mesh);
    /// @a texture at band voxel @a i's closest point (barycentric UVs of its triangle), in [0, 1].
    float sample(const Texture& texture, const ShellBand& band, size_t i) const;
    /// seed_texture at voxel @a i (0 without one); melt_texture (1 without one).
    float seedAt(const ShellBand& band, size_t i) const { return seed ? sample(*seed, band, i) : 0.f; }
    float meltAt(const ShellBand& band, size_t i) const { return melt ? sample(*melt, band, i) : 1.f; }
    /// Triangles where seed_texture may exceed 1/2 somewhere (conservative: the largest texel
    /// of the bilinear footprint of the triangle's UV box): every seeded voxel's closest point
    /// lies on one of them, so building their leaves builds every seed.
    std::vector<uint32_t> seedTriangles() const;
};

/// Reads a PNG as luminance; throws std::runtime_error naming the file.
Texture loadTexture(const std::string& path);

/// The shell's melt value of band voxel i: the melt field (@a meltField, may be null) at its
/// coordinate times the vertex-colour melt map (vertex_colours = "melt") times melt_texture;
/// null when none applies. Valid for any voxel built later too (the band's leaves are lazy).
/// Holds @a meltField (and an accessor), not the band.
std::function<float(const ShellBand&, size_t)> meltSource(openvdb::FloatGrid::ConstPtr meltField,
                                                          const ShellBand& band, const SurfaceTextures* textures);

/// meltSource over every voxel built so far; empty when none applies.
std::vector<float> meltMap(const ShellBand& band, const openvdb::FloatGrid* meltField, const SurfaceTextures* textures);

/// The shell domain's texture maps, or null (no shell, or no texture).
const SurfaceTextures* texturesOf(const Domain& domain);

} // namespace frostvdb::shell
