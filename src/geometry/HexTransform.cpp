/// @file HexTransform.cpp
/// @brief The hexagonal lattice's transforms (see HexTransform.h).
#include <frostvdb/geometry/HexTransform.h>
#include <frostvdb/geometry/HexLattice.h>

#include <cmath>

namespace frostvdb {
namespace hex {

openvdb::math::Transform::Ptr prismTransform(double h, double dz, double z0)
{
    openvdb::Mat4d m = openvdb::Mat4d::identity();
    m[0][0] = h;
    m[1][0] = 0.5 * h;
    m[1][1] = kRowHeight * h;
    m[2][2] = dz;
    m[3][2] = z0;
    return openvdb::math::Transform::createLinearTransform(m);
}

} // namespace hex
} // namespace frostvdb
