#pragma once
/// @file PhaseFieldSolver.h
/// @brief Steps the Kobayashi phase field (p, T) on sparse OpenVDB grids.
///
/// Each step: build the active region (|p| or |T - T_inf| above the tolerance, dilated by the
/// stencil reach 2 plus the front travel), give the new p and T grids that topology, then update
/// every region leaf in parallel (tree::LeafManager + TBB): the leaf's values and a halo of 2
/// are gathered into a padded dense block, pass 1 computes the anisotropy coefficients on the
/// block, pass 2 the Euler update of the leaf's voxels. Values back within the tolerance of the
/// far field are then switched off and pruned, so memory and cost follow the ice front.
/// In dense mode the region is the whole domain: the same code is the dense reference.
#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/core/Domain.h>
#include <frostvdb/ice/Kobayashi.h>

#include <openvdb/openvdb.h>
#include <openvdb/tree/LeafManager.h>

#include <vector>

namespace frostvdb {

struct PhaseFieldStepStats {
    uint64_t regionVoxels = 0;
    double regionSeconds = 0, kernelSeconds = 0, truncateSeconds = 0;
    // Second-order scheme: implicit solves (time is part of kernelSeconds).
    double solveSeconds = 0;
    double heatSeconds = 0; ///< the T system alone (latent heat + Crank-Nicolson solve)
    int64_t solves = 0, solverIterationsP = 0, solverIterationsT = 0, unconverged = 0;
    double lastResidual = 0;
    /// lw_cn: voxel-steps whose p left [0, 1] and was clipped back (only next to walker-frozen
    /// cells now, see PhaseFieldSolver.cpp).
    int64_t clippedVoxels = 0;
};

class PhaseFieldSolver {
public:
    PhaseFieldSolver(const KobayashiParams& params, const Domain& domain, const RegionSettings& region);

    const KobayashiParams& params() const { return mParams; }
    KobayashiParams& params() { return mParams; }

    /// Advances (p, T) by one step of dt, replacing the grid pointers with the new grids.
    /// @a growth accumulates the positive part of dp and @a freezeTime records the time at which
    /// p first exceeded 1/2 (either may be null). @a stepIndex and @a seed key the noise.
    /// Throws SimulationError naming field, voxel, step and time if a value goes non-finite or
    /// p leaves [-0.05, 1.05].
    void step(openvdb::FloatGrid::Ptr& p, openvdb::FloatGrid::Ptr& T, openvdb::FloatGrid* growth,
              openvdb::FloatGrid* freezeTime, int64_t stepIndex, double time, uint64_t seed,
              PhaseFieldStepStats* stats = nullptr);

    /// Updates only the voxels of an existing region (no truncation): the kernel alone, for
    /// benchmarks. Returns the number of voxels updated.
    uint64_t kernelOnly(const openvdb::MaskGrid& region, const openvdb::FloatGrid& p, const openvdb::FloatGrid& T,
                        openvdb::FloatGrid& pOut, openvdb::FloatGrid& tOut) const;

    /// The melt map (field `melt`, values in [0,1]); null for none. Not owned.
    void setMeltMap(const openvdb::FloatGrid* melt) { mMelt = melt; }

    struct Failure;

private:
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    void stepOnce(openvdb::FloatGrid::Ptr& p, openvdb::FloatGrid::Ptr& T, openvdb::FloatGrid* growth,
                  openvdb::FloatGrid* freezeTime, int64_t stepIndex, double time, uint64_t seed,
                  PhaseFieldStepStats* stats);
    void stepSecondOrder(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T,
                         openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
                         openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves,
                         const std::vector<FloatLeaf*>& gLeaves, const std::vector<FloatLeaf*>& fLeaves,
                         int64_t stepIndex, double tNext, uint64_t seed, Failure& failure,
                         PhaseFieldStepStats* stats);

    KobayashiParams mParams;
    Domain mDomain;
    RegionSettings mRegion;
    const openvdb::FloatGrid* mMelt = nullptr;
    /// The second-order scheme's memory for its midpoint coefficients.
    openvdb::FloatGrid::Ptr mLastInP, mLastInT; ///< p and T at the start of the last step
    double mLastStepDt = 0; ///< the last step's dt
    double mTheta = 0.5;    ///< implicit weight: 1/2 Crank-Nicolson, 1 in the start-up half-steps
};

/// The plain dense-array loop of the same stencil and arithmetic, on a 2D nx x ny plane with a
/// halo of 2 cells held at the far field (the sparse solver's boundary condition). Arrays are
/// (nx+4) x (ny+4), row-major in x. Used as the reference the sparse kernel is measured against.
class DensePhaseField {
public:
    DensePhaseField(const KobayashiParams& params, const Lattice& lattice, int nx, int ny);
    int nx() const { return mNx; }
    int ny() const { return mNy; }
    static constexpr int kHalo = 2;
    std::size_t index(int i, int j) const { return std::size_t(j + kHalo) * mStride + std::size_t(i + kHalo); }
    std::vector<float>& p() { return mP; }
    std::vector<float>& T() { return mT; }
    void step();

private:
    KobayashiParams mParams;
    Stencil mStencil;
    int mNx, mNy;
    std::size_t mStride;
    std::vector<float> mP, mT, mPn, mTn, mA, mCx, mCy, mGx, mGy, mGz;
};

} // namespace frostvdb
