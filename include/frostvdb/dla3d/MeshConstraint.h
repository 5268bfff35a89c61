#pragma once
/// @file MeshConstraint.h
/// @brief Bourke's constraint surface: a branch from a particle to a new one may not cross the
/// mesh, and the new particle's sphere may not reach into it. Tested only when a walker is about
/// to attach (never during the walk): first against a VDB unsigned distance field (one trilinear
/// look-up rules out most attachments far from the surface), then against the exact triangles
/// the bounding-volume hierarchy finds (geometry/TriangleBvh.h, the shell band's index too).
#include <frostvdb/geometry/Triangle.h>
#include <frostvdb/geometry/TriangleBvh.h>
#include <frostvdb/io/Mesh.h>

#include <openvdb/openvdb.h>

#include <atomic>
#include <vector>

namespace frostvdb::dla3d {

class MeshConstraint {
public:
    /// @param reach the longest branch plus particle radius that will be tested (sets the band)
    /// @param voxelSize voxel size of the distance field (metres)
    MeshConstraint(TriangleMesh mesh, double reach, double voxelSize);

    /// True when the segment @a from -> @a to crosses no triangle and no triangle comes closer
    /// than @a radius to @a to.
    bool allows(const openvdb::Vec3d& from, const openvdb::Vec3d& to, double radius) const;

    /// Exact tests (also used by the tests to check results independently of the pre-test).
    bool segmentCrosses(const openvdb::Vec3d& a, const openvdb::Vec3d& b) const;
    /// Exact distance to the nearest triangle within @a maxDistance (returns maxDistance if none).
    double distance(const openvdb::Vec3d& p, double maxDistance) const;

    const TriangleMesh& mesh() const { return mMesh; }
    openvdb::FloatGrid::ConstPtr distanceField() const { return mUdf; }

    uint64_t exactTests() const { return mExact.load(); }

private:
    /// Triangles whose bounding boxes overlap the box (@a lo, @a hi), ascending.
    std::vector<uint32_t> candidates(const openvdb::Vec3d& lo, const openvdb::Vec3d& hi) const;

    TriangleMesh mMesh;
    double mReach;
    openvdb::FloatGrid::Ptr mUdf;
    double mBand = 0; ///< the UDF's background: distances beyond it read as this
    std::vector<openvdb::Vec3d> mPoints; ///< the mesh's points in double, for the index
    geometry::TriangleBvh mBvh;          ///< the shell band's triangle index (geometry/TriangleBvh.h)
    mutable std::atomic<uint64_t> mExact{0}; ///< statistics only
};

/// Exact geometry helpers (geometry/Triangle.h), under their former names.
using geometry::closestPointOnTriangle;
using geometry::segmentHitsTriangle;

} // namespace frostvdb::dla3d
