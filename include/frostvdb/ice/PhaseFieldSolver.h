#pragma once
/// @file PhaseFieldSolver.h
/// @brief Steps the Kobayashi phase field (p, T) on sparse OpenVDB grids.
///
/// Each step: when due (every k steps, see RegionCadence in ActiveRegion.h) or when another
/// effect changed p or T, rebuild the active region (|p| or |T - T_inf| above the tolerance,
/// dilated by k (stencil reach 2 + front travel), whole leaves); give p and T that topology;
/// then update the region's leaves in parallel in blocks of up to 4x4 leaves (plane): the values
/// and a halo of 2 are gathered into a padded dense block, pass 1 computes the anisotropy
/// coefficients where the block's leaves need them, pass 2 the Euler update of the active voxels
/// into a staging area of 64 floats per plane leaf, copied into p and T once every block is done
/// (in place: a second pair of region-sized grids would cost 2 KiB per leaf each, 8x the plane's
/// voxels). The second-order scheme writes new grids (the last step's inputs, reused). When the
/// region is retired, values back within the tolerance of the far field are switched off and
/// pruned, so memory and cost follow the ice.
/// In dense mode the region is the whole domain: the same code is the dense reference.
#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/core/Domain.h>
#include <frostvdb/icephysics/ImplicitSystem.h>
#include <frostvdb/icephysics/Kobayashi.h>

#include <openvdb/openvdb.h>
#include <openvdb/tree/LeafManager.h>

#include <memory>
#include <vector>

namespace frostvdb {

struct PhaseFieldStepStats {
    uint64_t regionVoxels = 0; ///< the last step's region
    uint64_t voxelUpdates = 0; ///< region voxels summed over steps (the shell's voxel_updates)
    double regionSeconds = 0, kernelSeconds = 0, truncateSeconds = 0;
    /// Parts of regionSeconds: the region rebuilt (growths around other writers' cells are in
    /// regionSeconds only), p and T matched to it (forward Euler), and its plane-leaf view, leaf
    /// groups and leaf managers made.
    double regionBuildSeconds = 0, regionMatchSeconds = 0, regionLayoutSeconds = 0;
    // Second-order scheme: implicit solves (time is part of kernelSeconds).
    double solveSeconds = 0;
    double heatSeconds = 0; ///< the T system alone (latent heat + Crank-Nicolson solve)
    int64_t solves = 0, solverIterationsP = 0, solverIterationsT = 0, unconverged = 0;
    double lastResidual = 0;
    /// lw_cn: voxel-steps whose p left [0, 1] by more than rounding and was clipped back (only
    /// a solve that is not a positive scheme does that now, see PhaseFieldSolver.cpp).
    int64_t clippedVoxels = 0;
    int64_t rebuilds = 0;      ///< region rebuilds (every k steps, or when another effect wrote p or T)
    int64_t regionGrowths = 0; ///< standing regions grown around cells other effects reported
    uint64_t stagingPeakBytes = 0; ///< forward Euler's staging area at its largest
};

struct LeafGroups;
struct RegionEdit;
namespace plane {
class PlaneLeaves;
}

class PhaseFieldSolver {
public:
    PhaseFieldSolver(const KobayashiParams& params, const Domain& domain, const RegionSettings& region);
    ~PhaseFieldSolver();

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

    /// True when no other writer changes p or T between steps (the scene declares no other
    /// effect that writes them): the solver then knows its last outputs are this step's inputs
    /// when the grid pointers match, without fingerprinting both grids twice per step (~13% of
    /// the Euler kernel's instructions).
    void setSoleWriter(bool sole) { mSoleWriter = sole; }

    /// The lists of cells other writers changed in p and T since this solver's last step
    /// (core/FieldEdits.h), when every other writer reports its cells; null when not. With them
    /// the solver trusts its last outputs like a sole writer and grows the standing region around
    /// the listed cells (growActiveRegion) instead of rebuilding it; it clears them after reading.
    void setEditLogs(std::vector<openvdb::Coord>* p, std::vector<openvdb::Coord>* T)
    {
        mEditsP = p;
        mEditsT = T;
    }

    /// Where to list the cells whose p crosses 1/2 (either way) in a step, for a keeper of the
    /// ice set (the walkers' distance map, core/FieldEdits.h crossings); null: none kept. Every
    /// voxel the solver writes is checked, so the list holds every crossing it makes.
    void setCrossingLog(std::vector<openvdb::Coord>* cells) { mCrossings = cells; }

    /// Frees the per-step scratch (the Euler staging area); the next step makes it again.
    void releaseScratch()
    {
        std::vector<float>().swap(mStageP);
        std::vector<float>().swap(mStageT);
    }

    /// Bytes held by the region now, for `bench scale`'s account of the memory: its mask (folded
    /// when the fields are), and with folded fields the plane-leaf view the kernels walk.
    uint64_t regionBytes() const;
    uint64_t regionViewBytes() const;

    /// The melt map (field `melt`, values in [0,1]); null for none. Not owned.
    void setMeltMap(const openvdb::FloatGrid* melt) { mMelt = melt; }

    /// Every grid the scheme carries from one step to the next, by name (checkpoints save and
    /// restore them through these pointers; a null grid means "not started yet"). A new history
    /// member must be listed here: the resume tests compare resumed runs bit for bit.
    std::vector<std::pair<const char*, openvdb::FloatGrid::Ptr*>> historyGrids()
    {
        return {{"last_in_p", &mLastInP}, {"last_in_t", &mLastInT}};
    }
    /// The last step's dt (the midpoint extrapolation scales by it); saved with historyGrids().
    double& lastStepDt() { return mLastStepDt; }

    /// The region cadence's state (region topology, steps left, truncation flag): a resumed run
    /// must keep the region an uninterrupted run would keep, or the bits differ.
    struct CadenceState {
        openvdb::MaskGrid::Ptr region; ///< null: no region built yet
        int stepsLeft = 0;
        bool inputsTruncated = true;
        /// p and T are still what the solver returned (nobody wrote them since): a frame
        /// written in between may prune them, which makes the next step rebuild out of turn.
        bool inputsOurs = false;
    };
    int cadenceStepsLeft() const { return mCadence.stepsLeft(); }
    CadenceState cadenceState(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T) const
    {
        const bool unlisted = !editsReported() || (mEditsP->empty() && mEditsT->empty());
        return {mRegionMask, mCadence.stepsLeft(), mInputsTruncated, mRegionMask && inputsAreOurs(p, T) && unlisted};
    }
    /// @a p and @a T hold the values of @a oldP and @a oldT in the other plane layout
    /// (core/PlaneFold.h): when the old ones were this solver's last output, the new ones are
    /// (so a layout change does not force a rebuild out of turn, which would change the bits).
    void adoptRelaidFields(const openvdb::FloatGrid& oldP, const openvdb::FloatGrid& oldT, const openvdb::FloatGrid& p,
                           const openvdb::FloatGrid& T);
    /// Restores @a state and adopts @a p and @a T (the restored fields) as this solver's last output.
    void restoreCadence(const CadenceState& state, const openvdb::FloatGrid& p, const openvdb::FloatGrid& T);

    struct Failure;
    struct Accumulators;
    struct FoldedLayout;

private:
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    void stepOnce(openvdb::FloatGrid::Ptr& p, openvdb::FloatGrid::Ptr& T, openvdb::FloatGrid* growth,
                  openvdb::FloatGrid* freezeTime, int64_t stepIndex, double time, uint64_t seed,
                  PhaseFieldStepStats* stats);
    void stepSecondOrder(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T,
                         openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
                         openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves,
                         Accumulators& acc, int64_t stepIndex, double tNext, uint64_t seed, Failure& failure,
                         PhaseFieldStepStats* stats, const plane::PlaneLeaves* regionLeaves);
    /// True when @a p and @a T are, unchanged, the grids this solver returned last step.
    bool inputsAreOurs(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T) const;
    /// The region rebuild of a step: truncation when out of turn, the new region and its
    /// generation (@a inputGeneration is reset when the inputs were truncated).
    void rebuildRegionOf(openvdb::FloatGrid& p, openvdb::FloatGrid& T, bool ours, uint64_t& inputGeneration,
                         PhaseFieldStepStats* stats);
    /// The region built from @a p and @a T for @a steps, in their layout (folded fields give a
    /// folded region); with @a edit (folded fields), the standing region edited in place
    /// (RegionOfTopology.h).
    openvdb::MaskGrid::Ptr rebuildRegion(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T, int steps,
                                         RegionEdit* edit = nullptr) const;
    /// Folded p and T: the current region's plane leaves and numbering (made once per region generation).
    const FoldedLayout& foldedLayout();
    /// Gives the standing region the fields' layout (a checkpoint or a layout change of the fields
    /// may leave it in the other): the same cells, so the same bits.
    void layRegionOut(bool folded);
    /// An output grid with the region's topology, reusing @a spare when nobody else holds it.
    openvdb::FloatGrid::Ptr outputGrid(openvdb::FloatGrid::Ptr& spare, uint64_t spareGeneration,
                                       openvdb::FloatGrid& like);

    KobayashiParams mParams;
    Domain mDomain;
    RegionSettings mRegion;
    const openvdb::FloatGrid* mMelt = nullptr;
    // Region cadence (see ActiveRegion.h). A generation numbers each distinct region topology;
    // a grid tagged with the current generation has exactly the region's topology (0: unknown).
    RegionCadence mCadence;
    openvdb::MaskGrid::Ptr mRegionMask; ///< in the fields' layout: folded with folded p and T
    uint64_t mGeneration = 0, mRegionVoxels = 0;
    const openvdb::FloatGrid *mOutP = nullptr, *mOutT = nullptr; ///< what the last step returned
    uint64_t mPrintP = 0, mPrintT = 0, mOutGeneration = 0;      ///< their fingerprints, topology
    bool mInputsTruncated = true; ///< the last outputs were truncated (or are the initial state)
    bool mSoleWriter = false;     ///< see setSoleWriter
    std::vector<openvdb::Coord>*mEditsP = nullptr, *mEditsT = nullptr; ///< see setEditLogs
    bool editsReported() const { return mEditsP && mEditsT; }
    std::vector<openvdb::Coord>* mCrossings = nullptr; ///< see setCrossingLog
    /// Adds the leaves around the reported cells to the standing region and clears the lists;
    /// true when the region gained leaves.
    bool growRegionAroundEdits();
    openvdb::FloatGrid::Ptr mSpareP, mSpareT; ///< second order: last step's inputs, this step's output buffers
    std::vector<float> mStageP, mStageT;      ///< forward Euler: the new values until the kernel is done
    uint64_t mSpareGeneration = 0;
    bool mSpareOurs = false; ///< the spares were this solver's outputs (their off voxels hold the background)
    std::unique_ptr<LeafGroups> mGroups;      ///< the region's leaves in kernel blocks
    std::unique_ptr<FoldedLayout> mFolded;    ///< folded p and T: the region's folded layout
    uint64_t mGroupsGeneration = 0;
    std::unique_ptr<SlotLayout> mLayout;      ///< the implicit systems' rows (second order)
    uint64_t mLayoutGeneration = 0;
    bool mLayoutGroupOrder = false; ///< mLayout's rows are numbered by mGroups (else leaf order)
    /// Last step's implicit systems and start values, kept for their arrays (see ImplicitSystem).
    std::unique_ptr<ImplicitSystem> mSystemP, mSystemT;
    std::vector<double> mStartP, mStartT;
    /// The second-order scheme's memory for its midpoint coefficients.
    openvdb::FloatGrid::Ptr mLastInP, mLastInT; ///< p and T at the start of the last step
    /// The start-value grids as this solver left them (a restored checkpoint replaces them) and
    /// the region generation of their topology: they are reused as the next step's buffers.
    const openvdb::FloatGrid *mLastInOwned = nullptr, *mLastInOwnedT = nullptr;
    uint64_t mLastInGeneration = 0;
    double mLastStepDt = 0; ///< the last step's dt
    double mTheta = 0.5;    ///< implicit weight: 1/2 Crank-Nicolson, 1 in the start-up half-steps
};

/// The plain dense-array loop of the same stencil and arithmetic, on a 2D nx x ny plane with a
/// halo of 2 cells held at the far field (the sparse solver's boundary condition). Arrays are
/// (nx+4) x (ny+4), row-major in x. Used as the reference the sparse kernel is measured against:
/// it runs the plain rows (one cell at a time, EulerRows.h) unless told otherwise.
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
    /// Run the engine's vector rows (EulerRows.h) instead of the plain ones: the bench's answer
    /// to "what if the dense loop were vectorized too". Same bits either way.
    void setVectorRows(bool on) { mVectorRows = on; }

private:
    KobayashiParams mParams;
    Stencil mStencil;
    int mNx, mNy;
    std::size_t mStride;
    bool mVectorRows = false;
    std::vector<float> mP, mT, mPn, mTn, mA, mCx, mCy, mGx, mGy, mGz;
};

} // namespace frostvdb
