#include <frostvdb/core/Lattice.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/geometry/HexLattice.h>
#include <frostvdb/geometry/HexTransform.h>

#include <cmath>

namespace frostvdb {

Lattice::Lattice(LatticeKind kind, double spacing) : mKind(kind), mSpacing(spacing)
{
    using openvdb::Coord;
    if (kind == LatticeKind::Square)
        mNeighbours = {Coord(1, 0, 0), Coord(-1, 0, 0), Coord(0, 1, 0), Coord(0, -1, 0)};
    else // the one hexagonal lattice's neighbours, in opposite pairs
        for (int k : hex::kOppositePairs) mNeighbours.emplace_back(hex::kNeighbours[size_t(k)].q, hex::kNeighbours[size_t(k)].r, 0);
}

LatticeKind Lattice::parseKind(const std::string& name)
{
    if (name == "square") return LatticeKind::Square;
    if (name == "hexagonal") return LatticeKind::Hexagonal;
    throw SceneError("unknown lattice '" + name + "' (allowed: square | hexagonal)");
}

const char* Lattice::kindName(LatticeKind k)
{
    return k == LatticeKind::Square ? "square" : "hexagonal";
}

openvdb::Vec2d Lattice::planePosition(double i, double j) const
{
    if (mKind == LatticeKind::Square) return {i, j};
    const auto p = hex::position(i, j);
    return {p[0], p[1]};
}

Stencil Lattice::stencil(bool withZ) const
{
    Stencil s;
    const double h = mSpacing;
    const double n = double(mNeighbours.size());
    for (const auto& c : mNeighbours) {
        const openvdb::Vec2d p = planePosition(c.x(), c.y()); // unit length by construction
        StencilTap t;
        t.offset = c;
        t.ex = p.x();
        t.ey = p.y();
        t.wGrad = 2.0 / (n * h);
        t.wLap = 4.0 / (n * h * h);
        s.taps.push_back(t);
        s.wLapCentre -= t.wLap;
    }
    if (withZ) {
        for (int dz : {1, -1}) {
            StencilTap t;
            t.offset = openvdb::Coord(0, 0, dz);
            t.ez = dz;
            t.wGrad = 1.0 / (2.0 * h);
            t.wLap = 1.0 / (h * h);
            s.taps.push_back(t);
            s.wLapCentre -= t.wLap;
        }
    }
    s.radius = 1;
    s.spacing = h;
    s.hexagonal = mKind == LatticeKind::Hexagonal;
    return s;
}

openvdb::math::Transform::Ptr Lattice::transform(double voxelSize) const
{
    if (mKind == LatticeKind::Hexagonal) return hex::prismTransform(voxelSize, voxelSize); // sheared plane
    openvdb::Mat4d m = openvdb::Mat4d::identity();
    m.setToScale(openvdb::Vec3d(voxelSize));
    return openvdb::math::Transform::createLinearTransform(m);
}

} // namespace frostvdb
