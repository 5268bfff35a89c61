#pragma once
/// @file Dla.h
/// @brief Section [dla]: diffusion-limited aggregation walkers on the ice phase field p (ice
/// paper sections 4.1, 4.3, 4.4 and 6), with multiple-hit averaging, a sticking-probability
/// (melt) map, heat release L (dp/dt)_DLA into T (eq. 6), flow drift from `vel`, steam humidity
/// from `density`, and empty-space jumps that keep the hitting statistics of the plain walk.
///
/// Walk rules (per step, H walkers; see docs/dla.md for the full semantics):
/// @code
///   release on an empty cell (uniformly, or on the domain perimeter; steam adds extra walkers)
///   loop:
///     next to a cell with p > 1/2 ?  stick with probability melt(cell)  -> hits(cell) += 1
///                                    (hits == n: p(cell) = 1, heat L (1 - p_before) into T)
///     far from ice (lattice distance d)? jump to the exit point of the walk from the lattice
///                                    ball of radius d-2 around it (exact first-passage tables);
///                                    beyond the largest table, to a uniform point of the largest
///                                    free circle/sphere (walk on spheres), no cap
///     else step to a random lattice neighbour (+ whole-cell flow drift); leaving the domain kills
/// @endcode
/// Determinism: the walkers of a step are cut into batches of `batch` consecutive walker ids;
/// the walkers of a batch walk in parallel against the ice as it was at the start of the batch,
/// each with its own counter-based stream (seed, step, walker id), and their sticks are applied
/// in walker-id order. A walker whose stick cell froze earlier in the same batch resumes its walk
/// serially (in order) against the updated ice. The result does not depend on the thread count.
#include <frostvdb/core/Domain.h>
#include <frostvdb/core/Effect.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/ice/DlaSparse.h>

#include <openvdb/openvdb.h>

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace frostvdb {
namespace ice {

// kDlaHits ("dla_hits") is in core/FieldKeys.h.

enum class DlaRelease { Uniform, Perimeter };

/// A walker's random stream: SplitMix64 started at hashCounters(seed, walker, step, salt), so it
/// is a pure function of those counters (one finaliser per draw instead of CounterRng's two).
class WalkerRng {
public:
    WalkerRng(uint64_t seed, uint64_t walker, uint64_t step, uint64_t salt = 0)
        : mState(hashCounters(seed, walker, step, salt)) {}
    uint64_t next()
    {
        const uint64_t r = mix64(mState);
        mState += 0x9E3779B97F4A7C15ull;
        return r;
    }
    double uniform() { return toUnit(next()); }

private:
    uint64_t mState;
};

struct DlaParams {
    int64_t humidity = 300;                               ///< H: walkers released per step
    std::vector<std::pair<int64_t, int64_t>> schedule;    ///< (from step, H), sorted by step
    DlaRelease release = DlaRelease::Uniform;
    int hits = 1;                 ///< n: walkers that must stick at a cell before it freezes
    double heatRelease = -1.0;    ///< L; < 0 means K/6
    double dt = 0.0002;           ///< ice clock when no [phase_field] owns it
    double flowDrift = 1.0;       ///< scale of the drift vel * dt
    int64_t maxSteps = 0;         ///< walker lifetime in lattice steps (0: until it leaves)
    bool jumps = true;            ///< empty-space jumps
    int jumpMinRadius = 3;        ///< smallest jump (lattice radius)
    int jumpMaxRadius = 0;        ///< largest jump table (0: 128 on a plane, 32 in a box)
    bool sphereJumps = true;      ///< beyond the largest table: walk-on-spheres jumps, no cap
    int batch = 1024;             ///< walkers per parallel batch
    double steamHumidity = 0.0;   ///< gain of the local steam density on the walker release
    double steamReach = 0.05;     ///< metres above the plane where steam counts
    /// Test hook, never read from a scene: with this probability a jump's exit is redrawn and the
    /// one further along +x kept (a deliberate bias, to prove the statistics test can see one).
    double testJumpBias = 0.0;

    /// H at a step, after the schedule.
    int64_t humidityAt(int64_t step) const;
};

/// First-passage (exit) distribution of the lattice random walk started at the centre of the
/// lattice ball of graph radius r (a diamond on the square lattice, a hexagon on the hexagonal
/// one, an octahedron in a box): solved exactly (conjugate gradients on the Green's function of
/// the walk killed on the sphere), sampled in O(1) with an alias table.
struct SphereTable {
    int radius = 0;
    std::vector<openvdb::Coord> exits; ///< sphere offsets (graph distance exactly r)
    std::vector<double> prob;          ///< exit probability of each
    std::vector<uint32_t> aliasThreshold; ///< Vose alias table: keep i when low word < threshold
    std::vector<uint32_t> alias;
    double meanSteps = 0;              ///< expected number of lattice steps to reach the sphere
    double solverResidual = 0;         ///< CG relative residual reached

    /// Draws an exit index from one uniform 64-bit word (high half: slot, low half: alias test).
    uint32_t sample(uint64_t a) const
    {
        const uint32_t i = uint32_t(((a >> 32) * uint64_t(exits.size())) >> 32);
        return uint32_t(a) < aliasThreshold[i] ? i : alias[i];
    }
    /// The alias table with both candidate exits of each slot beside its threshold: a draw reads
    /// one 16-byte slot, not three arrays at three places (the walkers' jumps are cache misses).
    struct Slot {
        uint32_t threshold;
        int16_t keep[3], other[3]; ///< exits[i] and exits[alias[i]]
    };
    std::vector<Slot> slots;
    /// exits[sample(a)], from the packed slots.
    openvdb::Coord sampleExit(uint64_t a) const
    {
        const Slot& s = slots[size_t(((a >> 32) * uint64_t(slots.size())) >> 32)];
        const int16_t* o = uint32_t(a) < s.threshold ? s.keep : s.other;
        return openvdb::Coord(o[0], o[1], o[2]);
    }
};

/// The table for a neighbour set and radius, computed once per process and cached.
std::shared_ptr<const SphereTable> sphereTable(const std::vector<openvdb::Coord>& neighbours, int radius);

/// The lattice neighbours a walker moves between: the plane's 4 or 6, plus (0,0,+-1) in a box.
std::vector<openvdb::Coord> walkerNeighbours(const Domain& domain);

/// Counters of a run (or a batch), summed in walker order.
struct DlaStats {
    uint64_t released = 0, stuck = 0, frozen = 0, killed = 0, exhausted = 0;
    uint64_t conflicts = 0;  ///< sticks at a cell that froze earlier in the batch (walk resumed)
    uint64_t moves = 0;      ///< loop iterations actually executed (single steps + jumps)
    uint64_t jumps = 0;
    double latticeSteps = 0; ///< equivalent lattice steps (a jump counts its mean exit time)
    double dpDla = 0;        ///< sum of (1 - p_before) over DLA freezes
    double walkSeconds = 0, applySeconds = 0, syncSeconds = 0, steamSeconds = 0, tableSeconds = 0;
    double walkCpuSeconds = 0; ///< the process's CPU (all threads) in the walks: / walkSeconds, their parallelism
    double clearanceSeconds = 0; ///< shells: the ice's distance bounds brought up to date before a batch
};

/// One walker's end.
struct WalkEnd {
    enum Kind : uint8_t { Stuck, Killed, Exhausted } kind = Killed;
    int64_t cell = -1; ///< linear cell index where it stuck
    int64_t prev = -1; ///< the cell it stepped from by one lattice step (-1 after a jump/release)
    uint32_t moves = 0, jumps = 0;
    double latticeSteps = 0;
};

/// The walker machinery, sparse: memory and cost follow the ice and the walkers, not the domain.
///  - exact lattice distance to the ice below a small cap (0: ice, 1: next to ice), one byte per
///    cell, in 8-cell bricks allocated only where the distance is below the cap;
///  - an occupancy pyramid of the ice (blocks of 8 * 2^k cells, k = 0, 1, ...; each level keeps
///    the blocks whose 3^d neighbourhood holds ice): a Chebyshev lower bound of the distance to
///    the ice anywhere, with no cap, in O(log levels) hash probes;
///  - the walk: exact first-passage jump tables up to the largest table, and beyond it
///    walk-on-spheres jumps (uniform exit point on the largest free circle/sphere, the
///    continuum limit of the lattice walk) up to the distance to the ice or the domain edge.
/// Cells are named by a packed key of their offsets from the domain's minimum corner (21 bits
/// per axis). Used by the [dla] effect; public for tests.
class DlaEngine {
public:
    DlaEngine(const Domain& domain, const DlaParams& params, uint64_t seed);
    ~DlaEngine();

    /// Brings the ice flags in line with p > 1/2 (incremental when ice was only added).
    void sync(const openvdb::FloatGrid& p);
    /// sync() from a list of the cells whose p may have crossed 1/2 since the last sync (in
    /// either direction, repeats allowed), when every change of p > 1/2 other than this engine's
    /// own freezes is in the list: only those cells are read. The distances are the same unique
    /// capped minimum sync() gives (the order of freezing and repairing does not matter).
    void syncCells(const openvdb::FloatGrid& p, const std::vector<openvdb::Coord>& cells);
    /// Marks a cell as ice and updates the distances.
    void freeze(int64_t cell);
    /// Marks a cell as ice at once (isIce sees it) and leaves its distances to the next
    /// flushDistances(), which relaxes all such cells in one breadth-first pass. Walks read the
    /// distances: flush before walking.
    void freezeDeferred(int64_t cell);
    void flushDistances();
    bool distancesPending() const;
    bool isIce(int64_t cell) const;
    /// Lattice distance to the nearest ice: exact below distanceCap(), a lower bound above.
    int iceDistance(const openvdb::Coord& c) const;
    int distanceCap() const { return mCap; }
    /// Planes: the block distance (block steps, below its cap of 48) of the 4x4 block holding @a c;
    /// -1 in a box (no block distances). For tests: the incremental map against a rebuilt one.
    int blockDistance(const openvdb::Coord& c) const;
    uint64_t iceCount() const { return mIceCount; }
    /// Full rebuilds of the distances (sync found ice that melted), and cells melted in them.
    uint64_t rebuildCount() const { return mRebuilds; }
    /// Where the distance work goes (seconds and cells since construction): reading p in sync()
    /// and syncCells(), the cell and block breadth-first passes after new ice (walkers' freezes
    /// included), the repairs after melts, the full rebuilds.
    struct Work {
        double scanSeconds = 0, relaxSeconds = 0, coarseSeconds = 0, repairSeconds = 0, rebuildSeconds = 0;
        uint64_t fresh = 0, melted = 0, relaxed = 0; ///< cells frozen, melted, lowered by the passes
    };
    const Work& work() const { return mWork; }

    int64_t index(const openvdb::Coord& c) const
    {
        return int64_t(c.x() - mOrigin.x()) | (int64_t(c.y() - mOrigin.y()) << 21) |
               (int64_t(c.z() - mOrigin.z()) << 42);
    }
    openvdb::Coord coord(int64_t idx) const
    {
        const int64_t m = (int64_t(1) << 21) - 1;
        return openvdb::Coord(int(idx & m), int((idx >> 21) & m), int(idx >> 42)) + mOrigin;
    }
    /// Number of domain cells.
    int64_t cellCount() const { return mNx * mNy * mNz; }
    /// Bytes held by the sparse structures (distance bricks, pyramid, tables not counted).
    size_t memoryBytes() const;
    /// Distance bricks allocated.
    size_t brickCount() const;

    /// Optional inputs of a walk (null: none). The velocity is in index cells per lattice step.
    struct Inputs {
        const openvdb::FloatGrid* melt = nullptr;
        const openvdb::Vec3SGrid* vel = nullptr;
        openvdb::Mat3d velToCells = openvdb::Mat3d::zero(); ///< world vel -> cells per step
        bool velOnDomainTransform = true;
        const std::vector<double>* steamCdf = nullptr;      ///< cumulative release weights
        const std::vector<int64_t>* steamCells = nullptr;   ///< cells of the weights
        int64_t baseWalkers = 0; ///< walker ids >= this are steam walkers
    };

    /// Releases and walks walkers [first, first+count) of @a step in parallel (TBB) against the
    /// current ice; results indexed by walker - first.
    void walkBatch(int64_t step, uint64_t first, uint64_t count, const Inputs& in,
                   std::vector<WalkEnd>& out) const;
    /// Walks one walker from a given cell (or releases it when @a start < 0), with stream
    /// @a stream (a salt separates resumed walks from first walks).
    WalkEnd walk(int64_t step, uint64_t walker, uint64_t salt, int64_t start, const Inputs& in) const;

    double stickingProbability(const Inputs& in, int64_t cell) const;
    uint64_t seed() const { return mSeed; }
    const std::vector<openvdb::Coord>& neighbours() const { return mNbr; }
    const Domain& domain() const { return mDomain; }
    /// Largest jump table radius in use.
    int maxJumpRadius() const { return mTableForRadius.empty() ? 0 : int(mTableForRadius.size()) - 1; }

    struct Sparse; ///< the bricks and the pyramid (DlaEngine.cpp)
    struct Walker; ///< one walk in progress (DlaEngine.cpp)
    struct Probes; ///< per-task accessors of the optional grids (DlaEngine.cpp)
    struct SyncCache; ///< p > 1/2 per leaf at the last sync (DlaEngine.cpp)

private:
    void rebuild(const openvdb::FloatGrid& p);
    void relaxQueue();
    /// Brings the block distances in line with the blocks that gained or lost their ice.
    void flushCoarse();
    /// Takes melted cells out of the ice and repairs the distances around them.
    void repairMelted(const std::vector<int64_t>& melted);
    int64_t release(int64_t step, uint64_t walker, WalkerRng& rng, const Inputs& in) const;
    WalkEnd walkFrom(WalkerRng& rng, int64_t idx, const Inputs& in, Probes& pr) const;

    Domain mDomain;
    DlaParams mParams;
    uint64_t mSeed;
    openvdb::Coord mOrigin;
    int64_t mNx, mNy, mNz;
    int mDim;
    std::vector<openvdb::Coord> mNbr;
    int mCap = 16;              ///< exact distances below this (16 on a plane, 10 in a box)
    double mSphereScale = 1.0;  ///< index Chebyshev reach of a unit plane displacement
    double mGraphScale = 1.0;   ///< lattice (graph) distance reach of a unit plane displacement
    uint64_t mIceCount = 0;
    uint64_t mRebuilds = 0;
    Work mWork;
    std::unique_ptr<Sparse> mSparse;
    std::unique_ptr<SyncCache> mSyncCache;
    std::vector<int64_t> mQueue;
    std::vector<std::shared_ptr<const SphereTable>> mTables;
    std::vector<int16_t> mTableForRadius; ///< radius -> index in mTables of the largest <= it (-1)
    int mDigits = 1;

public:
    static constexpr int kBrickLog2 = 3;
};

/// The [dla] effect on a lattice (plane, box). create() reads the keys every discretisation
/// shares and returns the back end the domain asks for (ice/DlaBackend.h): this class on a
/// lattice, the surface walkers on a shell.
class DlaEffect : public Effect {
public:
    static std::unique_ptr<Effect> create(ParamDict& params, const World& world);
    explicit DlaEffect(const DlaParams& params) : mParams(params) {}

    std::string name() const override { return "dla"; }
    FieldDeclaration declaration() const override;
    void initialize(World& world) override;
    void step(World& world, const StepInfo& info) override;
    void addToFrame(World& world, Frame& frame) override;
    double time() const override { return mTime; }
    std::vector<std::pair<std::string, double>> timings() const override;
    std::vector<std::pair<std::string, double>> counters() const override;
    bool supportsCheckpoint() const override { return true; }
    void saveState(const World& world, StateWriter& out) const override;
    void loadState(World& world, const StateReader& in) override;
    /// The ice the walkers can freeze in the run, in the fields they write (p, T, growth_acc,
    /// freeze_time, dla_hits) and the frame's copies: at most one cell per `hits` walkers
    /// released, at most the whole domain (src/ice/DlaEffect.cpp).
    MemoryEstimate memoryEstimate(const World& world) const override;

    const DlaParams& params() const { return mParams; }
    const DlaStats& stats() const { return mStats; }
    const DlaEngine* engine() const { return mEngine.get(); }

private:
    void updateSteam(World& world);
    // step()'s stages
    /// The engine's distances brought in line with p (the listed crossings, or all of p).
    void syncDistances(World& world, const openvdb::FloatGrid& p);
    /// The walks' inputs (melt map, steam release, flow drift); returns the steam's extra walkers.
    int64_t walkerInputs(World& world, const StepInfo& info, double dt, int64_t H, const openvdb::FloatGrid* melt,
                         const openvdb::Vec3SGrid* vel, DlaEngine::Inputs& in);
    /// Where a walker whose stick cell froze earlier in its batch goes on from (-1: nowhere).
    int64_t resumeStart(const WalkEnd& e, const Domain& domain, int64_t step, uint64_t walker) const;
    /// dla_hits written from the touched counts; counts under ice and emptied leaves dropped.
    void updateHitCounts(const openvdb::FloatGrid& p, openvdb::Int32Grid& hits, std::vector<int64_t>& touched,
                         int64_t step);

    DlaParams mParams;
    double mHeat = 0; ///< L in use
    double mTime = 0;
    std::unique_ptr<DlaEngine> mEngine;
    DlaStats mStats;
    openvdb::GridBase::ConstPtr mSteamSource; ///< the density grid the steam map was built from
    /// A cell's hits while stepping, and the step that last listed it as touched (step + 1; 0:
    /// never), so each cell is listed once a step however many walkers stick at it.
    struct HitCount {
        int32_t count = 0;
        uint32_t listed = 0;
    };
    KeyMap<HitCount> mHitCount; ///< dla_hits by cell while stepping (hits > 1), sparse
    /// mHitCount from the dla_hits field (initialisation and a restored checkpoint).
    void loadHitCounts(const World& world);
    /// One more walker stuck at @a cell (listed in @a touched at its first stick of the step,
    /// stamped @a listedStamp); true when the count reaches n, which starts it again.
    bool countHit(int64_t cell, uint32_t listedStamp, std::vector<int64_t>& touched);
    std::vector<double> mSteamCdf;
    std::vector<int64_t> mSteamCells;
    double mSteamSum = 0;
};

} // namespace ice
} // namespace frostvdb
