/// @file PlaneDomain.cpp
/// @brief `[domain] kind = "plane"`: one layer of square or hexagonal cells at a fixed z, for 2D
/// growth (the ice paper's setting). Its frame is the world axes (normal +z).
#include "BlockDomain.h"

namespace frostvdb {
namespace {

class PlaneDomain : public DomainImpl {
public:
    /// The layer is index z = 0 (the flat kernels keep one z slice per leaf, at the leaf's
    /// origin); its world height @a worldZ goes into the transform.
    PlaneDomain(const Lattice& lattice, const openvdb::CoordBBox& bounds, double voxelSize, double worldZ)
        : DomainImpl(lattice, bounds, voxelSize, /*withZ=*/false)
    {
        if (worldZ != 0.0) mTransform->postTranslate(openvdb::Vec3d(0.0, 0.0, worldZ));
    }

    std::string kind() const override { return "plane"; }
    bool flat() const override { return true; }
    int intrinsicDimension() const override { return 2; }
    std::vector<openvdb::Coord> walkerNeighbours() const override { return mLattice.planeNeighbours(); }
    bool hasFrame() const override { return true; }
    VoxelFrame frame(const openvdb::Coord&) const override { return {}; }
    int parameterDimension() const override { return 2; }
    openvdb::Vec3d parameterToIndex(const std::vector<double>& u) const override
    {
        openvdb::Vec3d p = domains::blockParameterToIndex(mBounds, u);
        p.z() = mBounds.min().z(); // the plane's layer, whatever a third fraction says
        return p;
    }
    std::vector<std::string> boundaryNames() const override { return {"left", "right", "bottom", "top"}; }
    void forEachBoundaryVoxel(const std::string& name, int width,
                              const std::function<void(const openvdb::Coord&)>& fn) const override
    {
        domains::forEachFaceVoxel(mBounds, name, width, fn);
    }
};

Domain readPlane(ParamDict& d, const DomainCommon& c)
{
    const domains::BlockKeys k = domains::readBlockKeys(d, c, 2);
    const openvdb::Coord n(k.size.x(), k.size.y(), 1), o(k.origin.x(), k.origin.y(), 0);
    return Domain(std::make_shared<PlaneDomain>(k.lattice, domains::blockBounds(o, n), c.voxelSize, k.worldZ));
}

} // namespace

Domain makePlaneDomain(const Lattice& lattice, const openvdb::Coord& size, double voxelSize, const openvdb::Coord& origin)
{
    // index z stays 0 (see PlaneDomain); origin.z() places the layer at that many cells of height
    const openvdb::Coord n(size.x(), size.y(), 1);
    const openvdb::Coord o(origin.x(), origin.y(), 0);
    return Domain(std::make_shared<PlaneDomain>(lattice, domains::blockBounds(o, n), voxelSize, origin.z() * voxelSize));
}

FROSTVDB_REGISTER_DOMAIN(plane, "plane", "one voxel layer (2D growth)", readPlane);

} // namespace frostvdb
