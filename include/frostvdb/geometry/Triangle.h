#pragma once
/// @file Triangle.h
/// @brief Exact triangle geometry shared by the mesh users (dla3d's constraint surface, the
/// shell band): closest point on a triangle and segment-triangle intersection.
#include <openvdb/openvdb.h>

namespace frostvdb::geometry {

/// True when the segment @a a -> @a b meets the triangle (@a t0, @a t1, @a t2); touching counts
/// (Moller-Trumbore; a segment parallel to the triangle's plane does not hit).
bool segmentHitsTriangle(const openvdb::Vec3d& a, const openvdb::Vec3d& b, const openvdb::Vec3d& t0,
                         const openvdb::Vec3d& t1, const openvdb::Vec3d& t2);
/// The point of the triangle (@a a, @a b, @a c) closest to @a p (Ericson, Real-Time Collision
/// Detection 5.1.5).
openvdb::Vec3d closestPointOnTriangle(const openvdb::Vec3d& p, const openvdb::Vec3d& a, const openvdb::Vec3d& b,
                                      const openvdb::Vec3d& c);

} // namespace frostvdb::geometry
