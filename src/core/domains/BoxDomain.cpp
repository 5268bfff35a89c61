/// @file BoxDomain.cpp
/// @brief `[domain] kind = "box"`: a 3D block of cubic cells. No frame (a volume has no normal).
#include "BlockDomain.h"

namespace frostvdb {
namespace {

class BoxDomain : public DomainImpl {
public:
    BoxDomain(const Lattice& lattice, const openvdb::CoordBBox& bounds, double voxelSize)
        : DomainImpl(lattice, bounds, voxelSize, /*withZ=*/true) {}

    std::string kind() const override { return "box"; }
    bool flat() const override { return false; }
    int intrinsicDimension() const override { return 3; }
    std::vector<openvdb::Coord> walkerNeighbours() const override
    {
        auto n = mLattice.planeNeighbours();
        n.push_back(openvdb::Coord(0, 0, 1));
        n.push_back(openvdb::Coord(0, 0, -1));
        return n;
    }
    int parameterDimension() const override { return 3; }
    openvdb::Vec3d parameterToIndex(const std::vector<double>& u) const override
    {
        return domains::blockParameterToIndex(mBounds, u);
    }
    std::vector<std::string> boundaryNames() const override
    {
        return {"left", "right", "bottom", "top", "front", "back"};
    }
    void forEachBoundaryVoxel(const std::string& name, int width,
                              const std::function<void(const openvdb::Coord&)>& fn) const override
    {
        domains::forEachFaceVoxel(mBounds, name, width, fn);
    }
};

Domain readBox(ParamDict& d, const DomainCommon& c)
{
    const domains::BlockKeys k = domains::readBlockKeys(d, c, 3);
    return makeBoxDomain(k.lattice, k.size, c.voxelSize, k.origin);
}

} // namespace

Domain makeBoxDomain(const Lattice& lattice, const openvdb::Coord& size, double voxelSize, const openvdb::Coord& origin)
{
    return Domain(std::make_shared<BoxDomain>(lattice, domains::blockBounds(origin, size), voxelSize));
}

FROSTVDB_REGISTER_DOMAIN(box, "box", "a 3D block of voxels", readBox);

} // namespace frostvdb
