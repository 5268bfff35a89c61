#pragma once
/// @file Domain.h
/// @brief Where effects live, as an interface. A domain supplies its support (the voxels that
/// belong to it; the active region is clipped to it), its lattice with the stencils and
/// neighbourhoods over it, per-voxel geometry where it has one (normal, tangent frame), its world
/// placement (the index bounds need not start at 0), a parameterisation for seeds and maps, named
/// border parts, and the name of its discretisation.
///
/// Effects see only this interface; none of them asks which kind of domain it is. An effect whose
/// numerics differ by discretisation (the phase field, the walkers) asks a registry for the back
/// end registered under discretisation() (ice/PhaseFieldBackend.h, ice/DlaBackend.h).
/// Three kinds are built in:
/// - `plane` (src/core/domains/PlaneDomain.cpp) and `box` (BoxDomain.cpp): discretisation
///   "lattice", the regular grid every effect runs on;
/// - `shell` (src/core/domains/ShellDomain.cpp): a layer of voxels around a mesh, discretisation
///   "surface" (surface nodes) or "closest_point" (the thick band), with its own back ends in
///   src/shell.
/// Adding a kind is one implementation file:
/// @code
///   class MyDomain : public DomainImpl { ... };            // the interface below
///   static Domain readMine(ParamDict& d, const DomainCommon& c) { ... return Domain(impl); }
///   FROSTVDB_REGISTER_DOMAIN(mine, "mine", "what it is", readMine);
/// @endcode
/// `[domain] kind = "mine"` then selects it; its keys are read by its reader and listed in
/// docs/scene-reference.md. A kind with discretisation "lattice" runs every effect unchanged
/// (tests/domain_test.cpp adds one); a new discretisation registers its back ends beside it.
///
/// The border: the support's edge (a plane's four sides, a box's six faces, an open mesh's
/// rim), named by boundaryNames(); effects grow edge bands from it and walkers may leave there.
///
/// A Domain is a cheap, copyable handle to a DomainImpl shared by every effect. What it answers
/// through this interface (support, frames, parameterisation, border) is fixed at construction.
/// A shell's band is built lazily, leaf by leaf, as its back ends ask (the surface the support
/// describes does not change; only how much of it is held in memory does).
#include <frostvdb/core/Lattice.h>
#include <frostvdb/core/Params.h>

#include <openvdb/openvdb.h>

#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace frostvdb {

/// Per-voxel geometry of a domain that has a surface: a right-handed orthonormal frame
/// (tangent, bitangent, normal) in world space. The phase field's anisotropy angle is measured in
/// it; walkers on a surface step in its tangent plane.
struct VoxelFrame {
    openvdb::Vec3d tangent{1, 0, 0};
    openvdb::Vec3d bitangent{0, 1, 0};
    openvdb::Vec3d normal{0, 0, 1};
};

/// A point of the support drawn by DomainImpl::sampleSupport (scatter seeds).
struct SupportSample {
    openvdb::Vec3d index{0.0};   ///< index-space position (on the surface for a shell)
    openvdb::Vec2d uv{0.5, 0.5}; ///< texture coordinates: a plane's fractions (x, y), a mesh's UVs
    bool hasUv = false;          ///< false on a mesh without UVs
    float colour = -1.f;         ///< the mesh's vertex-colour luminance there (-1: none)
};

/// The interface a domain kind implements. The data every domain has (lattice, stencil, index
/// bounds, transform) lives in the base so the hot accessors are not virtual.
class DomainImpl {
public:
    virtual ~DomainImpl() = default;

    /// The `[domain] kind` this implementation was registered under ("plane", "box", ...).
    virtual std::string kind() const = 0;

    // ---- support ---------------------------------------------------------------------------
    /// True when voxel @a c belongs to the domain. Default: inside the index bounds.
    virtual bool contains(const openvdb::Coord& c) const { return mBounds.isInside(c); }
    /// Number of member voxels. Default: the bounds' volume.
    virtual uint64_t voxelCount() const { return mBounds.volume(); }
    /// Removes from @a mask every voxel outside the support (the active region's clip). Default:
    /// a clip to the bounds (whole leaves dropped or kept, straddling leaves voxel by voxel).
    virtual void clipToSupport(openvdb::MaskTree& mask) const;
    /// Activates every member voxel in @a mask (dense reference mode). Default: the bounds.
    virtual void fillSupport(openvdb::MaskTree& mask) const;

    // ---- lattice, stencils, neighbourhoods ----------------------------------------------------
    /// True when support and stencil stay in one z layer: kernels may then use 2D blocks, planar
    /// dilation and (x, y) leaf slots. A property of the support, not of a kind.
    virtual bool flat() const = 0;
    /// Intrinsic dimension: 2 for a plane or a surface shell, 3 for a volume.
    virtual int intrinsicDimension() const = 0;
    /// Walker (DLA) neighbourhood in index space: the lattice's plane neighbours, plus +-z for
    /// a volume.
    virtual std::vector<openvdb::Coord> walkerNeighbours() const = 0;

    // ---- per-voxel geometry ----------------------------------------------------------------
    /// True when frame() is meaningful (planes and shells; a volume has no normal).
    virtual bool hasFrame() const { return false; }
    /// The frame at voxel @a c (world space). Default: the world axes.
    virtual VoxelFrame frame(const openvdb::Coord& c) const { (void)c; return {}; }

    // ---- parameterisation, boundaries ----------------------------------------------------------
    /// Number of parameters of a position given as fractions (2 on a plane, 3 in a box; a shell
    /// with UVs: 2). Arrays of this length (or, where noted, shorter) place seeds.
    virtual int parameterDimension() const = 0;
    /// Index-space position of fractions @a u (missing trailing components: 0.5).
    virtual openvdb::Vec3d parameterToIndex(const std::vector<double>& u) const = 0;
    /// Names of the border parts edge bands can be grown from ("left", ..., "front", "back";
    /// a shell: "rim").
    virtual std::vector<std::string> boundaryNames() const = 0;
    /// Calls @a fn for every member voxel within @a width cells of boundary part @a name.
    virtual void forEachBoundaryVoxel(const std::string& name, int width,
                                      const std::function<void(const openvdb::Coord&)>& fn) const = 0;

    /// @a n points spread uniformly over the support (by area on a surface or a plane, by volume
    /// in a box), the k-th drawn from hashCounters(@a seed, k), so the same whatever the thread
    /// count. Default: uniform fractions through parameterToIndex, uv = the first two fractions.
    virtual std::vector<SupportSample> sampleSupport(size_t n, uint64_t seed) const;

    // ---- discretisation --------------------------------------------------------------------------
    /// The numerics effects pick their back end by: "lattice" (the regular grid of lattice() and
    /// stencil(); planes, boxes) unless the kind overrides it ("surface", "closest_point").
    virtual std::string discretisation() const { return "lattice"; }

    // ---- common data ---------------------------------------------------------------------------
    const Lattice& lattice() const { return mLattice; }
    const Stencil& stencil() const { return mStencil; }
    const openvdb::CoordBBox& bounds() const { return mBounds; }
    double voxelSize() const { return mVoxelSize; }
    openvdb::math::Transform::Ptr transform() const { return mTransform; }

protected:
    /// @a withZ: the stencil also reaches +-z (volumes and shells).
    DomainImpl(const Lattice& lattice, const openvdb::CoordBBox& bounds, double voxelSize, bool withZ);

    Lattice mLattice;
    Stencil mStencil;
    openvdb::CoordBBox mBounds;
    double mVoxelSize = 1.0;
    openvdb::math::Transform::Ptr mTransform;
};

/// What every [domain] shares, read before the kind's own keys.
struct DomainCommon {
    std::string kind;
    double voxelSize = 1e-4; ///< metres per cell
    double spacing = 3.0 / 64.0; ///< dimensionless PDE spacing h
};

/// The handle effects hold: forwards to the implementation.
class Domain {
public:
    Domain() = default;
    explicit Domain(std::shared_ptr<const DomainImpl> impl) : mImpl(std::move(impl)) {}

    /// Reads the [domain] section: `kind` picks a registered implementation, which reads the
    /// rest of the keys.
    static Domain fromParams(ParamDict& dict);

    explicit operator bool() const { return bool(mImpl); }
    const DomainImpl& impl() const { return *mImpl; }

    std::string kind() const { return mImpl->kind(); }
    bool flat() const { return mImpl->flat(); }
    /// Index axes the fields vary along: 2 when flat, else 3.
    int dimension() const { return flat() ? 2 : 3; }
    int intrinsicDimension() const { return mImpl->intrinsicDimension(); }
    const Lattice& lattice() const { return mImpl->lattice(); }
    /// Inclusive index bounds of the support (anywhere in index space; z is one layer when flat).
    const openvdb::CoordBBox& bbox() const { return mImpl->bounds(); }
    double voxelSize() const { return mImpl->voxelSize(); } ///< world metres per cell
    openvdb::math::Transform::Ptr transform() const { return mImpl->transform(); }
    /// The finite-difference operators of this domain.
    const Stencil& stencil() const { return mImpl->stencil(); }
    uint64_t voxelCount() const { return mImpl->voxelCount(); }
    bool contains(const openvdb::Coord& c) const { return mImpl->contains(c); }
    void clipToSupport(openvdb::MaskTree& m) const { mImpl->clipToSupport(m); }
    void fillSupport(openvdb::MaskTree& m) const { mImpl->fillSupport(m); }
    std::vector<openvdb::Coord> walkerNeighbours() const { return mImpl->walkerNeighbours(); }
    bool hasFrame() const { return mImpl->hasFrame(); }
    VoxelFrame frame(const openvdb::Coord& c) const { return mImpl->frame(c); }
    int parameterDimension() const { return mImpl->parameterDimension(); }
    openvdb::Vec3d parameterToIndex(const std::vector<double>& u) const { return mImpl->parameterToIndex(u); }
    /// Index-space position of a world position (metres).
    openvdb::Vec3d worldToIndex(const openvdb::Vec3d& w) const { return transform()->worldToIndex(w); }
    std::vector<std::string> boundaryNames() const { return mImpl->boundaryNames(); }
    void forEachBoundaryVoxel(const std::string& name, int width,
                              const std::function<void(const openvdb::Coord&)>& fn) const
    { mImpl->forEachBoundaryVoxel(name, width, fn); }
    std::vector<SupportSample> sampleSupport(size_t n, uint64_t seed) const { return mImpl->sampleSupport(n, seed); }
    std::string discretisation() const { return mImpl->discretisation(); }
    /// Index-space centre of the bounds (cell centre, may be fractional).
    openvdb::Vec3d centre() const;

private:
    std::shared_ptr<const DomainImpl> mImpl;
};

/// Reads a kind's own keys (after `kind`, `voxel_size` and `spacing`) and builds the domain.
/// With an empty dict it must return a valid default domain (`frostvdb keys` lists the keys so).
using DomainReader = std::function<Domain(ParamDict&, const DomainCommon&)>;

struct DomainInfo {
    std::string kind;
    std::string summary;
    DomainReader read;
};

class DomainRegistry {
public:
    static void add(DomainInfo info);
    /// Unregisters a kind (tests that register one for their own scope).
    static void remove(const std::string& kind);
    static const DomainInfo* find(const std::string& kind);
    static std::vector<const DomainInfo*> all(); ///< sorted by kind
};

struct DomainRegistrar {
    DomainRegistrar(const std::string& kind, const std::string& summary, DomainReader r)
    { DomainRegistry::add({kind, summary, std::move(r)}); }
};

/// Built-in kinds, for code that builds a domain without a scene (tests, benchmarks).
/// @a size: cells along x, y (z ignored for a plane); @a origin: index of the first cell.
Domain makePlaneDomain(const Lattice& lattice, const openvdb::Coord& size, double voxelSize,
                       const openvdb::Coord& origin = openvdb::Coord(0));
Domain makeBoxDomain(const Lattice& lattice, const openvdb::Coord& size, double voxelSize,
                     const openvdb::Coord& origin = openvdb::Coord(0));

} // namespace frostvdb

/// Registers a domain kind: @a READER is a DomainReader.
#define FROSTVDB_REGISTER_DOMAIN(ID, KIND, SUMMARY, READER) \
    static ::frostvdb::DomainRegistrar frostvdbDomainRegistrar_##ID(KIND, SUMMARY, READER)
