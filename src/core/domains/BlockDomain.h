#pragma once
/// @file BlockDomain.h
/// @brief What the plane and the box share: a block of lattice cells placed anywhere in index
/// space, and the keys that describe it (`lattice`, `size`, `origin`).
#include <frostvdb/core/Domain.h>

namespace frostvdb {
namespace domains {

struct BlockKeys {
    Lattice lattice;
    openvdb::Coord size;   ///< cells along x, y, z (z = 1 for a plane)
    openvdb::Coord origin; ///< index of the first cell
    double worldZ = 0.0;   ///< the origin's z in metres (a plane's height)
};

/// Reads `lattice`, `size` (@a dims entries) and `origin` (metres, snapped to a cell).
BlockKeys readBlockKeys(ParamDict& d, const DomainCommon& c, size_t dims);

/// Bounds of @a size cells starting at @a origin.
inline openvdb::CoordBBox blockBounds(const openvdb::Coord& origin, const openvdb::Coord& size)
{
    return openvdb::CoordBBox(origin, origin + size - openvdb::Coord(1));
}

/// Index position of fractions of @a bb (missing trailing components: 0.5).
openvdb::Vec3d blockParameterToIndex(const openvdb::CoordBBox& bb, const std::vector<double>& u);

/// The named faces of a block: left/right (x), bottom/top (y), front/back (z, boxes only); calls
/// @a fn for the cells of a band @a width thick along face @a name.
void forEachFaceVoxel(const openvdb::CoordBBox& bb, const std::string& name, int width,
                      const std::function<void(const openvdb::Coord&)>& fn);

} // namespace domains
} // namespace frostvdb
