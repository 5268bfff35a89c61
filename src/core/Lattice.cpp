#include <frostvdb/core/Lattice.h>
#include <frostvdb/core/Error.h>

#include <cmath>

namespace frostvdb {

Lattice::Lattice(LatticeKind kind, double spacing) : mKind(kind), mSpacing(spacing)
{
    using openvdb::Coord;
    if (kind == LatticeKind::Square)
        mNeighbours = {Coord(1, 0, 0), Coord(-1, 0, 0), Coord(0, 1, 0), Coord(0, -1, 0)};
    else
        mNeighbours = {Coord(1, 0, 0),  Coord(-1, 0, 0), Coord(0, 1, 0),
                       Coord(0, -1, 0), Coord(1, -1, 0), Coord(-1, 1, 0)};
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
    return {i + 0.5 * j, j * std::sqrt(3.0) / 2.0};
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
    openvdb::Mat4d m = openvdb::Mat4d::identity();
    if (mKind == LatticeKind::Square) {
        m.setToScale(openvdb::Vec3d(voxelSize));
    } else {
        // Row-vector convention (OpenVDB): world = index * M. Axial (i, j) -> (i + j/2, j*sqrt3/2).
        m[0][0] = voxelSize;
        m[1][0] = 0.5 * voxelSize;
        m[1][1] = std::sqrt(3.0) / 2.0 * voxelSize;
        m[2][2] = voxelSize;
    }
    return openvdb::math::Transform::createLinearTransform(m);
}

} // namespace frostvdb
