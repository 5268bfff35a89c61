#pragma once
/// @file GG3D.h
/// @brief The Gravner-Griffeath (2009) 3D snow-crystal model as published (Phys. Rev. E 79,
/// 011601; facts in /work/shared/facts/gravner-griffeath-3d.md), on plain arrays, no OpenVDB.
///
/// Lattice: triangular lattice x Z (hexagonal prisms), cells (q, r, z) in the axial coordinates
/// of HexLattice.h. State per cell: a (attached), b (boundary mass), d (diffusive mass).
/// One step, in order: diffusion (horizontal 1/7 average, vertical 8/14 + 3/14 + 3/14, drift phi
/// along -z, reflecting at the crystal), freezing, attachment (beta per configuration, hole
/// filling), melting. beta, kappa and mu are given per configuration ij, i = min(3, attached
/// horizontal neighbours), j = min(1, attached vertical neighbours).
///
/// Sparse: cells outside an active hexagonal-prism box hold the background (d = rho, a = b = 0)
/// implicitly; the box (and its storage) grows when the disturbance reaches its edge. Diffusion
/// is written in difference form (d + w * sum(d_n - d)), so a cell whose neighbourhood is all
/// background stays exactly background: with sparse_tolerance = 0 the sparse run is bit-identical
/// to a run on the whole domain.
///
/// Symmetry: the hexagonal seeds are D6 x (z -> m - z) symmetric. With wedge = true the solver
/// stores the 1/12 horizontal wedge { 0 <= r <= q }, and, when phi = 0, only the upper half in z:
/// the 1/24 fundamental domain. Neighbour sums are order-independent (symSum6), noise is keyed
/// by the canonical cell, so the reduced run is bit-identical to the full one.
#include <frostvdb/automata/HexLattice.h>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace frostvdb {
namespace automata {

/// Configuration order of the 7-entry arrays: 01, 10, 20, 30, 11, 21, 31.
constexpr int kGGConfigs = 7;
/// Index into the 7-entry arrays of configuration (i, j); -1 for 00.
inline int ggConfigIndex(int i, int j)
{
    static const int8_t idx[4][2] = {{-1, 0}, {1, 4}, {2, 5}, {3, 6}};
    return idx[i][j];
}
const char* ggConfigName(int k); ///< "01", "10", ...

struct GG3DParams {
    double rho = 0.1;
    std::array<double, kGGConfigs> beta{{2.5, 2.0, 2.0, 1.0, 2.0, 1.0, 1.0}};
    std::array<double, kGGConfigs> kappa{{0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1}};
    std::array<double, kGGConfigs> mu{{0.001, 0.001, 0.001, 0.001, 0.001, 0.001, 0.001}};
    double phi = 0.0;     ///< drift along -z
    double noise = 0.0;   ///< eps of the paper's noise (0 = deterministic, as every published flake)
    bool holeFill = true; ///< attach with >= 4 attached horizontal neighbours
    bool holeFillNeedsVertical = false; ///< ... and at least one attached vertical neighbour
};

/// A parameter change at a given step (the paper's time-varying cases, Figs. 32-38).
struct GG3DSwitch {
    int64_t step = 0;
    std::array<double, kGGConfigs> beta{}, kappa{}, mu{};
    bool hasBeta = false, hasKappa = false, hasMu = false;
    double phi = -1.0; ///< < 0: unchanged
};

enum class GG3DWalls { Reflecting, Reservoir };

struct GG3DConfig {
    GG3DParams p;
    std::vector<GG3DSwitch> switches;
    int domainRadius = 200;    ///< hexagon radius of the domain, cells
    int layers = 64;           ///< domain height in prism layers (centred on the seed)
    GG3DWalls walls = GG3DWalls::Reflecting;
    int seedRadius = 2;        ///< hexagonal seed prism: radius (hex distance) ...
    int seedHeight = 1;        ///< ... and height in layers
    int seedRadius2 = -1;      ///< optional second prism (two-radius seeds); < 0: none
    int seedHeight2 = 1;
    bool wedge = true;         ///< compute the 1/24 (1/12 if phi != 0) fundamental domain
    double sparseTolerance = 0.0; ///< |d - rho| at or below this counts as background at the box edge
    int stopRadius = 0;        ///< stop stepping when the crystal reaches this radius; 0 = 80 % of domain
    uint64_t seed = 1;         ///< noise seed
};

/// Bytes the solver may need at most for @a cfg (its whole domain allocated), for budget checks.
uint64_t gg3dMemoryEstimate(const GG3DConfig& cfg);
/// The solver's box after a run of @a steps steps, and its largest moment. The box starts at the
/// seed (+3 cells) and grows (a quarter of its radius, at least 4 rings, and a quarter of its
/// layers) when the disturbance reaches its last two rings or layers; growing, the old and the
/// new arrays are held side by side. The disturbance is where the vapour differs from rho in a
/// bit: one cell a step at first, then slower (the diffusion's kernel falls below rho's last bit
/// beyond Cramer's bound of its lazy walk), pushed on by the crystal as fast as it can grow.
/// The solver's own schedule is replayed on that reach (issue 25: the whole domain twice was
/// charged, 1.53x a 60-step run's peak).
struct GG3DSolverBytes {
    double grown = 0; ///< the box's arrays at the end
    double peak = 0;  ///< the largest moment: a growth's old and new arrays
    int radius = 0;   ///< the box at the end: hex radius ...
    int layers = 0;   ///< ... and layers
};
GG3DSolverBytes gg3dSolverBytes(const GG3DConfig& cfg, int64_t steps);

/// Attached cells a run of @a steps steps may end with, before anything grows (issue 25: the
/// frame's grids follow the crystal, 1,000-1,300 bytes per attached cell). The smaller of
///  - a kinetic bound: the first cell at a new radius has only its 1-2 horizontal neighbours
///    attached (configuration 10 or 20), the first at a new layer only its vertical one (01), and
///    its boundary mass gains at most (1 - kappa) d_max a step towards beta, so the crystal's
///    radius and half height grow by at most (1 - kappa) d_max / beta a step; both stop at the
///    stop radius and 80 % of the half height. The whole prism they span is counted;
///  - the vapour: with reflecting walls the crystal holds at most the domain's mass rho x cells,
///    less what stays vapour because growth stalls below mu beta / (1 - kappa) (the guard rail);
///    at the end of the shipped scenes it held 19-55 % of that (kMassShare, 45 %). A vapour
///    reservoir at the walls feeds it on: there the larger of that share and the cells the
///    reservoir's inflow builds (gg3dReservoirInflow, half an attached cell per unit of mass).
/// With @a detail: the model's terms, for messages.
double gg3dCrystalCellsEstimate(const GG3DConfig& cfg, int64_t steps, std::string* detail = nullptr);

/// The mass a vapour reservoir (rho beyond the walls) feeds into the crystal over a run of at
/// most @a steps steps (issue 25: a share of the domain's vapour charged the capped column 1.9x
/// its cells and the sandwich plate 0.39x). Quasi-steady diffusion from the reservoir into the
/// crystal's hull held near empty, through the layers above and below and the rings around it;
/// the hull grows from the seed, its leading direction at a measured share of its kinetic speed
/// (the tip's vapour is depleted) and the other slower, until it reaches the stop radius or 80 %
/// of the half height.
struct GG3DReservoirInflow {
    double mass = 0;       ///< vapour taken from the reservoir, in cells' mass
    int64_t steps = 0;     ///< steps until the hull reaches its stop (or the run's steps)
    double radius = 0;     ///< the hull at the end: hex radius ...
    double halfHeight = 0; ///< ... and half height, cells
};
GG3DReservoirInflow gg3dReservoirInflow(const GG3DConfig& cfg, int64_t steps);

class GG3D {
public:
    explicit GG3D(const GG3DConfig& cfg);

    /// One step; a no-op once the crystal has reached the stop radius.
    void step();
    int64_t steps() const { return mStep; }
    bool stopped() const { return mStopped; }
    const GG3DConfig& config() const { return mCfg; }
    const GG3DParams& params() const { return mP; }
    bool wedgeH() const { return mWedgeH; }
    bool halfZ() const { return mHalfZ; }
    /// Mirror plane of the seed: z -> m - z (m = 0 for odd seed heights, 1 for even).
    int mirror() const { return mM; }
    int domainZLo() const { return mZDomLo; }
    int domainZHi() const { return mZDomHi; }

    // Queries on the whole lattice (canonical lookup in reduced mode).
    bool attached(int q, int r, int z) const;
    double diffusive(int q, int r, int z) const;
    double boundaryMass(int q, int r, int z) const;
    int32_t attachStep(int q, int r, int z) const; ///< -1: not attached
    bool inDomain(int q, int r, int z) const
    {
        return hexDistance(q, r) <= mCfg.domainRadius && z >= mZDomLo && z <= mZDomHi;
    }

    /// Largest hex distance / |z - m/2| extent of an attached cell (-1 if none).
    int crystalRadius() const { return mCrystalR; }
    int crystalZMin() const { return mCrystalZLo; }
    int crystalZMax() const { return mCrystalZHi; }
    uint64_t attachedCount() const; ///< over the whole lattice
    /// Sum of b + d over the whole domain (background cells included).
    double totalMass() const;
    /// Active box: horizontal radius and layers [lo, hi] computed (whole lattice view).
    int activeRadius() const { return mRa; }
    int activeZLo() const { return mHalfZ ? mM - mZa : mZlo; }
    int activeZHi() const { return mZa; }
    /// Bytes held by the state arrays now, and the largest so far.
    uint64_t bytes() const;
    uint64_t peakBytes() const { return mPeakBytes; }
    /// Cells updated by the last step (the reduced domain's count in wedge mode).
    uint64_t cellsPerStep() const;

    /// Checkpoints: the counters a step carries over (step, stop flag, switches applied, active
    /// box, crystal extent, peak bytes) ...
    std::vector<int64_t> stateScalars() const;
    /// ... and back: rebuilds the active box's layout and re-applies the switches already passed;
    /// then visitArrays refills the arrays. Throws std::runtime_error on values from another set-up.
    void restoreScalars(const std::vector<int64_t>& s);
    /// The state arrays of the active box (scratch T and the noise hold included: the box's
    /// outer layers keep what the last regrowth wrote there), fn(name, std::vector<T>&).
    template <typename Fn>
    void visitArrays(Fn&& fn)
    {
        fn("d", mD);
        fn("t", mT);
        fn("b", mB);
        fn("hold", mHold);
        fn("flags", mFlags);
        fn("count", mCnt);
        fn("attach", mAttach);
    }
    /// Cells of the active box's storage (each array of visitArrays has this many, hold 0 or this).
    size_t storageSize() const { return mBox.size; }

private:
    struct Box {
        int q0 = 0, q1 = 0, r0 = 0, r1 = 0, z0 = 0, z1 = 0; // inclusive storage bounds
        int W = 1, H = 1;
        size_t plane = 1, size = 1;
        size_t index(int q, int r, int z) const
        {
            return size_t(z - z0) * plane + size_t(r - r0) * size_t(W) + size_t(q - q0);
        }
        bool contains(int q, int r, int z) const
        {
            return q >= q0 && q <= q1 && r >= r0 && r <= r1 && z >= z0 && z <= z1;
        }
    };
    struct RowSpan { int z, r, qa, qb; };

    void applySwitches();
    // The stages of step(), in order.
    template <typename Fn>
    void forRows(Fn&& fn) const; ///< fn(row, storage index of its first cell) over the rows, in parallel
    void holdNoise();
    void diffuseHorizontal();
    std::vector<size_t> diffuseVerticallyAndFreeze();
    void attach(const std::vector<size_t>& cells);
    void melt();
    void growActiveBox();
    void resize(int ra, int zlo, int zhi);
    Box boxFor(int ra, int zlo, int zhi) const;
    /// Makes @a nb the active box (radius @a ra, layers [zlo, zhi]): neighbour offsets, rows, ghosts.
    void adoptBox(const Box& nb, int ra, int zlo, int zhi);
    void buildRows();
    void syncGhosts(std::vector<double>& v);
    void syncGhosts(std::vector<uint8_t>& v);
    void initSeed();
    void recount(int q, int r, int z);
    bool edgeDisturbed() const;
    /// The stored cell holding (q, r, z)'s state: canonical image in reduced mode.
    bool storedOf(int& q, int& r, int& z) const;
    uint8_t flagAt(int q, int r, int z) const;
    size_t storedIndex(int q, int r, int z, bool& inBox) const;

    GG3DConfig mCfg;
    GG3DParams mP;
    bool mWedgeH = false, mHalfZ = false, mZSym = true, mStopped = false;
    int mM = 0, mZDomLo = 0, mZDomHi = 0;
    int mRa = 0, mZlo = 0, mZa = 0; // active: hex radius, z range [mZlo, mZa] (mZlo = mM/z-floor in halfZ)
    int mCrystalR = -1, mCrystalZLo = 0, mCrystalZHi = -1;
    int64_t mStep = 0;
    size_t mSwitchNext = 0;
    Box mBox;
    std::vector<RowSpan> mRows;
    std::vector<std::pair<size_t, size_t>> mGhosts; // (ghost, source) storage indices
    std::vector<double> mD, mT, mB, mHold;
    std::vector<uint8_t> mFlags; // bit 0 attached, bit 1 wall (reflecting)
    std::vector<uint8_t> mCnt;   // attached neighbours: horizontal (low nibble) | vertical << 4
    std::vector<int32_t> mAttach;
    std::array<int64_t, 6> mN{};
    uint64_t mPeakBytes = 0;
};

} // namespace automata
} // namespace frostvdb
