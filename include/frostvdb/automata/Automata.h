#pragma once
/// @file Automata.h
/// @brief The hexagonal snowflake automata on plain arrays (no OpenVDB):
///  - Packard-Wolfram: an unfrozen cell with exactly one frozen neighbour freezes.
///  - Coxe-Reiter (2003) fuzzy automaton on a two-level neighbourhood, 11 (C, N, P) cases.
///  - the probabilistic 12-class automaton (pFreeze / pMelt per neighbourhood class).
///  - Reiter (2005) local model (alpha, beta, gamma; receptive cells).
///  - Gravner-Griffeath (2008) 2D mesoscopic model and its 3D hexagonal-prism version (2009).
///
/// Every rule is a synchronous update; D6-symmetric set-ups (one seed cell) can be computed on
/// the 1/12 wedge only (HexLayout::wedgeRows) with a mirrored border, and give bit-identical
/// results to the full computation: sums over neighbour rings use symSum6, random draws are keyed
/// by neighbourhood class (probabilistic rule) or canonical cell (GG noise), never by raw cell.
/// Rows are updated in parallel with TBB; results do not depend on the thread count.
#include <frostvdb/automata/HexLattice.h>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace frostvdb {
namespace automata {

enum class Rule { Packard, CoxeReiter, Probabilistic, Reiter, GravnerGriffeath, GravnerGriffeath3D };

const char* ruleName(Rule r);
/// True for the rules whose update is D6-equivariant (all of them); the set-up must also be
/// symmetric (one seed cell, ring-symmetric background) for the wedge to be used.
bool isSymmetricRule(Rule r);

/// Coxe-Reiter cases, in the order of Table 1 as shipped (see docs/automata.md):
///  0 (C=1, N=0)            isolated ice thickens slowly        (1, 1/300, 0, 0)
///  1 (C=0, N=0)            far from ice: unchanged             (1, 0, 0, 0)
///  2 (C=0, N=1, P=0)       beside one ice cell, side-on        (1, 1/6, -1/12, -1/12)
///  3 (C=0, N=1, P=1)       in line with a branch tip (favoured) (1/5, 3/10, 1/10, -1/10)
///  4 (C=1, N=1)            ice with one ice neighbour           (1/20, 2/5, -3/20, -3/20)
///  5..7 (C=0, N>=2, P=0, 1, >=2)                               rows 6-8 of Table 1
///  8..10 (C=1, N>=2, P=0, 1, >=2)                              rows 9-11 of Table 1
int coxeReiterCase(int C, int N, int P);
constexpr int kCoxeReiterCases = 11;
/// Table 1 of Coxe & Reiter (2003), as printed (row 10's 4/22 included).
std::array<std::array<double, 4>, kCoxeReiterCases> coxeReiterTable1();

/// The 12 classes of the 63 non-empty 6-neighbourhoods under rotation and reflection, numbered
/// in the order the post's Gather finds them (tuples 000001, 000010, ... lexicographically, the
/// first tuple entry being neighbour 0). classOfMask[0] = -1 (empty neighbourhood).
std::array<int8_t, 64> neighbourhoodClasses();
int countNeighbourhoodClasses();
/// The post's tables (class order as above).
std::array<double, 12> defaultPFreeze();
std::array<double, 12> defaultPMelt();

struct CoxeReiterParams {
    double background = 0.17;
    double background2 = -1.0; ///< < 0: constant background; else alternates every `band` rings
    int band = 16;
    std::array<std::array<double, 4>, kCoxeReiterCases> weights = coxeReiterTable1();
};

struct ProbabilisticParams {
    std::array<double, 12> pFreeze = defaultPFreeze();
    std::array<double, 12> pMelt = defaultPMelt();
};

struct ReiterParams {
    double alpha = 1.0, beta = 0.4, gamma = 0.001;
};

/// Gravner-Griffeath parameters. In 2D only the j = 0 entries are used and beta[1][0] =
/// beta[2][0] = beta, beta[3][0] = 1 (the 2008 rules). Index [i][j]: i = min(3, horizontal
/// attached neighbours), j = min(1, vertical attached neighbours).
struct GravnerGriffeathParams {
    double rho = 0.635;
    double beta[4][2] = {{0, 1.6}, {1.6, 1.6}, {1.6, 1.6}, {1.0, 1.0}};
    double kappa[4][2] = {{0.005, 0.005}, {0.005, 0.005}, {0.005, 0.005}, {0.005, 0.005}};
    double mu[4][2] = {{0.015, 0.015}, {0.015, 0.015}, {0.015, 0.015}, {0.015, 0.015}};
    double alpha = 0.4, theta = 0.025, gamma = 0.0005, sigma = 0.0;
    /// Vertical diffusion weight per vertical neighbour (3D); 3/14 makes the prism lattice's
    /// diffusion isotropic for prisms one neighbour-distance high.
    double phi = 3.0 / 14.0;
    bool closed = false; ///< true: reflecting outer wall (mass conserved); false: vapour reservoir
};

struct AutomatonConfig {
    Rule rule = Rule::CoxeReiter;
    int radius = 100;     ///< hexagon radius in cells
    int layers = 1;       ///< prism layers (GG 3D), else 1
    int seedCells = 1;    ///< 1, 2, 3 or 4 initial ice cells (2-4 break the symmetry)
    uint64_t seed = 1;    ///< random seed (probabilistic rule, GG noise)
    bool wedge = true;    ///< compute the 1/12 wedge when the set-up is symmetric
    /// Further initial ice cells (batch flakes use D6-symmetric random clusters). The wedge is
    /// used only when the whole initial set is D6-symmetric.
    std::vector<Axial> extraSeeds;
    CoxeReiterParams cr;
    ProbabilisticParams prob;
    ReiterParams reiter;
    GravnerGriffeathParams gg;
};

/// One snowflake. The state is kept in full-size arrays; in wedge mode only the wedge and its
/// mirrored border are up to date until expand() copies the wedge onto the whole hexagon.
class HexAutomaton {
public:
    explicit HexAutomaton(const AutomatonConfig& cfg);

    void step();
    int64_t steps() const { return mStep; }
    const AutomatonConfig& config() const { return mCfg; }
    const HexLayout& layout() const { return mLayout; }
    int layers() const { return mLayers; }
    bool usesWedge() const { return mWedge; }
    /// Number of cells (prisms in 3D) an update touches per step.
    uint64_t cellsPerStep() const;
    /// Cells (prisms) of the whole lattice, i.e. what the full computation updates.
    uint64_t latticeCells() const;

    /// Makes the whole lattice consistent (a no-op for the full computation).
    void expand();

    // Per-cell state (call expand() first in wedge mode). layer in [0, layers).
    size_t cellIndex(int q, int r, int layer = 0) const
    {
        return size_t(layer + mLayerPad) * mLayout.size() + mLayout.index(q, r);
    }
    /// The rule's main value: 0/1 (Packard, probabilistic), fuzzy value (Coxe-Reiter), water
    /// (Reiter), crystal mass c for attached cells and 0 elsewhere (Gravner-Griffeath).
    double value(size_t i) const;
    bool frozen(size_t i) const;
    /// Step at which the cell froze (0 for seed cells), -1 if not frozen.
    int32_t freezeStep(size_t i) const { return mFreeze[i]; }
    /// Step at which the cell became thick ice (Coxe-Reiter value 1; other rules: freeze step).
    int32_t thickStep(size_t i) const { return mThick[i]; }
    /// Gravner-Griffeath masses (0 for other rules).
    double vapour(size_t i) const { return mV[i]; }
    double boundaryMass(size_t i) const { return mB.empty() ? 0.0 : mB[i]; }
    double crystalMass(size_t i) const { return mC.empty() ? 0.0 : mC[i]; }

    /// Sum of b + c + d over the lattice (Gravner-Griffeath); expand() first in wedge mode.
    double totalMass() const;
    uint64_t frozenCount() const;
    /// Largest hex distance of a frozen cell from the centre.
    int frozenRadius() const;
    /// Compares every cell with its 11 images: true if the state is exactly D6-symmetric.
    bool isD6Symmetric() const;

    /// Checkpoints: calls @a fn(name, member) for the step counter (int64_t&) and every per-cell
    /// array (std::vector<double|uint8_t|int32_t>&) the automaton carries from step to step. A new
    /// state member must be listed here; the resume tests compare every rule bit for bit.
    template <typename Fn>
    void visitState(Fn&& fn)
    {
        fn("step", mStep);
        fn("v", mV);
        fn("v2", mV2);
        fn("b", mB);
        fn("c", mC);
        fn("a", mA);
        fn("a2", mA2);
        fn("wall", mWall);
        fn("freeze", mFreeze);
        fn("thick", mThick);
    }

private:
    void initialise();
    void syncGhosts(std::vector<double>& a);
    void syncGhosts(std::vector<uint8_t>& a);
    template <typename Fn> void forRows(Fn&& fn);
    void stepPackard();
    void stepCoxeReiter();
    void stepProbabilistic();
    void stepReiter();
    void stepGG();
    void track(size_t i, bool isFrozen, bool isThick);

    AutomatonConfig mCfg;
    HexLayout mLayout;
    int mLayers = 1, mLayerPad = 0;
    bool mWedge = false, mGG = false, m3D = false;
    int64_t mStep = 0;
    std::vector<Row> mRows;
    std::vector<std::pair<uint32_t, uint32_t>> mGhosts; ///< (cell, canonical image), layer 0
    std::vector<std::pair<uint32_t, uint32_t>> mImages; ///< every hexagon cell, layer 0
    std::vector<uint32_t> mCanon;                         ///< canonical image per layer-0 cell
    std::vector<double> mV, mV2;                          ///< main value / GG vapour d
    std::vector<double> mB, mC;                           ///< GG boundary and crystal mass
    std::vector<uint8_t> mA, mA2;                         ///< GG attached / Reiter receptive
    std::vector<uint8_t> mWall;                           ///< cells outside the live lattice
    std::vector<int32_t> mFreeze, mThick;
    std::array<int8_t, 64> mClass{};
};

/// All images of a cell under D6 (its orbit, 1, 6 or 12 cells).
std::vector<Axial> d6Orbit(int q, int r);

/// Colour of a cell in the Coxe-Reiter scheme: fuzzy values below 0.5 from darkened cyan to
/// green, 0.5..1 from yellow to red, thick ice from red to purple with its age (0..1).
std::array<float, 3> coxeReiterColour(double value, bool thick, double age01);

} // namespace automata
} // namespace frostvdb
