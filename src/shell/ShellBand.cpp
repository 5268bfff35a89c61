/// @file ShellBand.cpp
/// @brief Builds the shell's narrow band from a mesh, leaf by leaf (a triangle hierarchy, exact
/// closest points, frames, neighbours, tricubic stencils), and does the closest-point extension.
#include <frostvdb/shell/ShellBand.h>

#include <frostvdb/core/Budget.h>
#include <frostvdb/geometry/Triangle.h>

#include <tbb/parallel_for.h>

#include <Eigen/Dense>

#include <algorithm>
#include <map>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>

namespace frostvdb::shell {

using openvdb::BBoxd;
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

/// Origins of the leaves that hold any voxel of @a box.
void leavesOfBox(const openvdb::CoordBBox& box, std::vector<Coord>& out)
{
    const Coord lo = leafOrigin(box.min()), hi = leafOrigin(box.max());
    for (int x = lo.x(); x <= hi.x(); x += kLeafDim)
        for (int y = lo.y(); y <= hi.y(); y += kLeafDim)
            for (int z = lo.z(); z <= hi.z(); z += kLeafDim) out.emplace_back(x, y, z);
}

openvdb::CoordBBox coordBox(const Vec3d& lo, const Vec3d& hi)
{
    return openvdb::CoordBBox(Coord(int(std::floor(lo.x())), int(std::floor(lo.y())), int(std::floor(lo.z()))),
                              Coord(int(std::ceil(hi.x())), int(std::ceil(hi.y())), int(std::ceil(hi.z()))));
}

void sortUnique(std::vector<Coord>& v)
{
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
}

} // namespace

// ---------------------------------------------------------------------------------------------
// ShellBand: construction

struct ShellBand::LeafData {
    std::vector<Coord> coords;
    std::vector<Vec3d> cp;
    std::vector<uint32_t> tri;
    std::vector<float> dist, normalOffset, lateral, luminance;
    std::vector<FrameFloats> frames;
};

void ShellBand::init(const TriangleMesh& mesh, const BandSettings& settings)
{
    if (mesh.empty()) throw std::runtime_error(mesh.source + ": mesh has no triangles");
    const double h = settings.voxelSize;
    mSettings = settings;
    mSurface = settings.discretisation == BandSettings::Discretisation::SurfaceNodes;
    mVoxelSize = h;
    mFrostThickness = settings.frostThickness;
    mColourUse = settings.colourUse;
    mSource = mesh.source;
    mTransform = openvdb::math::Transform::createLinearTransform(h);
    mPts.resize(mesh.points.size());
    for (size_t v = 0; v < mPts.size(); ++v) mPts[v] = Vec3d(mesh.points[v]) / h;
    mTris = mesh.triangles;
    mVNormal = mesh.vertexNormals();
    mTriNormal.resize(mTris.size());
    for (size_t t = 0; t < mTris.size(); ++t) mTriNormal[t] = mesh.normal(t);
    if (mesh.colours.size() == mesh.points.size()) mVColour = mesh.colours;
    mSurfaceVoxels = mesh.totalArea() / (h * h);
    mBvh = TriangleBvh(mPts, mTris);
    mGhosts = mSurface && !mesh.boundaryEdges().empty();
    BBoxd box(mPts[0], mPts[0]);
    for (const auto& p : mPts) box.expand(p);
    mBounds = coordBox(box.min() - Vec3d(halfWidth()), box.max() + Vec3d(halfWidth()));
    for (const auto& e : mesh.boundaryEdges()) {
        mBorderA.push_back(mPts[e.first]);
        mBorderB.push_back(mPts[e.second]);
    }
    mMask = openvdb::MaskGrid::create();
    mMask->setTransform(mTransform);
}

std::shared_ptr<const ShellBand> ShellBand::buildLazy(const TriangleMesh& mesh, const BandSettings& settings)
{
    std::shared_ptr<ShellBand> band(new ShellBand());
    band->init(mesh, settings);
    return band;
}

std::shared_ptr<const ShellBand> ShellBand::build(const TriangleMesh& mesh, const BandSettings& settings)
{
    auto band = buildLazy(mesh, settings);
    band->materialiseAll();
    return band;
}

bool ShellBand::voxelGeometry(const Coord& c, Vec3d& cp, uint32_t& tri, double& dist) const
{
    double d2 = 0;
    if (!mBvh.closestPointWithin(Vec3d(c.x(), c.y(), c.z()), halfWidth() * halfWidth(), cp, tri, d2)) return false;
    dist = std::sqrt(d2);
    return true;
}

VoxelFrame ShellBand::frameOn(uint32_t t, const Vec3d& cp, Vec3d* bary) const
{
    const auto& f = mTris[t];
    const Vec3d bc = barycentric(cp, mPts[f[0]], mPts[f[1]], mPts[f[2]]);
    if (bary) *bary = bc;
    Vec3d nrm = mVNormal[f[0]] * bc[0] + mVNormal[f[1]] * bc[1] + mVNormal[f[2]] * bc[2];
    if (nrm.length() < 1e-9) nrm = mTriNormal[t];
    nrm.normalize();
    return frameFor(nrm, mSettings);
}

void ShellBand::computeLeaf(const Coord& origin, LeafData& out) const
{
    // the triangles within reach of the leaf (a hair more: rounding): with a handful, each
    // voxel's closest point is searched among them only (the same answer as the whole tree's)
    std::vector<uint32_t> cand;
    const Vec3d lo(origin.x(), origin.y(), origin.z());
    const double reach = halfWidth() + 1e-6;
    mBvh.query(BBoxd(lo - Vec3d(reach), lo + Vec3d(kLeafDim - 1 + reach)), cand);
    if (cand.empty()) return;
    const bool fewTriangles = cand.size() <= 32;
    const double hw2 = halfWidth() * halfWidth();
    auto geometryOf = [&](const Coord& c, Vec3d& cp, uint32_t& t, double& d) {
        if (!fewTriangles) return voxelGeometry(c, cp, t, d);
        double d2 = 0;
        if (!mBvh.closestPointAmong(cand, Vec3d(c.x(), c.y(), c.z()), hw2, cp, t, d2)) return false;
        d = std::sqrt(d2);
        return true;
    };
    // voxels in the leaf's offset order (x, then y, then z slowest-to-fastest as OpenVDB stores them)
    for (int x = 0; x < kLeafDim; ++x)
        for (int y = 0; y < kLeafDim; ++y)
            for (int z = 0; z < kLeafDim; ++z) {
                const Coord c = origin + Coord(x, y, z);
                Vec3d cp;
                uint32_t t = 0;
                double d = 0;
                if (!geometryOf(c, cp, t, d)) continue;
                Vec3d bc;
                const VoxelFrame fr = frameOn(t, cp, &bc);
                const Vec3d off = Vec3d(c.x(), c.y(), c.z()) - cp;
                const double s = off.dot(fr.normal), lateral = (off - fr.normal * s).length();
                // surface nodes: the slab -1/2 < s <= 1/2 (one voxel thick: one node per surface
                // cell; half-open so a surface through voxel faces keeps one layer), and at most
                // half a voxel beyond an open border (a plane's cells whose centre is inside),
                // plus one ring of ghost nodes beyond it (held at the background: ghost())
                if (mSurface && (s <= -0.5 || s > 0.5 || lateral > (mGhosts ? kGhostLateral : 0.5))) continue;
                out.coords.push_back(c);
                out.cp.push_back(cp);
                out.tri.push_back(t);
                out.dist.push_back(float(d));
                out.frames.push_back(FrameFloats(fr));
                if (!mVColour.empty()) {
                    double l = 0;
                    for (int v = 0; v < 3; ++v) {
                        const auto& col = mVColour[mTris[t][v]];
                        l += bc[v] * (0.2126 * col.x() + 0.7152 * col.y() + 0.0722 * col.z());
                    }
                    out.luminance.push_back(float(std::clamp(l, 0.0, 1.0)));
                }
                out.normalOffset.push_back(float(s));
                out.lateral.push_back(float(lateral));
            }
}

int32_t ShellBand::leafSlot(const Coord& origin) const
{
    const auto it = mSlotOf.find(origin);
    return it == mSlotOf.end() ? -1 : it->second;
}

size_t ShellBand::materialise(std::vector<Coord> origins) const
{
    std::lock_guard<std::mutex> lock(mMutex);
    return materialiseLocked(std::move(origins));
}

size_t ShellBand::materialiseLocked(std::vector<Coord> origins) const
{
    sortUnique(origins);
    origins.erase(std::remove_if(origins.begin(), origins.end(), [&](const Coord& o) { return mSlotOf.count(o) > 0; }),
                  origins.end());
    if (origins.empty()) return 0;
    std::vector<LeafData> data(origins.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, origins.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t k = r.begin(); k < r.end(); ++k) computeLeaf(origins[k], data[k]);
    });
    const size_t before = mCoords.size();
    // Room for the new voxels first: a whole band is built in one call and gets exactly its size
    // (doubling growth left up to half of every array unused and its old copies on the heap:
    // 86 MiB of 249 on the windshield at 2 mm); a lazy band grows by at least half each time.
    size_t added = 0;
    for (const LeafData& d : data) added += d.coords.size();
    const auto room = [](auto& v, size_t extra) {
        const size_t need = v.size() + extra;
        if (need > v.capacity()) v.reserve(std::max(need, v.capacity() + v.capacity() / 2));
    };
    room(mCoords, added), room(mCp, added), room(mTriangle, added), room(mDistance, added), room(mFrames, added);
    room(mNormalOffset, added), room(mLateral, added);
    if (!mVColour.empty()) room(mLuminance, added);
    for (size_t k = 0; k < origins.size(); ++k) {
        LeafData& d = data[k];
        Leaf leaf;
        leaf.origin = origins[k];
        leaf.begin = uint32_t(mCoords.size());
        leaf.end = uint32_t(mCoords.size() + d.coords.size());
        mSlotOf[origins[k]] = int32_t(mLeaves.size());
        mLeaves.push_back(leaf);
        if (d.coords.empty()) continue;
        mIndex.addLeaf(origins[k], leaf.begin, d.coords); // the coordinates in offset order
        auto* ml = mMask->tree().touchLeaf(origins[k]);
        for (const Coord& c : d.coords) ml->setValueOn(c);
        mCoords.insert(mCoords.end(), d.coords.begin(), d.coords.end());
        for (const Vec3d& q : d.cp) mCp.emplace_back(q); // rounded to floats once, here
        mTriangle.insert(mTriangle.end(), d.tri.begin(), d.tri.end());
        mDistance.insert(mDistance.end(), d.dist.begin(), d.dist.end());
        mFrames.insert(mFrames.end(), d.frames.begin(), d.frames.end());
        mLuminance.insert(mLuminance.end(), d.luminance.begin(), d.luminance.end());
        mNormalOffset.insert(mNormalOffset.end(), d.normalOffset.begin(), d.normalOffset.end());
        mLateral.insert(mLateral.end(), d.lateral.begin(), d.lateral.end());
        d = LeafData(); // copied: its memory serves the next leaves' copies
    }
    const size_t n = mCoords.size();
    if (mSurface) { // the stencils replace the 6 Cartesian neighbours
        room(mTapBegin, added), room(mTapCount, added);
        mTapBegin.resize(n, nullptr);
        mTapCount.resize(n, 0);
        mLeafTaps.resize(mLeaves.size());
    } else {
        mNeighbours.resize(6 * n, -1);
        mNodes.resize(64 * n, -1);
        mWeights.resize(n);
    }
    return n - before;
}

void ShellBand::prepare(std::vector<Coord> origins) const
{
    std::lock_guard<std::mutex> lock(mMutex);
    prepareLocked(std::move(origins));
}

void ShellBand::prepareLocked(std::vector<Coord> origins) const
{
    sortUnique(origins);
    // the leaves and their 26 neighbours must be built: neighbours and tricubic nodes lie there
    std::vector<Coord> ring;
    for (const Coord& o : origins) {
        const int32_t s = leafSlot(o);
        if (s >= 0 && mLeaves[size_t(s)].prepared) continue;
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dz = -1; dz <= 1; ++dz) ring.push_back(o + Coord(dx * kLeafDim, dy * kLeafDim, dz * kLeafDim));
    }
    if (ring.empty()) return;
    materialiseLocked(ring);
    std::vector<uint32_t> todo;
    for (const Coord& o : origins) {
        const int32_t s = leafSlot(o);
        if (!mLeaves[size_t(s)].prepared) todo.push_back(uint32_t(s));
    }
    if (mSurface) {
        prepareSurface(todo);
        for (uint32_t s : todo) mLeaves[s].prepared = true;
        return;
    }
    bool missing = false;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, todo.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
        BandIndex::Accessor acc = mIndex.accessor();
        static const Coord nb[6] = {Coord(-1, 0, 0), Coord(1, 0, 0), Coord(0, -1, 0),
                                    Coord(0, 1, 0),  Coord(0, 0, -1), Coord(0, 0, 1)};
        for (size_t k = r.begin(); k < r.end(); ++k) {
            const Leaf& l = mLeaves[todo[k]];
            for (size_t i = l.begin; i < l.end; ++i) {
                const Coord& c = mCoords[i];
                for (int n = 0; n < 6; ++n) mNeighbours[6 * i + size_t(n)] = acc.getValue(c + nb[n]);
                const Vec3d q = closestPoint(i);
                const Coord base(int(std::floor(q.x())), int(std::floor(q.y())), int(std::floor(q.z())));
                double w[3][4];
                for (int a = 0; a < 3; ++a) cubicWeights(q[a] - base[a], w[a]);
                for (int a = 0; a < 3; ++a)
                    for (int j = 0; j < 4; ++j) mWeights[i][size_t(4 * a + j)] = float(w[a][j]);
                int32_t* nodes = &mNodes[64 * i];
                for (int z = 0; z < 4; ++z)
                    for (int y = 0; y < 4; ++y)
                        for (int x = 0; x < 4; ++x) {
                            const int32_t id = acc.getValue(base + Coord(x - 1, y - 1, z - 1));
                            if (id < 0) missing = true; // cannot happen when the distances are exact
                            nodes[16 * z + 4 * y + x] = id;
                        }
            }
        }
    });
    if (missing) throw std::runtime_error(mSource + ": internal error: a tricubic node of the shell band is missing");
    for (uint32_t s : todo) mLeaves[s].prepared = true;
}

/// Surface nodes: neighbours whose closest points lie nearer than this (voxels, in the tangent
/// plane) are left out of a stencil.
constexpr double kMinTapDistance = 0.5;
/// Surface nodes: a stencil whose centre weight (the sum of its Laplacian weights) exceeds this
/// is refitted on the wider ring (the plane's 5-point stencil has 4, the isotropic 9-point 10/3).
constexpr double kMaxCentreWeight = 6.0;
/// Surface nodes: the same bound on the gradient weights' absolute sum (a central difference
/// has 1, the flat layer's fit 1.0 per axis).
constexpr double kMaxGradientSpread = 4.0;
/// Surface nodes: a tap whose weights are all below this fraction of their operator's largest
/// (Laplacian, d/ds, d/dt) is dropped and the stencil refitted on the rest (see surfaceStencil).
/// Below 1/8, so a flat axis-aligned layer keeps its corners.
constexpr double kStrongTapFraction = 0.12;
/// Surface nodes: the weight powers phi = r^-power of the Laplacian's and the gradient's fits.
/// 6 gives a flat axis-aligned layer the isotropic 9-point Laplacian (docs/shells.md).
constexpr double kLaplacianWeightPower = 8.0;
constexpr double kGradientWeightPower = 6.0;

namespace {
/// A neighbour of a surface node: its band index, its closest point's tangent-plane coordinates
/// (s, t) from the node's, and the fits' weights r^-power (computed once: a refit reuses them).
struct StencilCandidate {
    int32_t id;
    double s, t, r2;
    double phiLap, phiGrad;
};

/// A fit's weights per candidate: the Laplacian's, and d/ds and d/dt's (fixed column counts:
/// Eigen's dynamic-width solve went through its blocked matrix kernels for one or two columns).
using LapWeights = Eigen::Matrix<double, Eigen::Dynamic, 1>;
using GradWeights = Eigen::Matrix<double, Eigen::Dynamic, 2>;

/// Weights w_j of least sum w_j^2 / phi_j, exact on (s, t, s^2, st, t^2) for @a rhs (one column
/// per operator); false for a degenerate layout (collinear).
template <int Cols>
bool fitStencil(const std::vector<StencilCandidate>& cand, double StencilCandidate::*phiOf,
                const Eigen::Matrix<double, 5, Cols>& rhs, Eigen::Matrix<double, Eigen::Dynamic, Cols>& w)
{
    Eigen::Matrix<double, 5, 5> g = Eigen::Matrix<double, 5, 5>::Zero();
    for (const StencilCandidate& c : cand) {
        const Eigen::Matrix<double, 5, 1> m(c.s, c.t, c.s * c.s, c.s * c.t, c.t * c.t);
        g += c.*phiOf * m * m.transpose();
    }
    // g is symmetric positive semi-definite: a pivoted LDL^T solves it (an eigensolver did until
    // session 17, at four times the cost: most of the band's build)
    const Eigen::LDLT<Eigen::Matrix<double, 5, 5>> ldlt(g);
    const auto d = ldlt.vectorD().cwiseAbs();
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !(d.minCoeff() > 1e-9 * d.maxCoeff())) return false;
    const Eigen::Matrix<double, 5, Cols> y = ldlt.solve(rhs);
    w.resize(Eigen::Index(cand.size()), rhs.cols());
    for (size_t k = 0; k < cand.size(); ++k) {
        const StencilCandidate& c = cand[k];
        const Eigen::Matrix<double, 5, 1> m(c.s, c.t, c.s * c.s, c.s * c.t, c.t * c.t);
        w.row(Eigen::Index(k)) = c.*phiOf * (m.transpose() * y);
    }
    return true;
}

/// Whether explicit steps can afford a fit. A lopsided neighbourhood (an open border, a gap in a
/// steep layer) fits the quadratic with large weights of both signs, and negative Laplacian
/// weights beyond a tenth of the centre weight made a 0.5 mm windshield unstable at a corner
/// after 1,600 steps.
bool stencilAcceptable(const LapWeights& wl, const GradWeights& wg)
{
    double centre = 0, spread = 0, gradSpread = 0;
    for (Eigen::Index k = 0; k < wl.rows(); ++k) {
        centre += wl(k, 0);
        spread += std::fabs(wl(k, 0));
        gradSpread += std::fabs(wg(k, 0)) + std::fabs(wg(k, 1));
    }
    const double negative = 0.5 * (spread - centre);
    return !(centre > kMaxCentreWeight || spread > 2.0 * kMaxCentreWeight || gradSpread > kMaxGradientSpread ||
             negative > 0.1 * centre);
}

/// The candidates strong in some operator: a weight at least kStrongTapFraction of that
/// operator's largest (Laplacian @a wl, d/ds and d/dt @a wg). About a fifth of a tilted layer's
/// taps carry little and cost as much as the strong ones in every step (docs/shells.md "The
/// step"); on a flat axis-aligned layer every tap is strong (the corners carry 1/8 of the
/// Laplacian), so its stencil is unchanged.
std::vector<StencilCandidate> strongCandidates(const std::vector<StencilCandidate>& cand, const LapWeights& wl,
                                               const GradWeights& wg)
{
    const Eigen::Index n = wl.rows();
    const double part = kStrongTapFraction, mL = wl.col(0).cwiseAbs().maxCoeff(),
                 mU = wg.col(0).cwiseAbs().maxCoeff(), mV = wg.col(1).cwiseAbs().maxCoeff();
    std::vector<StencilCandidate> strong;
    for (Eigen::Index k = 0; k < n; ++k)
        if (std::fabs(wl(k, 0)) >= part * mL || std::fabs(wg(k, 0)) >= part * mU || std::fabs(wg(k, 1)) >= part * mV)
            strong.push_back(cand[size_t(k)]);
    return strong;
}
} // namespace

void ShellBand::surfaceStencil(size_t i, BandIndex::Accessor& acc,
                               std::vector<SurfaceTap>& out) const
{
    // Generalised finite differences on the layer: weights w_j on differences u_j - u_i that are
    // exact for every quadratic in the tangent-plane coordinates (s, t) of the neighbours' closest
    // points, of least weighted norm sum w_j^2 / phi_j (fitStencil). At the node, where the
    // surface is a graph over its tangent plane with zero slope, u_ss + u_tt is the
    // Laplace-Beltrami operator. phi = r^-6 would make the stencil of a flat, axis-aligned layer
    // the isotropic 9-point Laplacian (edge 2/3, corner 1/6); the Laplacian uses r^-8 (edge 0.8,
    // corner 0.1: nearer the plane's 5-point stencil, measured in docs/shells.md), the gradient
    // r^-6 (Sobel-like).
    using Cand = StencilCandidate;
    const Coord c = mCoords[i];
    const Vec3d q = closestPoint(i);
    const VoxelFrame f = frame(i);
    std::vector<Cand> cand;
    const double minD = kMinTapDistance, pLap = kLaplacianWeightPower, pGrad = kGradientWeightPower;
    Eigen::Matrix<double, 5, 1> lapRhs = Eigen::Matrix<double, 5, 1>::Zero();
    Eigen::Matrix<double, 5, 2> gradRhs = Eigen::Matrix<double, 5, 2>::Zero();
    lapRhs(2, 0) = lapRhs(4, 0) = 2.0; // Laplacian: 2 (c_ss + c_tt)
    gradRhs(0, 0) = 1.0;               // d/ds
    gradRhs(1, 1) = 1.0;               // d/dt
    for (int reach = 1; reach <= kTapReach; ++reach) {
        cand.clear();
        for (int dz = -reach; dz <= reach; ++dz)
            for (int dy = -reach; dy <= reach; ++dy)
                for (int dx = -reach; dx <= reach; ++dx) {
                    if (dx == 0 && dy == 0 && dz == 0) continue;
                    const int32_t id = acc.getValue(c + Coord(dx, dy, dz));
                    if (id < 0) continue;
                    const Vec3d d = closestPoint(size_t(id)) - q;
                    const double s = d.dot(f.tangent), t = d.dot(f.bitangent), r2 = s * s + t * t;
                    // nearly the same surface point (two voxels of a steep slab): it adds no
                    // information, and a weight ~ 1/r^2 that explicit steps could not afford
                    if (r2 < minD * minD) continue;
                    cand.push_back({id, s, t, r2, std::pow(r2, -0.5 * pLap), std::pow(r2, -0.5 * pGrad)});
                }
        if (cand.size() < 5) continue;
        LapWeights wl;
        GradWeights wg;
        if (!fitStencil(cand, &Cand::phiLap, lapRhs, wl) || !fitStencil(cand, &Cand::phiGrad, gradRhs, wg) ||
            !stencilAcceptable(wl, wg))
            continue; // a wider ring
        // the weak taps dropped and the rest refitted, kept when the refit passes the same checks
        std::vector<Cand> strong = strongCandidates(cand, wl, wg);
        LapWeights sl;
        GradWeights sg;
        if (strong.size() >= 5 && strong.size() < cand.size() && fitStencil(strong, &Cand::phiLap, lapRhs, sl) &&
            fitStencil(strong, &Cand::phiGrad, gradRhs, sg) && stencilAcceptable(sl, sg)) {
            cand.swap(strong);
            wl = sl;
            wg = sg;
        }
        for (size_t k = 0; k < cand.size(); ++k)
            out.push_back({cand[k].id, float(wl(Eigen::Index(k), 0)), float(wg(Eigen::Index(k), 0)),
                           float(wg(Eigen::Index(k), 1))});
        return;
    }
    // Too few neighbours for a quadratic fit, or a fit too lopsided to step explicitly (an open
    // border's corner, a needle tip): an isotropic ring estimate over the nearest ring that keeps
    // the operators' signs (diffusion stays diffusion), first order.
    if (kTapReach > 1) {
        std::vector<Cand> inner;
        for (const Cand& k : cand)
            if (std::abs(mCoords[size_t(k.id)].x() - c.x()) <= 1 && std::abs(mCoords[size_t(k.id)].y() - c.y()) <= 1 &&
                std::abs(mCoords[size_t(k.id)].z() - c.z()) <= 1)
                inner.push_back(k);
        if (!inner.empty()) cand.swap(inner);
    }
    double sum2 = 0;
    for (const Cand& k : cand) sum2 += k.s * k.s + k.t * k.t;
    for (const Cand& k : cand) {
        const double r2 = k.s * k.s + k.t * k.t;
        out.push_back({k.id, float(4.0 / (double(cand.size()) * r2)), float(2.0 * k.s / sum2), float(2.0 * k.t / sum2)});
    }
}

void ShellBand::prepareSurface(const std::vector<uint32_t>& slots) const
{
    std::vector<std::vector<SurfaceTap>> taps(slots.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, slots.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
        BandIndex::Accessor acc = mIndex.accessor();
        for (size_t k = r.begin(); k < r.end(); ++k) {
            const Leaf& l = mLeaves[slots[k]];
            for (size_t i = l.begin; i < l.end; ++i) {
                const size_t before = taps[k].size();
                surfaceStencil(i, acc, taps[k]);
                mTapCount[i] = uint8_t(taps[k].size() - before); // at most 124
            }
        }
    });
    for (size_t k = 0; k < slots.size(); ++k) {
        const Leaf& l = mLeaves[slots[k]];
        auto& leafTaps = mLeafTaps[slots[k]];
        leafTaps = std::move(taps[k]);
        leafTaps.shrink_to_fit();
        mTapTotal += leafTaps.size();
        const SurfaceTap* at = leafTaps.data();
        for (size_t i = l.begin; i < l.end; ++i) {
            mTapBegin[i] = at;
            at += mTapCount[i];
        }
    }
}

void ShellBand::leavesOfTriangle(uint32_t t, std::vector<Coord>& out) const
{
    const auto& f = mTris[t];
    BBoxd b(mPts[f[0]], mPts[f[0]]);
    b.expand(mPts[f[1]]);
    b.expand(mPts[f[2]]);
    std::vector<Coord> box;
    leavesOfBox(coordBox(b.min() - Vec3d(halfWidth()), b.max() + Vec3d(halfWidth())), box);
    // a leaf's voxels lie within 3.5 sqrt 3 of its centre
    const double reach = halfWidth() + 0.5 * (kLeafDim - 1) * std::sqrt(3.0) + 1e-6;
    for (const Coord& o : box) {
        const Vec3d centre = Vec3d(o.x(), o.y(), o.z()) + Vec3d(0.5 * (kLeafDim - 1));
        const Vec3d q = geometry::closestPointOnTriangle(centre, mPts[f[0]], mPts[f[1]], mPts[f[2]]);
        if ((q - centre).length() <= reach) out.push_back(o);
    }
}

void ShellBand::materialiseAll() const
{
    std::lock_guard<std::mutex> lock(mMutex);
    if (mWhole) return;
    // Refuse before allocating (docs/shells.md): closest point, about 11.5 band voxels per surface
    // voxel at about 600 bytes each plus the solver's arrays; surface nodes, about one node per
    // surface voxel at bytesPerNode().
    const double estimate = mSurfaceVoxels * bytesPerSurfaceCell();
    const double available = double(availableMemoryBytes());
    if (available > 0 && estimate > available)
        throw std::runtime_error(mSource + ": the whole shell band would need about " + formatBytes(estimate) +
                                 " (mesh area / voxel_size^2 x the bytes per surface cell), more than the " +
                                 formatBytes(available) + " available; raise voxel_size, scale the mesh down or "
                                 "use the sparse region ([region] dense = false)");
    std::vector<Coord> reached;
    for (uint32_t t = 0; t < mTris.size(); ++t) leavesOfTriangle(t, reached);
    sortUnique(reached);
    materialiseLocked(reached);
    // every other leaf is provably empty (leavesOfTriangle is conservative): record it as such
    // instead of searching it, so preparing the reached leaves builds nothing more
    for (const Coord& o : reached)
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dz = -1; dz <= 1; ++dz) {
                    const Coord n = o + Coord(dx * kLeafDim, dy * kLeafDim, dz * kLeafDim);
                    if (mSlotOf.count(n)) continue;
                    Leaf l;
                    l.origin = n;
                    l.begin = l.end = uint32_t(mCoords.size());
                    l.prepared = true;
                    mSlotOf[n] = int32_t(mLeaves.size());
                    mLeaves.push_back(l);
                }
    prepareLocked(reached);
    if (mCoords.empty()) throw std::runtime_error(mSource + ": the shell band is empty (mesh smaller than a voxel?)");
    mWhole = true;
}

void ShellBand::materialiseTriangles(const std::vector<uint32_t>& triangles) const
{
    std::vector<Coord> origins;
    for (uint32_t t : triangles) leavesOfTriangle(t, origins);
    materialise(std::move(origins));
}

size_t ShellBand::materialiseBox(const openvdb::CoordBBox& box) const
{
    std::vector<Coord> origins;
    leavesOfBox(box, origins);
    return materialise(std::move(origins));
}

// ---------------------------------------------------------------------------------------------
// ShellBand: queries

int32_t ShellBand::indexOf(const Coord& c) const { return mIndex.getValue(c); }

bool ShellBand::contains(const Coord& c) const
{
    if (leafSlot(leafOrigin(c)) >= 0) return indexOf(c) >= 0;
    Vec3d cp;
    uint32_t t;
    double d;
    return voxelGeometry(c, cp, t, d);
}

VoxelFrame ShellBand::frameAt(const Coord& c) const
{
    const int32_t i = indexOf(c);
    if (i >= 0) return frame(size_t(i));
    if (leafSlot(leafOrigin(c)) >= 0) return VoxelFrame{};
    Vec3d cp;
    uint32_t t;
    double d;
    return voxelGeometry(c, cp, t, d) ? FrameFloats(frameOn(t, cp)).widened() : VoxelFrame{}; // as stored
}

std::vector<size_t> ShellBand::nearBorder(double width) const
{
    // Each border edge, sampled every 4 voxels at most, lists the leaves within reach of its
    // samples: a voxel whose closest point is within @a width of the edge lies within width +
    // 2 (half a sample spacing) + the half-width of a sample. Only those leaves' voxels are tested,
    // each against its leaf's edges (all voxels against all edges took 0.4 s of CPU on the pane).
    std::map<Coord, std::vector<uint32_t>> edgesOfLeaf; // ordered: the same schedule every run
    std::vector<Coord> build, origins;
    const double buildReach = width + halfWidth() + 1.0, testReach = width + halfWidth() + 3.0;
    for (size_t e = 0; e < mBorderA.size(); ++e) {
        const Vec3d a = mBorderA[e], b = mBorderB[e];
        const int n = std::max(1, int(std::ceil((b - a).length() / 4.0)));
        origins.clear();
        for (int k = 0; k <= n; ++k) {
            const Vec3d p = a + (b - a) * (double(k) / n);
            if (!mWhole) leavesOfBox(coordBox(p - Vec3d(buildReach), p + Vec3d(buildReach)), build);
            leavesOfBox(coordBox(p - Vec3d(testReach), p + Vec3d(testReach)), origins);
        }
        for (const Coord& o : origins) {
            auto& list = edgesOfLeaf[o];
            if (list.empty() || list.back() != uint32_t(e)) list.push_back(uint32_t(e));
        }
    }
    if (!mWhole) materialise(std::move(build)); // the leaves along the border first
    std::vector<std::pair<int32_t, const std::vector<uint32_t>*>> work;
    for (const auto& [o, edges] : edgesOfLeaf)
        if (const int32_t slot = leafSlot(o); slot >= 0) work.emplace_back(slot, &edges);
    std::vector<char> hit(size(), 0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, work.size()), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t w = r.begin(); w < r.end(); ++w) {
            const Leaf& l = mLeaves[size_t(work[w].first)];
            for (size_t i = l.begin; i < l.end; ++i)
                for (const uint32_t e : *work[w].second)
                    if (!ghost(i) && pointSegmentDistance(closestPoint(i), mBorderA[e], mBorderB[e]) <= width) {
                        hit[i] = 1;
                        break;
                    }
        }
    });
    std::vector<size_t> out;
    for (size_t i = 0; i < size(); ++i)
        if (hit[i]) out.push_back(i);
    return out;
}

std::vector<size_t> ShellBand::nearSurfacePoint(const Vec3d& centre, double radius) const
{
    if (!mWhole) {
        const double reach = radius + halfWidth() + 1.0;
        materialiseBox(coordBox(centre - Vec3d(reach), centre + Vec3d(reach)));
    }
    std::vector<size_t> out;
    for (size_t i = 0; i < size(); ++i)
        if ((closestPoint(i) - centre).length() <= radius) out.push_back(i);
    return out;
}

Vec3d ShellBand::nearestSurfacePoint(const Vec3d& p) const { return mBvh.closestPoint(p); }

// ---------------------------------------------------------------------------------------------
// ShellBand: the closest-point extension

void ShellBand::extend(const std::vector<float>& in, std::vector<float>& out, bool limit, float background,
                       const std::vector<uint32_t>* leafSlots) const
{
    if (!leafSlots) out.resize(size());
    if (mSurface) { // every voxel is a node on the surface: the extension is the identity
        if (&out != &in) forEachVoxel(leafSlots, [&](size_t i) { out[i] = in[i]; });
        (void)limit;
        (void)background;
        return;
    }
    const double bg = background;
    forEachVoxel(leafSlots, [&](size_t i) {
        const int32_t* nodes = &mNodes[64 * i];
        const float* w = mWeights[i].data();
        double sz = 0;
        for (int z = 0; z < 4; ++z) {
            double sy = 0;
            for (int y = 0; y < 4; ++y) {
                const int32_t* row = nodes + 16 * z + 4 * y;
                const double sx = double(w[0]) * (in[size_t(row[0])] - bg) + double(w[1]) * (in[size_t(row[1])] - bg) +
                                  double(w[2]) * (in[size_t(row[2])] - bg) + double(w[3]) * (in[size_t(row[3])] - bg);
                sy += double(w[4 + y]) * sx;
            }
            sz += double(w[8 + z]) * sy;
        }
        sz += bg;
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
    });
}

void ShellBand::extendPhase(const std::vector<float>& p, std::vector<float>& out, std::vector<float>& phi,
                            const std::vector<uint32_t>* leafSlots, const std::vector<uint32_t>* nodeSlots) const
{
    if (mSurface) {
        if (!leafSlots) out.resize(size());
        (void)phi;
        (void)nodeSlots;
        forEachVoxel(leafSlots, [&](size_t i) { out[i] = p[i]; });
        return;
    }
    phi.resize(size());
    // phi where the nodes are (the leaves around the extended ones)
    forEachVoxel(nodeSlots, [&](size_t i) {
        const double q = std::clamp(double(p[i]), 1e-6, 1.0 - 1e-6);
        phi[i] = float(std::atanh(2.0 * q - 1.0));
    });
    extend(phi, out, false, 0.f, leafSlots);
    forEachVoxel(leafSlots, [&](size_t i) {
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
    });
}

size_t ShellBand::memoryBytes() const
{
    const size_t n = size();
    const size_t stencil = mSurface ? sizeof(SurfaceTap*) + sizeof(uint8_t) : 64 * sizeof(int32_t) + sizeof(std::array<float, 12>);
    const size_t neighbours = mSurface ? 0 : 6 * sizeof(int32_t);
    return n * (sizeof(Coord) + sizeof(openvdb::Vec3s) + 3 * sizeof(float) + sizeof(FrameFloats) + sizeof(uint32_t) +
                neighbours + stencil) + mTapTotal * sizeof(SurfaceTap) + mLeafTaps.size() * sizeof(mLeafTaps[0]) +
           mLuminance.size() * sizeof(float) + mIndex.memUsage() + mMask->memUsage() +
           mLeaves.size() * (sizeof(Leaf) + 32) + mBvh.memoryBytes() +
           (mPts.size() * 2 + mTriNormal.size()) * sizeof(Vec3d) + mTris.size() * sizeof(openvdb::Vec3I);
}

} // namespace frostvdb::shell
