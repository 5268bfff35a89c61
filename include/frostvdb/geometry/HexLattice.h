#pragma once
/// @file HexLattice.h
/// @brief The one hexagonal lattice of frostvdb: axial coordinates, neighbours, ring distance,
/// D6 images, rounding and world positions. Used by the ice lattice (core/Lattice.h), the
/// snowflake automata (automata/HexLattice.h adds their array layout) and the Gravner-Griffeath
/// 3D prism lattice; the index-to-world transforms are in geometry/HexTransform.h. No OpenVDB
/// here, to keep the automata's compile times low.
///
/// Axial coordinates (q, r) (the ice code calls them (i, j)): world = h * (q + r/2, r*sqrt(3)/2);
/// a prism lattice adds z = dz * layer (+ an offset).
/// Neighbours in counter-clockwise order (direction k at 60k degrees):
///   N_k = (1,0), (0,1), (-1,1), (-1,0), (0,-1), (1,-1)
/// Second ring (Coxe-Reiter): points P_k = 2 N_k, edges E_k = N_k + N_{k+1}.
/// The ice lattice lists them in opposite pairs (kOppositePairs: N0, N3, N1, N4, N5, N2), the order
/// its stencils sum in.
///
/// D6 symmetry: the 12 symmetries of the hexagon permute cube coordinates (x, y, z) =
/// (q, -q-r, r) and may negate them. The fundamental wedge (1/12 of the lattice, the sector
/// between 0 and 30 degrees) is { 0 <= r <= q }; canonical() maps any cell onto it.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>

namespace frostvdb {
namespace hex {

struct Axial {
    int q = 0, r = 0;
    bool operator==(const Axial& o) const { return q == o.q && r == o.r; }
};

/// sqrt(3)/2, the distance between rows of cells in cell spacings (a literal: the double nearest
/// sqrt(3)/2, bit for bit std::sqrt(3.0) / 2.0). Plane (x, y) -> axial: r = y / kRowHeight,
/// q = x - r/2.
constexpr double kRowHeight = 0.8660254037844386467637231707529361834714;

/// Neighbour offsets in counter-clockwise order.
constexpr std::array<Axial, 6> kNeighbours{{{1, 0}, {0, 1}, {-1, 1}, {-1, 0}, {0, -1}, {1, -1}}};

/// The ice lattice's neighbour order: indices into kNeighbours, each direction then its opposite.
constexpr std::array<int, 6> kOppositePairs{{0, 3, 1, 4, 5, 2}};

/// Hexagonal (ring) distance from the origin.
inline int hexDistance(int q, int r)
{
    return std::max({std::abs(q), std::abs(r), std::abs(q + r)});
}

/// The image of (q, r) in the fundamental wedge { 0 <= r <= q } under D6.
inline Axial canonical(int q, int r)
{
    int a = q, b = r, c = -q - r; // cube coordinates x, z, y
    if (a < b) std::swap(a, b);
    if (b < c) std::swap(b, c);
    if (a < b) std::swap(a, b); // a >= b >= c
    if (b < 0) { const int t = a; a = -c; b = -b; c = -t; }
    return {a, b};
}

/// Position of axial (q, r) in the plane, in cell spacings.
inline std::array<double, 2> position(double q, double r)
{
    return {q + 0.5 * r, r * kRowHeight};
}

/// Nearest hexagonal cell to a fractional axial position (cube rounding).
inline Axial roundAxial(double fq, double fr)
{
    const double x = fq, z = fr, y = -x - z;
    double rx = std::round(x), ry = std::round(y), rz = std::round(z);
    const double dx = std::abs(rx - x), dy = std::abs(ry - y), dz = std::abs(rz - z);
    if (dx > dy && dx > dz) rx = -ry - rz;
    else if (dy > dz) ry = -rx - rz;
    else rz = -rx - ry;
    return {int(rx), int(rz)};
}

/// A plane position in cell spacings to the hexagonal cell that contains it.
inline Axial cellAt(double x, double y)
{
    const double r = y / kRowHeight;
    return roundAxial(x - 0.5 * r, r);
}

} // namespace hex
} // namespace frostvdb
