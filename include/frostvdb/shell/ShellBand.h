#pragma once
/// @file ShellBand.h
/// @brief The narrow band of voxels around a triangle mesh on which the shell domain runs its
/// surface PDEs by the closest point method (Ruuth & Merriman 2008).
///
/// Built from OpenVDB's mesh-to-volume (unsigned distance, so open meshes work, with the
/// closest-primitive index grid); per band voxel the exact closest point on the surface is
/// computed from that primitive and its one-ring. Per voxel the band keeps:
///  - cp(x), the closest point (index space), its distance and the smooth frame there
///    (interpolated vertex normal; tangent = the crystal axis projected on the tangent plane);
///  - the 6 face neighbours (band indices, -1 when outside the band);
///  - the tricubic interpolation stencil at cp(x): the 64 node indices and the 3 x 4 Lagrange
///    weights, so a closest-point extension u(x) = interp(u, cp(x)) is one gather per voxel.
///
/// Nested sets by distance d to the surface (in voxels):
///  - update set U (d <= kUpdateRadius = 3.5): every tricubic node of every cp lies within
///    2 sqrt(3) = 3.46 voxels of the surface, so U holds every node;
///  - coefficient set (d <= 4.5): the neighbours of U, where the phase field's anisotropic
///    coefficients are needed;
///  - the band (d <= kHalfWidth = 5.5): the neighbours of those (their central differences).
/// Memory is about 11 voxels times the surface area (in voxels), never the bounding box.
#include <frostvdb/core/Domain.h>
#include <frostvdb/io/Mesh.h>

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

namespace frostvdb::shell {

/// Band half-width in voxels (see the file comment for why 5.5 and not 4.5).
constexpr double kHalfWidth = 5.5;
/// Radius of the update set U in voxels: it must hold every tricubic node (2 sqrt 3 = 3.46).
constexpr double kUpdateRadius = 3.5;
/// Radius of the set where the phase field's coefficients are evaluated (the neighbours of U).
constexpr double kCoefficientRadius = 4.5;

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
};

class ShellBand {
public:
    /// Builds the band around @a mesh (world metres). Throws std::runtime_error naming the mesh's
    /// source when the mesh has no triangles or its band is empty.
    static std::shared_ptr<const ShellBand> build(const TriangleMesh& mesh, const BandSettings& settings);

    size_t size() const { return mCoords.size(); }
    const openvdb::Coord& coord(size_t i) const { return mCoords[i]; }
    const std::vector<openvdb::Coord>& coords() const { return mCoords; }
    /// Closest point on the surface, in index space (index = world / voxelSize).
    const openvdb::Vec3d& closestPoint(size_t i) const { return mCp[i]; }
    /// Unsigned distance to the surface, in voxels.
    float distance(size_t i) const { return mDistance[i]; }
    /// Signed offset along the normal at cp, in voxels: (x - cp) . n.
    float normalOffset(size_t i) const { return mNormalOffset[i]; }
    /// Distance from x to the normal line through cp, in voxels: 0 where x projects onto the
    /// surface's interior, > 0 beyond an open mesh's border (x's closest point is on the border).
    float lateralOffset(size_t i) const { return mLateral[i]; }
    const VoxelFrame& frame(size_t i) const { return mFrames[i]; }
    /// Band index of face neighbour k (0: -x, 1: +x, 2: -y, 3: +y, 4: -z, 5: +z), or -1.
    int32_t neighbour(size_t i, int k) const { return mNeighbours[6 * i + size_t(k)]; }
    bool inUpdateSet(size_t i) const { return mDistance[i] <= kUpdateRadius; }
    bool inCoefficientSet(size_t i) const { return mDistance[i] <= kCoefficientRadius; }
    /// Band index of voxel @a c, or -1.
    int32_t indexOf(const openvdb::Coord& c) const;
    /// Band index per voxel (background -1): the same topology as mask().
    const openvdb::Int32Grid& indexGrid() const { return *mIndex; }
    /// The band's voxels as a mask (for the domain's support).
    const openvdb::MaskGrid& mask() const { return *mMask; }
    double voxelSize() const { return mVoxelSize; }
    const openvdb::math::Transform::Ptr& transform() const { return mTransform; }
    /// Mesh area in square voxels (the surface the band covers).
    double surfaceVoxels() const { return mSurfaceVoxels; }
    /// The triangle cp(x) lies on.
    uint32_t triangle(size_t i) const { return mTriangle[i]; }
    /// Voxels within @a width voxels of the mesh's boundary edges (an open mesh's border).
    std::vector<size_t> nearBorder(double width) const;
    /// Voxels whose closest point is within @a radius voxels of the index position @a centre
    /// (a seed on the surface; distance measured in 3D between closest points).
    std::vector<size_t> nearSurfacePoint(const openvdb::Vec3d& centre, double radius) const;

    /// The band's closest point nearest to index position @a p (first in band order on ties).
    openvdb::Vec3d nearestSurfacePoint(const openvdb::Vec3d& p) const;
    /// Vertex-colour luminance at cp (barycentric), or empty when the mesh has no colours.
    const std::vector<float>& colourLuminance() const { return mLuminance; }
    BandSettings::ColourUse colourUse() const { return mColourUse; }
    /// Frost layer thickness of the outputs, in voxels (BandSettings::frostThickness).
    double frostThickness() const { return mFrostThickness; }

    /// Closest-point extension: out[i] = tricubic interpolation of @a in at cp(i), for every band
    /// voxel; with @a limit the value is clamped to the range of the 8 nodes around cp (no new
    /// extrema at a sharp interface). Thread-count independent (each output is one fixed sum).
    void extend(const std::vector<float>& in, std::vector<float>& out, bool limit) const;

    /// Closest-point extension of a phase field p in [0, 1] with a sharp interface (a couple of
    /// voxels wide, where a cubic is a poor fit): interpolates phi = atanh(2p - 1) (p clamped to
    /// [1e-6, 1 - 1e-6]), which is close to linear across an equilibrium tanh profile, maps back
    /// p = (1 + tanh phi) / 2 and clamps to the range of the 8 nodes around cp (0 stays 0).
    /// @a phi is scratch.
    void extendPhase(const std::vector<float>& p, std::vector<float>& out, std::vector<float>& phi) const;

    /// Bytes held by the band (the per-voxel arrays and the index grid).
    size_t memoryBytes() const;

    /// Number of the mesh's boundary edges (0: a closed mesh). (Appended for the walkers.)
    size_t borderEdgeCount() const { return mBorderA.size(); }

private:
    ShellBand() = default;
    double mVoxelSize = 1;
    double mFrostThickness = 2;
    BandSettings::ColourUse mColourUse = BandSettings::ColourUse::None;
    std::vector<float> mLuminance;
    double mSurfaceVoxels = 0;
    openvdb::math::Transform::Ptr mTransform;
    std::vector<openvdb::Coord> mCoords;
    std::vector<openvdb::Vec3d> mCp;
    std::vector<float> mDistance, mNormalOffset, mLateral;
    std::vector<VoxelFrame> mFrames;
    std::vector<uint32_t> mTriangle;
    std::vector<int32_t> mNeighbours;             ///< 6 per voxel
    std::vector<int32_t> mNodes;                  ///< 64 per voxel: x fastest, then y, then z
    std::vector<std::array<float, 12>> mWeights;  ///< per axis x, y, z: 4 Lagrange weights
    openvdb::Int32Grid::Ptr mIndex;               ///< band index per voxel, background -1
    openvdb::MaskGrid::Ptr mMask;
    std::vector<openvdb::Vec3d> mBorderA, mBorderB; ///< boundary edges, index space
};

/// Cubic Lagrange weights on nodes -1, 0, 1, 2 at fraction @a x in [0, 1).
inline void cubicWeights(double x, double w[4])
{
    w[0] = -x * (x - 1.0) * (x - 2.0) / 6.0;
    w[1] = (x + 1.0) * (x - 1.0) * (x - 2.0) / 2.0;
    w[2] = -(x + 1.0) * x * (x - 2.0) / 2.0;
    w[3] = (x + 1.0) * x * (x - 1.0) / 6.0;
}

} // namespace frostvdb::shell
