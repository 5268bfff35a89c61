#pragma once
/// @file Lattice.h
/// @brief The lattice a 2D effect lives on: square or hexagonal (3D boxes add the z axis to
/// the square one). A lattice knows its neighbour offsets in index space, the finite-difference
/// stencils built from them, and its index-to-world transform. A hexagonal lattice is stored in
/// axial coordinates (i, j) on an ordinary VDB index grid with a sheared transform:
/// world = h * (i + j/2, j*sqrt(3)/2).
///
/// Stencils from the neighbour unit vectors e_k (n of them, symmetric under inversion):
///   grad u  ~ 2/(n h)   * sum_k e_k u_k            (central differences on the square lattice)
///   lap  u  ~ 4/(n h^2) * sum_k (u_k - u_0)        (5-point square, 7-point hexagonal)
/// Both are second-order accurate on each lattice (Taylor expansion; the hexagonal weights are
/// those of the ice paper's Figure 3).
#include <openvdb/openvdb.h>

#include <string>
#include <vector>

namespace frostvdb {

enum class LatticeKind { Square, Hexagonal };

/// One neighbour tap: index offset, its unit direction in the lattice plane (or z), and the
/// stencil weights it carries (already divided by h or h^2).
struct StencilTap {
    openvdb::Coord offset;
    double ex = 0, ey = 0, ez = 0; ///< unit direction
    double wGrad = 0;              ///< weight of u_k in each gradient component (times e)
    double wLap = 0;               ///< weight of u_k in the Laplacian (centre gets -sum)
};

struct Stencil {
    std::vector<StencilTap> taps;
    double wLapCentre = 0; ///< weight of u_0 in the Laplacian
    int radius = 1;        ///< index-space reach of one application
    double spacing = 1;    ///< h: distance to every neighbour
    bool hexagonal = false;
};

class Lattice {
public:
    Lattice(LatticeKind kind = LatticeKind::Square, double spacing = 1.0);

    static LatticeKind parseKind(const std::string& name); ///< "square" | "hexagonal"
    static const char* kindName(LatticeKind k);

    LatticeKind kind() const { return mKind; }
    double spacing() const { return mSpacing; } ///< simulation (dimensionless) cell spacing h
    /// In-plane neighbour offsets: 4 (square) or 6 (hexagonal).
    const std::vector<openvdb::Coord>& planeNeighbours() const { return mNeighbours; }

    /// The stencil over the plane, or over the plane plus z when @a withZ (3D box domains).
    Stencil stencil(bool withZ) const;

    /// Position of cell (i, j) in the lattice plane, in units of the cell spacing.
    openvdb::Vec2d planePosition(double i, double j) const;
    /// Index-to-world transform for a world cell size (metres): uniform scale for square, sheared
    /// for hexagonal (z keeps the plain voxel size).
    openvdb::math::Transform::Ptr transform(double voxelSize) const;

private:
    LatticeKind mKind;
    double mSpacing;
    std::vector<openvdb::Coord> mNeighbours;
};

} // namespace frostvdb
