/// @file ShellBand.cpp
/// @brief Builds the shell's narrow band from a mesh (mesh-to-volume, exact closest points,
/// frames, neighbours, tricubic stencils) and does the closest-point extension.
#include <frostvdb/shell/ShellBand.h>

#include <frostvdb/dla3d/MeshConstraint.h> // closestPointOnTriangle

#include <openvdb/tools/MeshToVolume.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace frostvdb::shell {

using openvdb::Coord;
using openvdb::Vec3d;

namespace {

/// Barycentric coordinates of @a p (on or near the triangle's plane) in triangle (a, b, c).
Vec3d barycentric(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c)
{
    const Vec3d v0 = b - a, v1 = c - a, v2 = p - a;
    const double d00 = v0.dot(v0), d01 = v0.dot(v1), d11 = v1.dot(v1), d20 = v2.dot(v0), d21 = v2.dot(v1);
    const double den = d00 * d11 - d01 * d01;
    if (std::fabs(den) < 1e-300) return Vec3d(1.0 / 3.0);
    const double v = (d11 * d20 - d01 * d21) / den, w = (d00 * d21 - d01 * d20) / den;
    return Vec3d(1.0 - v - w, v, w);
}

double pointSegmentDistance(const Vec3d& p, const Vec3d& a, const Vec3d& b)
{
    const Vec3d ab = b - a;
    const double l2 = ab.lengthSqr();
    const double t = l2 > 0 ? std::clamp((p - a).dot(ab) / l2, 0.0, 1.0) : 0.0;
    return (p - (a + ab * t)).length();
}

/// The frame at a closest point: normal @a n; tangent = @a axis projected on the tangent plane
/// (the secondary axis where the first is within ~3 degrees of the normal).
VoxelFrame frameFor(const Vec3d& n, const BandSettings& s)
{
    VoxelFrame f;
    f.normal = n;
    Vec3d t = s.crystalAxis - n * s.crystalAxis.dot(n);
    if (t.length() < 0.05) t = s.secondaryAxis - n * s.secondaryAxis.dot(n);
    if (t.length() < 1e-6) t = std::fabs(n.x()) < 0.9 ? Vec3d(1, 0, 0) - n * n.x() : Vec3d(0, 1, 0) - n * n.y();
    t.normalize();
    f.tangent = t;
    f.bitangent = n.cross(t);
    return f;
}

} // namespace

std::shared_ptr<const ShellBand> ShellBand::build(const TriangleMesh& mesh, const BandSettings& settings)
{
    if (mesh.empty()) throw std::runtime_error(mesh.source + ": mesh has no triangles");
    std::shared_ptr<ShellBand> band(new ShellBand());
    ShellBand& b = *band;
    const double h = settings.voxelSize;
    b.mVoxelSize = h;
    b.mFrostThickness = settings.frostThickness;
    b.mColourUse = settings.colourUse;
    b.mTransform = openvdb::math::Transform::createLinearTransform(h);

    // Index-space copy of the mesh (meshToVolume's adapter works in index space).
    std::vector<Vec3d> pts(mesh.points.size());
    std::vector<openvdb::Vec3s> ptsS(mesh.points.size());
    for (size_t v = 0; v < pts.size(); ++v) {
        pts[v] = Vec3d(mesh.points[v]) / h;
        ptsS[v] = openvdb::Vec3s(pts[v]);
    }
    b.mSurfaceVoxels = mesh.totalArea() / (h * h);
    const std::vector<Vec3d> vnormal = mesh.vertexNormals();
    const auto vtris = mesh.vertexTriangles();

    openvdb::tools::QuadAndTriangleDataAdapter<openvdb::Vec3s, openvdb::Vec3I> adapter(ptsS, mesh.triangles);
    openvdb::Int32Grid primitive;
    const float bandVoxels = float(kHalfWidth + 1.5); // the exact distance below decides membership
    auto udf = openvdb::tools::meshToVolume<openvdb::FloatGrid>(adapter, *b.mTransform, bandVoxels, bandVoxels,
                                                                openvdb::tools::UNSIGNED_DISTANCE_FIELD, &primitive);

    // Candidates in tree order (deterministic), then the exact closest point per voxel in parallel.
    std::vector<Coord> cand;
    std::vector<uint32_t> candTri;
    {
        auto acc = primitive.getConstAccessor();
        const float keep = float((kHalfWidth + 1.0) * h);
        for (auto it = udf->cbeginValueOn(); it; ++it) {
            if (!it.isVoxelValue() || *it > keep) continue;
            const int32_t t = acc.getValue(it.getCoord());
            if (t < 0 || size_t(t) >= mesh.triangles.size()) continue;
            cand.push_back(it.getCoord());
            candTri.push_back(uint32_t(t));
        }
    }
    const size_t nc = cand.size();
    std::vector<Vec3d> cp(nc);
    std::vector<uint32_t> tri(nc);
    std::vector<double> dist(nc);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nc), [&](const tbb::blocked_range<size_t>& r) {
        std::vector<uint32_t> ring;
        for (size_t i = r.begin(); i < r.end(); ++i) {
            const Vec3d x(cand[i].x(), cand[i].y(), cand[i].z());
            // the primitive meshToVolume found and its one-ring (ties at edges and vertices)
            ring.clear();
            for (int v = 0; v < 3; ++v) {
                const auto& vt = vtris[mesh.triangles[candTri[i]][v]];
                ring.insert(ring.end(), vt.begin(), vt.end());
            }
            std::sort(ring.begin(), ring.end());
            ring.erase(std::unique(ring.begin(), ring.end()), ring.end());
            double best = std::numeric_limits<double>::max();
            for (uint32_t t : ring) {
                const auto& f = mesh.triangles[t];
                const Vec3d q = dla3d::closestPointOnTriangle(x, pts[f[0]], pts[f[1]], pts[f[2]]);
                const double d = (q - x).lengthSqr();
                if (d < best) { best = d; cp[i] = q; tri[i] = t; }
            }
            dist[i] = std::sqrt(best);
        }
    });

    // Members: exact distance within the half-width.
    b.mIndex = openvdb::Int32Grid::create(-1);
    b.mIndex->setTransform(b.mTransform);
    {
        auto acc = b.mIndex->getAccessor();
        for (size_t i = 0; i < nc; ++i) {
            if (dist[i] > kHalfWidth) continue;
            acc.setValue(cand[i], int32_t(b.mCoords.size()));
            b.mCoords.push_back(cand[i]);
            b.mCp.push_back(cp[i]);
            b.mTriangle.push_back(tri[i]);
            b.mDistance.push_back(float(dist[i]));
        }
    }
    const size_t n = b.mCoords.size();
    if (n == 0) throw std::runtime_error(mesh.source + ": the shell band is empty (mesh smaller than a voxel?)");
    b.mMask = openvdb::MaskGrid::create();
    b.mMask->setTransform(b.mTransform);
    b.mMask->tree().topologyUnion(b.mIndex->tree());

    b.mFrames.resize(n);
    if (mesh.colours.size() == mesh.points.size()) b.mLuminance.resize(n);
    b.mNormalOffset.resize(n);
    b.mLateral.resize(n);
    b.mNeighbours.resize(6 * n);
    b.mNodes.resize(64 * n);
    b.mWeights.resize(n);
    bool missing = false;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& r) {
        auto acc = b.mIndex->getConstAccessor();
        for (size_t i = r.begin(); i < r.end(); ++i) {
            const Coord& c = b.mCoords[i];
            const auto& f = mesh.triangles[b.mTriangle[i]];
            const Vec3d bc = barycentric(b.mCp[i], pts[f[0]], pts[f[1]], pts[f[2]]);
            Vec3d nrm = vnormal[f[0]] * bc[0] + vnormal[f[1]] * bc[1] + vnormal[f[2]] * bc[2];
            if (nrm.length() < 1e-9) nrm = mesh.normal(b.mTriangle[i]);
            nrm.normalize();
            b.mFrames[i] = frameFor(nrm, settings);
            if (!b.mLuminance.empty()) {
                double l = 0;
                for (int v = 0; v < 3; ++v) {
                    const auto& c = mesh.colours[f[v]];
                    l += bc[v] * (0.2126 * c.x() + 0.7152 * c.y() + 0.0722 * c.z());
                }
                b.mLuminance[i] = float(std::clamp(l, 0.0, 1.0));
            }
            const Vec3d off = Vec3d(c.x(), c.y(), c.z()) - b.mCp[i];
            const double s = off.dot(nrm);
            b.mNormalOffset[i] = float(s);
            b.mLateral[i] = float((off - nrm * s).length());
            static const Coord nb[6] = {Coord(-1, 0, 0), Coord(1, 0, 0), Coord(0, -1, 0),
                                        Coord(0, 1, 0), Coord(0, 0, -1), Coord(0, 0, 1)};
            for (int k = 0; k < 6; ++k) b.mNeighbours[6 * i + size_t(k)] = acc.getValue(c + nb[k]);
            // tricubic stencil at cp
            const Vec3d& q = b.mCp[i];
            const Coord base(int(std::floor(q.x())), int(std::floor(q.y())), int(std::floor(q.z())));
            double w[3][4];
            for (int a = 0; a < 3; ++a) cubicWeights(q[a] - base[a], w[a]);
            for (int a = 0; a < 3; ++a)
                for (int k = 0; k < 4; ++k) b.mWeights[i][size_t(4 * a + k)] = float(w[a][k]);
            int32_t* nodes = &b.mNodes[64 * i];
            for (int z = 0; z < 4; ++z)
                for (int y = 0; y < 4; ++y)
                    for (int x = 0; x < 4; ++x) {
                        const int32_t id = acc.getValue(base + Coord(x - 1, y - 1, z - 1));
                        if (id < 0) missing = true; // cannot happen when the distances are exact
                        nodes[16 * z + 4 * y + x] = id;
                    }
        }
    });
    if (missing)
        throw std::runtime_error(mesh.source + ": internal error: a tricubic node of the shell band is missing");

    for (const auto& e : mesh.boundaryEdges()) {
        b.mBorderA.push_back(pts[e.first]);
        b.mBorderB.push_back(pts[e.second]);
    }
    return band;
}

int32_t ShellBand::indexOf(const Coord& c) const { return mIndex->tree().getValue(c); }

std::vector<size_t> ShellBand::nearBorder(double width) const
{
    std::vector<char> hit(size(), 0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, size()), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i)
            for (size_t e = 0; e < mBorderA.size() && !hit[i]; ++e)
                if (pointSegmentDistance(mCp[i], mBorderA[e], mBorderB[e]) <= width) hit[i] = 1;
    });
    std::vector<size_t> out;
    for (size_t i = 0; i < size(); ++i)
        if (hit[i]) out.push_back(i);
    return out;
}

std::vector<size_t> ShellBand::nearSurfacePoint(const Vec3d& centre, double radius) const
{
    std::vector<size_t> out;
    for (size_t i = 0; i < size(); ++i)
        if ((mCp[i] - centre).length() <= radius) out.push_back(i);
    return out;
}

Vec3d ShellBand::nearestSurfacePoint(const Vec3d& p) const
{
    double best = std::numeric_limits<double>::max();
    Vec3d out = p;
    for (const auto& q : mCp) {
        const double d = (q - p).lengthSqr();
        if (d < best) { best = d; out = q; }
    }
    return out;
}

void ShellBand::extend(const std::vector<float>& in, std::vector<float>& out, bool limit) const
{
    out.resize(size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, size()), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            const int32_t* nodes = &mNodes[64 * i];
            const float* w = mWeights[i].data();
            double sz = 0;
            for (int z = 0; z < 4; ++z) {
                double sy = 0;
                for (int y = 0; y < 4; ++y) {
                    const int32_t* row = nodes + 16 * z + 4 * y;
                    const double sx = double(w[0]) * in[size_t(row[0])] + double(w[1]) * in[size_t(row[1])] +
                                      double(w[2]) * in[size_t(row[2])] + double(w[3]) * in[size_t(row[3])];
                    sy += double(w[4 + y]) * sx;
                }
                sz += double(w[8 + z]) * sy;
            }
            if (limit) {
                float lo = std::numeric_limits<float>::max(), hi = -lo;
                for (int z = 1; z < 3; ++z)
                    for (int y = 1; y < 3; ++y)
                        for (int x = 1; x < 3; ++x) {
                            const float v = in[size_t(nodes[16 * z + 4 * y + x])];
                            lo = std::min(lo, v);
                            hi = std::max(hi, v);
                        }
                sz = std::clamp(sz, double(lo), double(hi));
            }
            out[i] = float(sz);
        }
    });
}

void ShellBand::extendPhase(const std::vector<float>& p, std::vector<float>& out, std::vector<float>& phi) const
{
    phi.resize(size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, size()), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            const double q = std::clamp(double(p[i]), 1e-6, 1.0 - 1e-6);
            phi[i] = float(std::atanh(2.0 * q - 1.0));
        }
    });
    extend(phi, out, false);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, size()), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            const int32_t* nodes = &mNodes[64 * i];
            float lo = std::numeric_limits<float>::max(), hi = -lo;
            for (int z = 1; z < 3; ++z)
                for (int y = 1; y < 3; ++y)
                    for (int x = 1; x < 3; ++x) {
                        const float v = p[size_t(nodes[16 * z + 4 * y + x])];
                        lo = std::min(lo, v);
                        hi = std::max(hi, v);
                    }
            out[i] = std::clamp(float(0.5 * (1.0 + std::tanh(double(out[i])))), lo, hi);
        }
    });
}

size_t ShellBand::memoryBytes() const
{
    const size_t n = size();
    return n * (sizeof(Coord) + sizeof(Vec3d) + 3 * sizeof(float) + sizeof(VoxelFrame) +
                sizeof(uint32_t) + 6 * sizeof(int32_t) + 64 * sizeof(int32_t) + sizeof(std::array<float, 12>)) +
           mIndex->memUsage() + mMask->memUsage();
}

} // namespace frostvdb::shell
