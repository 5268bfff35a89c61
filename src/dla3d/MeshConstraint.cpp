/// @file MeshConstraint.cpp
#include <frostvdb/dla3d/MeshConstraint.h>

#include <frostvdb/core/Random.h>

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/MeshToVolume.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace frostvdb::dla3d {

using openvdb::Vec3d;

bool segmentHitsTriangle(const Vec3d& a, const Vec3d& b, const Vec3d& t0, const Vec3d& t1, const Vec3d& t2)
{
    // Moller-Trumbore on the segment a + s (b - a), s in [0, 1]; touching counts as a hit
    const Vec3d d = b - a, e1 = t1 - t0, e2 = t2 - t0;
    const Vec3d h = d.cross(e2);
    const double det = e1.dot(h);
    const double scale = e1.length() * e2.length() * d.length();
    if (std::abs(det) <= 1e-14 * scale) return false; // parallel: the sphere test catches grazing
    const double inv = 1.0 / det;
    const Vec3d s = a - t0;
    const double u = s.dot(h) * inv;
    if (u < 0.0 || u > 1.0) return false;
    const Vec3d q = s.cross(e1);
    const double v = d.dot(q) * inv;
    if (v < 0.0 || u + v > 1.0) return false;
    const double t = e2.dot(q) * inv;
    return t >= 0.0 && t <= 1.0;
}

Vec3d closestPointOnTriangle(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c)
{
    // Ericson, Real-Time Collision Detection 5.1.5
    const Vec3d ab = b - a, ac = c - a, ap = p - a;
    const double d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0 && d2 <= 0) return a;
    const Vec3d bp = p - b;
    const double d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0 && d4 <= d3) return b;
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
    const Vec3d cp = p - c;
    const double d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0 && d5 <= d6) return c;
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    const double denom = 1.0 / (va + vb + vc);
    return a + ab * (vb * denom) + ac * (vc * denom);
}

MeshConstraint::MeshConstraint(TriangleMesh mesh, double reach, double voxelSize)
    : mMesh(std::move(mesh)), mReach(reach)
{
    auto xform = openvdb::math::Transform::createLinearTransform(voxelSize);
    const float bandVoxels = float(std::ceil(2.0 * reach / voxelSize) + 3.0);
    // world-space points: meshToVolume applies the transform itself
    mUdf = openvdb::tools::meshToUnsignedDistanceField<openvdb::FloatGrid>(*xform, mMesh.points, mMesh.triangles,
                                                                          std::vector<openvdb::Vec4I>(), bandVoxels);
    mBand = mUdf->background();
    // triangle buckets: cell about the reach, so a test visits a handful of cells
    mCell = std::max(reach, voxelSize);
    for (uint32_t t = 0; t < mMesh.triangles.size(); ++t) {
        openvdb::BBoxd b;
        for (int v = 0; v < 3; ++v) b.expand(Vec3d(mMesh.points[mMesh.triangles[t][v]]));
        const auto lo = b.min() / mCell, hi = b.max() / mCell;
        for (int64_t x = int64_t(std::floor(lo.x())); x <= int64_t(std::floor(hi.x())); ++x)
            for (int64_t y = int64_t(std::floor(lo.y())); y <= int64_t(std::floor(hi.y())); ++y)
                for (int64_t z = int64_t(std::floor(lo.z())); z <= int64_t(std::floor(hi.z())); ++z)
                    mCells[cellKey(x, y, z)].push_back(t);
    }
}

uint64_t MeshConstraint::cellKey(int64_t x, int64_t y, int64_t z) const
{
    return coordKey(int32_t(x), int32_t(y), int32_t(z));
}

std::vector<uint32_t> MeshConstraint::candidates(const Vec3d& lo, const Vec3d& hi) const
{
    std::vector<uint32_t> out;
    for (int64_t x = int64_t(std::floor(lo.x() / mCell)); x <= int64_t(std::floor(hi.x() / mCell)); ++x)
        for (int64_t y = int64_t(std::floor(lo.y() / mCell)); y <= int64_t(std::floor(hi.y() / mCell)); ++y)
            for (int64_t z = int64_t(std::floor(lo.z() / mCell)); z <= int64_t(std::floor(hi.z() / mCell)); ++z) {
                auto it = mCells.find(cellKey(x, y, z));
                if (it != mCells.end()) out.insert(out.end(), it->second.begin(), it->second.end());
            }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
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
