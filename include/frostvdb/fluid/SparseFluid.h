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
/// Face velocities are stored in dense arrays over the box (8 bytes per face); the work (advection,
/// projection, the compact unknowns of fluid/MultigridPoisson.h) is spent on the listed active
/// faces and cells only, and the fixed faces (solid, boundary, free stream) are written only when
/// the band changes. Scratch buffers live as long as the solver (no allocation per step).
///
/// Units: one cell = 1 length unit; dt in the same time unit as the velocities.
#include <frostvdb/fluid/MultigridPoisson.h>

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

namespace frostvdb {
namespace fluid {

enum class SideKind : uint8_t { Outflow, Wall, Inflow };
enum class Profile : uint8_t { Uniform, Linear, Quadratic, Parabolic };
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
    /// Carries a cell-centred scalar (nx*ny*nz, x fastest) by the flow for dt, with the same
    /// scheme as the velocity, no added diffusion; inactive cells keep their value.
    void advectScalar(std::vector<double>& f, double dt) const;

    /// Velocity at a point in cell coordinates (cell (i,j,k) centred at (i,j,k)).
    openvdb::Vec3d sample(const openvdb::Vec3d& x) const;
    double divergence(int i, int j, int k) const;
    /// Max |div| over active fluid cells.
    double maxDivergence() const;
    /// Face value of component c at face (i,j,k) (the face below cell (i,j,k) along c).
    double face(int c, int i, int j, int k) const { return mU[c][faceIndex(c, i, j, k)]; }
    bool solid(int i, int j, int k) const { return mCell[cellIndex(i, j, k)] == kSolidCell; }
    bool active(int i, int j, int k) const { return mCell[cellIndex(i, j, k)] == kFluidCell; }
    size_t activeCells() const { return mActive; }
    double freeStream(int c, double i, double j, double k) const;
    const PoissonStats& pressureStats() const { return mStats; }
    /// The arrays carried from step to step (face velocities; the pressure on the current
    /// unknowns, the next solve's warm start), for checkpoints.
    std::vector<std::pair<const char*, std::vector<double>*>> historyArrays()
    {
        return {{"u", &mU[0]}, {"v", &mU[1]}, {"w", &mU[2]}, {"pressure", &mPressure}};
    }
    /// Largest |face velocity| (cells per unit time); NaN if any face is not finite.
    double maxSpeed() const;
    double advectSeconds = 0, projectSeconds = 0;

private:
    static constexpr uint8_t kInactiveCell = 0, kFluidCell = 1, kSolidCell = 2;
    size_t cellIndex(int i, int j, int k) const { return (size_t(k) * mN.y() + j) * mN.x() + i; }
    size_t faceIndex(int c, int i, int j, int k) const
    {
        const int ex = c == 0, ey = c == 1;
        return (size_t(k) * (mN.y() + ey) + j) * (mN.x() + ex) + i;
    }
    openvdb::Coord faceDims(int c) const
    {
        return {mN.x() + (c == 0), mN.y() + (c == 1), mN.z() + (c == 2 && mDim == 3)};
    }
    bool faceFixed(int c, int i, int j, int k, double& value) const;
    void applyBoundaries();
    void updateBand();
    openvdb::Coord faceCoord(int c, uint32_t f) const;
    void listActive();

    SparseFluidParams mP;
    openvdb::Coord mN;
    int mDim;
    std::array<SideKind, 6> mSide{};
    std::array<std::vector<double>, 3> mU;
    std::vector<uint8_t> mSolid, mCell;
    size_t mActive = 0;
    std::unique_ptr<MultigridPoisson> mPoisson;
    std::vector<double> mPressure; ///< on the poisson unknowns; warm start
    PoissonStats mStats;
    /// The faces that are not fixed (per component) and the fluid cells, as box indices: the only
    /// ones advection and projection visit. Rebuilt when the band changes.
    std::array<std::vector<uint32_t>, 3> mFaces;
    std::vector<uint32_t> mCells;
    /// Scratch kept across steps: the forward (semi-Lagrangian) field, MacCormack's bounds (one
    /// entry per listed face or cell), the projection's right-hand side.
    std::array<std::vector<double>, 3> mFwd;
    mutable std::vector<double> mLo, mHi, mScalarFwd;
    std::vector<double> mRhs;
};

} // namespace fluid
} // namespace frostvdb
