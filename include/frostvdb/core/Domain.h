#pragma once
/// @file Domain.h
/// @brief Where effects live: a plane one voxel thick (z = 0), or a 3D box. The domain supplies
/// the operators (the stencil over its lattice) and its support (which voxels belong to it), so
/// effects never assume a flat grid; a thin shell around a mesh is a further Domain kind with a
/// narrow-band support.
#include <frostvdb/core/Lattice.h>
#include <frostvdb/core/Params.h>

#include <openvdb/openvdb.h>

namespace frostvdb {

enum class DomainKind { Plane, Box };

class Domain {
public:
    Domain() = default;
    Domain(DomainKind kind, const Lattice& lattice, const openvdb::Coord& size, double voxelSize);

    /// Reads the [domain] section (kind, lattice, size, voxel_size, spacing).
    static Domain fromParams(ParamDict& dict);

    DomainKind kind() const { return mKind; }
    bool isPlane() const { return mKind == DomainKind::Plane; }
    int dimension() const { return isPlane() ? 2 : 3; }
    const Lattice& lattice() const { return mLattice; }
    /// Inclusive index bounding box, starting at (0,0,0); z is [0,0] for a plane.
    const openvdb::CoordBBox& bbox() const { return mBBox; }
    double voxelSize() const { return mVoxelSize; } ///< world metres per cell
    openvdb::math::Transform::Ptr transform() const { return mTransform; }
    /// The finite-difference operators of this domain.
    const Stencil& stencil() const { return mStencil; }
    uint64_t voxelCount() const { return mBBox.volume(); }

    bool contains(const openvdb::Coord& c) const { return mBBox.isInside(c); }
    /// Index-space centre of the domain (cell centre, may be fractional).
    openvdb::Vec3d centre() const;

private:
    DomainKind mKind = DomainKind::Plane;
    Lattice mLattice;
    openvdb::CoordBBox mBBox;
    double mVoxelSize = 1.0;
    openvdb::math::Transform::Ptr mTransform;
    Stencil mStencil;
};

} // namespace frostvdb
