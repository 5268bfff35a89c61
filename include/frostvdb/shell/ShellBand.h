#pragma once
/// @file ShellBand.h
/// @brief The narrow band of voxels around a triangle mesh on which the shell domain runs its
/// surface PDEs by the closest point method (Ruuth & Merriman 2008).
///
/// The band is built per 8^3 leaf ("brick"), only where it is needed: a bounding-volume
/// hierarchy over the mesh's triangles gives each voxel the exact closest point on the mesh
/// (the lowest triangle index on ties) when it lies within the half-width. build() materialises every leaf the mesh reaches (the whole band, the
/// reference); buildLazy() materialises none, and the shell's phase field asks for the leaves
/// around the ice as it grows (ShellPhaseField's active region), so a huge mesh with small
/// crystals costs what the crystals cost. A voxel's data does not depend on which leaves were
/// built before it, so the lazy band holds the same values as the whole one where both exist.
///
/// Per voxel the band keeps:
///  - cp(x), the closest point (index space), its distance and the smooth frame there
///    (interpolated vertex normal; tangent = the crystal axis projected on the tangent plane);
///  - once its leaf is "prepared" (all 26 neighbouring leaves built): the 6 face neighbours
///    (band indices, -1 outside the band) and the tricubic interpolation stencil at cp(x) (64 node
///    indices and 3 x 4 Lagrange weights), so an extension u(x) = interp(u, cp(x)) is one gather.
/// A leaf's voxels have consecutive band indices (leaf() ranges); indices never change once given.
///
/// Nested sets by distance d to the surface (in voxels):
///  - update set U (d <= kUpdateRadius = 3.5): every tricubic node of every cp lies within
///    2 sqrt(3) = 3.46 voxels of the surface, so U holds every node;
///  - coefficient set (d <= 4.5): the neighbours of U, where the phase field's anisotropic
///    coefficients are needed;
///  - the band (d <= kHalfWidth = 5.5): the neighbours of those (their central differences).
/// Memory is about 11 voxels times the built surface area (in voxels), never the bounding box.
///
/// Building leaves (materialise*, prepare, nearBorder, nearSurfacePoint on a lazy band) changes
/// the band: those calls are serialised by a mutex, and must not run while another thread reads
/// the band's arrays (the solver and the seeding call them between their parallel loops).
#include <frostvdb/core/Domain.h>
#include <frostvdb/geometry/TriangleBvh.h>
#include <frostvdb/io/Mesh.h>
#include <frostvdb/shell/BandIndex.h>

#include <openvdb/openvdb.h>

#include <tbb/parallel_for.h>

#include <array>
#include <cstdint>
#include <memory>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace frostvdb::shell {

/// Band half-width in voxels of the closest-point band (see the file comment for why 5.5 and
/// not 4.5); a surface-node band keeps the voxels within kLayerReach.
constexpr double kHalfWidth = 5.5;
/// Surface nodes: voxels whose centre lies within 1/2 along the normal and 1/2 beyond an open
/// border, so within sqrt(1/2) of the surface.
constexpr double kLayerReach = 0.7072;
/// Surface nodes on an open mesh: one ring of ghost nodes beyond the border (lateral offset in
/// (0.5, kGhostLateral]), within kGhostReach of the mesh, that the phase field holds at the
/// background (p = 0, T = T_inf): the plane's Dirichlet edge, so a border node's stencil is not
/// one-sided and frost grown from the border looks as it does on a plane.
constexpr double kGhostLateral = 1.5;
constexpr double kGhostReach = 1.59;
/// Radius of the update set U in voxels: it must hold every tricubic node (2 sqrt 3 = 3.46).
constexpr double kUpdateRadius = 3.5;
/// Radius of the set where the phase field's coefficients are evaluated (the neighbours of U).
constexpr double kCoefficientRadius = 4.5;
/// Edge of a band leaf (brick) in voxels: OpenVDB's leaf.
constexpr int kLeafDim = 8;

struct BandSettings {
    double voxelSize = 1e-4; ///< metres per voxel
    /// The crystal axis: a world direction projected on each tangent plane gives the frame's
    /// tangent (theta = 0 of the anisotropy). Where it is parallel to the normal the secondary
    /// axis is used instead.
    openvdb::Vec3d crystalAxis{1, 0, 0};
    openvdb::Vec3d secondaryAxis{0, 1, 0};
    /// Thickness of the output frost layer where growth has reached 1, in voxels (<= 4.5: the band).
    double frostThickness = 2.0;
    /// What the mesh's vertex colours (their luminance, interpolated at cp) control: nothing,
    /// seeds (ice where the luminance exceeds 1/2) or the melt map (T_e scale = luminance).
    enum class ColourUse { None, Seed, Melt } colourUse = ColourUse::None;
    /// How surface operators are discretised (docs/shells.md "Discretisation"):
    ///  - SurfaceNodes: one layer of voxels, those whose centre lies within half a voxel of the
    ///    surface along its normal (a slab one voxel thick: one node per surface cell on average,
    ///    the plane's density, whatever the orientation), with precomputed least-squares surface
    ///    stencils (Laplace-Beltrami and the two tangential derivatives) over the node's layer
    ///    neighbours. No extension, no off-surface voxels.
    ///  - ClosestPoint: the band of half-width 5.5 and the tricubic closest-point extension
    ///    (Ruuth & Merriman 2008), the reference; lw_cn (the implicit closest point method) and the
    ///    potential-flow wind run on it.
    enum class Discretisation { SurfaceNodes, ClosestPoint } discretisation = Discretisation::ClosestPoint;
};

/// One tap of a surface-node stencil: the neighbour's band index and its weights for the
/// Laplace-Beltrami operator and the derivatives along the node's tangent and bitangent (index
/// units: divide by h^2 and h). Weights act on differences u_j - u_i.
struct SurfaceTap {
    int32_t node = -1;
    float lap = 0, du = 0, dv = 0;
};

using geometry::TriangleBvh;

/// A node's frame as the band stores it: floats (36 bytes against VoxelFrame's 72; the kernel
/// reads it twice a step). frameFloats() rounds a frame once, where it is computed, so every
/// reader sees the same frame.
struct FrameFloats {
    openvdb::Vec3s tangent{1, 0, 0}, bitangent{0, 1, 0}, normal{0, 0, 1};
    FrameFloats() = default;
    explicit FrameFloats(const VoxelFrame& f) : tangent(f.tangent), bitangent(f.bitangent), normal(f.normal) {}
    VoxelFrame widened() const
    {
        VoxelFrame f;
        f.tangent = openvdb::Vec3d(tangent);
        f.bitangent = openvdb::Vec3d(bitangent);
        f.normal = openvdb::Vec3d(normal);
        return f;
    }
};

class ShellBand {
public:
    /// The whole band around @a mesh (world metres): every leaf the mesh reaches, prepared.
    /// Throws std::runtime_error naming the mesh's source when the mesh has no triangles, its band
    /// is empty or would not fit in the available memory.
    static std::shared_ptr<const ShellBand> build(const TriangleMesh& mesh, const BandSettings& settings);
    /// A band with no leaves built yet: materialise() builds them where they are needed.
    static std::shared_ptr<const ShellBand> buildLazy(const TriangleMesh& mesh, const BandSettings& settings);

    size_t size() const { return mCoords.size(); }
    const openvdb::Coord& coord(size_t i) const { return mCoords[i]; }
    const std::vector<openvdb::Coord>& coords() const { return mCoords; }
    /// Closest point on the surface, in index space (index = world / voxelSize).
    /// (Stored as floats: 12 bytes a voxel, 1e-4 voxels at 2,800 voxels from the origin.)
    openvdb::Vec3d closestPoint(size_t i) const { return openvdb::Vec3d(mCp[i]); }
    /// Unsigned distance to the surface, in voxels.
    float distance(size_t i) const { return mDistance[i]; }
    /// Signed offset along the normal at cp, in voxels: (x - cp) . n.
    float normalOffset(size_t i) const { return mNormalOffset[i]; }
    /// Distance from x to the normal line through cp, in voxels: 0 where x projects onto the
    /// surface's interior, > 0 beyond an open mesh's border (x's closest point is on the border).
    float lateralOffset(size_t i) const { return mLateral[i]; }
    /// Voxel @a i's tangent frame (stored as floats: FrameFloats).
    VoxelFrame frame(size_t i) const { return mFrames[i].widened(); }
    const FrameFloats& frameFloats(size_t i) const { return mFrames[i]; }
    /// frame(i).normal alone (the walkers' projections read only it).
    openvdb::Vec3d normal(size_t i) const { return openvdb::Vec3d(mFrames[i].normal); }
    /// Band index of face neighbour k (0: -x, 1: +x, 2: -y, 3: +y, 4: -z, 5: +z), or -1 (valid once
    /// the voxel's leaf is prepared). Closest-point band only: surface nodes have their stencils.
    int32_t neighbour(size_t i, int k) const { return mNeighbours[6 * i + size_t(k)]; }
    bool inUpdateSet(size_t i) const { return mSurface || mDistance[i] <= kUpdateRadius; }
    bool inCoefficientSet(size_t i) const { return mSurface || mDistance[i] <= kCoefficientRadius; }
    /// True for a surface-node band (BandSettings::Discretisation::SurfaceNodes).
    bool surfaceNodes() const { return mSurface; }
    /// The band's half-width in voxels (kHalfWidth; surface nodes: kLayerReach, kGhostReach on an open mesh).
    double halfWidth() const { return mSurface ? (mGhosts ? kGhostReach : kLayerReach) : kHalfWidth; }
    /// Surface nodes: true for a ghost node beyond an open border (see kGhostLateral).
    bool ghost(size_t i) const { return mGhosts && mLateral[i] > 0.5f; }
    /// Whether the band has ghost nodes at all, and every voxel's lateral offset (loops that
    /// test ghost() without branches).
    bool hasGhosts() const { return mGhosts; }
    const float* lateralOffsets() const { return mLateral.data(); }
    /// Surface nodes: the stencil of node @a i (valid once its leaf is prepared), taps in a fixed
    /// order (neighbour offsets z, y, x ascending), so every sum over it is one fixed sum.
    const SurfaceTap* tapsBegin(size_t i) const { return mTapBegin[i]; }
    const SurfaceTap* tapsEnd(size_t i) const { return mTapBegin[i] + mTapCount[i]; }
    /// Surface nodes: the largest voxel offset (Chebyshev) between a node and a stencil tap.
    static constexpr int kTapReach = 2;
    /// Band index of voxel @a c, or -1 (also where its leaf is not built yet).
    int32_t indexOf(const openvdb::Coord& c) const;
    /// Whether voxel @a c lies in the band (exact, also where its leaf is not built yet).
    bool contains(const openvdb::Coord& c) const;
    /// The frame at voxel @a c's closest point (computed from the mesh where its leaf is not built).
    VoxelFrame frameAt(const openvdb::Coord& c) const;
    /// Band index per voxel (-1 off the band): the same voxels as mask().
    const BandIndex& index() const { return mIndex; }
    /// The built band's voxels as a mask (for the domain's support).
    const openvdb::MaskGrid& mask() const { return *mMask; }
    double voxelSize() const { return mVoxelSize; }
    const openvdb::math::Transform::Ptr& transform() const { return mTransform; }
    /// Mesh area in square voxels (the surface the whole band covers).
    double surfaceVoxels() const { return mSurfaceVoxels; }
    /// The index-space box of the whole band (the mesh's bounds grown by the half-width).
    openvdb::CoordBBox bounds() const { return mBounds; }
    /// The triangle cp(x) lies on.
    uint32_t triangle(size_t i) const { return mTriangle[i]; }
    /// Voxels within @a width voxels of the mesh's boundary edges (an open mesh's border), ghosts excluded; builds
    /// the leaves along the border first.
    std::vector<size_t> nearBorder(double width) const;
    /// Voxels whose closest point is within @a radius voxels of the index position @a centre
    /// (a seed on the surface; distance measured in 3D between closest points); builds the leaves
    /// around it first.
    std::vector<size_t> nearSurfacePoint(const openvdb::Vec3d& centre, double radius) const;

    /// The closest point on the surface (the mesh) to index position @a p.
    openvdb::Vec3d nearestSurfacePoint(const openvdb::Vec3d& p) const;
    /// Vertex-colour luminance at cp (barycentric), or empty when the mesh has no colours.
    const std::vector<float>& colourLuminance() const { return mLuminance; }
    BandSettings::ColourUse colourUse() const { return mColourUse; }
    /// Frost layer thickness of the outputs, in voxels (BandSettings::frostThickness).
    double frostThickness() const { return mFrostThickness; }

    // ---- leaves (bricks) ----
    struct Leaf {
        openvdb::Coord origin;
        uint32_t begin = 0, end = 0; ///< band indices [begin, end); empty where the mesh does not reach
        bool prepared = false;       ///< neighbours and tricubic stencils filled
    };
    /// Every leaf built (or found empty) so far, in the order they were built.
    const std::vector<Leaf>& leaves() const { return mLeaves; }
    /// Slot of the leaf with origin @a origin in leaves(), or -1 when it was not built.
    int32_t leafSlot(const openvdb::Coord& origin) const;
    /// Builds the leaves with these origins (multiples of 8) that are not built yet: in sorted
    /// order, each in parallel, appended to the band. Returns how many voxels were added.
    size_t materialise(std::vector<openvdb::Coord> origins) const;
    /// Builds and prepares the leaves with these origins and their 26 neighbours' geometry.
    void prepare(std::vector<openvdb::Coord> origins) const;
    /// Builds and prepares every leaf the mesh reaches (the whole band). Throws when it would not
    /// fit in the available memory.
    void materialiseAll() const;
    /// Builds the leaves within the half-width of these triangles.
    void materialiseTriangles(const std::vector<uint32_t>& triangles) const;
    /// Builds the leaves holding any voxel of @a box.
    size_t materialiseBox(const openvdb::CoordBBox& box) const;
    /// True when every leaf the mesh reaches is built and prepared.
    bool whole() const { return mWhole; }

    /// Closest-point extension: out[i] = background + tricubic interpolation of (in - background)
    /// at cp(i), for every band voxel (with @a leafSlots, only for the voxels of those leaves; out
    /// must then hold size() values); with @a limit the value is clamped to the range of the 8
    /// nodes around cp (no new extrema at a sharp interface). Thread-count independent (each
    /// output is one fixed sum); a constant field equal to @a background stays exactly that.
    void extend(const std::vector<float>& in, std::vector<float>& out, bool limit, float background = 0.f,
                const std::vector<uint32_t>* leafSlots = nullptr) const;

    /// Closest-point extension of a phase field p in [0, 1] with a sharp interface (a couple of
    /// voxels wide, where a cubic is a poor fit): interpolates phi = atanh(2p - 1) (p clamped to
    /// [1e-6, 1 - 1e-6]), which is close to linear across an equilibrium tanh profile, maps back
    /// p = (1 + tanh phi) / 2 and clamps to the range of the 8 nodes around cp (0 stays 0).
    /// @a phi is scratch (size() values). @a leafSlots as in extend(); @a nodeSlots: leaves that
    /// hold every tricubic node of those (null: all).
    void extendPhase(const std::vector<float>& p, std::vector<float>& out, std::vector<float>& phi,
                     const std::vector<uint32_t>* leafSlots = nullptr,
                     const std::vector<uint32_t>* nodeSlots = nullptr) const;

    /// The extension's stencil at voxel @a i (its leaf prepared): 64 node indices (x fastest, then
    /// y, then z) and the 3 x 4 Lagrange weights per axis; extend() is sum_zyx wz wy wx u(node).
    /// (The implicit closest-point system builds its operator from them, shell/ShellImplicit.h.)
    const int32_t* stencilNodes(size_t i) const { return &mNodes[64 * i]; }
    const std::array<float, 12>& stencilWeights(size_t i) const { return mWeights[i]; }

    /// Surface nodes: the bytes a run holds per surface cell (band, stencils, the phase field's
    /// arrays, a frame's grids), for memory estimates; measured in docs/shells.md. Session 12
    /// (frames no longer publish World's grids): 600 on the pane's 0.29 M cells, 540-580 on the
    /// heroes, 770 on a 0.3 m test plate at 1 mm (peak above the program's own 54 MiB); session
    /// 15 stores frames and closest points as floats, 48 bytes a voxel less; session 18's compact
    /// band index (BandIndex.h) about 55 less (the pane: 15.7 MiB of index for 0.29 M nodes -> 1)
    /// and 560 then keeps the probe's dense plate within 1.5x (1.50 at 600 in a parallel ctest).
    static double surfaceBytesPerCell() { return 560.0; }
    /// The same for this band's discretisation (closest point: 11.5 band voxels of about 612 bytes).
    double bytesPerSurfaceCell() const { return mSurface ? surfaceBytesPerCell() : 11.5 * 612.0; }
    /// Bytes held by the band (the per-voxel arrays, the index grid, the mesh and its hierarchy).
    size_t memoryBytes() const;

    /// Number of the mesh's boundary edges (0: a closed mesh). (Appended for the walkers.)
    size_t borderEdgeCount() const { return mBorderA.size(); }
    /// Boundary edge @a e's end points (index space).
    std::pair<openvdb::Vec3d, openvdb::Vec3d> borderEdge(size_t e) const { return {mBorderA[e], mBorderB[e]}; }

    /// Calls fn(i) for every band voxel (@a leafSlots null) or every voxel of those leaves, in
    /// parallel; fn must write only to index i.
    template <typename Fn>
    void forEachVoxel(const std::vector<uint32_t>* leafSlots, const Fn& fn) const
    {
        if (!leafSlots) {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, size(), 1024), [&](const tbb::blocked_range<size_t>& r) {
                for (size_t i = r.begin(); i < r.end(); ++i) fn(i);
            });
            return;
        }
        tbb::parallel_for(tbb::blocked_range<size_t>(0, leafSlots->size(), 2), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t s = r.begin(); s < r.end(); ++s) {
                const Leaf& l = mLeaves[(*leafSlots)[s]];
                for (size_t i = l.begin; i < l.end; ++i) fn(i);
            }
        });
    }

private:
    ShellBand() = default;
    struct LeafData; // one leaf's voxels, computed in parallel, appended in order
    void init(const TriangleMesh& mesh, const BandSettings& settings);
    void computeLeaf(const openvdb::Coord& origin, LeafData& out) const;
    size_t materialiseLocked(std::vector<openvdb::Coord> origins) const;
    void prepareLocked(std::vector<openvdb::Coord> origins) const;
    /// Surface nodes: fills the 6 neighbours and the stencils of these leaves' voxels.
    void prepareSurface(const std::vector<uint32_t>& slots) const;
    /// Surface nodes: the least-squares stencil of voxel @a i (its 26 or 124 neighbours built).
    void surfaceStencil(size_t i, BandIndex::Accessor& acc, std::vector<SurfaceTap>& out) const;
    /// Closest point of voxel @a c (exact, lowest triangle index on ties): false beyond the half-width.
    bool voxelGeometry(const openvdb::Coord& c, openvdb::Vec3d& cp, uint32_t& tri, double& dist) const;
    VoxelFrame frameOn(uint32_t tri, const openvdb::Vec3d& cp, openvdb::Vec3d* bary = nullptr) const;
    /// Leaves (origins) within the half-width of triangle @a t.
    void leavesOfTriangle(uint32_t t, std::vector<openvdb::Coord>& out) const;

    double mVoxelSize = 1;
    double mFrostThickness = 2;
    BandSettings mSettings;
    BandSettings::ColourUse mColourUse = BandSettings::ColourUse::None;
    double mSurfaceVoxels = 0;
    openvdb::CoordBBox mBounds;
    openvdb::math::Transform::Ptr mTransform;
    // the mesh, index space
    std::string mSource;
    std::vector<openvdb::Vec3d> mPts, mVNormal;
    std::vector<openvdb::Vec3I> mTris;
    std::vector<openvdb::Vec3d> mTriNormal;
    std::vector<openvdb::Vec3s> mVColour;
    TriangleBvh mBvh;
    std::vector<openvdb::Vec3d> mBorderA, mBorderB; ///< boundary edges, index space
    // per voxel (mutable: leaves are built on demand)
    mutable std::vector<float> mLuminance;
    mutable std::vector<openvdb::Coord> mCoords;
    mutable std::vector<openvdb::Vec3s> mCp;
    mutable std::vector<float> mDistance, mNormalOffset, mLateral;
    mutable std::vector<FrameFloats> mFrames;
    mutable std::vector<uint32_t> mTriangle;
    mutable std::vector<int32_t> mNeighbours;             ///< 6 per voxel
    bool mSurface = false;                                ///< surface nodes (else closest point)
    bool mGhosts = false;                                 ///< surface nodes on an open mesh: a ghost ring
    /// Surface nodes: each prepared leaf's taps, in its voxels' order. Kept per leaf (not one
    /// array) so preparing never holds two copies of them (docs/shells.md "Memory").
    mutable std::vector<std::vector<SurfaceTap>> mLeafTaps;
    mutable size_t mTapTotal = 0;                        ///< taps in all leaves
    mutable std::vector<const SurfaceTap*> mTapBegin;     ///< per voxel: its first tap
    mutable std::vector<uint8_t> mTapCount;               ///< per voxel: number of taps
    mutable std::vector<int32_t> mNodes;                  ///< 64 per voxel: x fastest, then y, then z
    mutable std::vector<std::array<float, 12>> mWeights;  ///< per axis x, y, z: 4 Lagrange weights
    mutable BandIndex mIndex;                             ///< band index per voxel, -1 off the band
    mutable openvdb::MaskGrid::Ptr mMask;
    mutable std::vector<Leaf> mLeaves;
    struct CoordHash {
        size_t operator()(const openvdb::Coord& c) const
        {
            return size_t(c.x()) * 73856093u ^ size_t(c.y()) * 19349663u ^ size_t(c.z()) * 83492791u;
        }
    };
    mutable std::unordered_map<openvdb::Coord, int32_t, CoordHash> mSlotOf;
    mutable bool mWhole = false;
    mutable std::mutex mMutex;
};

/// Origin of the leaf holding voxel @a c.
inline openvdb::Coord leafOrigin(const openvdb::Coord& c)
{
    return openvdb::Coord(c.x() & ~(kLeafDim - 1), c.y() & ~(kLeafDim - 1), c.z() & ~(kLeafDim - 1));
}

/// Cubic Lagrange weights on nodes -1, 0, 1, 2 at fraction @a x in [0, 1).
inline void cubicWeights(double x, double w[4])
{
    w[0] = -x * (x - 1.0) * (x - 2.0) / 6.0;
    w[1] = (x + 1.0) * (x - 1.0) * (x - 2.0) / 2.0;
    w[2] = -(x + 1.0) * x * (x - 2.0) / 2.0;
    w[3] = (x + 1.0) * x * (x - 1.0) / 6.0;
}

} // namespace frostvdb::shell
