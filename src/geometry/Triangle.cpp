/// @file Triangle.cpp
#include <frostvdb/geometry/Triangle.h>

#include <cmath>

namespace frostvdb::geometry {

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

} // namespace frostvdb::geometry
