#include <frostvdb/core/Domain.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Random.h>

#include <openvdb/tree/LeafManager.h>

#include <map>

namespace frostvdb {

namespace {
std::map<std::string, DomainInfo>& registry()
{
    static std::map<std::string, DomainInfo> r;
    return r;
}
using MaskLeaf = openvdb::MaskTree::LeafNodeType;
} // namespace

void DomainRegistry::add(DomainInfo info) { registry()[info.kind] = std::move(info); }

void DomainRegistry::remove(const std::string& kind) { registry().erase(kind); }

const DomainInfo* DomainRegistry::find(const std::string& kind)
{
    auto it = registry().find(kind);
    return it == registry().end() ? nullptr : &it->second;
}

std::vector<const DomainInfo*> DomainRegistry::all()
{
    std::vector<const DomainInfo*> v;
    for (auto& [k, info] : registry()) v.push_back(&info);
    return v;
}

DomainImpl::DomainImpl(const Lattice& lattice, const openvdb::CoordBBox& bounds, double voxelSize, bool withZ)
    : mLattice(lattice), mStencil(lattice.stencil(withZ)), mBounds(bounds), mVoxelSize(voxelSize),
      mTransform(lattice.transform(voxelSize))
{
}

void DomainImpl::clipToSupport(openvdb::MaskTree& tree) const
{
    // Leaves inside are kept, leaves outside dropped, straddling leaves masked voxel by voxel
    // (cheaper than Tree::clip for a handful of boundary leaves).
    const openvdb::CoordBBox& box = mBounds;
    std::vector<openvdb::Coord> outside;
    for (auto it = tree.cbeginLeaf(); it; ++it)
        if (!box.hasOverlap(it->getNodeBoundingBox())) outside.push_back(it->origin());
    for (const auto& o : outside) delete tree.stealNode<MaskLeaf>(o, false, false);
    openvdb::tree::LeafManager<openvdb::MaskTree> leaves(tree);
    leaves.foreach([&](MaskLeaf& leaf, size_t) {
        openvdb::CoordBBox in = leaf.getNodeBoundingBox();
        if (box.isInside(in)) return;
        // Word by word: a word is one x, its bits (y << 3 | z); a plane's leaves all straddle
        // its one-layer box, so this runs for every leaf of a plane region.
        in.intersect(box);
        const openvdb::Coord lo = in.min() - leaf.origin(), hi = in.max() - leaf.origin();
        const uint64_t zBits = ((uint64_t(2) << hi.z()) - 1) & ~((uint64_t(1) << lo.z()) - 1);
        uint64_t keep = 0;
        for (int y = lo.y(); y <= hi.y(); ++y) keep |= zBits << (8 * y);
        auto& mask = leaf.getValueMask();
        for (int x = 0; x < 8; ++x)
            mask.template getWord<uint64_t>(openvdb::Index(x)) &= (x >= lo.x() && x <= hi.x()) ? keep : 0;
    });
}

void DomainImpl::fillSupport(openvdb::MaskTree& tree) const { tree.fill(mBounds, true, true); }

std::vector<SupportSample> DomainImpl::sampleSupport(size_t n, uint64_t seed) const
{
    std::vector<SupportSample> out(n);
    const int dims = parameterDimension();
    for (size_t k = 0; k < n; ++k) {
        std::vector<double> u(static_cast<size_t>(dims));
        for (int a = 0; a < dims; ++a) u[size_t(a)] = toUnit(hashCounters(seed, k, uint64_t(a)));
        out[k].index = parameterToIndex(u);
        out[k].uv = openvdb::Vec2d(u[0], dims > 1 ? u[1] : 0.5);
        out[k].hasUv = true;
    }
    return out;
}

openvdb::Vec3d Domain::centre() const
{
    const auto& a = bbox().min();
    const auto& b = bbox().max();
    return openvdb::Vec3d(0.5 * (a.x() + b.x()), 0.5 * (a.y() + b.y()), 0.5 * (a.z() + b.z()));
}

Domain Domain::fromParams(ParamDict& d)
{
    std::vector<std::string> kinds;
    std::string doc;
    for (const auto* info : DomainRegistry::all()) {
        kinds.push_back(info->kind);
        doc += (doc.empty() ? "" : "; ") + info->kind + ": " + info->summary;
    }
    DomainCommon c;
    c.kind = d.getString("kind", "plane", kinds, doc);
    // OpenVDB refuses a transform whose cell volume is below 3e-15 (Maps.h): 1.44e-5 m on the
    // square lattice, 1.51e-5 m on the hexagonal one (volume sqrt(3)/2 voxel_size^3).
    c.voxelSize = d.getFloat("voxel_size", 0.0001, 1.6e-5, 1e3, "m",
        "world size of one cell in metres (what DCC tools see); OpenVDB's transforms need at least "
        "about 1.5e-5 m (a cell volume of 3e-15 m^3): scale smaller subjects in the DCC tool");
    c.spacing = d.getFloat("spacing", 3.0 / 64.0, 1e-4, 10.0, "",
        "dimensionless grid spacing h of the PDEs (the ice paper uses 3/64)");
    const DomainInfo* info = DomainRegistry::find(c.kind);
    if (!info) d.fail("kind", "no domain kind '" + c.kind + "'");
    return info->read(d, c);
}

} // namespace frostvdb
