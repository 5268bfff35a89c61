#pragma once
/// @file Mesh.h
/// @brief Triangle meshes read through Assimp (OBJ, STL, PLY, and whatever else Assimp reads),
/// placed in the world by scale, rotation and translation. Shared by every effect that takes a
/// mesh (the [dla3d] constraints and launch surfaces; later the shell domain).
///
/// Placement order: scale, then rotate about x, y, z (degrees, in that order), then translate.
/// All meshes of a file are merged into one triangle list; polygons are triangulated; duplicate
/// vertices are joined so neighbouring triangles share indices.
#include <openvdb/openvdb.h>

#include <string>
#include <vector>

namespace frostvdb {

struct MeshPlacement {
    openvdb::Vec3d scale{1.0, 1.0, 1.0};
    openvdb::Vec3d rotateDegrees{0.0, 0.0, 0.0}; ///< about x, then y, then z
    openvdb::Vec3d translate{0.0, 0.0, 0.0};
    /// The placement as a matrix acting on row vectors (OpenVDB's convention: p' = p * M).
    openvdb::Mat4d matrix() const;
};

struct TriangleMesh {
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec3s> colours; ///< per vertex, empty when the file has none
    std::vector<openvdb::Vec2s> uvs;     ///< per vertex, empty when the file has none
    std::string source;                  ///< file it was read from

    bool empty() const { return triangles.empty(); }
    /// World bounding box of the points.
    openvdb::BBoxd bbox() const;
    /// Area of triangle @a t and its unit normal (right-handed winding).
    double area(size_t t) const;
    openvdb::Vec3d normal(size_t t) const;
    double totalArea() const;
    /// Applies a placement to the points.
    void transform(const MeshPlacement& placement);
    /// Per-vertex unit normals: the area-weighted mean of the adjacent triangles' normals (smooth
    /// shading normals; the shell's frame interpolates them across a triangle).
    std::vector<openvdb::Vec3d> vertexNormals() const;
    /// Edges used by exactly one triangle (an open mesh's border, e.g. a glass's rim), as vertex
    /// index pairs in a fixed order (sorted).
    std::vector<std::pair<uint32_t, uint32_t>> boundaryEdges() const;
    /// For each vertex, the triangles that use it (sorted).
    std::vector<std::vector<uint32_t>> vertexTriangles() const;
    /// Why this mesh, placed by @a placement, has collapsed ("" when it has not): no triangles, a
    /// zero scale factor, non-finite or zero-area geometry, or single-precision vertices too coarse
    /// for its size where it was moved to. With @a voxelSize > 0 also a mesh smaller than one voxel
    /// or placed beyond exact single-precision voxel positions (2^24 voxels out).
    std::string collapseProblem(const MeshPlacement& placement, double voxelSize = 0.0) const;
};

/// Refuses (std::runtime_error naming the file) a PLY whose header declares more elements than
/// the file's size can hold; other formats pass.
void checkPlyHeader(const std::string& path);

/// A closed icosphere of @a radius about the origin, @a subdivisions times subdivided (20 * 4^s
/// triangles), outward winding. The shell domain's default mesh and the tests' sphere.
TriangleMesh makeIcosphere(double radius, int subdivisions);
/// An open square plate [-size/2, size/2]^2 in the z = 0 plane of n x n cells (2 n^2 triangles),
/// normal +z.
TriangleMesh makePlate(double size, int n);

/// Reads a triangle mesh and applies @a placement. Throws std::runtime_error with one line
/// naming the file when it is missing, not a regular file, unreadable, has no triangles or
/// collapses where it is placed (TriangleMesh::collapseProblem without a voxel size). The file is
/// recorded in the current InputFileScope (io/InputFiles.h).
TriangleMesh loadMesh(const std::string& path, const MeshPlacement& placement = {});

/// Writes a triangle (and optional quad) mesh as Wavefront OBJ (used for optional geometry output).
void writeObj(const std::string& path, const std::vector<openvdb::Vec3s>& points,
              const std::vector<openvdb::Vec3I>& triangles, const std::vector<openvdb::Vec4I>& quads = {});
/// Same as binary little-endian PLY.
void writePly(const std::string& path, const std::vector<openvdb::Vec3s>& points,
              const std::vector<openvdb::Vec3I>& triangles, const std::vector<openvdb::Vec4I>& quads = {});

} // namespace frostvdb
