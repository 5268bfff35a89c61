/// @file DlaEngine.cpp
/// @brief The DLA walkers, sparse: exact capped lattice distances to the ice in 8-cell bricks
/// that exist only near the ice, an occupancy pyramid of the ice for uncapped lower bounds of
/// the distance anywhere, release, walk, jumps (exact tables, then walk on spheres).
///
/// Why bricks in a flat hash map and not VDB accessors: a walker reads its cell's distance at
/// every step, and 10^9 steps per run make a byte read from a cached brick (~1 ns) against a
/// ValueAccessor probe (~10-20 ns) the difference between seconds and minutes. A walker keeps
/// the brick it is in; a hash probe happens only when it crosses into another brick.
#include <frostvdb/ice/Dla.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/geometry/HexLattice.h>

#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <chrono>
#include <unordered_map>
#include <cmath>
#include <cstdlib>
#include <new>
#include <stdexcept>

namespace frostvdb {
namespace ice {

int64_t DlaParams::humidityAt(int64_t step) const
{
    int64_t h = humidity;
    for (const auto& s : schedule)
        if (step >= s.first) h = s.second;
    return h;
}

std::vector<openvdb::Coord> walkerNeighbours(const Domain& domain)
{
    return domain.walkerNeighbours();
}

namespace {
constexpr int kB = 1 << DlaEngine::kBrickLog2; // brick side
constexpr int kBMask = kB - 1;
constexpr int kNoBound = 1 << 30;
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

inline uint64_t packKey(int64_t x, int64_t y, int64_t z) { return uint64_t(x) | uint64_t(y) << 21 | uint64_t(z) << 42; }
inline int cellInBrick(int x, int y, int z) { return (x & kBMask) | (y & kBMask) << 3 | (z & kBMask) << 6; }
/// Blocks of the block distances: 4x4 cells, distances below 48 block steps (186 cells on the
/// hexagonal and square lattices: beyond the largest jump table, where walk-on-spheres jumps
/// take over and the pyramid's bound is used as well).
constexpr int kCoarseLog2 = 2;
constexpr int kCoarse = 1 << kCoarseLog2;
constexpr int kCoarseCap = 48;
} // namespace

/// Small domains (at most this many cells, 2048^2 on a plane) find their bricks through a
/// directory and keep the pyramid's near counts in arrays: a look-up is one or two loads instead
/// of a hash and a probe (the walkers read a brick each time they cross into one and the pyramid
/// at every jump far from the ice; the distance passes read a brick at every brick change). Both
/// take at most 1/64 byte per cell then; larger domains keep the hash maps alone, whose memory
/// follows the ice, not the domain.
constexpr int64_t kDenseCells = int64_t(1) << 22;

/// Where the bricks are, for look-ups: tiles of 16 x 16 bricks (one z layer each) over the
/// domain's bricks, each tile a table of brick pointers allocated when its first brick is made.
/// Off (covers nothing) until cover() is called.
struct BrickDirectory {
    static constexpr int kTileLog2 = 4;
    static constexpr int kTile = 1 << kTileLog2;
    int tx = 0, ty = 0, tz = 0; ///< tiles per axis (0: off)
    std::vector<std::unique_ptr<uint8_t*[]>> tiles;

    /// Covers @a nbx x @a nby x @a nbz bricks.
    void cover(int64_t nbx, int64_t nby, int64_t nbz)
    {
        tx = int((nbx + kTile - 1) >> kTileLog2);
        ty = int((nby + kTile - 1) >> kTileLog2);
        tz = int(nbz);
        clear();
    }
    void clear()
    {
        tiles.clear();
        tiles.resize(size_t(tx) * size_t(ty) * size_t(tz));
    }
    bool covers(int bx, int by, int bz) const
    {
        return unsigned(bx >> kTileLog2) < unsigned(tx) && unsigned(by >> kTileLog2) < unsigned(ty) &&
               unsigned(bz) < unsigned(tz);
    }
    size_t tileOf(int bx, int by, int bz) const
    {
        return (size_t(bz) * size_t(ty) + size_t(by >> kTileLog2)) * size_t(tx) + size_t(bx >> kTileLog2);
    }
    static size_t inTile(int bx, int by) { return size_t((bx & (kTile - 1)) | (by & (kTile - 1)) << kTileLog2); }
    /// The brick at (bx, by, bz), covered; null if none.
    uint8_t* find(int bx, int by, int bz) const
    {
        uint8_t* const* t = tiles[tileOf(bx, by, bz)].get();
        return t ? t[inTile(bx, by)] : nullptr;
    }
    /// The pointer slot of a covered brick, its tile made when missing.
    uint8_t*& slot(int bx, int by, int bz)
    {
        auto& t = tiles[tileOf(bx, by, bz)];
        if (!t) t.reset(new uint8_t*[size_t(kTile * kTile)]());
        return t[inTile(bx, by)];
    }
    size_t bytes() const
    {
        size_t b = tiles.size() * sizeof(tiles[0]);
        for (const auto& t : tiles)
            if (t) b += sizeof(uint8_t*) * size_t(kTile * kTile);
        return b;
    }
};

/// Byte values in 8-cell bricks (8x8 on a plane, 8^3 in a box), found through the directory
/// where it covers them and a flat hash map elsewhere, only where some value is below the cap (a
/// missing brick reads as the cap everywhere).
struct ByteBricks {
    int brickVolume = 64;
    uint8_t cap = 16;
    BrickDirectory directory;                     ///< brick -> its cells, inside the domain's bricks
    KeyMap<uint8_t*> brickOf;                     ///< brick key -> its cells, outside the directory
    /// The bricks, in chunks of kChunk allocated as they fill (stable addresses), each brick
    /// aligned to a cache line: a walker's read of a brick touches one line, and bricks made
    /// together (near the same ice) sit together.
    static constexpr size_t kChunk = 64;
    struct Aligned {
        void operator()(uint8_t* p) const { std::free(p); }
    };
    std::vector<std::unique_ptr<uint8_t, Aligned>> pool;
    size_t bricks = 0; ///< bricks handed out

    void clearBricks()
    {
        directory.clear();
        brickOf.clear();
        pool.clear();
        bricks = 0;
    }
    size_t brickBytes() const
    {
        return directory.bytes() + brickOf.bytes() + pool.size() * kChunk * size_t(brickVolume);
    }
    const uint8_t* brick(int bx, int by, int bz) const
    {
        if (directory.covers(bx, by, bz)) return directory.find(bx, by, bz);
        uint8_t* const* b = brickOf.find(packKey(bx, by, bz));
        return b ? *b : nullptr;
    }
    uint8_t* brickForWrite(int bx, int by, int bz)
    {
        uint8_t** at;
        if (directory.covers(bx, by, bz)) {
            at = &directory.slot(bx, by, bz);
        } else {
            auto ins = brickOf.insert(packKey(bx, by, bz), nullptr);
            at = ins.first;
        }
        if (!*at) {
            if (bricks == pool.size() * kChunk) {
                void* chunk = std::aligned_alloc(64, kChunk * size_t(brickVolume));
                if (!chunk) throw std::bad_alloc();
                pool.emplace_back(static_cast<uint8_t*>(chunk));
            }
            uint8_t* b = pool.back().get() + (bricks % kChunk) * size_t(brickVolume);
            ++bricks;
            std::fill(b, b + brickVolume, cap);
            *at = b;
        }
        return *at;
    }
    int fine(int x, int y, int z) const
    {
        const uint8_t* b = brick(x >> DlaEngine::kBrickLog2, y >> DlaEngine::kBrickLog2, z >> DlaEngine::kBrickLog2);
        return b ? b[cellInBrick(x, y, z)] : cap;
    }
    void setFine(int x, int y, int z, int d)
    {
        brickForWrite(x >> DlaEngine::kBrickLog2, y >> DlaEngine::kBrickLog2, z >> DlaEngine::kBrickLog2)[cellInBrick(x, y, z)] =
            uint8_t(d);
    }
};

/// The sparse state: distance bricks and the occupancy pyramid, in cell offsets from the origin;
/// on a plane also the block distances (see Coarse below).
struct DlaEngine::Sparse : ByteBricks {
    int dim = 2;
    /// Block distances (planes): for each block of kCoarse x kCoarse cells, the lattice distance
    /// in block steps to the nearest block that holds ice, below coarse.cap (a BFS on the block
    /// lattice, the same unique capped minimum as the cell distances). A cell of a block at block
    /// distance D is at least kCoarse * D - coarseSlack lattice steps from any ice (the lattice
    /// distance is a norm; coarseSlack is the largest distance between two cells of one block).
    /// Beyond the exact cell cap this bound is within a block or two of the true distance, where
    /// the pyramid's is within a factor 2, so the walkers' jumps there are about twice as large.
    bool coarseOn = false;
    ByteBricks coarse;
    int coarseSlack = 0;
    KeyMap<uint32_t> coarseCount;      ///< ice cells per block
    std::vector<int64_t> coarseGained; ///< blocks whose count left 0 since the last flush
    std::vector<int64_t> coarseLost;   ///< blocks whose count fell to 0 since the last flush
    /// Level k: blocks of 8 * 2^k cells. occupied[k]: per block, its ice cells (k = 0) or its
    /// occupied child blocks (k > 0); near[k]: per block, the occupied blocks in its 3^d
    /// neighbourhood (the blocks with none are where a Chebyshev bound holds). Counts, so that a
    /// melt takes its cell out again: the pyramid is always that of the current ice.
    std::vector<KeyMap<uint32_t>> occupied;
    std::vector<KeyMap<uint8_t>> near;
    /// near[k] as an array over the level's blocks (and one beyond each upper edge) on a small
    /// domain (kDenseCells); empty where the level uses the map.
    struct DenseLevel {
        std::vector<uint8_t> count;
        int64_t nx = 0, ny = 0, nz = 0;
        size_t at(int bx, int by, int bz) const { return (size_t(bz) * size_t(ny) + size_t(by)) * size_t(nx) + size_t(bx); }
        bool inside(int bx, int by, int bz) const { return bx < nx && by < ny && bz < nz; } // (never negative)
    };
    std::vector<DenseLevel> nearDense;

    /// The levels' arrays for a domain of @a n cells per axis.
    void denseLevels(const int64_t n[3])
    {
        nearDense.assign(near.size(), DenseLevel{});
        for (size_t k = 0; k < near.size(); ++k) {
            const int sh = kBrickLog2 + int(k);
            DenseLevel& d = nearDense[k];
            d.nx = ((n[0] - 1) >> sh) + 2;
            d.ny = ((n[1] - 1) >> sh) + 2;
            d.nz = dim == 3 ? ((n[2] - 1) >> sh) + 2 : 1;
            d.count.assign(size_t(d.nx * d.ny * d.nz), 0);
        }
    }
    /// The near count of block (bx, by, bz) at level k, for writing.
    uint8_t& nearCount(size_t k, int bx, int by, int bz)
    {
        DenseLevel& d = nearDense[k];
        if (!d.count.empty() && d.inside(bx, by, bz)) return d.count[d.at(bx, by, bz)];
        return *near[k].insert(packKey(bx, by, bz), 0).first;
    }
    /// Whether no block of the 3^d neighbourhood of block (bx, by, bz) at level k holds ice.
    bool nearFree(size_t k, int bx, int by, int bz) const
    {
        const DenseLevel& d = nearDense[k];
        if (!d.count.empty() && d.inside(bx, by, bz)) return d.count[d.at(bx, by, bz)] == 0;
        const uint8_t* n = near[k].find(packKey(bx, by, bz));
        return !n || *n == 0;
    }

    void clear()
    {
        clearBricks();
        for (auto& m : occupied) m.clear();
        for (auto& m : near) m.clear();
        for (auto& d : nearDense) std::fill(d.count.begin(), d.count.end(), uint8_t(0));
        coarse.clearBricks();
        coarseCount.clear();
        coarseGained.clear();
        coarseLost.clear();
    }
    /// Adds (+1) or removes (-1) an ice cell: a block's count changes level by level while a
    /// block becomes occupied (or empty), and then its neighbourhood's near counts.
    void changeIce(int x, int y, int z, int sign)
    {
        if (coarseOn) {
            const uint64_t key = packKey(x >> kCoarseLog2, y >> kCoarseLog2, z >> kCoarseLog2);
            uint32_t& n = *coarseCount.insert(key, 0).first;
            if (sign > 0 && n++ == 0) coarseGained.push_back(int64_t(key));
            if (sign < 0 && --n == 0) coarseLost.push_back(int64_t(key));
        }
        const int zr = dim == 3 ? 1 : 0;
        for (size_t k = 0; k < occupied.size(); ++k) {
            const int sh = kBrickLog2 + int(k);
            const int bx = x >> sh, by = y >> sh, bz = z >> sh;
            uint32_t& n = *occupied[k].insert(packKey(bx, by, bz), 0).first;
            const uint32_t before = n;
            n = uint32_t(int64_t(n) + sign);
            if ((sign > 0 && before != 0) || (sign < 0 && n != 0)) break; // the levels above keep their count
            for (int dz = -zr; dz <= zr; ++dz)
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        if (bx + dx < 0 || by + dy < 0 || bz + dz < 0) continue;
                        uint8_t& m = nearCount(k, bx + dx, by + dy, bz + dz);
                        m = uint8_t(int(m) + sign);
                    }
        }
    }
    void addIce(int x, int y, int z) { changeIce(x, y, z, +1); }
    /// Chebyshev lower bound of the distance to the ice (0: none known; kNoBound: no ice).
    /// @a hint: the level found last time for a nearby cell (updated), where the scan starts.
    int bound(int x, int y, int z, bool anyIce, int& hint) const
    {
        if (!anyIce) return kNoBound;
        // free at level k implies free below it (the neighbourhoods nest): from the hint, scan
        // up while free or down until free (a walker's successive cells mostly keep their level)
        auto freeAt = [&](int k) {
            const int sh = kBrickLog2 + k;
            return nearFree(size_t(k), x >> sh, y >> sh, z >> sh);
        };
        const int top = int(near.size()) - 1;
        int lo = std::min(std::max(hint, -1), top);
        if (lo >= 0 && !freeAt(lo)) {
            do --lo;
            while (lo >= 0 && !freeAt(lo));
        } else {
            while (lo < top && freeAt(lo + 1)) ++lo;
        }
        hint = lo;
        if (lo < 0) return 0;
        const int s = kB << lo;
        auto edge = [&](int v) { const int o = v & (s - 1); return std::min(o, s - 1 - o); };
        int m = std::min(edge(x), edge(y));
        if (dim == 3) m = std::min(m, edge(z));
        return s + 1 + m;
    }
};

namespace {
/// Cached brick access for a sequence of nearby cells (one hash probe per brick change). In the
/// anonymous namespace: its calls are inlined, not calls through the library's PLT.
struct BrickCursor {
    ByteBricks& S;
    int bx = -1, by = -1, bz = -1;
    uint8_t* brick = nullptr;
    explicit BrickCursor(ByteBricks& s) : S(s) {}
    int get(int x, int y, int z)
    {
        at(x, y, z, false);
        return brick ? brick[cellInBrick(x, y, z)] : S.cap;
    }
    void set(int x, int y, int z, int d)
    {
        at(x, y, z, true);
        brick[cellInBrick(x, y, z)] = uint8_t(d);
    }
    void at(int x, int y, int z, bool write)
    {
        const int cx = x >> DlaEngine::kBrickLog2, cy = y >> DlaEngine::kBrickLog2, cz = z >> DlaEngine::kBrickLog2;
        // a missing brick is never cached: the other cursor of a BFS may create it meanwhile
        if (cx != bx || cy != by || cz != bz || !brick) {
            bx = cx;
            by = cy;
            bz = cz;
            brick = write ? S.brickForWrite(cx, cy, cz) : const_cast<uint8_t*>(S.brick(cx, cy, cz));
        }
    }
};
} // namespace

/// Which voxels of each leaf of p were above 1/2 at the last sync (leaves with none are
/// absent): a leaf whose set is unchanged holds no new ice, so sync looks up the ice flags only
/// in leaves that changed, not at every ice cell every step.
struct DlaEngine::SyncCache {
    struct Hash {
        size_t operator()(const openvdb::Coord& c) const { return size_t(c.hash<20>()); }
    };
    std::unordered_map<openvdb::Coord, openvdb::util::NodeMask<3>, Hash> above;
    bool folded = false; ///< keyed by folded leaves (core/PlaneFold.h); a layout change starts afresh
};

DlaEngine::~DlaEngine() = default;

size_t DlaEngine::memoryBytes() const
{
    size_t b = mSparse->brickBytes() + mSparse->coarse.brickBytes() + mSparse->coarseCount.bytes();
    for (auto& m : mSparse->occupied) b += m.bytes();
    for (auto& m : mSparse->near) b += m.bytes();
    for (auto& d : mSparse->nearDense) b += d.count.size();
    return b;
}

size_t DlaEngine::brickCount() const { return mSparse->bricks; }

DlaEngine::DlaEngine(const Domain& domain, const DlaParams& params, uint64_t seed)
    : mDomain(domain), mParams(params), mSeed(hashCounters(seed, 0xD1A)), mNbr(walkerNeighbours(domain)),
      mSparse(std::make_unique<Sparse>())
{
    const auto& bb = domain.bbox();
    mOrigin = bb.min();
    mNx = bb.dim().x();
    mNy = bb.dim().y();
    mNz = bb.dim().z();
    if (std::max(std::max(mNx, mNy), mNz) >= (int64_t(1) << 21))
        throw std::invalid_argument("DlaEngine: at most 2^21 cells per axis");
    mDim = domain.dimension();
    // 16 on a plane: beyond it the block distances are within 12 steps of the true distance, and
    // every freeze's BFS, and every melt's repair, costs the cap squared (32 was the cap before
    // the block distances: Figure 7 made 4 % more moves at 16, and spent half the time relaxing)
    mCap = mDim == 3 ? 10 : 16;
    mSparse->dim = mDim;
    mSparse->brickVolume = mDim == 3 ? kB * kB * kB : kB * kB;
    mSparse->cap = uint8_t(mCap);
    // Block distances on planes (in a box the blocks of a reach of 48 would hold too many).
    if (mDim == 2) {
        mSparse->coarseOn = true;
        mSparse->coarse.cap = uint8_t(kCoarseCap);
        mSparse->coarse.brickVolume = kB * kB;
        // the largest lattice distance between two cells of one block: a BFS over the offsets
        // [-(kCoarse-1), kCoarse-1]^2 from 0 (shortest paths between them stay in that box)
        constexpr int w = 2 * kCoarse - 1, c0 = kCoarse - 1;
        std::vector<int> dist(size_t(w * w), -1);
        std::vector<int> queue{c0 + w * c0};
        dist[size_t(c0 + w * c0)] = 0;
        for (size_t q = 0; q < queue.size(); ++q) {
            const int u = queue[q], ux = u % w, uy = u / w;
            for (const auto& o : mNbr) {
                const int vx = ux + o.x(), vy = uy + o.y();
                if (o.z() != 0 || vx < 0 || vy < 0 || vx >= w || vy >= w || dist[size_t(vx + w * vy)] >= 0) continue;
                dist[size_t(vx + w * vy)] = dist[size_t(u)] + 1;
                queue.push_back(vx + w * vy);
            }
        }
        mSparse->coarseSlack = *std::max_element(dist.begin(), dist.end());
    }
    int levels = 1;
    const int64_t extent = std::max(std::max(mNx, mNy), mNz);
    while ((int64_t(kB) << (levels - 1)) < extent) ++levels;
    mSparse->occupied.resize(size_t(levels));
    mSparse->near.resize(size_t(levels));
    mSparse->nearDense.resize(size_t(levels)); // arrays only on a small domain:
    if (mNx * mNy * mNz <= kDenseCells) {
        const int64_t cells[3] = {mNx, mNy, mNz};
        mSparse->denseLevels(cells);
        // the brick directories over the domain's cell bricks and block bricks
        auto bricksOf = [](int64_t n, int log2) { return (n + (int64_t(1) << log2) - 1) >> log2; };
        mSparse->directory.cover(bricksOf(mNx, kBrickLog2), bricksOf(mNy, kBrickLog2), bricksOf(mNz, kBrickLog2));
        if (mSparse->coarseOn) {
            const int b = kCoarseLog2 + kBrickLog2;
            mSparse->coarse.directory.cover(bricksOf(mNx, b), bricksOf(mNy, b), bricksOf(mNz, b));
        }
    }
    mDigits = std::max(1, int(48.0 / std::log2(double(mNbr.size()))));
    // A unit displacement in the lattice plane moves the index by at most this (Chebyshev): 1 on
    // the square lattice, 2/sqrt(3) on the hexagonal one (axial coordinates).
    mSphereScale = domain.lattice().kind() == LatticeKind::Hexagonal ? 1.0 / hex::kRowHeight : 1.0;
    // and the lattice (graph) distance by at most this: sqrt(2) (square, L1), 2/sqrt(3)
    // (hexagonal), sqrt(3) (cubic)
    mGraphScale = domain.lattice().kind() == LatticeKind::Hexagonal ? 1.0 / hex::kRowHeight
                                                                     : (mDim == 3 ? std::sqrt(3.0) : std::sqrt(2.0));

    // jump tables: every radius up to 16, then ~20% apart, up to the largest useful one
    if (params.jumps) {
        int rmax = params.jumpMaxRadius > 0 ? params.jumpMaxRadius : (mDim == 2 ? 128 : 32);
        int64_t half = std::max(mNx, mNy);
        if (mDim == 3) half = std::max(half, mNz);
        rmax = int(std::min<int64_t>(rmax, (half + 1) / 2));
        std::vector<int> radii;
        for (int r = std::max(2, params.jumpMinRadius); r <= rmax; r = r < 16 ? r + 1 : int(std::ceil(r * 1.2)))
            radii.push_back(r);
        if (!radii.empty() && radii.back() != rmax && rmax >= params.jumpMinRadius) radii.push_back(rmax);
        mTables.resize(radii.size());
        tbb::parallel_for(size_t(0), radii.size(), [&](size_t i) { mTables[i] = sphereTable(mNbr, radii[i]); });
        if (!radii.empty()) {
            mTableForRadius.assign(size_t(radii.back()) + 1, -1);
            for (size_t i = 0; i < radii.size(); ++i)
                for (int r = radii[i]; r <= radii.back(); ++r) mTableForRadius[size_t(r)] = int16_t(i);
        }
    }
}

bool DlaEngine::isIce(int64_t cell) const
{
    const int64_t m = (int64_t(1) << 21) - 1;
    return mSparse->fine(int(cell & m), int((cell >> 21) & m), int(cell >> 42)) == 0;
}

int DlaEngine::iceDistance(const openvdb::Coord& c) const
{
    const openvdb::Coord r = c - mOrigin;
    const int f = mSparse->fine(r.x(), r.y(), r.z());
    if (f < mCap) return f;
    int hint = -1;
    const int pyramid = std::max(mCap, mSparse->bound(r.x(), r.y(), r.z(), mIceCount > 0, hint));
    if (!mSparse->coarseOn) return pyramid;
    const int d = mSparse->coarse.fine(r.x() >> kCoarseLog2, r.y() >> kCoarseLog2, r.z() >> kCoarseLog2);
    return std::max(pyramid, kCoarse * d - mSparse->coarseSlack);
}

int DlaEngine::blockDistance(const openvdb::Coord& c) const
{
    if (!mSparse->coarseOn) return -1;
    const openvdb::Coord r = c - mOrigin;
    return mSparse->coarse.fine(r.x() >> kCoarseLog2, r.y() >> kCoarseLog2, r.z() >> kCoarseLog2);
}

namespace {
/// Multi-source breadth-first relaxation of capped lattice distances from the cells in @a queue
/// (already set; first in, first out is breadth-first while they share one distance).
/// A neighbour in the dequeued cell's own brick (most of them: 8x8 bricks, 4 or 6 neighbours) is
/// read and written through that brick's pointer, kept while consecutive cells share a brick;
/// only a neighbour across a brick face goes through the cursor (a hash probe when its brick
/// changes). The same cells are lowered in the same order as with one cursor per side.
void relaxFrom(ByteBricks& S, std::vector<int64_t>& queue, int cap, const std::vector<openvdb::Coord>& nbr, int64_t nx,
               int64_t ny, int64_t nz)
{
    BrickCursor there(S);
    const int64_t m = (int64_t(1) << 21) - 1;
    int hx = -1, hy = -1, hz = -1;
    uint8_t* here = nullptr; // the brick of the dequeued cell (it holds a value below the cap: it exists)
    const size_t deg = nbr.size();
    int ox[8], oy[8], oz[8];
    for (size_t n = 0; n < deg && n < 8; ++n) {
        ox[n] = nbr[n].x();
        oy[n] = nbr[n].y();
        oz[n] = nbr[n].z();
    }
    if (deg > 8) throw std::logic_error("relaxFrom: at most 8 neighbours");
    for (size_t q = 0; q < queue.size(); ++q) {
        const int64_t u = queue[q];
        const int x = int(u & m), y = int((u >> 21) & m), z = int(u >> 42);
        const int bx = x >> DlaEngine::kBrickLog2, by = y >> DlaEngine::kBrickLog2, bz = z >> DlaEngine::kBrickLog2;
        if (bx != hx || by != hy || bz != hz) {
            hx = bx;
            hy = by;
            hz = bz;
            here = const_cast<uint8_t*>(S.brick(bx, by, bz));
            if (!here) here = S.brickForWrite(bx, by, bz); // (never: a queued cell holds a value below the cap)
        }
        const int d = here[cellInBrick(x, y, z)] + 1;
        if (d >= cap) continue;
        for (size_t n = 0; n < deg; ++n) {
            const int i = x + ox[n], j = y + oy[n], k = z + oz[n];
            if (i < 0 || j < 0 || k < 0 || i >= nx || j >= ny || k >= nz) continue;
            if ((i >> DlaEngine::kBrickLog2) == bx && (j >> DlaEngine::kBrickLog2) == by &&
                (k >> DlaEngine::kBrickLog2) == bz) {
                uint8_t& v = here[cellInBrick(i, j, k)];
                if (v > d) {
                    v = uint8_t(d);
                    queue.push_back(int64_t(packKey(i, j, k)));
                }
            } else if (there.get(i, j, k) > d) {
                there.set(i, j, k, d);
                queue.push_back(int64_t(packKey(i, j, k)));
            }
        }
    }
}

/// After the sources at the cells @a removed were taken out (their values were 0): the values
/// that depended on them only, and the new ones there, by the decremental breadth-first update.
///  1. By levels from the removed cells: a cell at distance L loses its support when none of its
///     neighbours at L - 1 kept theirs (it is marked with kLost); only such cells can change.
///  2. Each lost cell starts from its best neighbour that kept its value (plus one), and the lost
///     cells are relaxed among themselves by distance levels.
/// The cells that kept their value are right (a neighbour one step closer that kept its own), so
/// the result is the unique capped BFS minimum from the remaining sources, the values a rebuild
/// gives, at the cost of the cells that change and their neighbours.
void repairAround(ByteBricks& S, const std::vector<int64_t>& removed, int cap, int /*dim*/,
                  const std::vector<openvdb::Coord>& nbr, int64_t nx, int64_t ny, int64_t nz)
{
    constexpr uint8_t kLost = 255;
    const int64_t m = (int64_t(1) << 21) - 1;
    BrickCursor here(S), there(S);
    auto forNeighbours = [&](int64_t u, auto&& f) {
        const int x = int(u & m), y = int((u >> 21) & m), z = int(u >> 42);
        for (const auto& o : nbr) {
            const int i = x + o.x(), j = y + o.y(), k = z + o.z();
            if (i < 0 || j < 0 || k < 0 || i >= nx || j >= ny || k >= nz) continue;
            f(i, j, k);
        }
    };
    auto unpackTo = [m](int64_t u, int& x, int& y, int& z) {
        x = int(u & m);
        y = int((u >> 21) & m);
        z = int(u >> 42);
    };
    // 1. the cells that lose their support, level by level
    std::vector<int64_t> lost, level, next;
    for (int64_t u : removed) {
        int x, y, z;
        unpackTo(u, x, y, z);
        if (here.get(x, y, z) == kLost) continue; // listed twice
        here.set(x, y, z, kLost);
        level.push_back(u);
    }
    lost = level;
    for (int d = 1; d < cap && !level.empty(); ++d) {
        next.clear();
        for (int64_t u : level)
            forNeighbours(u, [&](int i, int j, int k) {
                if (there.get(i, j, k) != d) return;
                // still supported by a neighbour at d - 1 that kept its value?
                bool supported = false;
                forNeighbours(int64_t(packKey(i, j, k)), [&](int a, int b, int c) {
                    supported = supported || here.get(a, b, c) == d - 1;
                });
                if (supported) return;
                there.set(i, j, k, kLost);
                next.push_back(int64_t(packKey(i, j, k)));
            });
        lost.insert(lost.end(), next.begin(), next.end());
        level.swap(next);
    }
    // 2. new values: from the neighbours that kept theirs, then among the lost cells
    std::vector<std::vector<int64_t>> bucket(static_cast<size_t>(cap));
    std::vector<uint8_t> start(lost.size());
    for (size_t q = 0; q < lost.size(); ++q) {
        int best = cap;
        forNeighbours(lost[q], [&](int i, int j, int k) {
            const int v = there.get(i, j, k);
            if (v != kLost) best = std::min(best, v + 1);
        });
        start[q] = uint8_t(best);
    }
    for (size_t q = 0; q < lost.size(); ++q) {
        int x, y, z;
        unpackTo(lost[q], x, y, z);
        here.set(x, y, z, cap);
        if (start[q] < cap) bucket[start[q]].push_back(lost[q]);
    }
    for (int d = 1; d < cap; ++d) {
        auto& list = bucket[size_t(d)];
        for (size_t q = 0; q < list.size(); ++q) {
            int x, y, z;
            unpackTo(list[q], x, y, z);
            if (here.get(x, y, z) <= d) continue;
            here.set(x, y, z, d);
            if (d + 1 < cap)
                forNeighbours(list[q], [&](int i, int j, int k) {
                    if (there.get(i, j, k) > d + 1) bucket[size_t(d) + 1].push_back(int64_t(packKey(i, j, k)));
                });
        }
        std::vector<int64_t>().swap(list);
    }
}
} // namespace

void DlaEngine::relaxQueue() { relaxFrom(*mSparse, mQueue, mCap, mNbr, mNx, mNy, mNz); }

void DlaEngine::flushCoarse()
{
    Sparse& S = *mSparse;
    if (!S.coarseOn) return;
    const int64_t bx = (mNx + kCoarse - 1) >> kCoarseLog2, by = (mNy + kCoarse - 1) >> kCoarseLog2,
                  bz = (mNz + kCoarse - 1) >> kCoarseLog2;
    const int64_t m = (int64_t(1) << 21) - 1;
    auto count = [&](int64_t key) { const uint32_t* n = S.coarseCount.find(uint64_t(key)); return n ? *n : 0u; };
    std::vector<int64_t> lost;
    for (int64_t key : S.coarseLost)
        if (count(key) == 0) {
            S.coarse.setFine(int(key & m), int((key >> 21) & m), int(key >> 42), S.coarse.cap);
            lost.push_back(key);
        }
    S.coarseLost.clear();
    if (!lost.empty()) repairAround(S.coarse, lost, S.coarse.cap, mDim, mNbr, bx, by, bz);
    std::vector<int64_t> gained;
    for (int64_t key : S.coarseGained)
        if (count(key) != 0) {
            S.coarse.setFine(int(key & m), int((key >> 21) & m), int(key >> 42), 0);
            gained.push_back(key);
        }
    S.coarseGained.clear();
    relaxFrom(S.coarse, gained, S.coarse.cap, mNbr, bx, by, bz);
}

void DlaEngine::freeze(int64_t cell)
{
    freezeDeferred(cell);
    flushDistances();
}

void DlaEngine::freezeDeferred(int64_t cell)
{
    if (isIce(cell)) return;
    const openvdb::Coord r = coord(cell) - mOrigin;
    mSparse->setFine(r.x(), r.y(), r.z(), 0);
    mSparse->addIce(r.x(), r.y(), r.z());
    ++mIceCount;
    ++mWork.fresh;
    mQueue.push_back(cell);
}

void DlaEngine::flushDistances()
{
    // One multi-source BFS from every cell frozen since the last flush (all at distance 0, so
    // first-in first-out is breadth-first): each cell is lowered once, not once per new ice
    // cell near it, and the capped distances are the same unique minimum as one-by-one relaxing.
    // The cell and the block distances are separate maps (their own bricks, hash maps and
    // queues): their two passes run side by side when both have work and a second thread is free.
    auto cells = [this] {
        if (mQueue.empty()) return;
        const auto t0 = Clock::now();
        const size_t sources = mQueue.size();
        relaxQueue();
        mWork.relaxed += mQueue.size() - sources;
        mQueue.clear();
        mWork.relaxSeconds += since(t0);
    };
    auto blocks = [this] {
        const auto t1 = Clock::now();
        flushCoarse();
        mWork.coarseSeconds += since(t1);
    };
    const Sparse& S = *mSparse;
    if (!mQueue.empty() && S.coarseOn && (!S.coarseGained.empty() || !S.coarseLost.empty()))
        tbb::parallel_invoke(cells, blocks);
    else {
        cells();
        blocks();
    }
}

bool DlaEngine::distancesPending() const
{
    return !mQueue.empty() || !mSparse->coarseGained.empty() || !mSparse->coarseLost.empty();
}

void DlaEngine::rebuild(const openvdb::FloatGrid& p)
{
    const auto t0 = Clock::now();
    mSparse->clear();
    mIceCount = 0;
    mQueue.clear();
    const bool fold = plane::isFolded(p); // p's cells stored at fold(c) (core/PlaneFold.h)
    for (auto it = p.cbeginValueOn(); it; ++it) {
        if (!(*it > 0.5f)) continue;
        openvdb::CoordBBox bb = it.getBoundingBox();
        bb.intersect(fold ? plane::foldedBBox(mDomain.bbox()) : mDomain.bbox());
        for (auto s = bb.begin(); s; ++s) {
            const openvdb::Coord c = fold ? plane::unfold(*s) : *s;
            if (fold && !mDomain.bbox().isInside(c)) continue;
            const openvdb::Coord r = c - mOrigin;
            if (mSparse->fine(r.x(), r.y(), r.z()) == 0) continue;
            mSparse->setFine(r.x(), r.y(), r.z(), 0);
            mSparse->addIce(r.x(), r.y(), r.z());
            ++mIceCount;
            mQueue.push_back(index(c));
        }
    }
    relaxQueue(); // multi-source BFS
    mQueue.clear();
    flushCoarse();
    mWork.rebuildSeconds += since(t0);
}

void DlaEngine::sync(const openvdb::FloatGrid& p)
{
    // p > 1/2 cells: counted per leaf in parallel; the new ones (leaves whose set changed since
    // the last sync) collected (the order of freezing does not matter: the capped distances are
    // the unique BFS minimum).
    using Mask = openvdb::util::NodeMask<3>;
    const auto t0 = Clock::now();
    if (!mSyncCache || mSyncCache->folded != plane::isFolded(p)) {
        mSyncCache = std::make_unique<SyncCache>();
        mSyncCache->folded = plane::isFolded(p);
    }
    openvdb::tree::LeafManager<const openvdb::FloatTree> leaves(p.tree());
    const size_t nl = leaves.leafCount();
    std::vector<uint64_t> counts(nl, 0);
    std::vector<std::vector<int64_t>> fresh(nl);
    std::vector<Mask> above(nl);
    std::vector<char> changed(nl, 0);
    const openvdb::CoordBBox dom = mDomain.bbox();
    const auto& cache = mSyncCache->above;
    const bool fold = plane::isFolded(p); // p's cells stored at fold(c) (core/PlaneFold.h)
    auto cellAt = [fold](const openvdb::Coord& s) { return fold ? plane::unfold(s) : s; };
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nl, 8), [&](const tbb::blocked_range<size_t>& r) {
        BrickCursor cur(*mSparse); // read only here
        for (size_t l = r.begin(); l != r.end(); ++l) {
            const auto& leaf = leaves.leaf(l);
            const bool inside = !fold && dom.isInside(leaf.getNodeBoundingBox());
            Mask& m = above[l];
            const float* v = leaf.buffer().data();
            for (openvdb::Index w = 0; w < Mask::WORD_COUNT; ++w)
                for (uint64_t bits = leaf.getValueMask().template getWord<uint64_t>(w); bits; bits &= bits - 1) {
                    const openvdb::Index n = openvdb::Index(w * 64 + __builtin_ctzll(bits));
                    if (v[n] > 0.5f && (inside || dom.isInside(cellAt(leaf.offsetToGlobalCoord(n))))) m.setOn(n);
                }
            counts[l] = m.countOn();
            const auto known = cache.find(leaf.origin());
            if (known == cache.end() ? m.isOff() : known->second == m) continue; // nothing new here
            changed[l] = 1;
            for (openvdb::Index w = 0; w < Mask::WORD_COUNT; ++w) {
              uint64_t bits = m.template getWord<uint64_t>(w);
              if (known != cache.end()) bits &= ~known->second.template getWord<uint64_t>(w); // ice at the last sync
              for (; bits; bits &= bits - 1) {
                const openvdb::Coord c = cellAt(leaf.offsetToGlobalCoord(openvdb::Index(w * 64 + __builtin_ctzll(bits))));
                const openvdb::Coord q = c - mOrigin;
                if (cur.get(q.x(), q.y(), q.z()) != 0) fresh[l].push_back(index(c));
              }
            }
        }
    });
    uint64_t count = 0, nfresh = 0;
    for (size_t l = 0; l < nl; ++l) {
        count += counts[l];
        nfresh += fresh[l].size();
    }
    std::vector<int64_t> tiles; // active tiles above 1/2 (rare: a pruned block of ice)
    auto tileIt = p.tree().cbeginValueOn();
    tileIt.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1); // tiles only
    for (auto& it = tileIt; it; ++it) {
        if (!(*it > 0.5f)) continue;
        openvdb::CoordBBox bb = it.getBoundingBox();
        bb.intersect(fold ? plane::foldedBBox(dom) : dom);
        for (auto s = bb.begin(); s; ++s) {
            const openvdb::Coord c = cellAt(*s);
            if (!dom.isInside(c)) continue;
            ++count;
            const int64_t i = index(c);
            if (!isIce(i)) tiles.push_back(i);
        }
    }
    nfresh += tiles.size();
    // The sets seen now, for the next sync (a leaf that left p with ice in it changes the count).
    auto& store = mSyncCache->above;
    if (count != mIceCount + nfresh) {
        // Some ice melted: find it (ice cells whose p is now at most 1/2) and repair the
        // distances around it; start again from the ice only when not every melted cell is found
        // (one that left p's active voxels) or when so many melted that a rebuild is cheaper.
        std::vector<std::vector<int64_t>> lost(nl);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nl, 8), [&](const tbb::blocked_range<size_t>& r) {
            BrickCursor cur(*mSparse); // read only here
            for (size_t l = r.begin(); l != r.end(); ++l) {
                if (!changed[l]) continue; // a melt changes the leaf's set; a missed one forces a rebuild below
                for (auto it = leaves.leaf(l).cbeginValueOn(); it; ++it) {
                    if (*it > 0.5f) continue;
                    const openvdb::Coord c = cellAt(it.getCoord());
                    if (!dom.isInside(c)) continue;
                    const openvdb::Coord q = c - mOrigin;
                    if (cur.get(q.x(), q.y(), q.z()) == 0) lost[l].push_back(index(c));
                }
            }
        });
        std::vector<int64_t> melted;
        for (const auto& v : lost) melted.insert(melted.end(), v.begin(), v.end());
        if (count + melted.size() != mIceCount + nfresh || melted.size() * 16 > mIceCount) {
            mWork.scanSeconds += since(t0);
            ++mRebuilds;
            rebuild(p);
            store.clear();
            for (size_t l = 0; l < nl; ++l)
                if (!above[l].isOff()) store[leaves.leaf(l).origin()] = above[l];
            return;
        }
        mWork.scanSeconds += since(t0);
        repairMelted(melted);
    } else {
        mWork.scanSeconds += since(t0);
    }
    for (size_t l = 0; l < nl; ++l) {
        if (!changed[l]) continue;
        if (above[l].isOff()) store.erase(leaves.leaf(l).origin());
        else store[leaves.leaf(l).origin()] = above[l];
    }
    for (const auto& f : fresh)
        for (int64_t i : f) freezeDeferred(i);
    for (int64_t i : tiles) freezeDeferred(i);
    flushDistances();
}

void DlaEngine::syncCells(const openvdb::FloatGrid& p, const std::vector<openvdb::Coord>& cells)
{
    const auto t0 = Clock::now();
    const openvdb::CoordBBox dom = mDomain.bbox();
    std::vector<int64_t> ids;
    ids.reserve(cells.size());
    for (const auto& c : cells)
        if (dom.isInside(c)) ids.push_back(index(c));
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    std::vector<int64_t> fresh, melted;
    {
        openvdb::tree::ValueAccessor<const openvdb::FloatTree, false> acc(p.tree());
        const bool fold = plane::isFolded(p); // p's cells stored at fold(c) (core/PlaneFold.h)
        for (int64_t id : ids) {
            const openvdb::Coord c = coord(id);
            const bool above = acc.getValue(fold ? plane::fold(c) : c) > 0.5f;
            const bool ice = isIce(id);
            if (above && !ice) fresh.push_back(id);
            else if (!above && ice) melted.push_back(id);
        }
    }
    mWork.scanSeconds += since(t0);
    if (!melted.empty()) {
        if (melted.size() * 16 > mIceCount) { // as sync(): a rebuild is cheaper
            ++mRebuilds;
            rebuild(p);
            mSyncCache.reset(); // sync() starts its per-leaf sets afresh
            return;
        }
        repairMelted(melted);
        mSyncCache.reset();
    }
    for (int64_t i : fresh) freezeDeferred(i);
    flushDistances();
}

void DlaEngine::repairMelted(const std::vector<int64_t>& melted)
{
    const auto t0 = Clock::now();
    mWork.melted += melted.size();
    Sparse& S = *mSparse;
    const int64_t m = (int64_t(1) << 21) - 1;
    for (int64_t cell : melted) {
        const int x = int(cell & m), y = int((cell >> 21) & m), z = int(cell >> 42);
        S.setFine(x, y, z, mCap);
        S.changeIce(x, y, z, -1);
        --mIceCount;
    }
    repairAround(S, melted, mCap, mDim, mNbr, mNx, mNy, mNz);
    mWork.repairSeconds += since(t0);
}

double DlaEngine::stickingProbability(const Inputs& in, int64_t cell) const
{
    if (!in.melt) return 1.0;
    return double(in.melt->tree().getValue(coord(cell)));
}

int64_t DlaEngine::release(int64_t step, uint64_t walker, WalkerRng& rng, const Inputs& in) const
{
    const uint64_t n = uint64_t(cellCount());
    auto below = [&](uint64_t m) { return uint64_t((static_cast<unsigned __int128>(rng.next()) * m) >> 64); };
    for (int tries = 0; tries < 64; ++tries) {
        int64_t cell = -1;
        if (in.steamCdf && walker >= uint64_t(in.baseWalkers) && !in.steamCdf->empty()) {
            const double u = rng.uniform() * in.steamCdf->back();
            const size_t k = size_t(std::upper_bound(in.steamCdf->begin(), in.steamCdf->end(), u) - in.steamCdf->begin());
            cell = (*in.steamCells)[std::min(k, in.steamCells->size() - 1)];
        } else if (mParams.release == DlaRelease::Uniform) {
            const int64_t k = int64_t(below(n));
            cell = int64_t(packKey(k % mNx, (k / mNx) % mNy, k / (mNx * mNy)));
        } else {
            // perimeter: a face (edge) chosen by its cell count, then a cell on it
            const int64_t fx = mNy * mNz, fy = mNx * mNz, fz = mDim == 3 ? mNx * mNy : 0;
            const uint64_t total = uint64_t(2 * (fx + fy + fz));
            int64_t k = int64_t(below(total));
            int64_t x, y, z;
            const int64_t face = k < 2 * fx ? 0 : (k < 2 * (fx + fy) ? 1 : 2);
            if (face == 0) {
                x = (k % 2) ? mNx - 1 : 0;
                k /= 2;
                y = k % mNy;
                z = k / mNy;
            } else if (face == 1) {
                k -= 2 * fx;
                y = (k % 2) ? mNy - 1 : 0;
                k /= 2;
                x = k % mNx;
                z = k / mNx;
            } else {
                k -= 2 * (fx + fy);
                z = (k % 2) ? mNz - 1 : 0;
                k /= 2;
                x = k % mNx;
                y = k / mNx;
            }
            cell = int64_t(packKey(x, y, z));
        }
        // a block at block distance >= 1 holds no ice (the block bricks are few and cached)
        if (mSparse->coarseOn) {
            const int64_t m = (int64_t(1) << 21) - 1;
            if (mSparse->coarse.fine(int(cell & m) >> kCoarseLog2, int((cell >> 21) & m) >> kCoarseLog2, 0) > 0)
                return cell;
        }
        if (!isIce(cell)) return cell;
    }
    return -1;
}

/// One walk in progress: position (offsets from the origin), the brick it reads from and the
/// directory tile that brick was found in.
struct DlaEngine::Walker {
    const Sparse& S;
    int x = 0, y = 0, z = 0;
    int bx = -1, by = -1, bz = -1;
    const uint8_t* brick = nullptr;
    size_t tileIndex = ~size_t(0);
    const uint8_t* const* tile = nullptr;
    explicit Walker(const Sparse& s) : S(s) {}
    int fine(int i, int j, int k)
    {
        const int ci = i >> kBrickLog2, cj = j >> kBrickLog2, ck = k >> kBrickLog2;
        if (ci != bx || cj != by || ck != bz) {
            bx = ci;
            by = cj;
            bz = ck;
            brick = brickAt(ci, cj, ck);
        }
        return brick ? brick[cellInBrick(i, j, k)] : S.cap;
    }
    /// The brick at (ci, cj, ck). Inside the directory the walker keeps the tile it is in (walks
    /// never make bricks or tiles), so a brick change within a tile is one load.
    const uint8_t* brickAt(int ci, int cj, int ck)
    {
        const BrickDirectory& d = S.directory;
        if (!d.covers(ci, cj, ck)) return S.brick(ci, cj, ck);
        const size_t t = d.tileOf(ci, cj, ck);
        if (t != tileIndex) {
            tileIndex = t;
            tile = d.tiles[t].get();
        }
        return tile ? tile[BrickDirectory::inTile(ci, cj)] : nullptr;
    }
    /// The block distance of the block holding cell (i, j) (planes).
    int cbx = -1, cby = -1;
    const uint8_t* cbrick = nullptr;
    int block(int i, int j)
    {
        const int bi = i >> kCoarseLog2, bj = j >> kCoarseLog2;
        const int ci = bi >> kBrickLog2, cj = bj >> kBrickLog2;
        if (ci != cbx || cj != cby) {
            cbx = ci;
            cby = cj;
            cbrick = S.coarse.brick(ci, cj, 0);
        }
        return cbrick ? cbrick[cellInBrick(bi, bj, 0)] : S.coarse.cap;
    }
};

/// Per-thread probes of the optional grids (an accessor registers with its tree: one per task).
struct DlaEngine::Probes {
    std::unique_ptr<openvdb::FloatGrid::ConstAccessor> melt;
    std::unique_ptr<openvdb::Vec3SGrid::ConstAccessor> vel;
    explicit Probes(const Inputs& in)
    {
        if (in.melt) melt = std::make_unique<openvdb::FloatGrid::ConstAccessor>(in.melt->getConstAccessor());
        if (in.vel) vel = std::make_unique<openvdb::Vec3SGrid::ConstAccessor>(in.vel->getConstAccessor());
    }
};

WalkEnd DlaEngine::walk(int64_t step, uint64_t walker, uint64_t salt, int64_t start, const Inputs& in) const
{
    if (distancesPending()) throw std::logic_error("DlaEngine::walk: flushDistances() first");
    WalkerRng rng(mSeed, walker, uint64_t(step), salt);
    const int64_t idx = start >= 0 ? start : release(step, walker, rng, in);
    if (idx < 0) return WalkEnd{};
    Probes pr(in);
    return walkFrom(rng, idx, in, pr);
}

void DlaEngine::walkBatch(int64_t step, uint64_t first, uint64_t count, const Inputs& in,
                          std::vector<WalkEnd>& out) const
{
    if (distancesPending()) throw std::logic_error("DlaEngine::walkBatch: flushDistances() first");
    out.assign(size_t(count), WalkEnd{});
    tbb::parallel_for(tbb::blocked_range<uint64_t>(0, count, 16), [&](const tbb::blocked_range<uint64_t>& r) {
        Probes pr(in);
        for (uint64_t w = r.begin(); w != r.end(); ++w) {
            WalkerRng rng(mSeed, first + w, uint64_t(step));
            const int64_t idx = release(step, first + w, rng, in);
            if (idx < 0) continue;
            out[size_t(w)] = walkFrom(rng, idx, in, pr);
        }
    });
}

namespace {

/// What one walk reads and never changes (the stages of DlaEngine::walkFrom take it).
struct WalkContext {
    const DlaParams& P;
    const DlaEngine::Sparse& sparse;
    const std::vector<std::shared_ptr<const SphereTable>>& tables;
    const std::vector<int16_t>& tableForRadius;
    int dim, cap, nx, ny, nz, maxR, sphereMin, coarseSlack;
    bool spheres, hex, anyIce, coarse, drift;
    double graphScale, sphereScale;
};

/// A walk-on-spheres jump of plane radius @a rho: a uniform point on the circle (sphere in a
/// box), in cells (axial cells on a hexagonal plane), rounded to the nearest cell.
inline openvdb::Coord sphereJumpOffset(WalkerRng& rng, double rho, int dim, bool hexagonal)
{
    const double u = rng.uniform(), w = rng.uniform();
    double px, py, pz = 0.0;
    if (dim == 2) {
        const double a = 2.0 * M_PI * u;
        px = rho * std::cos(a);
        py = rho * std::sin(a);
    } else {
        const double c = 2.0 * u - 1.0, sn = std::sqrt(std::max(0.0, 1.0 - c * c)), a = 2.0 * M_PI * w;
        px = rho * sn * std::cos(a);
        py = rho * sn * std::sin(a);
        pz = rho * c;
    }
    double di = px, dj = py;
    if (hexagonal) { // plane (X, Y) -> axial (i, j): Y = j sqrt(3)/2, X = i + j/2
        dj = py * (1.0 / hex::kRowHeight);
        di = px - 0.5 * dj;
    }
    return openvdb::Coord(int(std::lround(di)), int(std::lround(dj)), int(std::lround(pz)));
}

/// The empty-space jump from the walker's cell, whose fine distance is @a f (block distance
/// @a db): the largest jump the ice and the domain edge allow, a walk-on-spheres circle beyond
/// the tables or an exact first-passage table below. Moves the walker and returns the expected
/// lattice steps the jump stands for (0: none taken); @a v is the drift read at the start.
template <typename VelocityAt>
inline double emptySpaceJump(const WalkContext& c, WalkerRng& rng, DlaEngine::Walker& W, int f, int db, int& levelHint,
                             VelocityAt&& velocityAt, openvdb::Vec3d& v)
{
    int &x = W.x, &y = W.y, &z = W.z;
    // exact lattice (graph) distance below the cap, else the pyramid's Chebyshev bound
    const bool exact = f < c.cap;
    int dIce;      // a lower bound of the lattice (graph) distance to the ice
    int cheb = -1; // a Chebyshev bound from the pyramid, when one was read
    if (exact) {
        dIce = f;
    } else if (c.coarse) {
        // the block distance; beyond its cap the pyramid's Chebyshev bound as well
        dIce = std::max(c.cap, kCoarse * db - c.coarseSlack);
        if (db >= kCoarseCap) {
            cheb = std::max(c.cap, c.sparse.bound(x, y, z, c.anyIce, levelHint));
            dIce = std::max(dIce, cheb);
        }
    } else {
        dIce = std::max(c.cap, c.sparse.bound(x, y, z, c.anyIce, levelHint));
    }
    int dOut = 1 + std::min(std::min(x, c.nx - 1 - x), std::min(y, c.ny - 1 - y));
    if (c.dim == 3) dOut = std::min(dOut, 1 + std::min(z, c.nz - 1 - z));
    // interior of the ball inside the domain (r <= dOut), no cell of it next to ice and the
    // landing cell at least 2 from the ice (r <= dIce - 2): the walk inside is a free walk
    int r = std::min(dIce - 2, dOut);
    double rhoMax = 1e300;
    if (c.drift) {
        v = velocityAt(x, y, z);
        const double vm = v.length();
        // the drift over the jump's mean time (~r^2 steps) must stay under half a cell
        if (vm > 0) {
            rhoMax = std::sqrt(0.5 / vm);
            r = std::min(r, int(rhoMax));
        }
    }
    // beyond the largest table: a circle (sphere) of plane radius rho whose cells, with a
    // cell of rounding, stay 2 away from the ice and inside the domain. A graph distance
    // covers a disc of radius d / mGraphScale, a Chebyshev bound one of d / mSphereScale.
    // Both scales are >= 1, so no circle is larger than dIce - 3: the divisions only
    // where a circle can beat the tables.
    double rho = 0;
    if (c.spheres && dIce - 3 > c.sphereMin) {
        double rhoIce;
        if (exact || !c.coarse) rhoIce = double(dIce - 3) / (exact ? c.graphScale : c.sphereScale);
        else {
            rhoIce = double(std::max(c.cap, kCoarse * db - c.coarseSlack) - 3) / c.graphScale;
            if (cheb >= 0) rhoIce = std::max(rhoIce, double(cheb - 3) / c.sphereScale);
        }
        rho = std::min(std::min(rhoMax, rhoIce), double(dOut - 1) / c.sphereScale);
    }
    double jumpSteps = 0;
    if (c.spheres && rho > double(c.sphereMin)) {
        const openvdb::Coord o = sphereJumpOffset(rng, rho, c.dim, c.hex);
        x += o.x();
        y += o.y();
        z += o.z();
        jumpSteps = rho * rho; // E[exit time] = rho^2 / E|step|^2, unit steps
    } else {
        r = std::min(r, c.maxR);
        const int ti = r >= c.P.jumpMinRadius ? c.tableForRadius[size_t(r)] : -1;
        if (ti >= 0) {
            const SphereTable& t = *c.tables[size_t(ti)];
            openvdb::Coord o = t.sampleExit(rng.next());
            if (c.P.testJumpBias > 0 && rng.uniform() < c.P.testJumpBias) {
                const openvdb::Coord o2 = t.sampleExit(rng.next());
                if (o2.x() > o.x()) o = o2;
            }
            x += o.x();
            y += o.y();
            z += o.z();
            jumpSteps = t.meanSteps;
        }
    }
    return jumpSteps;
}

/// One random lattice step: a direction from the walker's digits of @a bits (@a left of them
/// unused); ice cannot be entered (the walker stays: only a cell next to ice, f == 1, has an ice
/// neighbour). Returns false when the step leaves the domain.
template <typename Outside>
inline bool latticeStep(WalkerRng& rng, uint64_t& bits, int& left, int digits, const std::vector<openvdb::Coord>& nbr,
                        int f, DlaEngine::Walker& W, int64_t& prev, Outside&& outside)
{
    const int deg = int(nbr.size());
    if (left == 0) {
        bits = rng.next();
        left = digits;
    }
    const unsigned dir = unsigned((static_cast<unsigned __int128>(bits) * unsigned(deg)) >> 64);
    bits *= uint64_t(deg);
    --left;
    const int i = W.x + nbr[dir].x(), j = W.y + nbr[dir].y(), k = W.z + nbr[dir].z();
    if (outside(i, j, k)) return false;
    if (f != 1 || W.fine(i, j, k) != 0) {
        prev = int64_t(packKey(W.x, W.y, W.z));
        W.x = i;
        W.y = j;
        W.z = k;
    }
    return true;
}

/// The drift carried in @a acc, moved whole cells at a time along each axis; a push against the
/// ice spends it. Returns false when it carries the walker out of the domain.
template <typename Outside>
inline bool applyDrift(openvdb::Vec3d& acc, int dim, DlaEngine::Walker& W, int64_t& prev, Outside&& outside)
{
    for (int a = 0; a < dim; ++a) {
        while (std::fabs(acc[a]) >= 1.0) {
            const int s = acc[a] > 0 ? 1 : -1;
            int i = W.x, j = W.y, k = W.z;
            (a == 0 ? i : a == 1 ? j : k) += s;
            if (outside(i, j, k)) return false;
            if (W.fine(i, j, k) == 0) { // pushed against the ice: the drift is spent
                acc[a] = 0;
                break;
            }
            prev = int64_t(packKey(W.x, W.y, W.z));
            W.x = i;
            W.y = j;
            W.z = k;
            acc[a] -= s;
        }
    }
    return true;
}

} // namespace

WalkEnd DlaEngine::walkFrom(WalkerRng& rng, int64_t idx, const Inputs& in, Probes& pr) const
{
    const DlaParams& P = mParams;
    const int dim = mDim, cap = mCap, digits = mDigits;
    auto& meltAcc = pr.melt;
    auto& velAcc = pr.vel;
    WalkEnd end;
    const auto& nbr = mNbr;
    const int nx = int(mNx), ny = int(mNy), nz = int(mNz);
    const openvdb::Coord o0 = mOrigin;
    Walker W(*mSparse);
    {
        const openvdb::Coord c = coord(idx) - o0;
        W.x = c.x();
        W.y = c.y();
        W.z = c.z();
    }
    int &x = W.x, &y = W.y, &z = W.z;
    int64_t prev = -1;
    uint64_t bits = 0;
    int left = 0;
    double steps = 0;
    const bool drift = velAcc != nullptr;
    openvdb::Vec3d acc(0.0);
    const int maxR = mTableForRadius.empty() ? 0 : int(mTableForRadius.size()) - 1;
    // walk on spheres beyond the tables: not for a hexagonal box (its walk is not isotropic)
    const bool spheres = P.jumps && P.sphereJumps && !(dim == 3 && mDomain.lattice().kind() == LatticeKind::Hexagonal);
    // the transform only when a velocity needs it (a shared_ptr copy per walk is two atomic
    // operations on one cache line that both threads write)
    openvdb::math::Transform::Ptr xform;
    if (drift && !in.velOnDomainTransform) xform = mDomain.transform();
    const bool coarse = mSparse->coarseOn;
    const int coarseSlack = mSparse->coarseSlack;
    int levelHint = -1; // the pyramid level of the last bound
    const WalkContext ctx{P, *mSparse, mTables, mTableForRadius, dim, cap, nx, ny, nz, maxR,
                          std::max(maxR, P.jumpMinRadius), coarseSlack, spheres,
                          mDomain.lattice().kind() == LatticeKind::Hexagonal, mIceCount > 0, coarse, drift,
                          mGraphScale, mSphereScale};

    auto abs = [&](int i, int j, int k) { return openvdb::Coord(i + o0.x(), j + o0.y(), k + o0.z()); };
    auto velocityAt = [&](int i, int j, int k) {
        openvdb::Vec3d v;
        if (in.velOnDomainTransform) {
            v = velAcc->getValue(abs(i, j, k));
        } else {
            const openvdb::Vec3d w = xform->indexToWorld(abs(i, j, k).asVec3d());
            v = velAcc->getValue(in.vel->transform().worldToIndexNodeCentered(w));
        }
        const auto& m = in.velToCells;
        openvdb::Vec3d cells(m(0, 0) * v[0] + m(0, 1) * v[1] + m(0, 2) * v[2],
                             m(1, 0) * v[0] + m(1, 1) * v[1] + m(1, 2) * v[2],
                             dim == 3 ? m(2, 0) * v[0] + m(2, 1) * v[1] + m(2, 2) * v[2] : 0.0);
        return cells;
    };
    auto outside = [&](int i, int j, int k) { return i < 0 || j < 0 || k < 0 || i >= nx || j >= ny || k >= nz; };
    auto key = [&](int i, int j, int k) { return int64_t(packKey(i, j, k)); };

    for (;;) {
        // The block distance first: where it puts the ice beyond the cap, the cell distance is
        // the cap without a probe of the (many, mostly uncached) cell bricks; the block bricks
        // are 16 times fewer and cover 32x32 cells each.
        const int db = coarse ? W.block(x, y) : 0;
        const int f = coarse && kCoarse * db - coarseSlack >= cap ? cap : W.fine(x, y, z);
        if (f == 1) { // next to ice: the sticking roll
            double s = 1.0;
            if (meltAcc) s = double(meltAcc->getValue(abs(x, y, z)));
            if (s >= 1.0 || (s > 0.0 && rng.uniform() < s)) {
                end.kind = WalkEnd::Stuck;
                end.cell = key(x, y, z);
                end.prev = prev;
                end.latticeSteps = steps;
                return end;
            }
        }
        if (P.maxSteps > 0 && steps >= double(P.maxSteps)) {
            end.kind = WalkEnd::Exhausted;
            end.latticeSteps = steps;
            return end;
        }
        ++end.moves;
        // empty-space jump
        bool jumped = false;
        if ((maxR > 0 || spheres) && f >= P.jumpMinRadius + 2) {
            openvdb::Vec3d v(0.0);
            const double jumpSteps = emptySpaceJump(ctx, rng, W, f, db, levelHint, velocityAt, v);
            if (jumpSteps > 0) {
                steps += jumpSteps;
                ++end.jumps;
                prev = -1;
                if (outside(x, y, z)) break;
                if (!drift) continue;
                acc += v * jumpSteps;
                jumped = true;
            }
        }
        if (!jumped) {
            if (!latticeStep(rng, bits, left, digits, nbr, f, W, prev, outside)) break;
            steps += 1;
            if (drift) acc += velocityAt(x, y, z);
        }
        if (drift && !applyDrift(acc, dim, W, prev, outside)) break;
    }
    end.kind = WalkEnd::Killed;
    end.latticeSteps = steps;
    return end;
}

} // namespace ice
} // namespace frostvdb
