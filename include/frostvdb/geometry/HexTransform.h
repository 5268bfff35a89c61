#pragma once
/// @file HexTransform.h
/// @brief Index-to-world transforms of the hexagonal lattice (geometry/HexLattice.h): the sheared
/// plane and the prism lattice, defined once for the ice lattice, the automata and GG-3D.
#include <openvdb/math/Transform.h>

namespace frostvdb {
namespace hex {

/// world = (h (q + r/2), h r sqrt(3)/2, dz layer + z0) for index (q, r, layer). OpenVDB's
/// row-vector convention: world = index * M.
openvdb::math::Transform::Ptr prismTransform(double h, double dz, double z0 = 0.0);

} // namespace hex
} // namespace frostvdb
