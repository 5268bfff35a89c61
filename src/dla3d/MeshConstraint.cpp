/// @file MeshConstraint.cpp
#include <frostvdb/dla3d/MeshConstraint.h>


#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/MeshToVolume.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace frostvdb::dla3d {

using openvdb::Vec3d;

MeshConstraint::MeshConstraint(TriangleMesh mesh, double reach, double voxelSize)
    : mMesh(std::move(mesh)), mReach(reach)
{
    auto xform = openvdb::math::Transform::createLinearTransform(voxelSize);
    const float bandVoxels = float(std::ceil(2.0 * reach / voxelSize) + 3.0);
    // world-space points: meshToVolume applies the transform itself
    mUdf = openvdb::tools::meshToUnsignedDistanceField<openvdb::FloatGrid>(*xform, mMesh.points, mMesh.triangles,
                                                                          std::vector<openvdb::Vec4I>(), bandVoxels);
    mBand = mUdf->background();
    mPoints.assign(mMesh.points.begin(), mMesh.points.end());
    mBvh = geometry::TriangleBvh(mPoints, mMesh.triangles);
}

std::vector<uint32_t> MeshConstraint::candidates(const Vec3d& lo, const Vec3d& hi) const
{
    std::vector<uint32_t> out;
    mBvh.query(openvdb::BBoxd(lo, hi), out);
    return out;
}

bool MeshConstraint::segmentCrosses(const Vec3d& a, const Vec3d& b) const
{
    Vec3d lo = a, hi = a;
    lo = openvdb::math::minComponent(lo, b);
    hi = openvdb::math::maxComponent(hi, b);
    for (uint32_t t : candidates(lo, hi)) {
        const auto& f = mMesh.triangles[t];
        if (segmentHitsTriangle(a, b, Vec3d(mMesh.points[f[0]]), Vec3d(mMesh.points[f[1]]), Vec3d(mMesh.points[f[2]])))
            return true;
    }
    return false;
}

double MeshConstraint::distance(const Vec3d& p, double maxDistance) const
{
    double best = maxDistance;
    const Vec3d r(maxDistance);
    for (uint32_t t : candidates(p - r, p + r)) {
        const auto& f = mMesh.triangles[t];
        const Vec3d c = closestPointOnTriangle(p, Vec3d(mMesh.points[f[0]]), Vec3d(mMesh.points[f[1]]),
                                               Vec3d(mMesh.points[f[2]]));
        best = std::min(best, (c - p).length());
    }
    return best;
}

bool MeshConstraint::allows(const Vec3d& from, const Vec3d& to, double radius) const
{
    const double need = (to - from).length() + radius;
    // pre-test: the distance field (trilinear, error below one voxel diagonal) at the new particle
    const Vec3d ijk = mUdf->transform().worldToIndex(to);
    const double udf = openvdb::tools::BoxSampler::sample(mUdf->tree(), ijk);
    const double slack = std::sqrt(3.0) * mUdf->voxelSize()[0];
    if (udf - slack >= need || udf >= mBand - 1e-6) return true;
    mExact.fetch_add(1, std::memory_order_relaxed);
    if (segmentCrosses(from, to)) return false;
    return distance(to, radius) >= radius * (1.0 - 1e-9);
}

} // namespace frostvdb::dla3d
