/// @file TriangleBvh.cpp
#include <frostvdb/geometry/TriangleBvh.h>

#include <frostvdb/geometry/Triangle.h>

#include <algorithm>
#include <limits>
#include <numeric>

namespace frostvdb::geometry {

using openvdb::BBoxd;
using openvdb::Vec3d;

namespace {

/// Squared distance from @a p to box @a b (0 inside).
double boxDistanceSqr(const Vec3d& p, const BBoxd& b)
{
    double d = 0;
    for (int a = 0; a < 3; ++a) {
        const double e = std::max({b.min()[a] - p[a], 0.0, p[a] - b.max()[a]});
        d += e * e;
    }
    return d;
}

bool overlaps(const BBoxd& a, const BBoxd& b)
{
    for (int k = 0; k < 3; ++k)
        if (a.max()[k] < b.min()[k] || b.max()[k] < a.min()[k]) return false;
    return true;
}

} // namespace

TriangleBvh::TriangleBvh(const std::vector<Vec3d>& points, const std::vector<openvdb::Vec3I>& triangles)
    : mPoints(&points), mTriangles(&triangles)
{
    const uint32_t n = uint32_t(triangles.size());
    mBoxes.resize(n);
    std::vector<Vec3d> centres(n);
    for (uint32_t t = 0; t < n; ++t) {
        BBoxd b(points[triangles[t][0]], points[triangles[t][0]]);
        b.expand(points[triangles[t][1]]);
        b.expand(points[triangles[t][2]]);
        mBoxes[t] = b;
        centres[t] = b.getCenter();
    }
    mOrder.resize(n);
    std::iota(mOrder.begin(), mOrder.end(), 0u);
    if (n) buildNode(mOrder, 0, n, mBoxes, centres);
}

int32_t TriangleBvh::buildNode(std::vector<uint32_t>& order, uint32_t first, uint32_t count, std::vector<BBoxd>& boxes,
                               std::vector<Vec3d>& centres)
{
    const int32_t id = int32_t(mNodes.size());
    mNodes.emplace_back();
    BBoxd box = boxes[order[first]];
    for (uint32_t k = first + 1; k < first + count; ++k) box.expand(boxes[order[k]]);
    mNodes[size_t(id)].box = box;
    if (count <= 4) {
        mNodes[size_t(id)].first = first;
        mNodes[size_t(id)].count = count;
        return id;
    }
    // median split of the centres along the box's longest axis (ties by index: deterministic)
    const Vec3d ext = box.extents();
    const int a = ext[0] >= ext[1] && ext[0] >= ext[2] ? 0 : (ext[1] >= ext[2] ? 1 : 2);
    const uint32_t half = count / 2;
    std::nth_element(order.begin() + first, order.begin() + first + half, order.begin() + first + count,
                     [&](uint32_t l, uint32_t r) {
                         return centres[l][a] < centres[r][a] || (centres[l][a] == centres[r][a] && l < r);
                     });
    const int32_t left = buildNode(order, first, half, boxes, centres);
    const int32_t right = buildNode(order, first + half, count - half, boxes, centres);
    mNodes[size_t(id)].left = left;
    mNodes[size_t(id)].right = right;
    return id;
}

void TriangleBvh::query(const BBoxd& box, std::vector<uint32_t>& out) const
{
    out.clear();
    if (mNodes.empty()) return;
    int32_t stack[128];
    int top = 0;
    stack[top++] = 0;
    while (top) {
        const Node& n = mNodes[size_t(stack[--top])];
        if (!overlaps(n.box, box)) continue;
        if (n.left < 0) {
            for (uint32_t k = n.first; k < n.first + n.count; ++k)
                if (overlaps(mBoxes[mOrder[k]], box)) out.push_back(mOrder[k]);
            continue;
        }
        stack[top++] = n.left;
        stack[top++] = n.right;
    }
    std::sort(out.begin(), out.end());
}

bool TriangleBvh::closestPointWithin(const Vec3d& p, double maxDistSqr, Vec3d& out, uint32_t& tri, double& distSqr) const
{
    double best = maxDistSqr;
    bool found = false;
    if (mNodes.empty()) return false;
    int32_t stack[128];
    int top = 0;
    stack[top++] = 0;
    while (top) {
        const Node& n = mNodes[size_t(stack[--top])];
        if (boxDistanceSqr(p, n.box) > best) continue;
        if (n.left < 0) {
            for (uint32_t k = n.first; k < n.first + n.count; ++k) {
                const uint32_t t = mOrder[k];
                if (boxDistanceSqr(p, mBoxes[t]) > best) continue;
                const auto& f = (*mTriangles)[t];
                const Vec3d q =
                    geometry::closestPointOnTriangle(p, (*mPoints)[f[0]], (*mPoints)[f[1]], (*mPoints)[f[2]]);
                const double d = (q - p).lengthSqr();
                // the lowest triangle index wins ties, whatever order the nodes are visited in
                if (d < best || (d == best && (!found || t < tri))) { best = d; tri = t; out = q; found = true; }
            }
            continue;
        }
        // nearer child last, so it is searched first
        const double dl = boxDistanceSqr(p, mNodes[size_t(n.left)].box), dr = boxDistanceSqr(p, mNodes[size_t(n.right)].box);
        if (dl <= dr) { stack[top++] = n.right; stack[top++] = n.left; }
        else { stack[top++] = n.left; stack[top++] = n.right; }
    }
    distSqr = best;
    return found;
}

bool TriangleBvh::closestPointAmong(const std::vector<uint32_t>& candidates, const Vec3d& p, double maxDistSqr,
                                    Vec3d& out, uint32_t& tri, double& distSqr) const
{
    // closestPointWithin's leaf loop over the candidates: its answer is the least (distance,
    // index) within reach, whatever the order the triangles are tried in
    double best = maxDistSqr;
    bool found = false;
    for (const uint32_t t : candidates) {
        if (boxDistanceSqr(p, mBoxes[t]) > best) continue;
        const auto& f = (*mTriangles)[t];
        const Vec3d q = geometry::closestPointOnTriangle(p, (*mPoints)[f[0]], (*mPoints)[f[1]], (*mPoints)[f[2]]);
        const double d = (q - p).lengthSqr();
        if (d < best || (d == best && (!found || t < tri))) { best = d; tri = t; out = q; found = true; }
    }
    distSqr = best;
    return found;
}

Vec3d TriangleBvh::closestPoint(const Vec3d& p, uint32_t* tri) const
{
    Vec3d out = p;
    uint32_t t = 0;
    double d = 0;
    closestPointWithin(p, std::numeric_limits<double>::max(), out, t, d);
    if (tri) *tri = t;
    return out;
}

size_t TriangleBvh::memoryBytes() const
{
    return mNodes.size() * sizeof(Node) + mOrder.size() * sizeof(uint32_t) + mBoxes.size() * sizeof(BBoxd);
}

} // namespace frostvdb::geometry
