#pragma once
/// @file SparseFluid.h
/// @brief A stable-fluid solver (Stam 1999, MAC layout) in 2D or 3D on a box, solved only in a
/// band around the obstacles and their wake (Kim, Henson & Lin 2004 section 4.2 name a 3D flow as
/// their missing piece).
///
/// Where it works: the cells within `bandWidth` cells (box distance) of a solid, stretched
/// `wakeLength` cells downstream, are active. Beyond them the free stream (the inflow profile
/// carried along the flow axis) is the fixed background: faces between two inactive cells hold
/// it, and inactive cells are p = 0 (Dirichlet) for the pressure solve, so the free stream enters
/// the band as a boundary condition. bandWidth <= 0 makes the whole box active (the full-domain
/// solve the band is measured against).
///
/// Layout (why staggered): a MAC grid keeps the discrete divergence and gradient adjoint, so the
/// projection leaves exactly the divergence the pressure solve's residual says and no
/// checkerboard modes; solids block whole faces, which is how the ice paper treats p > 1/2.
/// Storage (why leaf blocks): face velocities live in 8^3 blocks (8^2 in 2D), allocated only where
/// a face touches a band or solid cell, and found through a block table over the box (4 bytes per
/// 512 box cells). A face in no allocated block is the background: the free stream, or 0 on a
/// wall, computed where it is read, so face memory and advection follow the band, not the box. A
/// flat table gives a block in one load, where an OpenVDB tree accessor needs a cached walk per
/// corner of every trilinear sample; the samplers stay at one load per corner inside a block. The
/// work (advection, projection, the compact unknowns of fluid/MultigridPoisson.h) is spent on the
/// listed active faces and cells only, and the fixed faces (solid, boundary, free stream) are
/// written only when the band changes. Scratch buffers live as long as the solver.
/// The pressure system (fluid/MultigridPoisson.h) is set up on the bounding box of the band, so
/// its 4-byte padded index follows the band's extent. What is still box-sized: two bytes of cell
/// flags per box cell (solid, band).
///
/// Units: one cell = 1 length unit; dt in the same time unit as the velocities.
#include <frostvdb/fluid/MultigridPoisson.h>

#include <openvdb/openvdb.h>

#include <frostvdb/fluid/Boundary.h>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

namespace frostvdb {
namespace fluid {

enum class Advection : uint8_t { SemiLagrangian, MacCormack };

struct SparseFluidParams {
    int inflowSide = 0;           ///< 0..5: -x, +x, -y, +y, -z, +z; the opposite side is outflow
    Profile profile = Profile::Uniform;
    int profileAxis = -1;         ///< axis the profile varies along (-1: the first axis across the flow)
    double inflowSpeed = 1.0;
    SideKind lateral = SideKind::Outflow; ///< the four other sides
    /// Per side (-x, +x, -y, +y, -z, +z) an override of `lateral` (0 outflow, 1 wall; -1: lateral).
    std::array<int, 6> sides{{-1, -1, -1, -1, -1, -1}};
    double bandWidth = 8;         ///< cells around the solids that are solved (<= 0: all)
    double wakeLength = 16;       ///< the band stretched this many cells downstream
    Advection advection = Advection::MacCormack;
    PoissonSettings poisson{};    ///< relative 1e-5 by default
};

class SparseFluid {
public:
    /// @a dims cells; dim 2 uses dims.x() x dims.y() (dims.z() ignored).
    SparseFluid(const SparseFluidParams& params, const openvdb::Coord& dims, int dim);

    int dim() const { return mDim; }
    const openvdb::Coord& dims() const { return mN; }
    /// Obstacles (solid cells): the band and the pressure system follow them.
    void setSolid(const std::function<bool(int, int, int)>& solid);
    /// Every face to the free stream, then the boundary conditions.
    void setFreeStream();
    /// Boundary conditions, advection (velocity by itself), projection.
    void step(double dt);
    void project();
    /// A band cell whose carried scalar changed, and its new value.
    struct ScalarChange {
        openvdb::Coord cell;
        double value;
    };
    /// Carries the cell-centred scalar @a f by the flow for dt, with the same scheme as the
    /// velocity and no added diffusion, over the band cells only: cell (i,j,k) of the box is voxel
    /// @a origin + (i,j,k) of @a f (inactive voxels read as the background; samples are clamped to
    /// the box). Returns the band cells whose value changed, in a fixed order; every other cell
    /// keeps its value.
    std::vector<ScalarChange> advectScalar(const openvdb::FloatGrid& f, const openvdb::Coord& origin, double dt) const;

    /// Velocity at a point in cell coordinates (cell (i,j,k) centred at (i,j,k)).
    openvdb::Vec3d sample(const openvdb::Vec3d& x) const;
    double divergence(int i, int j, int k) const;
    /// Max |div| over active fluid cells.
    double maxDivergence() const;
    /// Face value of component c at face (i,j,k) (the face below cell (i,j,k) along c).
    double face(int c, int i, int j, int k) const;
    bool solid(int i, int j, int k) const { return mCell[cellIndex(i, j, k)] == kSolidCell; }
    bool active(int i, int j, int k) const { return mCell[cellIndex(i, j, k)] == kFluidCell; }
    size_t activeCells() const { return mActive; }
    double freeStream(int c, double i, double j, double k) const;
    const PoissonStats& pressureStats() const { return mStats; }
    /// The arrays carried from step to step (face velocities in their storage, blocks or one
    /// box array as the band decides; the pressure on the current unknowns, the next solve's
    /// warm start), for checkpoints.
    std::vector<std::pair<const char*, std::vector<double>*>> historyArrays()
    {
        return {{"u", &mU[0]}, {"v", &mU[1]}, {"w", &mU[2]}, {"pressure", &mPressure}};
    }
    /// Largest |face velocity| (cells per unit time); NaN if any face is not finite.
    double maxSpeed() const;
    /// Storage that follows the band: allocated face blocks of the box's blocks, and the bytes
    /// of the face velocities (current and advected copy) in them.
    size_t faceBlocks() const { return mDenseY ? mSlot.size() : mBlockOrigin.size(); }
    /// True when the band covers so much of the box that one box array is the smaller store.
    bool denseFaces() const { return mDenseY > 0; }
    size_t boxBlocks() const { return mSlot.size(); }
    size_t faceBytes() const;
    /// Bytes of the cell flags (two per box cell) and the multigrid index (its bounding box).
    size_t boxBytes() const;
    double advectSeconds = 0, projectSeconds = 0;

private:
    static constexpr uint8_t kInactiveCell = 0, kFluidCell = 1, kSolidCell = 2;
    size_t cellIndex(int i, int j, int k) const { return (size_t(k) * mN.y() + j) * mN.x() + i; }
    openvdb::Coord faceDims(int c) const
    {
        return {mN.x() + (c == 0), mN.y() + (c == 1), mN.z() + (c == 2 && mDim == 3)};
    }
    /// Storage entry of face or cell (i, j, k), or -1 if in no allocated block. Blocked: block
    /// slot << mLogVol | local offset; dense (mDenseY > 0): one array over the (n + 1) box.
    int64_t entryOf(int i, int j, int k) const
    {
        if (mDenseY) return i + j * mDenseY + k * mDenseZ;
        const int64_t s = mSlot[(size_t(k >> 3) * mBlocks.y() + size_t(j >> 3)) * mBlocks.x() + size_t(i >> 3)];
        return s < 0 ? -1 : (s << mLogVol) | ((i & 7) | (j & 7) << 3 | (k & 7) << 6);
    }
    openvdb::Coord entryCoord(uint32_t e) const
    {
        if (mDenseY) {
            const int k = mDim == 3 ? int(e / uint32_t(mDenseZ)) : 0;
            const uint32_t r = mDim == 3 ? e - uint32_t(k) * uint32_t(mDenseZ) : e;
            const int j = int(r / uint32_t(mDenseY));
            return {int(r - uint32_t(j) * uint32_t(mDenseY)), j, k};
        }
        const openvdb::Coord& o = mBlockOrigin[e >> mLogVol];
        return {o.x() + int(e & 7), o.y() + int((e >> 3) & 7), mDim == 3 ? o.z() + int((e >> 6) & 7) : 0};
    }
    double background(int c, int i, int j, int k) const;
    void allocateBlocks();
    bool faceFixed(int c, int i, int j, int k, double& value) const;
    void applyBoundaries();
    void updateBand();
    void listActive();

    SparseFluidParams mP;
    openvdb::Coord mN;
    int mDim;
    std::array<SideKind, 6> mSide{};
    /// The block table over the box (-1: not allocated), each slot's first cell, and per
    /// component the face values of the allocated blocks.
    openvdb::Coord mBlocks;
    int mLogVol = 9;
    int64_t mDenseY = 0, mDenseZ = 0; ///< > 0: the faces are one array over the box (row, plane strides)
    std::vector<int32_t> mSlot;
    std::vector<openvdb::Coord> mBlockOrigin;
    std::array<std::vector<double>, 3> mU;
    std::vector<uint8_t> mSolid, mCell;
    size_t mActive = 0;
    std::unique_ptr<MultigridPoisson> mPoisson;
    openvdb::Coord mPoissonOrigin{0, 0, 0}, mPoissonDims{0, 0, 0}; ///< its box: the band's bounding box
    std::vector<double> mPressure; ///< on the poisson unknowns; warm start
    PoissonStats mStats;
    /// The faces that are not fixed (per component) and the fluid cells, as storage entries: the
    /// only ones advection and projection visit. Rebuilt when the band changes.
    std::array<std::vector<uint32_t>, 3> mFaces;
    std::vector<uint32_t> mCells;
    /// Scratch kept across steps: the forward (semi-Lagrangian) field, MacCormack's bounds (one
    /// entry per listed face or cell), the projection's right-hand side.
    std::array<std::vector<double>, 3> mFwd;
    mutable std::vector<double> mLo, mHi, mScalar, mScalarFwd;
    std::vector<double> mRhs;
};

} // namespace fluid
} // namespace frostvdb
