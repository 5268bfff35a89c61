#pragma once
/// @file TriangleBvh.h
/// @brief The one triangle index of the mesh users (the shell band, dla3d's constraint surface).
#include <openvdb/openvdb.h>

#include <cstdint>
#include <vector>

namespace frostvdb::geometry {

/// A bounding-volume hierarchy over a mesh's triangles: the triangles whose bounding boxes
/// overlap a box, and the closest point on the mesh. It keeps pointers to @a points and
/// @a triangles, which must outlive it and not move. Used by the shell band (index space) and
/// dla3d's mesh constraint (world metres).
class TriangleBvh {
public:
    TriangleBvh() = default;
    TriangleBvh(const std::vector<openvdb::Vec3d>& points, const std::vector<openvdb::Vec3I>& triangles);
    /// Triangles whose bounding box overlaps @a box, sorted by index.
    void query(const openvdb::BBoxd& box, std::vector<uint32_t>& out) const;
    /// The closest point on the mesh to @a p; @a tri gets its triangle (lowest index on ties).
    openvdb::Vec3d closestPoint(const openvdb::Vec3d& p, uint32_t* tri = nullptr) const;
    /// The same among the points within sqrt(@a maxDistSqr) of @a p: false when there is none.
    bool closestPointWithin(const openvdb::Vec3d& p, double maxDistSqr, openvdb::Vec3d& out, uint32_t& tri,
                            double& distSqr) const;
    /// closestPointWithin searching only @a candidates (triangle indices): the same answer when
    /// they hold every triangle within reach of @a p (a query() around it), found without the
    /// tree's descent (the shell band asks this for the 512 voxels of a leaf, a handful of
    /// triangles each).
    bool closestPointAmong(const std::vector<uint32_t>& candidates, const openvdb::Vec3d& p, double maxDistSqr,
                           openvdb::Vec3d& out, uint32_t& tri, double& distSqr) const;
    size_t memoryBytes() const;
    const openvdb::BBoxd& box(uint32_t t) const { return mBoxes[t]; }

private:
    struct Node {
        openvdb::BBoxd box;
        int32_t left = -1, right = -1; ///< children, -1 in a leaf
        uint32_t first = 0, count = 0; ///< range of mOrder in a leaf
    };
    int32_t buildNode(std::vector<uint32_t>& order, uint32_t first, uint32_t count, std::vector<openvdb::BBoxd>& boxes,
                      std::vector<openvdb::Vec3d>& centres);
    const std::vector<openvdb::Vec3d>* mPoints = nullptr;
    const std::vector<openvdb::Vec3I>* mTriangles = nullptr;
    std::vector<Node> mNodes;
    std::vector<uint32_t> mOrder;
    std::vector<openvdb::BBoxd> mBoxes; ///< per triangle
};

} // namespace frostvdb::geometry
