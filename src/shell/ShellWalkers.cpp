/// @file ShellWalkers.cpp
/// @brief DLA walkers on a shell's surface (see ShellWalkers.h).
#include <frostvdb/shell/ShellWalkers.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <optional>
#include <limits>
#include <cmath>

namespace frostvdb::shell {

using openvdb::Coord;
using openvdb::Vec3d;

namespace {

/// A bucket's sort key: z, then y, then x (the order pointList() and assign() follow).
uint64_t packBucket(const Coord& b)
{
    constexpr int64_t kOff = int64_t(1) << 20, kMask = (int64_t(1) << 21) - 1;
    const int64_t i = int64_t(b.x()) + kOff, j = int64_t(b.y()) + kOff, k = int64_t(b.z()) + kOff;
    return uint64_t(i & kMask) | (uint64_t(j & kMask) << 21) | (uint64_t(k & kMask) << 42);
}

/// The bucket packBucket() packed.
Coord unpackBucket(uint64_t key)
{
    constexpr int64_t kOff = int64_t(1) << 20, kMask = (int64_t(1) << 21) - 1;
    return Coord(int(int64_t(key & kMask) - kOff), int(int64_t((key >> 21) & kMask) - kOff),
                 int(int64_t((key >> 42) & kMask) - kOff));
}

using IndexAccessor = BandIndex::Accessor;

/// One trilinear pass of the band's closest points at @a y.
bool interpolateCp(const ShellBand& b, IndexAccessor& acc, const Vec3d& y, Vec3d& out, double* lateral)
{
    const Coord base = Coord::floor(y);
    const Vec3d f = y - Vec3d(base.x(), base.y(), base.z());
    Vec3d sum(0.0);
    double lat = 0;
    for (int k = 0; k < 2; ++k)
        for (int j = 0; j < 2; ++j)
            for (int i = 0; i < 2; ++i) {
                const int32_t id = acc.getValue(base + Coord(i, j, k));
                if (id < 0) return false;
                const double w = (i ? f.x() : 1 - f.x()) * (j ? f.y() : 1 - f.y()) * (k ? f.z() : 1 - f.z());
                sum += b.closestPoint(size_t(id)) * w;
                lat += w * double(b.lateralOffset(size_t(id)));
            }
    out = sum;
    if (lateral) *lateral = lat;
    return true;
}

/// Surface nodes: a node near @a y: the voxel holding y when it is one; else, of its 6 face
/// neighbours that are nodes, the one whose closest point is nearest y (a column along the
/// normal's dominant axis crosses the one-voxel slab within a voxel of y, so one is nearly always
/// there); else the same among the 26 around it (lowest index on ties), or -1.
int32_t nodeNear(const ShellBand& b, IndexAccessor& acc, const Vec3d& y)
{
    const Coord c = Coord::round(y);
    int32_t id = acc.getValue(c);
    if (id >= 0) return id;
    double best = std::numeric_limits<double>::max();
    static const Coord faces[6] = {Coord(-1, 0, 0), Coord(1, 0, 0), Coord(0, -1, 0),
                                   Coord(0, 1, 0),  Coord(0, 0, -1), Coord(0, 0, 1)};
    for (const Coord& o : faces) {
        const int32_t k = acc.getValue(c + o);
        if (k < 0) continue;
        const double d = (b.closestPoint(size_t(k)) - y).lengthSqr();
        if (d < best || (d == best && k < id)) { best = d; id = k; }
    }
    if (id >= 0) return id;
    for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) {
                const int32_t k = acc.getValue(c + Coord(dx, dy, dz));
                if (k < 0) continue;
                const double d = (b.closestPoint(size_t(k)) - y).lengthSqr();
                if (d < best || (d == best && k < id)) { best = d; id = k; }
            }
    return id;
}

/// Surface nodes: @a y projected on the tangent plane at a nearby node's closest point (twice:
/// the second from the first's projection). A surface point lies within about 0.7 voxels of some
/// node's closest point (one node per surface cell); @a lateral is the distance beyond that, so a
/// point more than about half a voxel past an open border reads lateral > 0.5, as on the
/// closest-point band.
bool projectOnNodes(const ShellBand& b, IndexAccessor& acc, const Vec3d& y, Vec3d& out, double* lateral,
                    int32_t* node = nullptr)
{
    // One pass: the tangent plane of the node nearest y lies within O(kappa h^2) of the surface
    // (a second pass moved points by about 1e-3 voxels and cost a third of the walk).
    const int32_t k = nodeNear(b, acc, y);
    if (k < 0) return false;
    const Vec3d& cp = b.closestPoint(size_t(k));
    const Vec3d n = b.normal(size_t(k));
    out = y - n * (y - cp).dot(n);
    if (lateral) *lateral = std::max(0.0, (out - cp).length() - 0.7);
    if (node) *node = k;
    return true;
}

bool projectWith(const ShellBand& b, IndexAccessor& acc, const Vec3d& y, Vec3d& out, double* lateral)
{
    if (b.surfaceNodes()) return projectOnNodes(b, acc, y, out, lateral);
    Vec3d q;
    if (!interpolateCp(b, acc, y, q, lateral)) return false;
    Vec3d q2; // a second pass: the first lands within O(kappa h^2) of the surface
    out = interpolateCp(b, acc, q, q2, nullptr) ? q2 : q;
    return true;
}

std::optional<VoxelFrame> frameWith(const ShellBand& b, IndexAccessor& acc, const Vec3d& x)
{
    const int32_t id = b.surfaceNodes() ? nodeNear(b, acc, x) : acc.getValue(Coord::round(x));
    if (id < 0) return std::nullopt;
    return b.frame(size_t(id));
}

/// Surface nodes: the node a stick point at @a x flags (nearest, closest point within half a
/// voxel), or -1.
int32_t nodeOfStick(const ShellBand& b, IndexAccessor& acc, const Vec3d& x)
{
    const int32_t k = nodeNear(b, acc, x);
    return k >= 0 && (b.closestPoint(size_t(k)) - x).lengthSqr() < 0.25 ? k : -1;
}

/// Moves @a x by @a length along the tangent direction @a dir: sub-steps each projected back to
/// the surface, the direction carried to the new tangent plane (a discrete geodesic). A sub-step
/// of s leaves the surface by about s^2 kappa / 2: its length follows the curvature kappa measured
/// by the last sub-step's turn of the normal, so that this stays below one voxel, where the
/// nearest node is still found and its tangent plane is within O(kappa h^2) of the surface (up to
/// kShootStepMax voxels where the surface is flat). The first sub-step is taken long, as if the
/// surface were flat, and retaken at kShootStep when its turn says it was not (a jump on a gently
/// curved mesh, the windshield's, is then one projection instead of two: the projections' cache
/// misses were half a jump's cost). A sub-step that finds no surface, across a crease, is taken
/// again at kShootStep. Half a voxel cost 40 % more sub-steps for the same walks (docs/shells.md
/// "Walkers"). @a start: the frame at x; @a lastNode (surface nodes): the node whose tangent plane
/// the end point was projected on, as a lattice step leaves it.
constexpr double kShootStep = 3.0, kShootStepMax = 32.0;
bool shootWith(const ShellBand& b, IndexAccessor& acc, Vec3d& x, Vec3d dir, double length, bool open,
               const VoxelFrame& start, int32_t& lastNode)
{
    double left = length, next = kShootStepMax;
    bool first = true;
    std::optional<VoxelFrame> last = start;
    while (left > 1e-12) {
        double s = std::min(next, left);
        Vec3d q;
        double lat = 0;
        int32_t node = -1; // surface nodes: the node whose tangent plane q lies on gives the frame
        auto project = [&] {
            return b.surfaceNodes() ? projectOnNodes(b, acc, x + dir * s, q, &lat, &node)
                                    : projectWith(b, acc, x + dir * s, q, &lat);
        };
        if (!project()) {
            if (s <= kShootStep) return false;
            s = std::min(kShootStep, left);
            if (!project()) return false;
        }
        if (open && lat > 0.5) return false;
        const std::optional<VoxelFrame> f = node >= 0 ? b.frame(size_t(node)) : frameWith(b, acc, q);
        if (!f) return false;
        // kappa ~ the normal's turn over this sub-step; the next keeps s^2 kappa / 2 <= 1
        const double turn = last ? std::acos(std::clamp(last->normal.dot(f->normal), -1.0, 1.0)) : 1.0;
        if (first && s > kShootStep && s * turn > 2.0) { // too curved for the long first sub-step
            first = false;
            next = kShootStep;
            continue;
        }
        first = false;
        Vec3d nd = q - x;
        nd -= f->normal * nd.dot(f->normal);
        if (nd.length() < 1e-9) nd = dir - f->normal * dir.dot(f->normal);
        if (nd.length() < 1e-9) return false;
        dir = nd.unit();
        x = q;
        lastNode = node;
        left -= s;
        next = turn > 1e-9 ? std::clamp(std::sqrt(2.0 * s / turn), kShootStep, kShootStepMax) : kShootStepMax;
        last = f;
    }
    return true;
}

} // namespace

// ---------------------------------------------------------------------------------------------
// SurfacePointIndex

void SurfacePointIndex::clear()
{
    mBuckets.clear();
    mFreeSlots.clear();
    mSlots = std::make_shared<CountTree>(0);
    for (auto& c : mCounts) c = std::make_shared<CountTree>(0);
    for (auto& c : mNear) c = std::make_shared<NearTree>(uint8_t(0));
    mCount = 0;
    if (!mClearSlots) {
        mClearSlots = std::make_shared<CountTree>(0);
        mClearBlocks = std::make_shared<CountTree>(0);
    }
    forgetClearances();
}

void SurfacePointIndex::forgetClearances()
{
    mPendingInserts.clear();
    mPendingErases.clear();
    for (size_t s = 0; s < mClearBucket.size(); ++s) mClear[s].store(-1.f, std::memory_order_relaxed);
    for (size_t k = 0; k < mClearBlockRanges.size(); ++k) {
        mClearBlockMax[k].store(-1.f, std::memory_order_relaxed);
        mClearBlockDirty[k].store(0, std::memory_order_relaxed);
    }
}

void SurfacePointIndex::raiseBlockMax(size_t k, float v) const
{
    float m = mClearBlockMax[k].load(std::memory_order_relaxed);
    while (v > m && !mClearBlockMax[k].compare_exchange_weak(m, v, std::memory_order_relaxed)) {
    }
}

void SurfacePointIndex::addNear(int k, const Coord& b, int32_t delta)
{
    openvdb::tree::ValueAccessor<NearTree, false> acc(*mNear[size_t(k)]);
    for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) {
                const Coord c = b + Coord(dx, dy, dz);
                const int32_t n = int32_t(acc.getValue(c)) + delta;
                if (n > 0) acc.setValue(c, uint8_t(n));
                else acc.setValueOff(c, uint8_t(0));
            }
}

namespace {
Coord bucketOf(const Vec3d& q, int level)
{
    const double size = SurfacePointIndex::kBucket * double(1 << level);
    return Coord(int(std::floor(q.x() / size)), int(std::floor(q.y() / size)), int(std::floor(q.z() / size)));
}


/// Squared distance from @a q to the box of bucket @a b of edge @a size (voxels).
double boxDistance2(const Coord& b, const Vec3d& q, double size = SurfacePointIndex::kBucket)
{
    double d2 = 0;
    for (int a = 0; a < 3; ++a) {
        const double lo = size * double(b[a]), gap = std::max({lo - q[a], 0.0, q[a] - (lo + size)});
        d2 += gap * gap;
    }
    return d2;
}
} // namespace

void SurfacePointIndex::enableClearance(size_t count, const std::function<Vec3d(size_t)>& site)
{
    // the fine buckets the sites touch (8 bytes per site while they are found: the windshield
    // hero has 4.5 M), then their slots block by block (each block's slots contiguous, for the
    // scans of inserts and erases)
    std::vector<uint64_t> fine(count);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) fine[i] = packBucket(bucketOf(site(i), 0));
    });
    tbb::parallel_sort(fine.begin(), fine.end());
    fine.erase(std::unique(fine.begin(), fine.end()), fine.end());
    auto blockOf = [](const Coord& b) { return Coord(b.x() >> 2, b.y() >> 2, b.z() >> 2); };
    std::vector<std::pair<uint64_t, uint64_t>> keys(fine.size()); // (block key, bucket key)
    for (size_t k = 0; k < fine.size(); ++k) keys[k] = {packBucket(blockOf(unpackBucket(fine[k]))), fine[k]};
    std::vector<uint64_t>().swap(fine);
    std::sort(keys.begin(), keys.end());
    mClearSlots = std::make_shared<CountTree>(0);
    mClearBlocks = std::make_shared<CountTree>(0);
    mClearBucket.clear();
    mClearBlockRanges.clear();
    mClearBlockOf.clear();
    openvdb::tree::ValueAccessor<CountTree, false> slots(*mClearSlots), blocks(*mClearBlocks);
    for (size_t k = 0; k < keys.size(); ++k) {
        const Coord b = unpackBucket(keys[k].second);
        const int32_t s = int32_t(mClearBucket.size());
        mClearBucket.push_back(b);
        slots.setValue(b, s + 1);
        if (k == 0 || keys[k].first != keys[k - 1].first) { // a new block
            blocks.setValue(blockOf(b), int32_t(mClearBlockRanges.size()) + 1);
            mClearBlockRanges.emplace_back(s, s);
        }
        mClearBlockRanges.back().second = s + 1;
        mClearBlockOf.push_back(int32_t(mClearBlockRanges.size()) - 1);
    }
    mClear.reset(new std::atomic<float>[mClearBucket.size()]);
    mClearBlockMax.reset(new std::atomic<float>[mClearBlockRanges.size()]);
    mClearBlockDirty.reset(new std::atomic<uint8_t>[mClearBlockRanges.size()]);
    forgetClearances();
}

template<typename F> void SurfacePointIndex::forEachClearanceNear(const Vec3d& q, F&& f) const
{
    if (mClearBucket.empty()) return;
    const double cap2 = kClearCap * kClearCap, blockSize = 4.0 * kBucket;
    const Coord lo = bucketOf(q - Vec3d(kClearCap), 2), hi = bucketOf(q + Vec3d(kClearCap), 2);
    openvdb::tree::ValueAccessor<const CountTree, false> blocks(*mClearBlocks);
    for (int z = lo.z(); z <= hi.z(); ++z)
        for (int y = lo.y(); y <= hi.y(); ++y)
            for (int x = lo.x(); x <= hi.x(); ++x) {
                const int32_t at = blocks.getValue(Coord(x, y, z)) - 1;
                if (at < 0) continue;
                // the block's box: none of its buckets is nearer, or q is farther than every
                // clearance known in it (an insert there lowers none, an erase forgets none)
                const float most = mClearBlockMax[size_t(at)].load(std::memory_order_relaxed);
                if (most < 0.f) continue;
                const double d2 = boxDistance2(Coord(x, y, z), q, blockSize);
                // (compared as f's distances are: rounded to float, which keeps their order)
                if (d2 >= cap2 || float(std::sqrt(d2)) > most) continue;
                const auto [begin, end] = mClearBlockRanges[size_t(at)];
                for (int32_t s = begin; s < end; ++s) {
                    const float v = mClear[size_t(s)].load(std::memory_order_relaxed);
                    if (v < 0.f) continue; // not known: computed in full when read
                    const double d2 = boxDistance2(mClearBucket[size_t(s)], q);
                    if (d2 < cap2) f(size_t(s), v, float(std::sqrt(d2)));
                }
            }
}

void SurfacePointIndex::flushClearances() const
{
    if (mPendingInserts.empty() && mPendingErases.empty()) return;
    // Erases first: a known clearance stays exact unless an erased point was at its distance
    // (then it is forgotten, and computed again when read). Each check reads the value before
    // any erase (or the -1 another erase stored): the same slots are forgotten in any order.
    tbb::parallel_for(tbb::blocked_range<size_t>(0, mPendingErases.size(), 64), [&](const auto& r) {
        for (size_t i = r.begin(); i < r.end(); ++i)
            forEachClearanceNear(mPendingErases[i], [&](size_t s, float v, float d) {
                if (d > v) return;
                mClear[s].store(-1.f, std::memory_order_relaxed);
                mClearBlockDirty[size_t(mClearBlockOf[s])].store(1, std::memory_order_relaxed);
            });
    });
    // Then the inserts still present (one erased again since is not ice): each known clearance
    // takes the minimum with the points' distances (an atomic minimum: any order, same values).
    tbb::parallel_for(tbb::blocked_range<size_t>(0, mPendingInserts.size(), 64), [&](const auto& r) {
        CountAccessor slots(*mSlots);
        for (size_t i = r.begin(); i < r.end(); ++i) {
            const Vec3d& q = mPendingInserts[i];
            const int32_t slot = slots.getValue(bucketOf(q, 0)) - 1;
            if (slot < 0) continue;
            const auto& v = mBuckets[size_t(slot)];
            if (std::find(v.begin(), v.end(), q) == v.end()) continue;
            forEachClearanceNear(q, [&](size_t s, float known, float d) {
                if (!(d < known)) return;
                while (d < known && !mClear[s].compare_exchange_weak(known, d, std::memory_order_relaxed)) {
                }
                mClearBlockDirty[size_t(mClearBlockOf[s])].store(1, std::memory_order_relaxed);
            });
        }
    });
    mPendingInserts.clear();
    mPendingErases.clear();
    // the maxima of the blocks whose values fell, exact again (the skips above then stay tight)
    tbb::parallel_for(tbb::blocked_range<size_t>(0, mClearBlockRanges.size(), 256), [&](const auto& r) {
        for (size_t k = r.begin(); k < r.end(); ++k) {
            if (!mClearBlockDirty[k].load(std::memory_order_relaxed)) continue;
            mClearBlockDirty[k].store(0, std::memory_order_relaxed);
            float most = -1.f;
            for (int32_t s = mClearBlockRanges[k].first; s < mClearBlockRanges[k].second; ++s)
                most = std::max(most, mClear[size_t(s)].load(std::memory_order_relaxed));
            mClearBlockMax[k].store(most, std::memory_order_relaxed);
        }
    });
}

double SurfacePointIndex::clearance(const Coord& b, CountAccessor& slots, CountAccessor& clearSlots) const
{
    const int32_t s = clearSlots.getValue(b) - 1;
    if (s < 0) return -1.0;
    const float known = mClear[size_t(s)].load(std::memory_order_relaxed);
    if (known >= 0.f) return double(known);
    // The minimum over every point of its squared distance to b's box, capped: visited in any
    // order it is the same value. The fine buckets within reach lie in at most 2 x 2 x 2 leaves
    // of the slot tree, read in place (a ring scan's 13^3 accessor probes, mostly of empty
    // buckets, cost more than the points).
    double best2 = kClearCap * kClearCap;
    const int reach = int(std::ceil(kClearCap / kBucket)); // fine buckets
    const openvdb::CoordBBox cube(b.offsetBy(-reach), b.offsetBy(reach));
    using Leaf = CountTree::LeafNodeType;
    const Coord first = cube.min() & ~(Leaf::DIM - 1), last = cube.max() & ~(Leaf::DIM - 1);
    for (int z = first.z(); z <= last.z(); z += Leaf::DIM)
        for (int y = first.y(); y <= last.y(); y += Leaf::DIM)
            for (int x = first.x(); x <= last.x(); x += Leaf::DIM) {
                const Leaf* leaf = slots.probeConstLeaf(Coord(x, y, z));
                if (!leaf) continue;
                for (auto it = leaf->cbeginValueOn(); it; ++it) {
                    const Coord f = it.getCoord();
                    if (!cube.isInside(f)) continue;
                    double gap2 = 0; // between f's box and b's
                    for (int a = 0; a < 3; ++a) {
                        const double cells = double(std::max({0, f[a] - b[a] - 1, b[a] - f[a] - 1}));
                        gap2 += (kBucket * cells) * (kBucket * cells);
                    }
                    if (gap2 >= best2) continue;
                    for (const Vec3d& q : mBuckets[size_t(*it - 1)]) best2 = std::min(best2, boxDistance2(b, q));
                }
            }
    const float value = float(std::sqrt(best2));
    mClear[size_t(s)].store(value, std::memory_order_relaxed);
    raiseBlockMax(size_t(mClearBlockOf[size_t(s)]), value);
    return double(value);
}

SurfacePointIndex::NearAccessors SurfacePointIndex::nearAccessors() const
{
    NearAccessors out;
    out.reserve(kLevels);
    for (const auto& c : mNear) out.emplace_back(*c);
    return out;
}

std::vector<Vec3d>& SurfacePointIndex::bucketAt(const Coord& b)
{
    int32_t slot = mSlots->getValue(b) - 1;
    if (slot < 0) {
        if (mFreeSlots.empty()) {
            slot = int32_t(mBuckets.size());
            mBuckets.emplace_back();
        } else {
            slot = mFreeSlots.back();
            mFreeSlots.pop_back();
        }
        mSlots->setValue(b, slot + 1);
    }
    return mBuckets[size_t(slot)];
}

void SurfacePointIndex::insert(const Vec3d& q)
{
    bucketAt(bucketOf(q, 0)).push_back(q);
    for (int k = 0; k < kLevels; ++k) {
        const Coord b = bucketOf(q, k);
        const int32_t n = mCounts[size_t(k)]->getValue(b) + 1;
        mCounts[size_t(k)]->setValue(b, n);
        if (n == 1) addNear(k, b, 1);
    }
    ++mCount;
    if (!mClearBucket.empty()) mPendingInserts.push_back(q);
}

void SurfacePointIndex::assign(const std::vector<Vec3d>& points)
{
    clear();
    // (fine key, position in the list): each bucket's points keep the order insert() gives them
    std::vector<std::pair<uint64_t, uint32_t>> keyed(points.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) keyed[i] = {packBucket(bucketOf(points[i], 0)), uint32_t(i)};
    });
    tbb::parallel_sort(keyed.begin(), keyed.end());
    using Accessor = openvdb::tree::ValueAccessor<CountTree, false>;
    std::vector<Accessor> acc;
    acc.reserve(kLevels);
    for (auto& c : mCounts) acc.emplace_back(*c);
    for (size_t a = 0; a < keyed.size();) {
        size_t e = a;
        while (e < keyed.size() && keyed[e].first == keyed[a].first) ++e;
        auto& v = bucketAt(bucketOf(points[keyed[a].second], 0));
        v.reserve(e - a);
        for (size_t k = a; k < e; ++k) v.push_back(points[keyed[k].second]);
        // a level's bucket is the fine bucket's coordinates halved k times (floor: exact, as
        // the divisions by powers of two in bucketOf are)
        const Coord b0 = bucketOf(v.front(), 0);
        for (int k = 0; k < kLevels; ++k) {
            const Coord b(b0.x() >> k, b0.y() >> k, b0.z() >> k);
            acc[size_t(k)].setValue(b, acc[size_t(k)].getValue(b) + int32_t(e - a));
        }
        a = e;
    }
    for (int k = 0; k < kLevels; ++k) {
        openvdb::tree::ValueAccessor<NearTree, false> near(*mNear[size_t(k)]);
        for (auto it = mCounts[size_t(k)]->cbeginValueOn(); it; ++it) {
            const Coord b = it.getCoord();
            for (int dz = -1; dz <= 1; ++dz)
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        const Coord c = b + Coord(dx, dy, dz);
                        near.setValue(c, uint8_t(near.getValue(c) + 1));
                    }
        }
    }
    mCount = points.size();
}

bool SurfacePointIndex::erase(const Vec3d& q)
{
    const Coord fine = bucketOf(q, 0);
    const int32_t slot = mSlots->getValue(fine) - 1;
    if (slot < 0) return false;
    auto& v = mBuckets[size_t(slot)];
    const auto at = std::find(v.begin(), v.end(), q);
    if (at == v.end()) return false;
    v.erase(at); // keeps the others' order: distances are minima anyway
    if (v.empty()) {
        mSlots->setValueOff(fine, 0);
        mFreeSlots.push_back(slot);
    }
    for (int k = 0; k < kLevels; ++k) {
        const Coord b = bucketOf(q, k);
        const int32_t n = mCounts[size_t(k)]->getValue(b) - 1;
        if (n > 0) mCounts[size_t(k)]->setValue(b, n);
        else {
            mCounts[size_t(k)]->setValueOff(b, 0);
            addNear(k, b, -1);
        }
    }
    --mCount;
    if (!mClearBucket.empty()) mPendingErases.push_back(q);
    return true;
}

std::vector<double> SurfacePointIndex::pointList() const
{
    std::vector<std::pair<uint64_t, int32_t>> keys; // (bucket key, slot)
    for (auto it = mSlots->cbeginValueOn(); it; ++it) keys.emplace_back(packBucket(it.getCoord()), *it - 1);
    std::sort(keys.begin(), keys.end());
    std::vector<double> out;
    out.reserve(3 * mCount);
    for (const auto& [key, slot] : keys)
        for (const Vec3d& q : mBuckets[size_t(slot)]) out.insert(out.end(), {q.x(), q.y(), q.z()});
    return out;
}

double SurfacePointIndex::distance(const Vec3d& x) const
{
    flushClearances();
    Cursor c(*this);
    return c.distance(x);
}

bool SurfacePointIndex::hasPointWithin(const Vec3d& x, double r, bool inclusive) const
{
    if (mCount == 0) return false;
    const Coord lo = bucketOf(x - Vec3d(r), 0), hi = bucketOf(x + Vec3d(r), 0);
    CountAccessor slots(*mSlots);
    for (int z = lo.z(); z <= hi.z(); ++z)
        for (int y = lo.y(); y <= hi.y(); ++y)
            for (int xb = lo.x(); xb <= hi.x(); ++xb) {
                const int32_t slot = slots.getValue(Coord(xb, y, z)) - 1;
                if (slot < 0) continue;
                for (const Vec3d& q : mBuckets[size_t(slot)]) {
                    const double d = std::sqrt((q - x).lengthSqr()); // as distance() rounds it
                    if (inclusive ? d <= r : d < r) return true;
                }
            }
    return false;
}

double SurfacePointIndex::coarseBound(const Vec3d& x, NearAccessors& near) const
{
    // free 3x3x3 neighbourhood at level k: no point within 4 * 2^k (of any point of x's fine
    // bucket, which lies inside x's bucket at every level). A level's neighbourhood lies inside
    // the next one's, so occupancy only grows with k: the first occupied level by bisection.
    auto occupied = [&](int k) { return near[size_t(k)].getValue(bucketOf(x, k)) > 0; };
    int lo = 1, hi = kLevels; // levels below lo are free; level hi is occupied (or hi = kLevels)
    while (lo < hi) {
        const int mid = (lo + hi) / 2;
        if (occupied(mid)) hi = mid;
        else lo = mid + 1;
    }
    if (lo == kLevels) return kFar; // nothing within the top level's reach
    return kBucket * double(1 << (lo - 1));
}

void SurfacePointIndex::Cursor::enter(const Vec3d& x, const Coord& b)
{
    const uint64_t key = packBucket(b);
    if (key == mKey) return;
    mKey = key;
    mNearCount = -1; // gathered when first needed
    // the bucket's lower bound: its clearance (exact below the cap, where it is the largest
    // bound any point of the box has), else the pyramid's too
    const double c = mIndex.clearance(b, mSlotAcc, mClearAcc);
    mLower = c >= 0.0 && c < kClearCap ? c : std::max(c, mIndex.coarseBound(x, mNearAcc));
}

double SurfacePointIndex::Cursor::walkDistance(const Vec3d& x, double near)
{
    if (mIndex.mCount == 0) return kFar;
    enter(x, bucketOf(x, 0));
    if (mLower > kBucket) return mLower;
    const Coord lo = bucketOf(x - Vec3d(near), 0), hi = bucketOf(x + Vec3d(near), 0);
    for (int z = lo.z(); z <= hi.z(); ++z)
        for (int y = lo.y(); y <= hi.y(); ++y)
            for (int xb = lo.x(); xb <= hi.x(); ++xb) {
                const int32_t slot = mSlotAcc.getValue(Coord(xb, y, z)) - 1;
                if (slot < 0) continue;
                for (const Vec3d& q : mIndex.mBuckets[size_t(slot)])
                    if (std::sqrt((q - x).lengthSqr()) <= near) return 0.0; // as distance() rounds it
            }
    return std::nextafter(near, kFar);
}

double SurfacePointIndex::Cursor::distance(const Vec3d& x)
{
    if (mIndex.mCount == 0) return kFar;
    const Coord b = bucketOf(x, 0);
    enter(x, b);
    // no point within kBucket: the nearest fine buckets' points would not give the distance
    if (mLower > kBucket) return mLower;
    if (mNearCount < 0) {
        mNearCount = 0;
        for (int dz = -1; dz <= 1; ++dz)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) {
                    const int32_t slot = mSlotAcc.getValue(b + Coord(dx, dy, dz)) - 1;
                    if (slot >= 0) mNear[size_t(mNearCount++)] = &mIndex.mBuckets[size_t(slot)];
                }
    }
    double best2 = kFar * kFar;
    for (int k = 0; k < mNearCount; ++k)
        for (const Vec3d& q : *mNear[size_t(k)]) best2 = std::min(best2, (q - x).lengthSqr());
    const double best = std::sqrt(best2);
    if (best <= kBucket) return best;
    // nothing within kBucket of x: the 3x3x3 fine buckets around it hold every point nearer
    return std::min(best, std::max(mLower, kBucket));
}

// ---------------------------------------------------------------------------------------------
// ShellWalkers

ShellWalkers::ShellWalkers(std::shared_ptr<const ShellBand> band, const ice::DlaParams& params, uint64_t seed)
    : mBand(std::move(band)), mParams(params), mSeed(seed),
      mMaxJump(params.jumpMaxRadius > 0 ? params.jumpMaxRadius : 64), mOpen(mBand->borderEdgeCount() > 0)
{
    const ShellBand& b = *mBand;
    const bool open = b.borderEdgeCount() > 0;
    for (size_t i = 0; i < b.size(); ++i) {
        // beyond an open border (near the surface's plane): the closest point is on the border
        if (open && b.lateralOffset(i) > 0.5f && std::fabs(b.normalOffset(i)) <= 1.0f) mBorder.insert(b.closestPoint(i));
        else if (inLayer(i)) mLayer.push_back(i);
    }
    if (open && b.surfaceNodes()) // no voxels beyond the border: the border edges themselves
        for (size_t e = 0; e < b.borderEdgeCount(); ++e) {
            const auto [a, c] = b.borderEdge(e);
            const int n = std::max(1, int(std::ceil((c - a).length() / 0.5)));
            for (int k = 0; k <= n; ++k) mBorder.insert(a + (c - a) * (double(k) / n));
        }
    if (mBorder.size() > 0)
        for (size_t i : mLayer)
            if (mBorder.distance(b.closestPoint(i)) <= 1.5) mBorderLayer.push_back(i);
    // walkers query distances on the surface: a clearance for each fine bucket it crosses
    const auto site = [&b](size_t i) { return b.closestPoint(i); };
    mIce.enableClearance(b.size(), site);
    mBorder.enableClearance(b.size(), site);
    if (b.surfaceNodes()) mIceNode.assign(b.size(), 0);
    mCoarseNear = !mParams.jumps || double(mParams.jumpMinRadius) + 2.0 > SurfacePointIndex::kBucket;
}

void ShellWalkers::sync(const std::vector<float>& p)
{
    std::fill(mIceNode.begin(), mIceNode.end(), uint8_t(0));
    std::vector<Vec3d> ice;
    for (size_t i : mLayer)
        if (p[i] > 0.5f) {
            ice.push_back(mBand->closestPoint(i));
            if (!mIceNode.empty()) mIceNode[i] = 1;
        }
    mIce.assign(ice);
}

void ShellWalkers::addIce(const Vec3d& x)
{
    mIce.insert(x);
    if (mIceNode.empty()) return;
    BandIndex::Accessor acc = mBand->index().accessor();
    if (const int32_t k = nodeOfStick(*mBand, acc, x); k >= 0) mIceNode[size_t(k)] = 1;
}

void ShellWalkers::forgetSticks(const std::vector<Vec3d>& sticks, const std::vector<float>& p)
{
    BandIndex::Accessor acc = mBand->index().accessor();
    for (const Vec3d& x : sticks) {
        mIce.erase(x); // one copy: a stick on a node's closest point leaves the node's own
        if (mIceNode.empty()) continue;
        if (const int32_t k = nodeOfStick(*mBand, acc, x); k >= 0)
            mIceNode[size_t(k)] = inLayer(size_t(k)) && p[size_t(k)] > 0.5f;
    }
}

void ShellWalkers::restoreIce(const std::vector<double>& xyz)
{
    mIce.clear();
    std::fill(mIceNode.begin(), mIceNode.end(), uint8_t(0));
    for (size_t k = 0; k + 2 < xyz.size(); k += 3) addIce(Vec3d(xyz[k], xyz[k + 1], xyz[k + 2]));
}

void ShellWalkers::removeIceVoxels(const std::vector<size_t>& voxels)
{
    for (size_t i : voxels)
        if (inLayer(i)) {
            mIce.erase(mBand->closestPoint(i));
            if (!mIceNode.empty()) mIceNode[i] = 0;
        }
}

void ShellWalkers::addIceVoxels(const std::vector<size_t>& voxels)
{
    for (size_t i : voxels)
        if (inLayer(i)) {
            mIce.insert(mBand->closestPoint(i));
            if (!mIceNode.empty()) mIceNode[i] = 1;
        }
}

/// The most moves (steps and jumps) a walker makes: about 1,000 times a typical walk's.
constexpr uint32_t kMaxMoves = 1000000;

/// Graph steps between two distance queries (sticking is checked at every step, on the nodes).
constexpr int kGraphBurst = 8;

ShellWalkers::GraphStep ShellWalkers::graphStep(int32_t node, ice::WalkerRng& rng, bool checkIce) const
{
    GraphStep out;
    out.node = node;
    const SurfaceTap* first = mBand->tapsBegin(size_t(node));
    const SurfaceTap* last = mBand->tapsEnd(size_t(node));
    float sum = 0.f, strongest = 0.f;
    for (const SurfaceTap* t = first; t != last; ++t)
        if (t->node != node && t->lap > 0.f) {
            sum += t->lap;
            strongest = std::max(strongest, t->lap);
        }
    if (!(sum > 0.f)) return out; // NoStencil: the caller takes a projected step
    for (const SurfaceTap* t = first; checkIce && t != last; ++t)
        if (t->node != node && t->lap >= 0.5f * strongest && mIceNode[size_t(t->node)]) {
            out.kind = GraphStep::NextToIce;
            return out;
        }
    out.latticeSteps = 4.0 / double(sum); // E|step|^2 = sum w r^2 / sum w = 4 / sum w (exact on r^2)
    float u = float(rng.uniform()) * sum;
    const SurfaceTap* pick = nullptr;
    for (const SurfaceTap* t = first; t != last; ++t)
        if (t->node != node && t->lap > 0.f) {
            pick = t;
            if ((u -= t->lap) < 0.f) break;
        }
    if (mIceNode[size_t(pick->node)]) {
        out.kind = GraphStep::Blocked; // ice cannot be entered: the walker stays
        return out;
    }
    out.kind = GraphStep::Moved;
    out.node = pick->node;
    return out;
}

int32_t ShellWalkers::siteOf(const Vec3d& x) const
{
    if (!mBand->surfaceNodes()) return mBand->indexOf(Coord::round(x));
    BandIndex::Accessor acc = mBand->index().accessor();
    return nodeNear(*mBand, acc, x);
}

bool ShellWalkers::project(const Vec3d& y, Vec3d& out, double* lateral) const
{
    BandIndex::Accessor acc = mBand->index().accessor();
    return projectWith(*mBand, acc, y, out, lateral);
}

int32_t ShellWalkers::freeNodeNear(const Vec3d& x, const std::vector<float>& p) const
{
    BandIndex::Accessor acc = mBand->index().accessor();
    const Coord c = Coord::round(x);
    int32_t id = -1;
    double best = std::numeric_limits<double>::max();
    for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) {
                const int32_t k = acc.getValue(c + Coord(dx, dy, dz));
                if (k < 0 || p[size_t(k)] > 0.5f || mBand->ghost(size_t(k))) continue;
                const double d = (mBand->closestPoint(size_t(k)) - x).lengthSqr();
                if (d < best || (d == best && k < id)) { best = d; id = k; }
            }
    return id;
}

std::vector<size_t> ShellWalkers::markDisc(const Vec3d& x) const
{
    std::vector<size_t> out;
    BandIndex::Accessor acc = mBand->index().accessor();
    if (mBand->surfaceNodes()) { // one node per surface cell: a stick freezes the node holding it, as on a plane
        const int32_t id = nodeNear(*mBand, acc, x);
        if (id >= 0) out.push_back(size_t(id));
        return out;
    }
    const std::optional<VoxelFrame> f = frameWith(*mBand, acc, x);
    const Vec3d n = f ? f->normal : Vec3d(0, 0, 1);
    // the disc's voxels lie along the normal through x, within the band's half-width
    const double reach = mBand->halfWidth() + 1.0;
    openvdb::CoordBBox box(Coord::floor(x - n * reach), Coord::floor(x - n * reach));
    box.expand(Coord::floor(x + n * reach));
    box.expand(1);
    const double r2 = kMarkRadius * kMarkRadius;
    for (auto it = box.begin(); it; ++it) {
        const int32_t id = acc.getValue(*it);
        if (id >= 0 && (mBand->closestPoint(size_t(id)) - x).lengthSqr() <= r2) out.push_back(size_t(id));
    }
    std::sort(out.begin(), out.end());
    return out;
}

void ShellWalkers::walkBatch(int64_t step, uint64_t first, uint64_t count, const Inputs& in,
                             std::vector<ShellWalkEnd>& out) const
{
    out.assign(size_t(count), ShellWalkEnd{});
    mIce.flushClearances();
    // one walker per task at most: a walk takes tens of microseconds, and a few long ones in a
    // chunk of 16 left the other thread idle at the batch's end
    tbb::parallel_for(tbb::blocked_range<uint64_t>(0, count, 1), [&](const tbb::blocked_range<uint64_t>& r) {
        for (uint64_t w = r.begin(); w < r.end(); ++w) out[size_t(w)] = walk(step, first + w, 0, nullptr, in);
    });
}

/// One walker's state along its walk, shared by walk()'s stages.
struct ShellWalkers::Walk {
    Walk(const ShellWalkers& w, const Inputs& inputs, ice::WalkerRng r)
        : b(*w.mBand), in(inputs), rng(r), acc(b.index().accessor()), ice(w.mIce), border(w.mBorder),
          onNodes(b.surfaceNodes()), onlyStickNear(w.mCoarseNear)
    {
    }
    const ShellBand& b;
    const Inputs& in;
    ice::WalkerRng rng;
    IndexAccessor acc;
    SurfacePointIndex::Cursor ice, border;
    /// Surface nodes: the node whose tangent plane x was last projected on gives its frame (no
    /// look-up per step); the closest-point band reads the frame of the voxel holding x.
    const bool onNodes;
    /// Below a jump's reach the walk only compares its distance with kStickRadius (mCoarseNear).
    const bool onlyStickNear;
    int32_t node = -1;
    Vec3d x{0.0};
    double d = 0;     ///< distance to the ice (a lower bound)
    double steps = 0; ///< lattice steps so far
    ShellWalkEnd end;

    std::optional<VoxelFrame> frame()
    {
        if (!onNodes) return frameWith(b, acc, x);
        if (node < 0) return std::nullopt;
        return b.frame(size_t(node));
    }
    Vec3d driftAt(const Vec3d& p)
    {
        if (!in.drift) return Vec3d(0.0);
        const int32_t id = acc.getValue(Coord::round(p));
        return id < 0 ? Vec3d(0.0) : Vec3d((*in.drift)[size_t(id)]);
    }
    /// The distance to the ice after a release, a jump or a burst.
    double iceDistance() { return onlyStickNear ? ice.walkDistance(x, kStickRadius) : ice.distance(x); }
    bool projectStep(const Vec3d& y, Vec3d& q, double* lat)
    {
        return onNodes ? projectOnNodes(b, acc, y, q, lat, &node) : projectWith(b, acc, y, q, lat);
    }
    /// Next to ice: the sticking roll (the melt map's probability at the walker's site).
    bool sticks()
    {
        double s = 1.0;
        if (in.melt) {
            const int32_t id = onNodes ? node : acc.getValue(Coord::round(x));
            if (id >= 0) s = double((*in.melt)[size_t(id)]);
        }
        return s >= 1.0 || (s > 0.0 && rng.uniform() < s);
    }
    ShellWalkEnd finish(ShellWalkEnd::Kind kind)
    {
        end.kind = kind;
        if (kind == ShellWalkEnd::Stuck) end.point = x;
        end.latticeSteps = steps;
        return end;
    }
};

ShellWalkEnd ShellWalkers::walk(int64_t step, uint64_t walker, uint64_t salt, const Vec3d* start,
                                const Inputs& in) const
{
    // a closed surface without ice: nothing to stick to and no border to leave by
    if (mIce.size() == 0 && !mOpen) return ShellWalkEnd{};
    mIce.flushClearances(); // a serial walk after sticks (in a batch: flushed before it, returns at once)
    Walk w(*this, in, ice::WalkerRng(mSeed, walker, uint64_t(step), salt));
    if (start) w.x = *start;
    else if (!releaseSite(w, walker)) return w.end;
    if (w.onNodes) w.node = nodeNear(w.b, w.acc, w.x);
    w.d = w.iceDistance();
    for (;;) {
        if (w.d <= kStickRadius && w.sticks()) return w.finish(ShellWalkEnd::Stuck);
        // max_steps, and a safety cap on the work (moves and jumps): a walker enclosed by ice it
        // cannot stick to (a melt map of 0 all along it) would otherwise walk for ever
        if ((mParams.maxSteps > 0 && w.steps >= double(mParams.maxSteps)) || w.end.moves >= kMaxMoves)
            return w.finish(ShellWalkEnd::Exhausted);
        ++w.end.moves;
        const std::optional<VoxelFrame> f = w.frame();
        if (!f) break;
        const Vec3d v = w.driftAt(w.x);
        Move m = jump(w, *f, v);
        if (m == Move::NotTaken) m = graphBurst(w);
        if (m == Move::NotTaken) m = latticeStep(w, *f, v);
        if (m == Move::Stuck) return w.finish(ShellWalkEnd::Stuck);
        if (m == Move::Left) break;
    }
    return w.finish(ShellWalkEnd::Killed);
}

bool ShellWalkers::releaseSite(Walk& w, uint64_t walker) const
{
    // a surface point away from the ice (uniform by area, or on the border)
    const Inputs& in = w.in;
    const auto& sites = mParams.release == ice::DlaRelease::Perimeter ? mBorderLayer : mLayer;
    const bool steam = in.steamCdf && !in.steamCdf->empty() && walker >= uint64_t(in.baseWalkers);
    if (sites.empty() && !steam) return false;
    for (int t = 0; t < 64; ++t) {
        if (steam) { // a site by its steam weight (DlaEngine::release's rule)
            const double u = w.rng.uniform() * in.steamCdf->back();
            const size_t k =
                size_t(std::upper_bound(in.steamCdf->begin(), in.steamCdf->end(), u) - in.steamCdf->begin());
            w.x = w.b.closestPoint((*in.steamSites)[std::min(k, in.steamSites->size() - 1)]);
        } else {
            const uint64_t pick = uint64_t((static_cast<unsigned __int128>(w.rng.next()) * sites.size()) >> 64);
            w.x = w.b.closestPoint(sites[size_t(pick)]);
        }
        if (!mIce.hasPointWithin(w.x, kStickRadius, true)) return true;
    }
    return false;
}

ShellWalkers::Move ShellWalkers::jump(Walk& w, const VoxelFrame& f, const Vec3d& v) const
{
    // walk on spheres: a uniform point of the free geodesic circle
    if (!mParams.jumps || w.d - 2.0 < double(mParams.jumpMinRadius)) return Move::NotTaken;
    double r = std::min({w.d - 2.0, w.border.distance(w.x) - 1.0, double(mMaxJump)});
    const double vm = v.length();
    if (vm > 0) r = std::min(r, std::sqrt(0.5 / vm)); // the drift over the jump stays < 1/2
    if (r < double(mParams.jumpMinRadius)) return Move::NotTaken;
    const double a = 2.0 * M_PI * w.rng.uniform();
    int32_t landed = -1;
    if (!shootWith(w.b, w.acc, w.x, f.tangent * std::cos(a) + f.bitangent * std::sin(a), r, mOpen, f, landed))
        return Move::Left;
    w.steps += r * r; // mean exit time of the unit-step walk from a disc of radius r
    ++w.end.jumps;
    w.end.hasPrev = false;
    if (vm > 0) {
        Vec3d q;
        double lat = 0;
        if (!projectWith(w.b, w.acc, w.x + v * (r * r), q, &lat) || (mOpen && lat > 0.5)) return Move::Left;
        w.x = q;
        landed = -1; // moved on by the drift
    }
    if (w.onNodes) w.node = landed >= 0 ? landed : nodeNear(w.b, w.acc, w.x);
    w.d = w.iceDistance();
    return Move::Moved;
}

ShellWalkers::Move ShellWalkers::graphBurst(Walk& w) const
{
    // on surface nodes without drift: a burst of node-graph steps, then one distance query
    if (!w.onNodes || w.node < 0 || w.in.drift) return Move::NotTaken;
    for (int n = 0; n < kGraphBurst; ++n) {
        GraphStep g = graphStep(w.node, w.rng, true);
        if (g.kind == GraphStep::NextToIce) {
            if (w.sticks()) return Move::Stuck;
            g = graphStep(w.node, w.rng, false); // the roll failed: it walks on
        }
        if (g.kind == GraphStep::NoStencil) {
            if (n == 0) return Move::NotTaken; // a projected step instead
            break;
        }
        w.steps += g.latticeSteps;
        if (n > 0) ++w.end.moves;
        if (g.kind != GraphStep::Moved) continue;
        if (mOpen && w.b.lateralOffset(size_t(g.node)) > 0.25f) return Move::Left; // past the border: it leaves
        w.end.prev = w.x;
        w.end.hasPrev = true;
        w.node = g.node;
        w.x = w.b.closestPoint(size_t(w.node));
        if (mParams.maxSteps > 0 && w.steps >= double(mParams.maxSteps)) break;
    }
    w.d = w.iceDistance();
    return Move::Moved;
}

ShellWalkers::Move ShellWalkers::latticeStep(Walk& w, const VoxelFrame& f, const Vec3d& v) const
{
    // one lattice step along one of the six tangent directions, plus the drift
    const unsigned k = unsigned((static_cast<unsigned __int128>(w.rng.next()) * 6u) >> 64);
    const double a = double(k) * (M_PI / 3.0);
    const Vec3d y = w.x + f.tangent * std::cos(a) + f.bitangent * std::sin(a) + v;
    const int32_t nodeBefore = w.node;
    Vec3d q;
    double lat = 0;
    if (!w.projectStep(y, q, &lat) || (mOpen && lat > 0.5)) return Move::Left; // left the mesh's border
    w.steps += 1;
    double dq = w.ice.distance(q);
    // ice cannot be entered: a walker next to ice whose step lands on it stays
    if (w.d <= kStickRadius && dq < 0.5) {
        w.node = nodeBefore;
        return Move::Moved;
    }
    if (w.d > kStickRadius && dq <= kStickRadius) {
        // contact: the walker stops where its step first comes within one spacing of the ice
        // (bisection on the step), so stuck points sit one spacing from the ice, as the
        // plane's stuck cells sit next to theirs
        double lo = 0, hi = 1;
        for (int it = 0; it < 12; ++it) {
            const double mid = 0.5 * (lo + hi);
            (w.ice.distance(w.x + (q - w.x) * mid) <= kStickRadius ? hi : lo) = mid;
        }
        Vec3d c;
        const int32_t nodeAtQ = w.node;
        if (w.projectStep(w.x + (q - w.x) * hi, c, nullptr) && w.ice.distance(c) <= kStickRadius) {
            q = c;
            dq = w.ice.distance(q);
        } else {
            w.node = nodeAtQ;
        }
    }
    w.end.prev = w.x;
    w.end.hasPrev = true;
    w.x = q;
    w.d = dq;
    return Move::Moved;
}

} // namespace frostvdb::shell
