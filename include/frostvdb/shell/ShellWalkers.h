#pragma once
/// @file ShellWalkers.h
/// @brief DLA walkers on a shell's surface (issue 11 item 4): the plane's [dla] rules on a curved
/// surface, with positions on the surface instead of lattice cells.
///
/// A walker is a point x on the surface (index space). Each lattice step moves it one voxel
/// along one of the six directions cos(k pi/3) t + sin(k pi/3) b of the smooth tangent frame at x
/// (t = the crystal axis projected on the tangent plane, so the local lattice is hexagonal and
/// turns with the crystal frame), plus the tangential wind drift, and projects it back to the
/// surface with the band's closest point (trilinear interpolation of cp(x) over the 8 band voxels
/// around it, twice). Ice is the set of closest points of the band's surface-layer voxels
/// (|normal offset| <= 1/2, inside the border) with p > 1/2 when the walkers start, plus the points
/// where walkers stuck, plus the layer voxels another effect (the phase field) turned to ice since;
/// a walker sticks when ice lies within one lattice spacing of it (with the sticking probability
/// of the melt map at its voxel).
///
/// Empty-space jumps (walk on spheres): where the Euclidean distance d to the nearest ice (a lower
/// bound of the geodesic one) is large, the walker jumps to a uniform point of the geodesic
/// circle of radius r = d - 2 around it (also kept 1 voxel inside the open border), found by
/// shooting a geodesic: sub-steps of up to 3 voxels along a direction re-projected on each tangent
/// plane. Every point of that disc is more than one spacing from the ice, so the walk inside it
/// is free and its exit point is uniform on the circle (exactly on a flat or spherical surface,
/// to first order in curvature elsewhere); the jump counts r^2 lattice steps (the mean exit time).
///
/// An open mesh's border removes a walker (like leaving a plane's domain): a step whose
/// unprojected point lies more than half a voxel beyond the border ends the walk (Killed).
///
/// Determinism: walker w of step s draws from ice::WalkerRng(seed, w, s, salt), walks of a batch
/// see the ice as it was at the batch start; the caller applies sticks in walker order.
#include <frostvdb/ice/Dla.h>
#include <frostvdb/shell/ShellBand.h>

#include <openvdb/openvdb.h>

#include <array>
#include <atomic>
#include <functional>
#include <memory>
#include <vector>

namespace frostvdb::shell {

/// Points in index space, bucketed for distance queries: exact up to one bucket (4 voxels),
/// a lower bound beyond: each fine bucket's clearance (below) where sites were given, and an
/// occupancy pyramid of buckets 8 .. 512 voxels.
class SurfacePointIndex {
public:
    static constexpr double kBucket = 4.0;
    static constexpr int kLevels = 8;
    /// Clearances are exact below this (voxels) and read kClearCap beyond.
    static constexpr double kClearCap = 24.0;

    SurfacePointIndex() { clear(); }
    void clear();
    void insert(const openvdb::Vec3d& q);
    /// The index of exactly these points, as clear() and insert() in this order would leave it,
    /// built by sorting (a full sync of millions of ice nodes: 2.5 M inserts took 1.5 s).
    void assign(const std::vector<openvdb::Vec3d>& points);
    /// Removes one point equal to @a q (false when there is none).
    bool erase(const openvdb::Vec3d& q);
    size_t size() const { return mCount; }
    /// Every point as x, y, z triples, bucket by bucket in key order.
    std::vector<double> pointList() const;
    /// Lower bound of the Euclidean distance from @a x to the nearest point: exact when it is at
    /// most kBucket; kFar when there is no point within the pyramid's top level.
    double distance(const openvdb::Vec3d& x) const;
    static constexpr double kFar = 1e9;
    /// Whether a point lies nearer than @a r (at most @a r when @a inclusive) to @a x, for
    /// r <= kBucket: the same answer as comparing distance() with r, from the (at most 8) fine
    /// buckets the ball touches, stopping at the first such point (near the ice a fine bucket's
    /// 3x3x3 hold hundreds of points), and reading no clearance (nothing needs flushing).
    bool hasPointWithin(const openvdb::Vec3d& x, double r, bool inclusive) const;

    /// Keeps a clearance for every fine bucket holding one of the @a count points @a site(k)
    /// (where queries will be):
    /// min(kClearCap, the distance from the bucket's box to the nearest point), a lower bound for
    /// any x in it. The pyramid's bound is a power of two below the distance (4 for any point 4-16
    /// voxels from the ice), which kept walkers there from jumping (docs/shells.md "Walkers").
    /// Clearances are computed when first read and kept exact as points come and go (an insert
    /// lowers the ones it beats, an erase forgets the ones it may have set), so every value read
    /// is the same function of the points whatever the order of queries, inserts and threads.
    void enableClearance(size_t count, const std::function<openvdb::Vec3d(size_t)>& site);
    /// Brings the clearances up to the points inserted and erased since the last call (in
    /// parallel: the erases' checks, then the inserts' minima, each in any order give the same
    /// values). Queries beyond kBucket read clearances: call this first, never beside them.
    /// distance() and the walkers' batches call it; it returns at once when nothing is pending.
    void flushClearances() const;

    /// Repeated queries along a walk: the points of the 3x3x3 fine buckets around the last
    /// query's bucket and the coarse levels' bound are kept until the walk leaves that bucket
    /// (the index must not change meanwhile). Same results as distance().
    /// Bucket grids are shallow trees (root, 16^3 internal nodes, 8^3 leaves): OpenVDB's default
    /// 32^3 top nodes cost 256 KiB each, and these 32 small grids held 20 MiB of them.
    using CountTree = openvdb::tree::Tree3<int32_t, 4, 3>::Type;
    /// Occupied buckets among the 3x3x3 around a bucket (at most 27: a byte per bucket).
    using NearTree = openvdb::tree::Tree3<uint8_t, 4, 3>::Type;
    /// Accessors cache the nodes last visited (one set per thread); they are not registered with
    /// the tree, which does not change during a walk. Queries read the fine level's counts (which
    /// buckets to look up) and every level's neighbourhood counts (the coarse bound).
    using CountAccessor = openvdb::tree::ValueAccessor<const CountTree, false>;
    using NearAccessors = std::vector<openvdb::tree::ValueAccessor<const NearTree, false>>;
    NearAccessors nearAccessors() const;

    class Cursor {
    public:
        explicit Cursor(const SurfacePointIndex& index)
            : mIndex(index), mSlotAcc(*index.mSlots), mNearAcc(index.nearAccessors()),
              mClearAcc(*index.mClearSlots)
        {
        }
        double distance(const openvdb::Vec3d& x);
        /// What a walk needs of distance(x) where it is at most kBucket: only whether a point
        /// lies within @a near (inclusive), with an early exit. Returns distance(x) where that
        /// is more than kBucket; else 0 when a point lies within @a near, and otherwise the next
        /// double above @a near (both lower bounds still). A walker compares a distance below
        /// jumpMinRadius + 2 (> kBucket) with the sticking radius alone, so its walk is the same
        /// as with distance(), without the minimum over the hundreds of points near the ice.
        double walkDistance(const openvdb::Vec3d& x, double near);

    private:
        const SurfacePointIndex& mIndex;
        CountAccessor mSlotAcc; ///< the fine buckets' slots
        NearAccessors mNearAcc;
        CountAccessor mClearAcc; ///< the fine buckets' clearance slots
        uint64_t mKey = ~uint64_t(0);
        /// the occupied fine buckets of the 3x3x3 around the last query's (read in place)
        std::array<const std::vector<openvdb::Vec3d>*, 27> mNear{};
        int mNearCount = -1; ///< -1: not gathered yet
        double mLower = -1;  ///< the bucket's lower bound (clearance, or the pyramid's beyond the cap)
        /// Moves the cursor to fine bucket @a b (holding @a x): its lower bound mLower.
        void enter(const openvdb::Vec3d& x, const openvdb::Coord& b);
    };

private:
    /// The coarse levels' lower bound for any point of the fine bucket holding @a x.
    double coarseBound(const openvdb::Vec3d& x, NearAccessors& near) const;
    /// The clearance of fine bucket @a b (-1 when it holds no site), computed when unknown.
    double clearance(const openvdb::Coord& b, CountAccessor& slots, CountAccessor& clearSlots) const;
    /// Calls @a f(slot, its clearance, distance from its box to @a q) for each known clearance
    /// whose bucket is nearer than kClearCap to @a q.
    template<typename F> void forEachClearanceNear(const openvdb::Vec3d& q, F&& f) const;

    /// Clearances (see enableClearance): slot s + 1 of a fine bucket in mClearSlots, its bucket
    /// mClearBucket[s] and value mClear[s] (-1: not known); the slots of a block of 4^3 fine
    /// buckets are a range (mClearBlocks: index + 1 into mClearBlockRanges), for inserts and erases.
    CountTree::Ptr mClearSlots, mClearBlocks;
    std::vector<openvdb::Coord> mClearBucket;
    std::unique_ptr<std::atomic<float>[]> mClear;
    std::vector<std::pair<int32_t, int32_t>> mClearBlockRanges;
    /// Per block: at least its largest known clearance (-1: none known), so that a point farther
    /// from the block's box changes none of its buckets and their scan is skipped (raised when a
    /// clearance is computed, brought down to the exact maximum after each flush where values
    /// fell); and the block of each clearance slot.
    std::unique_ptr<std::atomic<float>[]> mClearBlockMax;
    std::vector<int32_t> mClearBlockOf;
    /// Blocks whose clearances a flush lowered or forgot (their maximum is computed again).
    std::unique_ptr<std::atomic<uint8_t>[]> mClearBlockDirty;
    /// Raises block @a k's maximum to at least @a v.
    void raiseBlockMax(size_t k, float v) const;
    /// Points inserted and erased since the last flushClearances() (mutable: flushed by const
    /// queries in serial code, before any parallel walk reads the clearances).
    mutable std::vector<openvdb::Vec3d> mPendingInserts, mPendingErases;
    void forgetClearances();

    /// The fine buckets' points: slot s holds a bucket's points in the order they came (the
    /// slot of fine bucket b is mSlots(b) - 1; 0: empty). A tree read through a cached accessor:
    /// a hash map's look-ups were a third of a walker's distance queries.
    std::vector<std::vector<openvdb::Vec3d>> mBuckets;
    std::vector<int32_t> mFreeSlots; ///< slots of buckets that emptied
    CountTree::Ptr mSlots;
    /// The points of bucket @a b (made when absent).
    std::vector<openvdb::Vec3d>& bucketAt(const openvdb::Coord& b);
    /// level k: points per bucket of 4 * 2^k, as a sparse grid of bucket coordinates (counts,
    /// so points can be removed)
    std::array<CountTree::Ptr, kLevels> mCounts;
    /// level k: occupied buckets among the 3x3x3 around each bucket (kept as buckets fill and
    /// empty), so the coarse bound reads one value per level instead of 27
    std::array<NearTree::Ptr, kLevels> mNear;
    /// Adds @a delta to the neighbourhood counts around bucket @a b of level @a k.
    void addNear(int k, const openvdb::Coord& b, int32_t delta);
    size_t mCount = 0;
};

/// One walker's end.
struct ShellWalkEnd {
    enum Kind : uint8_t { Stuck, Killed, Exhausted } kind = Killed;
    openvdb::Vec3d point{0.0};  ///< where it stuck (index space, on the surface)
    openvdb::Vec3d prev{0.0};   ///< the point of its last single step (valid when hasPrev)
    bool hasPrev = false;
    uint32_t moves = 0, jumps = 0;
    double latticeSteps = 0;
};

class ShellWalkers {
public:
    /// A walker sticks when ice lies within this distance (one lattice spacing), voxels.
    static constexpr double kStickRadius = 1.0;
    /// A stick freezes the band voxels whose closest point lies within this distance (voxels):
    /// a disc of about one voxel of area (pi 0.6^2 = 1.13), as a plane's stick freezes one cell.
    /// (0.9 would survive the phase field's re-extension alone, as the 8 inner tricubic nodes of
    /// the stick point lie within sqrt(3)/2 of it, but froze 2.5 voxels of surface per stick and
    /// a hybrid run on a sphere iced over.)
    static constexpr double kMarkRadius = 0.6;

    /// @a params: the [dla] keys (humidity, hits, max_steps, jumps, jump_min_radius,
    /// jump_max_radius (0: 64), release uniform | perimeter = the open mesh's border).
    ShellWalkers(std::shared_ptr<const ShellBand> band, const ice::DlaParams& params, uint64_t seed);

    const ShellBand& band() const { return *mBand; }
    /// The ice: surface-layer voxels with p > 1/2 (p in band order).
    void sync(const std::vector<float>& p);
    /// Adds a stick point @a x to the ice. The walkers' ice is the stick points themselves (as
    /// the plane's is the stuck cells), not the wider disc of voxels a stick freezes.
    void addIce(const openvdb::Vec3d& x);
    /// Adds the surface-layer voxels among @a voxels (ice that another effect grew).
    void addIceVoxels(const std::vector<size_t>& voxels);
    /// Removes the surface-layer voxels among @a voxels (ice that melted); stick points stay
    /// until the next sync() or forgetSticks().
    void removeIceVoxels(const std::vector<size_t>& voxels);
    /// Removes the stick points @a sticks (added by addIce since the last sync()), and the node
    /// flags they set, so that with the surface-layer voxels kept up to date by addIceVoxels and
    /// removeIceVoxels the ice is what sync(p) would build, without rebuilding it.
    void forgetSticks(const std::vector<openvdb::Vec3d>& sticks, const std::vector<float>& p);
    /// Lower bound of the distance (voxels) from @a x to the ice.
    double iceDistance(const openvdb::Vec3d& x) const { return mIce.distance(x); }
    /// Whether ice lies nearer than @a r (at most SurfacePointIndex::kBucket) to @a x.
    bool iceNearer(const openvdb::Vec3d& x, double r) const { return mIce.hasPointWithin(x, r, false); }
    size_t icePoints() const { return mIce.size(); }
    /// The walkers' ice as x, y, z triples (bucket by bucket in key order; for checkpoints), and
    /// the same set restored (distances are minima: the order does not change any result).
    std::vector<double> icePointList() const { return mIce.pointList(); }
    void restoreIce(const std::vector<double>& xyz);
    /// Surface nodes: which nodes walkers treat as ice (checkpoints: a stick point restored near a
    /// node that has melted since would mark it again).
    const std::vector<uint8_t>& iceNodes() const { return mIceNode; }
    void restoreIceNodes(const std::vector<uint8_t>& flags)
    {
        if (flags.size() == mIceNode.size()) mIceNode = flags;
    }
    /// Band voxels whose closest point lies within kMarkRadius of @a x (ascending band index);
    /// on surface nodes, the node nearest @a x (one per surface cell, as a plane's stick freezes one cell).
    std::vector<size_t> markDisc(const openvdb::Vec3d& x) const;
    /// Surface nodes: the node a stick at @a x freezes: of the nodes around it that are not ice
    /// yet (p <= 1/2), the one whose closest point is nearest (a walker sticks next to the ice and
    /// freezes its own cell, as on a plane); -1 when all are ice.
    int32_t freeNodeNear(const openvdb::Vec3d& x, const std::vector<float>& p) const;
    /// Band index of the voxel holding @a x (the walker's site: hits and melt are read there).
    int32_t siteOf(const openvdb::Vec3d& x) const;
    /// Surface-layer voxels (release sites) and those within a voxel of the border.
    const std::vector<size_t>& layer() const { return mLayer; }
    const std::vector<size_t>& borderLayer() const { return mBorderLayer; }

    /// Optional inputs (empty vectors: none), indexed by band voxel.
    struct Inputs {
        const std::vector<float>* melt = nullptr;           ///< sticking probability
        const std::vector<openvdb::Vec3f>* drift = nullptr; ///< voxels per lattice step (tangential)
        /// Steam (the plane's rule): walkers from baseWalkers on are released at a layer site
        /// (band index, steamSites) drawn by the cumulative weights steamCdf.
        int64_t baseWalkers = 0;
        const std::vector<double>* steamCdf = nullptr;
        const std::vector<size_t>* steamSites = nullptr;
    };
    /// Brings the ice's distance bounds up to the ice added and removed since the last batch
    /// (walkBatch does it too; called first, it is timed apart from the walks).
    void flushIce() const { mIce.flushClearances(); }
    /// Walkers [first, first + count) of @a step in parallel; results indexed by walker - first.
    void walkBatch(int64_t step, uint64_t first, uint64_t count, const Inputs& in,
                   std::vector<ShellWalkEnd>& out) const;
    /// One walker, released (when @a start is null) or from @a start, with stream salt @a salt.
    ShellWalkEnd walk(int64_t step, uint64_t walker, uint64_t salt, const openvdb::Vec3d* start,
                      const Inputs& in) const;

    /// Closest point of index position @a y by trilinear interpolation of the band's closest
    /// points (applied twice); false when y is not inside the band. @a lateral: the interpolated
    /// distance beyond an open border of the first pass.
    bool project(const openvdb::Vec3d& y, openvdb::Vec3d& out, double* lateral = nullptr) const;
    /// Lower bound of the distance from @a x to an open mesh's border (kFar when closed).
    double borderDistance(const openvdb::Vec3d& x) const { return mBorder.distance(x); }
    int maxJump() const { return mMaxJump; }

private:
    std::shared_ptr<const ShellBand> mBand;
    ice::DlaParams mParams;
    uint64_t mSeed;
    int mMaxJump;
    bool mOpen; ///< the mesh has a border (walkers beyond it are removed)
    /// Whether a walk may read its distance to the ice as Cursor::walkDistance (no jump is as
    /// short as SurfacePointIndex::kBucket + 2).
    bool mCoarseNear = false;
    std::vector<size_t> mLayer, mBorderLayer;
    SurfacePointIndex mIce, mBorder;
    /// Surface nodes: 1 where the node is ice (its closest point is in mIce), for the graph step.
    std::vector<uint8_t> mIceNode;
    /// A surface-layer voxel: a release site, and ice when p > 1/2.
    bool inLayer(size_t i) const
    {
        return std::fabs(mBand->normalOffset(i)) <= 0.5f && mBand->lateralOffset(i) <= 0.25f;
    }

    /// Surface nodes: one step of the node-graph walk from @a node (walkOnGraph in the .cpp).
    struct GraphStep {
        enum Kind : uint8_t { Moved, Blocked, NextToIce, NoStencil } kind = NoStencil;
        int32_t node = -1;
        double latticeSteps = 0;
    };
    /// @a checkIce: report NextToIce (no move) when a strong neighbour is ice.
    GraphStep graphStep(int32_t node, ice::WalkerRng& rng, bool checkIce) const;

    // walk()'s stages on one walker's state (ShellWalkers.cpp): a jump, a burst of graph steps
    // or one projected lattice step, each moves the walker, declines, leaves the surface or sticks
    struct Walk;
    enum class Move : uint8_t { NotTaken, Moved, Left, Stuck };
    bool releaseSite(Walk& w, uint64_t walker) const;
    Move jump(Walk& w, const VoxelFrame& f, const openvdb::Vec3d& v) const;
    Move graphBurst(Walk& w) const;
    Move latticeStep(Walk& w, const VoxelFrame& f, const openvdb::Vec3d& v) const;
};

} // namespace frostvdb::shell
