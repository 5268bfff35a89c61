#pragma once
/// @file ShellPhaseField.h
/// @brief Surface PDEs on a shell band by the explicit closest point method (Ruuth & Merriman
/// 2008): a Cartesian 3D step in the band's update set, then the closest-point re-extension
/// u(x) = interp(u, cp(x)) with tricubic interpolation (ShellBand::extend). The lw_cn scheme
/// (params.scheme = SecondOrder) uses the implicit closest point method instead (Macdonald &
/// Ruuth 2009; stepImplicit below, shell/ShellImplicit.h).
///
/// Heat: u' = u + dt lap u (7-point Laplacian), re-extended. Wind (optional): a prescribed
/// direction projected on each tangent plane advects T (first-order upwind), as [fluid]'s flow
/// does on a plane.
///
/// Phase field: Kobayashi's eqs. 1-2 on the surface, written as
///   tau dp/dt = div_S(eps^2 grad_S p + eps eps' (n x grad_S p)) + n(p, T),
///   dT/dt = lap_S T + K dp/dt,
/// which is the plane's equation 1 (its cross terms are div(eps eps' (-p_y, p_x)) and
/// (-p_y, p_x) = e_z x grad p). theta is the angle of grad_S p in the voxel's tangent frame
/// (tangent = the crystal axis projected on the tangent plane), so the anisotropy follows the
/// surface, not the voxel axes. Because the extension makes every field constant along the
/// normals, 3D Cartesian differences of the extended fields are the surface operators at the
/// surface (Ruuth & Merriman's principles). Pass 1 (coefficient set) evaluates a = eps^2 and
/// C = eps eps' (n x g) from the central gradient g projected on the tangent plane; pass 2
/// (update set) computes a lap p + grad a . g + div C, the reaction, and the Euler update,
/// exactly as the plane's kobayashiAux/kobayashiEuler pair does with (cx, cy) replaced by C.
/// The eps(theta) evaluation is the plane's own Anisotropy functor.
///
/// Active region (setActiveRegion): a voxel with |p| > tol or |T - T_inf| > tol is "off the
/// background". One step reads at most 9 voxels away (the extension's nodes lie within 7.5
/// voxels of x, each updated from values 2 away), so every band leaf within 9 voxels of an
/// off-background voxel (per leaf, the box of its off-background voxels grown by 9) is stepped
/// (ShellBand::prepare, which builds the ring of leaves around them too). A voxel outside is
/// more than 9 voxels from anything off the background, so its pass-1 coefficients are those of
/// a zero gradient and its extension variable that of p = 0: set once, never recomputed. At tol = 0 every voxel left out would have kept its
/// background value exactly (the extension interpolates differences from the background, so a
/// constant stays bit-exact): the answer equals the whole band's bit for bit. The stepped set
/// only grows. Time and memory then follow the ice and its heat halo, not the mesh's area.
///
/// Every array is indexed by band voxel; every output is one fixed sum: the result does not
/// depend on the thread count.
#include <frostvdb/icephysics/Kobayashi.h>
#include <frostvdb/shell/ShellBand.h>
#include <frostvdb/shell/SlabSweep.h>
#include <frostvdb/shell/SurfaceTapSums.h>
#include <frostvdb/shell/ShellImplicit.h>

#include <functional>
#include <memory>
#include <vector>

namespace frostvdb::shell {

/// One explicit closest-point heat step: u at the update set += dt lap u (spacing @a h), then
/// re-extension to the whole band. @a scratch is reused between calls.
void heatStep(const ShellBand& band, std::vector<float>& u, double dt, double h, std::vector<float>& scratch);

struct ShellStepStats {
    double kernelSeconds = 0, extendSeconds = 0;
    uint64_t voxelUpdates = 0; ///< band voxels stepped (update set) summed over steps
    // lw_cn (the implicit closest-point method) only:
    double solveSeconds = 0;            ///< the two band solves
    int64_t solves = 0, iterationsP = 0, iterationsT = 0, unconverged = 0;
    int64_t clippedVoxels = 0;          ///< p' clipped back into [0, 1] (see stepImplicit)
    double maxClip = 0;                 ///< the largest distance clipped
    double lastResidual = 0;
};

class ShellPhaseField {
public:
    /// @a h: the PDE grid spacing (the domain's `spacing`).
    ShellPhaseField(std::shared_ptr<const ShellBand> band, const KobayashiParams& params, double h);

    const ShellBand& band() const { return *mBand; }
    /// The fields (band order). Non-const access marks them changed: the next step rescans
    /// every built leaf for the active region. Arrays grow with the band (see grow()).
    std::vector<float>& p() { mDirty = mCrossedAll = true; return mP; }
    std::vector<float>& T() { mDirty = true; return mT; }
    const std::vector<float>& p() const { return mP; }
    const std::vector<float>& T() const { return mT; }
    /// Steps only the band around the ice (tolerance @a tolerance >= 0, see the file comment), or
    /// with @a active false the whole band (built here if it is not yet: the reference).
    void setActiveRegion(bool active, double tolerance);
    bool activeRegion() const { return mActive; }
    /// Leaves stepped (band leaf slots), and the band voxels in them.
    const std::vector<uint32_t>& steppedLeaves() const { return mStepped; }
    size_t steppedVoxels() const;
    /// The active region's state for a checkpoint: @a stepped has the origin voxel of every
    /// stepped leaf on; @a boxes holds, at the min corner of each leaf's box of off-background
    /// voxels, 1 + the leaf offset of its max corner. restoreRegion() (after the fields were read
    /// back) rebuilds the same region, so a resumed run steps the same voxels as an uninterrupted one.
    void regionState(openvdb::Int32Grid& boxes, openvdb::MaskGrid& stepped) const;
    void restoreRegion(const openvdb::Int32Grid& boxes, const openvdb::MaskGrid& stepped);
    /// Sizes every array to the band (new voxels at the background: p 0, T T_inf, melt from the
    /// melt source).
    void grow();
    /// The melt value of band voxel i (shell/ShellTexture.h meltSource: the melt field x the colour
    /// melt map x melt_texture), for every voxel built so far and every voxel built later; null:
    /// no melt map (1 everywhere). @a now: the same values for the voxels built so far when the
    /// caller has them (shell::meltMap, leaf by leaf; empty: computed here).
    void setMeltSource(std::function<float(const ShellBand&, size_t)> melt, std::vector<float> now = {});
    /// The melt values per band voxel (empty: none).
    const std::vector<float>& melt() const { return mMelt; }
    /// For an effect that writes single voxels between steps (the walkers' freezes): p, T, growth
    /// and freeze_time without marking everything changed; the writer lists the voxels it wrote
    /// with touched(), so the next step rescans only their leaves for the active region.
    std::vector<float>& pForEdit() { return mP; }
    std::vector<float>& TForEdit() { return mT; }
    void touched(const std::vector<size_t>& voxels);
    /// For that effect's next look at p's side of 1/2: the leaf slots (ascending) where a step
    /// since the last call moved p across 1/2 on some voxel (surface nodes' explicit steps record
    /// them in their copy-back pass). False when that is not known (another writer used p(), or a
    /// step that does not record them ran): then every voxel may have changed side.
    bool takeCrossedLeaves(std::vector<uint32_t>& slots);
    std::vector<float>& growthValues() { return mGrowth; }
    std::vector<float>& freezeValues() { return mFreeze; }
    /// A prescribed wind (PDE units: cells of spacing h per unit of ice time) that advects the
    /// heat; each voxel uses its projection on the tangent plane (first-order upwind).
    void setWind(const openvdb::Vec3d& wind);
    /// Largest dt at which the upwind advection with the diffusion stays a positive combination.
    double windStabilityLimit() const;
    /// A tangential wind per band voxel (same units; empty: none), e.g. shell/ShellWind.h's
    /// potential flow. Replaces setWind's. It cannot follow a growing band: build the band whole
    /// first (ShellBand::materialiseAll), or grow() throws.
    void setWindField(std::vector<openvdb::Vec3f> wind)
    {
        mWindWorld = openvdb::Vec3d(0.0);
        mWind = std::move(wind);
    }
    /// The tangential wind per band voxel built so far (empty: none).
    const std::vector<openvdb::Vec3f>& windField() const { return mWind; }

    /// Surface nodes' Euler step as one sweep of slabs (default, shell/SlabSweep.h) or, with
    /// @a on false, as three passes over the whole band: the reference the sweep is tested against.
    void setSlabSweep(bool on) { mSlabSweep = on; }

    /// Re-extends p and T off the surface (after seeds were written anywhere in the band).
    void extendAll();
    /// One step of dt at time @a time (the time after the step goes to freeze_time): forward
    /// Euler, or with params.scheme = SecondOrder the lw_cn step (see "lw_cn" below).
    void step(double time, ShellStepStats* stats = nullptr) { step(time, 0, 0, stats); }
    /// The same with Kobayashi's interface noise (params.noise > 0): chi in [-1/2, 1/2] is a pure
    /// function of (@a seed, @a stepIndex, the voxel's coordinate), as on a plane, so the result
    /// does not depend on the thread count or on the band's voxel order.
    void step(double time, int64_t stepIndex, uint64_t seed, ShellStepStats* stats);

    // ---- lw_cn: the plane's second-order scheme (Kobayashi.h kobayashiSecondOrderRow) by the
    // implicit closest point method (Macdonald & Ruuth 2009, shell/ShellImplicit.h) ----
    // The phase row: eq. 8's advection-diffusion a lap p + grad a . grad p with a = eps^2(theta)
    // (theta in the voxel's tangent frame, of p extrapolated to the step's midpoint) as the plane's
    // advectionDiffusionCoefficients on the 7-point stencil, in a Crank-Nicolson average, plus
    // the plane's bounded linearised reaction; the heat row: lap T (plus the tangential wind,
    // upwind) in a Crank-Nicolson average, the latent heat K (p' - p) added once p' is solved.
    // Every neighbour value of an implicit row is the extension E of the unknowns (the centre the
    // unknown itself: M&R's stabilised split), the explicit half reads E of the start values the
    // same way; rows are the update set of the stepped leaves. After the solves only the voxels
    // that are not rows (d > 3.5, read by the next step's coefficients and by the outputs) are
    // filled by extension. The first step is two implicit-Euler half-steps (Rannacher), as on a
    // plane. The history below is what a checkpoint must keep to resume bit for bit.
    /// Start values of the last step (band order) and its dt; empty history: no step taken yet.
    std::vector<float>& historyP() { return mStartP; }
    std::vector<float>& historyT() { return mStartT; }
    bool& hasHistory() { return mHistory; }
    double& lastStepDt() { return mLastDt; }
    const std::vector<float>& historyP() const { return mStartP; }
    const std::vector<float>& historyT() const { return mStartT; }
    bool hasHistory() const { return mHistory; }
    double lastStepDt() const { return mLastDt; }

private:
    /// One theta-step of @a dt (theta 1/2: Crank-Nicolson, 1: implicit Euler).
    void stepImplicit(double dt, double theta, double tNext, int64_t stepIndex, uint64_t seed, ShellStepStats* stats);
    // stepImplicit's stages (ShellPhaseField.cpp)
    const BandRows& implicitRows(); ///< the rows of the stepped set (built again when it grew)
    /// p extrapolated to the theta-point (pe) and eps^2(pe) on the coefficient set.
    void thetaPointCoefficients(const KobayashiParams& k, float ex);
    /// The extensions the rows' neighbours read: E T^n, Ep(p^n), Ep(pf) and E pf.
    void implicitExtensions(const BandRows& rows, float ex, float theta);
    /// The p and T systems' rows, right-hand sides and first guesses.
    void assembleImplicitRows(const BandRows& rows, const KobayashiParams& k, double theta, float ex,
                              int64_t stepIndex, uint64_t seed);
    struct ClipCount {
        int64_t clipped = 0;
        double maxClip = 0;
    };
    /// p' back into [0, 1] (counted), or an error beyond [-0.25, 1.25].
    ClipCount clipImplicitPhase(const BandRows& rows, double tNext, double dt);
    /// The solution into the band: rows, then the extension elsewhere; history, growth, freeze time.
    void writeBackImplicit(const BandRows& rows, double tNext);
    /// The forward Euler step on a surface-node band (ShellBand::surfaceNodes): the nodes' stencils
    /// instead of Cartesian differences, nothing to extend.
    void stepSurface(double time, int64_t stepIndex, uint64_t seed, ShellStepStats* stats);
    /// Finds new hot leaves and grows the stepped set (active mode), or lists every leaf.
    void updateRegion();
    std::shared_ptr<const ShellBand> mBand;
    KobayashiParams mParams;
    Anisotropy mAniso;
    double mH;
    std::vector<float> mP, mT, mPn, mTn, mPOld, mGrowth, mFreeze, mMelt;
    uint64_t mUpdateCount = 0; ///< voxels in the update set
    std::vector<float> mA, mCx, mCy, mCz, mGx, mGy, mGz;
    std::vector<SurfaceCoefficients> mCoef; ///< surface nodes: pass 1's coefficients (shell/SurfaceTapSums.h)
    std::vector<FieldSums> mFieldSums;      ///< surface nodes: pass 1's sums of p and T, read by pass 2
    std::vector<WindSums> mWindSums;        ///< surface nodes under a wind: pass 1's derivatives of T
    std::vector<openvdb::Vec3f> mWind; ///< tangential wind per voxel (empty: none)
    openvdb::Vec3d mWindWorld{0.0};
    bool mActive = false, mDirty = true;
    double mTolerance = 0;
    std::function<float(const ShellBand&, size_t)> mMeltSource;
    std::vector<openvdb::CoordBBox> mOff;        ///< per leaf slot: box of its off-background voxels
    std::vector<char> mInStepped;                 ///< per leaf slot
    std::vector<uint8_t> mBlocker;                ///< per leaf slot: the neighbour that last kept it unsaturated
    std::vector<uint32_t> mStepped;               ///< leaf slots stepped (sorted)
    std::vector<uint32_t> mTouched;               ///< leaf slots written by others since the last scan
    std::vector<uint8_t> mCrossed;                ///< per leaf slot: p crossed 1/2 since takeCrossedLeaves
    bool mCrossedAll = true;                      ///< unknown which: every leaf may have
    std::vector<float> mPhi;                      ///< extendPhase's atanh(2p - 1)
    bool mSlabSweep = true;                       ///< stepSurface: one sweep (else three passes)
    SlabSweep mSweep;                             ///< its schedule, built for mSweepSlots
    std::vector<uint32_t> mSweepSlots;
    size_t mSlotsSeen = 0;                        ///< leaf slots scanned for heat so far
    size_t mNonEmptyLeaves = size_t(-1);          ///< built leaves holding voxels, at the last full scan
    // lw_cn
    std::vector<float> mStartP, mStartT, mPe, mPf; ///< last step's start values; p at the step's theta-point and end
    bool mHistory = false;
    double mLastDt = 0;
    std::unique_ptr<BandRows> mRows;
    size_t mRowsStepped = size_t(-1), mRowsBand = size_t(-1); ///< what mRows was built for
    BandSystem mSysP, mSysT;
    std::vector<double> mXP, mXT, mP0, mEP, mEPFixed, mET, mETFixed, mEPhiN, mEPhiF;
};

/// Typed shared state (key shell::kSurfaceFields): the phase field's solver on a shell, whose
/// band-order arrays [dla] freezes into (null: no phase field in the scene).
struct SurfaceFields {
    ShellPhaseField* solver = nullptr;
};

} // namespace frostvdb::shell
