#pragma once
/// @file MeshConstraint.h
/// @brief Bourke's constraint surface: a branch from a particle to a new one may not cross the
/// mesh, and the new particle's sphere may not reach into it. Tested only when a walker is about
/// to attach (never during the walk): first against a VDB unsigned distance field (one trilinear
/// look-up rules out most attachments far from the surface), then against the exact triangles
/// bucketed in a hashed grid.
#include <frostvdb/geometry/Triangle.h>
#include <frostvdb/io/Mesh.h>

#include <openvdb/openvdb.h>

#include <atomic>
#include <unordered_map>
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
    std::vector<uint32_t> candidates(const openvdb::Vec3d& lo, const openvdb::Vec3d& hi) const;
    uint64_t cellKey(int64_t x, int64_t y, int64_t z) const;

    TriangleMesh mMesh;
    double mReach;
    openvdb::FloatGrid::Ptr mUdf;
    double mBand = 0; ///< the UDF's background: distances beyond it read as this
    double mCell;
    std::unordered_map<uint64_t, std::vector<uint32_t>> mCells;
    mutable std::atomic<uint64_t> mExact{0}; ///< statistics only
};

/// Exact geometry helpers (geometry/Triangle.h), under their former names.
using geometry::closestPointOnTriangle;
using geometry::segmentHitsTriangle;

} // namespace frostvdb::dla3d
