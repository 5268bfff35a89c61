#include <frostvdb/core/Domain.h>
#include <frostvdb/core/Error.h>

namespace frostvdb {

Domain::Domain(DomainKind kind, const Lattice& lattice, const openvdb::Coord& size, double voxelSize)
    : mKind(kind), mLattice(lattice), mVoxelSize(voxelSize)
{
    const int nz = kind == DomainKind::Plane ? 1 : size.z();
    mBBox = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(size.x() - 1, size.y() - 1, nz - 1));
    mTransform = lattice.transform(voxelSize);
    mStencil = lattice.stencil(kind == DomainKind::Box);
}

Domain Domain::fromParams(ParamDict& d)
{
    const std::string kind = d.getString("kind", "plane", {"plane", "box"},
        "plane: one voxel layer at z = 0 (2D growth); box: a 3D block of voxels");
    const std::string lattice = d.getString("lattice", "square", {"square", "hexagonal"},
        "cell lattice of the plane; hexagonal gives six-fold DLA and stencils (box domains use square)");
    const auto size = d.getFloatArray("size", {256, 256}, {2, 3}, 1, 1 << 20, "cells",
        "cells along x, y (and z for a box)");
    const double voxelSize = d.getFloat("voxel_size", 0.0001, 1e-9, 1e3, "m",
        "world size of one cell in metres (what DCC tools see)");
    const double spacing = d.getFloat("spacing", 3.0 / 64.0, 1e-4, 10.0, "",
        "dimensionless grid spacing h of the PDEs (the ice paper uses 3/64)");
    if (kind == "box" && size.size() != 3) d.fail("size", "a box domain needs [nx, ny, nz]");
    if (kind == "plane" && size.size() != 2) d.fail("size", "a plane domain needs [nx, ny]");
    if (kind == "box" && lattice != "square")
        d.fail("lattice", "box domains use the cubic (square) lattice");
    for (double s : size)
        if (s != double(int(s))) d.fail("size", "sizes must be whole numbers of cells");
    try { // OpenVDB refuses near-singular maps: say so in scene terms, not as an exception deep inside
        Lattice(Lattice::parseKind(lattice), spacing).transform(voxelSize);
    } catch (const std::exception&) {
        d.fail("voxel_size", "too small for an OpenVDB transform (it needs roughly 3e-5 m or more); scale the volume in the DCC tool instead");
    }
    const openvdb::Coord n{int(size[0]), int(size[1]), size.size() > 2 ? int(size[2]) : 1};
    return Domain(kind == "box" ? DomainKind::Box : DomainKind::Plane,
                  Lattice(Lattice::parseKind(lattice), spacing), n, voxelSize);
}

openvdb::Vec3d Domain::centre() const
{
    const auto& a = mBBox.min();
    const auto& b = mBBox.max();
    return openvdb::Vec3d(0.5 * (a.x() + b.x()), 0.5 * (a.y() + b.y()), 0.5 * (a.z() + b.z()));
}

} // namespace frostvdb
