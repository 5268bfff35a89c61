#pragma once
/// @file Fluid.h
/// @brief Stam's "stable fluids" coupled to the ice (Kim, Henson & Lin 2004, sections 4.2-4.3):
/// the crystal (p > 1/2) is a solid obstacle, the flow is advanced by semi-Lagrangian
/// self-advection, optional implicit viscosity and a pressure projection, and the temperature
/// T is then carried by the flow with no diffusion of its own (eq. 7 with kappa = 0; T is
/// diffused by the phase field, eq. 2).
///
/// The flow lives on a dense staggered (MAC) square grid in the lattice plane with the lattice
/// spacing h: for a square lattice it is the domain's own cells, for a hexagonal one the
/// axis-aligned rectangle around the sheared domain. The flow reaches every cell, so this grid is
/// not sparse (see docs/fluid.md). Plane domains only.
///
/// Units: lengths in the PDE's dimensionless units (one cell = h = [domain] spacing), time in
/// the ice clock's units, so a velocity u moves a point by u * dt / h cells per step. The field
/// `vel` in World (and in frames) holds u * voxel_size / h at every domain cell: world metres per
/// unit of simulation time, as icephysics/IceState.h documents and [dla] reads it.
#include <frostvdb/fluid/Boundary.h>
#include <frostvdb/core/Effect.h>
#include <frostvdb/fluid/SparseFluid.h>

#include <openvdb/openvdb.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace frostvdb {
namespace fluid { class MultigridPoisson; }
namespace ice {

enum class FluidEdge { Left = 0, Right = 1, Bottom = 2, Top = 3 };
using fluid::Profile;  // the one boundary vocabulary (fluid/Boundary.h)
using fluid::SideKind;

struct FluidParams {
    FluidEdge inflowEdge = FluidEdge::Left;
    Profile profile = Profile::Uniform;
    double inflowSpeed = 3.5;   ///< dimensionless (the paper's 3.5)
    bool closedWalls = false;   ///< side walls (parallel to the inflow) closed instead of outflow
    double viscosity = 0.0;     ///< kinematic viscosity nu (dimensionless), implicit
    double tolerance = 1e-5;    ///< projection: max |div u| h / inflow_speed
    int maxIterations = 2000;   ///< per linear solve
    double solidThreshold = 0.5;///< p above this is an obstacle
    /// Projection solver: multigrid-preconditioned CG (fluid/MultigridPoisson.h, iterations flat
    /// in the grid size) or the Jacobi-preconditioned CG kept as the reference.
    bool multigrid = true;
};

/// Statistics of the last step, for tests and benchmarks.
struct FluidStepStats {
    int pressureIterations = 0;
    double pressureResidual = 0; ///< max |div u| h after the projection (velocity units)
    bool pressureConverged = true;
    int viscosityIterations = 0;
};

/// The dense MAC-grid solver: nx x ny cells of size h, cell (i, j) centred at (i, j) in cell
/// units; u on the x faces ((nx+1) x ny), v on the y faces (nx x (ny+1)).
class StableFluid2D {
public:
    StableFluid2D(const FluidParams& params, int nx, int ny, double h);
    ~StableFluid2D();

    int nx() const { return mNx; }
    int ny() const { return mNy; }
    const FluidParams& params() const { return mParams; }
    SideKind wall(FluidEdge e) const { return mWalls[int(e)]; }

    /// Obstacle cells (nx * ny, row-major, x fastest): nonzero = solid.
    void setSolid(std::vector<uint8_t> solid);
    const std::vector<uint8_t>& solid() const { return mSolid; }
    /// The free stream: the inflow profile carried across the whole grid (divergence-free).
    void setFreeStream();
    /// One step: boundary conditions, self-advection, viscosity, projection.
    void step(double dt);
    /// Boundary conditions and obstacles, then the projection alone.
    void project();

    /// Velocity at plane position (x, y) in cell units (bilinear on the MAC grid, clamped to the
    /// grid: zero-gradient outside).
    openvdb::Vec2d sample(double x, double y) const;
    /// Cell-centred discrete divergence (per unit time) of cell (i, j); 0 for solid cells.
    double divergence(int i, int j) const;
    double maxDivergence() const;
    double& u(int i, int j) { return mU[size_t(j) * (mNx + 1) + i]; }
    double& v(int i, int j) { return mV[size_t(j) * mNx + i]; }
    double u(int i, int j) const { return mU[size_t(j) * (mNx + 1) + i]; }
    double v(int i, int j) const { return mV[size_t(j) * mNx + i]; }
    /// Inflow speed along the inflow edge at fraction s in [0,1] (left to right along top/bottom,
    /// bottom to top along left/right).
    double profile(double s) const;
    const FluidStepStats& stats() const { return mStats; }
    /// The arrays carried from step to step (face velocities, and the pressure that warm-starts
    /// the next projection), for checkpoints. Obstacles are rebuilt from p every step.
    std::vector<std::pair<const char*, std::vector<double>*>> historyArrays()
    {
        return {{"u", &mU}, {"v", &mV}, {"pressure", &mPhi}};
    }
    /// Seconds spent in advection, viscosity and projection since construction.
    double advectSeconds = 0, viscositySeconds = 0, projectSeconds = 0;

private:
    bool uFixed(int i, int j, double& value) const;
    bool vFixed(int i, int j, double& value) const;
    void applyBoundaries();
    void advect(double dt);
    void diffuse(double dt);
    bool isSolid(int i, int j) const { return mSolid[size_t(j) * mNx + i] != 0; }

    FluidParams mParams;
    int mNx, mNy;
    double mH;
    SideKind mWalls[4];
    std::vector<double> mU, mV, mPhi;
    std::vector<uint8_t> mSolid;
    FluidStepStats mStats;
    std::unique_ptr<fluid::MultigridPoisson> mPoisson; ///< rebuilt when the obstacles change
    std::vector<uint8_t> mPoissonSolid;                ///< the obstacles mPoisson was built for
};

} // namespace ice

/// Section [fluid]: the stable-fluid flow around the crystal and the advection of T.
class FluidEffect : public Effect {
public:
    static std::unique_ptr<Effect> create(ParamDict& dict, const World& world);

    std::string name() const override { return "fluid"; }
    FieldDeclaration declaration() const override;
    void initialize(World& world) override;
    void step(World& world, const StepInfo& info) override;
    void addToFrame(World& world, Frame& frame) override;
    bool writePreview(World& world, const Frame& frame, const std::string& pngPath) override;
    std::vector<std::pair<std::string, double>> timings() const override;
    /// capped_solves: pressure solves that stopped at max_iterations before the tolerance (the
    /// first one is also reported on stderr); max_pressure_iterations: the most any solve took.
    std::vector<std::pair<std::string, double>> counters() const override;
    /// dense2d: the solver's arrays over its MAC grid (the hexagonal lattice's axis-aligned
    /// rectangle), its multigrid and conjugate-gradient vectors, the projection's scratch, and
    /// the `vel` grid over the whole domain with the frame's copy of it (src/fluid/FluidEffect.cpp
    /// counts each). The band solver stores faces and the multigrid only where the band is, but
    /// the band may grow to fill the box, so its worst case is charged (measured: 3027 MiB at
    /// 256^3, about 190 B per cell, `bench fluid noref 256^3`; a 4 % band takes 214 MiB,
    /// `bench fluid plate 256^3`).
    MemoryEstimate memoryEstimate(const World& world) const override;
    bool supportsCheckpoint() const override { return true; }
    void saveState(const World& world, StateWriter& out) const override;
    void loadState(World& world, const StateReader& in) override;

    const ice::StableFluid2D& solver() const { return *mFluid; }
    const ice::FluidParams& params() const { return mParams; }
    /// The band-limited 2D/3D solver (solver = "sparse"; the default on box domains), or null.
    const fluid::SparseFluid* sparseSolver() const { return mSparse.get(); }

private:
    // solver = "sparse" (src/ice/FluidEffectSparse.cpp): fluid/SparseFluid.h in 2D or 3D.
    void initializeSparse(World& world);
    void stepSparse(World& world, const StepInfo& info);
    void updateObstaclesSparse(World& world);
    void writeVelocitySparse(World& world);
    void advectTemperatureSparse(World& world, double dt);
    bool writePreviewSparse(World& world, const std::string& pngPath);
    double cellsPerUnit(const World& world) const; ///< PDE velocity -> cells per unit time

    void updateObstacles(World& world);
    void writeVelocityField(World& world);
    void advectTemperature(World& world, double dt);
    /// Aux-grid (cell units) position of domain cell (i, j).
    openvdb::Vec2d auxPosition(double i, double j) const;

    ice::FluidParams mParams;
    std::unique_ptr<ice::StableFluid2D> mFluid;
    double mOffsetX = 0, mOffsetY = 0; ///< aux cell (0,0) sits at plane position (offset)
    bool mHex = false;
    openvdb::Coord mOrigin{0, 0, 0}; ///< the domain's first cell (aux cell (0, 0))
    double mObstacleSeconds = 0, mVelOutSeconds = 0, mAdvectTSeconds = 0;
    bool mSparseMode = false;
    int64_t mCappedSolves = 0;
    int mMostIterations = 0;
    /// Counts a pressure solve that hit max_iterations (reported once on stderr).
    void notePressureSolve(bool converged, int iterations, double residual, int64_t step);
    fluid::SparseFluidParams mSparseParams;
    std::unique_ptr<fluid::SparseFluid> mSparse;
};

} // namespace frostvdb
