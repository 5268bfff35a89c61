#include "BlockDomain.h"

#include <frostvdb/core/Error.h>

#include <algorithm>
#include <cmath>

namespace frostvdb {
namespace domains {

BlockKeys readBlockKeys(ParamDict& d, const DomainCommon& c, size_t dims)
{
    const bool box = dims == 3;
    const std::string lattice = d.getString("lattice", "square", {"square", "hexagonal"},
        "cell lattice of the plane; hexagonal gives six-fold DLA and stencils (box domains use square)");
    const auto size = d.getFloatArray("size", {256, 256},
        {2, 3}, 1, 1 << 20, "cells", "cells along x, y (and z for a box)");
    const auto origin = d.getFloatArray("origin", {0, 0, 0}, {2, 3}, -1e6, 1e6, "m",
        "world position of the first cell's centre [x, y(, z)] (x, y snapped to the nearest cell; a plane lies exactly at height z)");
    if (box && size.size() != 3) d.fail("size", "a box domain needs [nx, ny, nz]");
    if (!box && size.size() != 2) d.fail("size", "a plane domain needs [nx, ny]");
    if (box && lattice != "square") d.fail("lattice", "box domains use the cubic (square) lattice");
    for (double s : size)
        if (s != double(int(s))) d.fail("size", "sizes must be whole numbers of cells");
    BlockKeys k;
    k.lattice = Lattice(Lattice::parseKind(lattice), c.spacing);
    openvdb::math::Transform::Ptr xf;
    try { // OpenVDB refuses near-singular maps: say so in scene terms, not as an exception deep inside
        xf = k.lattice.transform(c.voxelSize);
    } catch (const std::exception&) {
        d.fail("voxel_size", "too small for an OpenVDB transform (it needs a cell volume of at least 3e-15 m^3, about 1.5e-5 m); scale the volume in the DCC tool instead");
    }
    k.size = openvdb::Coord(int(size[0]), int(size[1]), box ? int(size[2]) : 1);
    const openvdb::Vec3d o(origin[0], origin[1], origin.size() > 2 ? origin[2] : 0.0);
    k.worldZ = o.z();
    const openvdb::Vec3d idx = xf->worldToIndex(o);
    k.origin = openvdb::Coord(int(std::lround(idx.x())), int(std::lround(idx.y())), int(std::lround(idx.z())));
    const openvdb::Coord hi = k.origin + k.size;
    for (int a = 0; a < 3; ++a)
        if (std::abs(int64_t(k.origin[a])) > (1 << 28) || std::abs(int64_t(hi[a])) > (1 << 28))
            d.fail("origin", "places the domain beyond +-2^28 cells of the world origin");
    return k;
}

openvdb::Vec3d blockParameterToIndex(const openvdb::CoordBBox& bb, const std::vector<double>& u)
{
    const openvdb::Vec3d lo = bb.min().asVec3d(), span = (bb.max() - bb.min()).asVec3d();
    openvdb::Vec3d p;
    for (int a = 0; a < 3; ++a) p[a] = lo[a] + (size_t(a) < u.size() ? u[size_t(a)] : 0.5) * span[a];
    return p;
}

void forEachFaceVoxel(const openvdb::CoordBBox& bb, const std::string& name, int width,
                      const std::function<void(const openvdb::Coord&)>& fn)
{
    int axis = -1;
    bool low = true;
    if (name == "left") axis = 0;
    else if (name == "right") { axis = 0; low = false; }
    else if (name == "bottom") axis = 1;
    else if (name == "top") { axis = 1; low = false; }
    else if (name == "front") axis = 2;
    else if (name == "back") { axis = 2; low = false; }
    if (axis < 0) throw std::invalid_argument("no boundary part '" + name + "'");
    const int n = std::max(1, width);
    openvdb::Coord a = bb.min(), b = bb.max();
    if (low) b[axis] = std::min(bb.max()[axis], bb.min()[axis] + n - 1);
    else a[axis] = std::max(bb.min()[axis], bb.max()[axis] - n + 1);
    const openvdb::CoordBBox band(a, b);
    for (auto it = band.begin(); it; ++it) fn(*it);
}

} // namespace domains
} // namespace frostvdb
