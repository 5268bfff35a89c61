#pragma once
/// @file ShellPhaseField.h
/// @brief Surface PDEs on a shell band by the explicit closest point method (Ruuth & Merriman
/// 2008): a Cartesian 3D step in the band's update set, then the closest-point re-extension
/// u(x) = interp(u, cp(x)) with tricubic interpolation (ShellBand::extend).
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
/// Every array is indexed by band voxel; every output is one fixed sum: the result does not
/// depend on the thread count.
#include <frostvdb/ice/Kobayashi.h>
#include <frostvdb/shell/ShellBand.h>

#include <memory>
#include <vector>

namespace frostvdb::shell {

/// One explicit closest-point heat step: u at the update set += dt lap u (spacing @a h), then
/// re-extension to the whole band. @a scratch is reused between calls.
void heatStep(const ShellBand& band, std::vector<float>& u, double dt, double h, std::vector<float>& scratch);

struct ShellStepStats {
    double kernelSeconds = 0, extendSeconds = 0;
    uint64_t voxelUpdates = 0; ///< band voxels stepped (update set) summed over steps
};

class ShellPhaseField {
public:
    /// @a h: the PDE grid spacing (the domain's `spacing`).
    ShellPhaseField(std::shared_ptr<const ShellBand> band, const KobayashiParams& params, double h);

    const ShellBand& band() const { return *mBand; }
    std::vector<float>& p() { return mP; }
    std::vector<float>& T() { return mT; }
    std::vector<float>& growthValues() { return mGrowth; }
    std::vector<float>& freezeValues() { return mFreeze; }
    /// A prescribed wind (PDE units: cells of spacing h per unit of ice time) that advects the
    /// heat; each voxel uses its projection on the tangent plane (first-order upwind).
    void setWind(const openvdb::Vec3d& wind);
    /// Largest dt at which the upwind advection with the diffusion stays a positive combination.
    double windStabilityLimit() const;
    /// A tangential wind per band voxel (same units; empty: none), e.g. shell/ShellWind.h's
    /// potential flow. Replaces setWind's.
    void setWindField(std::vector<openvdb::Vec3f> wind) { mWind = std::move(wind); }
    /// Per-voxel melt temperature scale in [0, 1] (empty: 1 everywhere).
    void setMelt(std::vector<float> melt) { mMelt = std::move(melt); }

    /// Re-extends p and T off the surface (after seeds were written anywhere in the band).
    void extendAll();
    /// One forward-Euler step of dt at time @a time (the time after the step goes to freeze_time).
    void step(double time, ShellStepStats* stats = nullptr) { step(time, 0, 0, stats); }
    /// The same with Kobayashi's interface noise (params.noise > 0): chi in [-1/2, 1/2] is a pure
    /// function of (@a seed, @a stepIndex, the voxel's coordinate), as on a plane, so the result
    /// does not depend on the thread count or on the band's voxel order.
    void step(double time, int64_t stepIndex, uint64_t seed, ShellStepStats* stats);

private:
    std::shared_ptr<const ShellBand> mBand;
    KobayashiParams mParams;
    Anisotropy mAniso;
    double mH;
    std::vector<float> mP, mT, mPn, mTn, mPOld, mGrowth, mFreeze, mMelt;
    uint64_t mUpdateCount = 0; ///< voxels in the update set
    std::vector<float> mA, mCx, mCy, mCz, mGx, mGy, mGz;
    std::vector<openvdb::Vec3f> mWind; ///< tangential wind per voxel (empty: none)
};

} // namespace frostvdb::shell
