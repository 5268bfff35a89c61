#include <frostvdb/ice/PhaseFieldSolver.h>
#include <frostvdb/core/Fields.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/core/RegionOfTopology.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/icephysics/EulerRows.h>
#include <frostvdb/icephysics/ImplicitSystem.h>
#include <frostvdb/icephysics/SecondOrderRows.h>

#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <memory>
#include <optional>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <type_traits>

namespace frostvdb {

namespace {

using FloatLeaf = openvdb::FloatTree::LeafNodeType;
using Clock = std::chrono::steady_clock;
constexpr int kDim = FloatLeaf::DIM; // 8
constexpr int kHalo = 2;             // stencil reach of one Kobayashi step

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

/// Leaves per side of a plane block: the kernels work on groups of up to 4x4 leaves (32x32
/// voxels) at once, so the halo and the ring of anisotropy coefficients that each block
/// recomputes cost 13% of its cells instead of 56% for a single leaf (measured: bench sparse).
/// Boxes keep one leaf per block.
constexpr int kPlaneGroup = 4;

/// A group's voxels plus a halo of kHalo cells, as flat arrays (x fastest).
struct Block {
    int bx, by, bz;
    bool plane;
    std::vector<float> p, T, a, cx, cy, gx, gy, gz;
    std::vector<float> melt, pe, te; ///< melt map; midpoint estimates (second-order scheme)
    std::vector<double> dp, chi;     ///< forward Euler on planes: dp and noise draws per cell
    /// Plane blocks: per row, the cells (bit x) whose coefficients pass 1 must compute: the
    /// group's leaves present in the region plus a ring of one cell.
    std::vector<uint64_t> need;
    explicit Block(bool flat)
        : bx((flat ? kPlaneGroup : 1) * kDim + 2 * kHalo), by(bx), bz(flat ? 1 : kDim + 2 * kHalo),
          plane(flat)
    {
        const size_t n = size_t(bx) * by * bz;
        for (auto* v : {&p, &T, &a, &cx, &cy, &gx, &gy, &gz, &melt, &pe, &te}) v->assign(n, 0.f);
        dp.assign(n, 0.0);
        chi.assign(n, 0.0);
        need.assign(size_t(by), 0);
    }
    size_t index(int x, int y, int z) const { return (size_t(z) * by + y) * bx + x; }
    /// Block coordinates of the group's first voxel: the block starts kHalo cells before it.
    openvdb::Coord origin(const openvdb::Coord& groupOrigin) const
    {
        return groupOrigin - openvdb::Coord(kHalo, kHalo, plane ? 0 : kHalo);
    }
};

} // namespace

/// Leaves of a region grouped into blocks: kPlaneGroup^2 leaves on a plane, one in a box.
/// Depends only on the region's topology (the leaf order of LeafManager), so it is cached.
struct LeafGroups {
    std::vector<size_t> leaves;        ///< leaf indices, group by group
    std::vector<size_t> start;         ///< group g owns leaves[start[g] .. start[g+1])
    std::vector<openvdb::Coord> origin; ///< first voxel of each group
    template <typename LeafManagerT>
    LeafGroups(const LeafManagerT& lm, bool plane)
    {
        if (plane && countedInto(lm)) return;
        const int span = (plane ? kPlaneGroup : 1) * kDim;
        auto groupOf = [span, plane](const openvdb::Coord& o) {
            auto fl = [span](int v) { return (v >= 0 ? v / span : -((-v + span - 1) / span)) * span; };
            return plane ? openvdb::Coord(fl(o.x()), fl(o.y()), o.z()) : o;
        };
        std::vector<std::pair<openvdb::Coord, size_t>> keyed(lm.leafCount());
        for (size_t i = 0; i < keyed.size(); ++i) keyed[i] = {groupOf(lm.leaf(i).origin()), i};
        std::sort(keyed.begin(), keyed.end(), [](const auto& a, const auto& b) {
            return a.first < b.first || (a.first == b.first && a.second < b.second);
        });
        for (size_t i = 0; i < keyed.size(); ++i) {
            if (i == 0 || keyed[i].first != keyed[i - 1].first) {
                start.push_back(i);
                origin.push_back(keyed[i].first);
            }
            leaves.push_back(keyed[i].second);
        }
        start.push_back(keyed.size());
    }
    size_t count() const { return origin.size(); }

private:
    /// Plane groups by a counting sort over the dense box of group keys: the order the sort above
    /// gives (groups by origin, x first; leaves by index), in time linear in the leaves (the sort
    /// was serial, 10 % of a region rebuild at 8192^2). False, with nothing done, when the box is
    /// much larger than the leaves (a few scattered seeds) or the leaves are not on one layer.
    template <typename LeafManagerT>
    bool countedInto(const LeafManagerT& lm)
    {
        constexpr int kSpan = kPlaneGroup * kDim;
        const size_t n = lm.leafCount();
        if (n == 0) return false;
        auto key = [](int v) { return v >= 0 ? v / kSpan : -((-v + kSpan - 1) / kSpan); };
        const int z = lm.leaf(0).origin().z();
        openvdb::CoordBBox box; // group keys
        for (size_t i = 0; i < n; ++i) {
            const openvdb::Coord& o = lm.leaf(i).origin();
            if (o.z() != z) return false;
            box.expand(openvdb::Coord(key(o.x()), key(o.y()), 0));
        }
        const size_t w = size_t(box.dim().x()), h = size_t(box.dim().y());
        if (w * h > 4 * n + 4096) return false;
        auto slotOf = [&](const openvdb::Coord& o) {
            return size_t(key(o.x()) - box.min().x()) * h + size_t(key(o.y()) - box.min().y());
        };
        std::vector<uint32_t> next(w * h + 1, 0); // per slot: its count, then its next position
        for (size_t i = 0; i < n; ++i) ++next[slotOf(lm.leaf(i).origin()) + 1];
        for (size_t k = 0; k < w * h; ++k) {
            if (next[k + 1]) {
                start.push_back(next[k]);
                origin.emplace_back((box.min().x() + int(k / h)) * kSpan, (box.min().y() + int(k % h)) * kSpan, z);
            }
            next[k + 1] += next[k];
        }
        start.push_back(n);
        leaves.resize(n);
        for (size_t i = 0; i < n; ++i) leaves[next[slotOf(lm.leaf(i).origin())]++] = i;
        return true;
    }
};

namespace {

/// Copies the grid's values over the block's footprint, leaf by leaf, falling back to the tile
/// or background value where no leaf exists. @a z0: the plane's z (planes only).
using ConstAcc = openvdb::tree::ValueAccessor<const openvdb::FloatTree, /*IsSafe=*/false>;

void gather(const ConstAcc& acc, const Block& b, const openvdb::Coord& groupOrigin,
            int z0, std::vector<float>& out)
{
    const openvdb::Coord bo = b.origin(groupOrigin);
    auto floor8 = [](int v) { return v & ~(kDim - 1); };
    const int zFirst = b.plane ? floor8(z0) : floor8(bo.z());
    const int zLast = b.plane ? floor8(z0) : bo.z() + b.bz - 1;
    for (int lzo = zFirst; lzo <= zLast; lzo += kDim)
        for (int lyo = floor8(bo.y()); lyo <= bo.y() + b.by - 1; lyo += kDim)
            for (int lxo = floor8(bo.x()); lxo <= bo.x() + b.bx - 1; lxo += kDim) {
                const openvdb::Coord lo(lxo, lyo, lzo);
                const int x0 = std::max(lo.x(), bo.x()), x1 = std::min(lo.x() + kDim, bo.x() + b.bx);
                const int y0 = std::max(lo.y(), bo.y()), y1 = std::min(lo.y() + kDim, bo.y() + b.by);
                const int zb0 = b.plane ? z0 : std::max(lo.z(), bo.z());
                const int zb1 = b.plane ? z0 + 1 : std::min(lo.z() + kDim, bo.z() + b.bz);
                const int zOff = b.plane ? z0 : bo.z(); // block z index = z - zOff
                if (x0 >= x1 || y0 >= y1 || zb0 >= zb1) continue;
                if (const FloatLeaf* leaf = acc.probeConstLeaf(lo)) {
                    const float* buf = leaf->buffer().data();
                    for (int z = zb0; z < zb1; ++z)
                        for (int y = y0; y < y1; ++y) {
                            float* dst = &out[b.index(x0 - bo.x(), y - bo.y(), z - zOff)];
                            const float* src = buf + ((((x0 & 7) << 6) | ((y & 7) << 3) | (z & 7)));
                            for (int x = x0; x < x1; ++x, src += 64) *dst++ = *src;
                        }
                } else {
                    const float v = acc.getValue(lo);
                    for (int z = zb0; z < zb1; ++z)
                        for (int y = y0; y < y1; ++y) {
                            float* dst = &out[b.index(x0 - bo.x(), y - bo.y(), z - zOff)];
                            for (int x = x0; x < x1; ++x) *dst++ = v;
                        }
                }
            }
}

/// Copies @a n floats (a row run of a folded leaf) in constant-size pieces that compile to
/// vector moves: a variable-length std::copy_n was a call to memmove per run, 7 % of the samples
/// of `bench scale` (perf --call-graph dwarf).
inline void copyRun(const float* src, float* dst, int n)
{
    for (; n >= 8; n -= 8, src += 8, dst += 8) std::memcpy(dst, src, 8 * sizeof(float));
    if (n >= 4) { std::memcpy(dst, src, 4 * sizeof(float)); n -= 4; src += 4; dst += 4; }
    for (; n > 0; --n) *dst++ = *src++;
}

/// gather() from a folded plane field (core/PlaneFold.h) over block cells [bx0, bx1) x [by0, by1)
/// (the whole block by default), folded leaf by folded leaf (a 64 x 8 tile: one probe, then up to
/// 8 runs of contiguous x).
void gatherFolded(const ConstAcc& acc, const Block& b, const openvdb::Coord& groupOrigin, std::vector<float>& out,
                  int bx0 = 0, int bx1 = -1, int by0 = 0, int by1 = -1)
{
    const openvdb::Coord bo = b.origin(groupOrigin);
    if (bx1 < 0) bx1 = b.bx;
    if (by1 < 0) by1 = b.by;
    const int gx0 = bo.x() + bx0, gx1 = bo.x() + bx1, gy0 = bo.y() + by0, gy1 = bo.y() + by1;
    for (int ty = gy0 & ~7; ty < gy1; ty += 8) {
        const int y0 = std::max(ty, gy0), y1 = std::min(ty + 8, gy1);
        for (int tx = gx0 & ~63; tx < gx1; tx += 64) {
            const int x0 = std::max(tx, gx0), x1 = std::min(tx + 64, gx1);
            const openvdb::Coord f = plane::fold(openvdb::Coord(x0, y0, 0));
            float* dst = &out[b.index(x0 - bo.x(), y0 - bo.y(), 0)];
            if (const FloatLeaf* leaf = acc.probeConstLeaf(f)) {
                const float* src = leaf->buffer().data() + (((y0 & 7) << 6) | (x0 & 63));
                for (int y = y0; y < y1; ++y, src += 64, dst += b.bx) copyRun(src, dst, x1 - x0);
            } else {
                const float v = acc.getValue(f);
                for (int y = y0; y < y1; ++y, dst += b.bx) std::fill_n(dst, x1 - x0, v);
            }
        }
    }
}

/// The part of a plane block that the rows of a group read (both schemes): the box of the
/// group's present leaves and kHalo cells around it, in block cells [x0, x1) x [y0, y1) (the
/// whole block in a box). A group at the region's edge often holds one or two of its 16 leaves;
/// gathering and extrapolating only this part gives the same values wherever they are read.
struct BlockRect {
    int x0 = 0, x1 = 0, y0 = 0, y1 = 0;
};

template <typename LeafT>
BlockRect presentRect(const Block& b, const openvdb::Coord& groupOrigin, const LeafT* const* leaves, size_t count)
{
    BlockRect r{0, b.bx, 0, b.by};
    if (!b.plane || count == 0) return r;
    const openvdb::Coord bo = b.origin(groupOrigin);
    r = {b.bx, 0, b.by, 0};
    for (size_t q = 0; q < count; ++q) {
        const openvdb::Coord o = leaves[q]->origin() - bo; // kHalo + 8 * leaf index in the group
        r.x0 = std::min(r.x0, o.x() - kHalo);
        r.x1 = std::max(r.x1, o.x() + kDim + kHalo);
        r.y0 = std::min(r.y0, o.y() - kHalo);
        r.y1 = std::max(r.y1, o.y() + kDim + kHalo);
    }
    return r;
}

/// gather() on the cells of @a rect only (planes; boxes take the whole block).
void gatherRect(const ConstAcc& acc, const Block& b, const openvdb::Coord& groupOrigin, int z0, const BlockRect& rect,
                std::vector<float>& out)
{
    if (!b.plane) {
        gather(acc, b, groupOrigin, z0, out);
        return;
    }
    const openvdb::Coord bo = b.origin(groupOrigin);
    auto floor8 = [](int v) { return v & ~(kDim - 1); };
    const int zLeaf = floor8(z0);
    const int gx0 = bo.x() + rect.x0, gx1 = bo.x() + rect.x1, gy0 = bo.y() + rect.y0, gy1 = bo.y() + rect.y1;
    for (int lyo = floor8(gy0); lyo < gy1; lyo += kDim)
        for (int lxo = floor8(gx0); lxo < gx1; lxo += kDim) {
            const openvdb::Coord lo(lxo, lyo, zLeaf);
            const int x0 = std::max(lxo, gx0), x1 = std::min(lxo + kDim, gx1);
            const int y0 = std::max(lyo, gy0), y1 = std::min(lyo + kDim, gy1);
            if (const FloatLeaf* leaf = acc.probeConstLeaf(lo)) {
                const float* buf = leaf->buffer().data();
                for (int y = y0; y < y1; ++y) {
                    float* dst = &out[b.index(x0 - bo.x(), y - bo.y(), 0)];
                    const float* src = buf + ((((x0 & 7) << 6) | ((y & 7) << 3) | (z0 & 7)));
                    for (int x = x0; x < x1; ++x, src += 64) *dst++ = *src;
                }
            } else {
                const float v = acc.getValue(lo);
                for (int y = y0; y < y1; ++y) {
                    float* dst = &out[b.index(x0 - bo.x(), y - bo.y(), 0)];
                    for (int x = x0; x < x1; ++x) *dst++ = v;
                }
            }
        }
}


/// Marks, on a plane block, the cells pass 1 must cover: each present leaf and a ring of one.
template <typename LeafT>
void markNeeded(Block& b, const openvdb::Coord& groupOrigin, const LeafT* const* leaves, size_t count)
{
    std::fill(b.need.begin(), b.need.end(), 0ull);
    if (!b.plane) return;
    const openvdb::Coord bo = b.origin(groupOrigin);
    for (size_t q = 0; q < count; ++q) {
        const openvdb::Coord o = leaves[q]->origin() - bo; // >= kHalo in x and y
        const uint64_t bits = ((uint64_t(1) << (kDim + 2)) - 1) << (o.x() - 1);
        for (int y = o.y() - 1; y <= o.y() + kDim; ++y) b.need[size_t(y)] |= bits;
    }
}

/// Calls f(i) for every cell pass 1 covers: on a plane the marked cells, in a box every cell
/// with a full ring of neighbours.
template <typename F>
inline void forNeeded(const Block& b, F&& f)
{
    if (b.plane) {
        for (int y = 1; y < b.by - 1; ++y) {
            uint64_t bits = b.need[size_t(y)];
            const size_t row = b.index(0, y, 0);
            while (bits) {
                const int x = __builtin_ctzll(bits);
                bits &= bits - 1;
                f(row + size_t(x));
            }
        }
        return;
    }
    for (int z = 1; z < b.bz - 1; ++z)
        for (int y = 1; y < b.by - 1; ++y)
            for (int x = 1; x < b.bx - 1; ++x) f(b.index(x, y, z));
}

/// True when p is exactly 0 over a plane leaf and the two cells around it: everything the
/// update of its voxels reads (kobayashiEulerHeatOnly applies).
template <typename LeafT>
bool phaseZeroAround(const Block& b, const openvdb::Coord& groupOrigin, const LeafT& leaf)
{
    if (!b.plane) return false;
    const openvdb::Coord o = leaf.origin() - b.origin(groupOrigin);
    for (int y = o.y() - kHalo; y < o.y() + kDim + kHalo; ++y) {
        const float* row = &b.p[b.index(o.x() - kHalo, y, 0)];
        for (int x = 0; x < kDim + 2 * kHalo; ++x)
            if (row[x] != 0.f) return false;
    }
    return true;
}

/// Pass 1 over the cells the block's leaves need, on @a phase.
void auxPass(Block& b, const std::vector<float>& phase, const FlatStencil& st, const Anisotropy& an)
{
    forNeeded(b, [&](size_t i) {
        kobayashiAux(phase.data(), i, st, an, b.a.data(), b.cx.data(), b.cy.data(), b.gx.data(), b.gy.data(),
                     b.gz.data());
    });
}

/// Calls f(n, i, c) for every active voxel of @a leaf: n its offset in the leaf, i its block
/// cell, c its coordinate. Word by word over the value mask (word x, bit (y << 3) | z).
template <typename LeafT, typename F>
inline void forActiveVoxels(const Block& b, const openvdb::Coord& groupOrigin, int z0, const LeafT& leaf, F&& f)
{
    const openvdb::Coord bo = b.origin(groupOrigin);
    const openvdb::Coord lo = leaf.origin();
    const auto& mask = leaf.getValueMask();
    for (int x = 0; x < kDim; ++x) {
        uint64_t bits = mask.template getWord<uint64_t>(openvdb::Index(x));
        while (bits) {
            const int bit = __builtin_ctzll(bits);
            bits &= bits - 1;
            const int y = bit >> 3, z = bit & 7;
            const openvdb::Coord c(lo.x() + x, lo.y() + y, lo.z() + z);
            const size_t i = b.index(c.x() - bo.x(), c.y() - bo.y(), b.plane ? c.z() - z0 : c.z() - bo.z());
            f(openvdb::Index(x * 64 + bit), i, c);
        }
    }
}

/// Kobayashi's noise chi in [-1/2, 1/2] for a voxel and step (0 when the noise is off): a pure
/// function of (seed, step, voxel), so both schemes draw the same values whatever the threads.
inline double noiseDraw(const KobayashiParams& k, uint64_t seed, int64_t stepIndex, const openvdb::Coord& c)
{
    if (k.noise == 0) return 0.0;
    return toUnit(hashCounters(seed, uint64_t(stepIndex), coordKey(c.x(), c.y(), c.z()))) - 0.5;
}

/// Local T_e from the melt map (1 where there is none).
inline double meltTemperatureAt(const KobayashiParams& k, const Block& b, size_t i, bool haveMelt)
{
    return haveMelt ? k.localMeltTemperature(b.melt[i]) : k.meltTemperature;
}

} // namespace

/// The first bad voxel found (smallest coordinate, so the report does not depend on threads).
struct PhaseFieldSolver::Failure {
    std::mutex mutex;
    bool any = false;
    openvdb::Coord where;
    std::string field;
    float value = 0;
    void report(const openvdb::Coord& c, const char* f, float v)
    {
        std::lock_guard<std::mutex> lock(mutex);
        if (!any || c < where) { any = true; where = c; field = f; value = v; }
    }
};

namespace {
using Failure = PhaseFieldSolver::Failure;

} // namespace

/// The growth and freeze-time accumulators. Written in place where their leaf exists; writes
/// into missing leaves are queued per thread and applied serially afterwards (topology must not
/// change in parallel), so no empty accumulator leaves are made and pruned each step.
struct PhaseFieldSolver::Accumulators {
    openvdb::FloatTree* growth = nullptr;
    openvdb::FloatTree* freeze = nullptr;
    /// The field is folded (core/PlaneFold.h): a plane leaf's voxels live in a slice of the
    /// folded leaf foldedLeafOrigin(origin), shared with 7 other plane leaves, so its mask words
    /// are set atomically.
    bool foldG = false, foldF = false;
    struct Pending {
        openvdb::Coord c;
        float v;
        bool growth;
    };
    tbb::enumerable_thread_specific<std::vector<Pending>> pending;

    /// Records dp > 0 and the first time p exceeds 1/2 at voxel n (coordinate c) of a leaf whose
    /// accumulator leaves are @a gl and @a fl (null when absent).
    inline void record(FloatLeaf* gl, FloatLeaf* fl, openvdb::Index n, const openvdb::Coord& c, double dp, float pn,
                       float tNext, std::vector<Pending>*& local)
    {
        if (growth && dp > 0) {
            if (gl) gl->setValueOn(n, gl->getValue(n) + float(dp));
            else queue(local).push_back({c, float(dp), true});
        }
        if (freeze && pn > 0.5f) {
            if (fl) { if (!fl->isValueOn(n)) fl->setValueOn(n, tNext); }
            else queue(local).push_back({c, tNext, false});
        }
    }
    /// The accumulator leaf holding the voxels of the plane (or box) leaf at @a lo, null if none.
    static FloatLeaf* leafFor(openvdb::FloatTree* t, bool fold, const openvdb::Coord& lo)
    {
        return t ? t->probeLeaf(fold ? plane::foldedLeafOrigin(lo) : lo) : nullptr;
    }
    /// The offset in leafFor's leaf of voxel @a n of the plane leaf at @a lo.
    static openvdb::Index slot(bool fold, const openvdb::Coord& lo, openvdb::Index n)
    {
        return fold ? plane::foldedOffset(lo, int(n >> 6), int((n >> 3) & 7)) : n;
    }
    static void markOn(FloatLeaf& l, bool fold, openvdb::Index s)
    {
        if (fold) plane::setOnAtomic(l, s);
        else l.getValueMask().setOn(s);
    }
    static bool isOn(const FloatLeaf& l, bool fold, openvdb::Index s)
    {
        return fold ? plane::isOnAtomic(l, s) : l.getValueMask().isOn(s);
    }
    std::vector<Pending>& queue(std::vector<Pending>*& local)
    {
        if (!local) local = &pending.local();
        return *local;
    }
    void apply()
    {
        std::unique_ptr<openvdb::tree::ValueAccessor<openvdb::FloatTree>> ga, fa;
        if (growth) ga = std::make_unique<openvdb::tree::ValueAccessor<openvdb::FloatTree>>(*growth);
        if (freeze) fa = std::make_unique<openvdb::tree::ValueAccessor<openvdb::FloatTree>>(*freeze);
        for (auto& list : pending) {
            for (const auto& e : list) {
                if (e.growth) {
                    const openvdb::Coord c = foldG ? plane::fold(e.c) : e.c;
                    ga->setValueOn(c, ga->getValue(c) + e.v);
                } else {
                    const openvdb::Coord c = foldF ? plane::fold(e.c) : e.c;
                    if (!fa->isValueOn(c)) fa->setValueOn(c, e.v);
                }
            }
            list.clear();
        }
    }
};

namespace {
using Accumulators = PhaseFieldSolver::Accumulators;

/// The new values of an in-place step, leaf by leaf in LeafManager order: one slot per voxel a
/// leaf can hold on the domain (64 on a plane: its one z layer, slot = offset >> 3; 512 in a
/// box). A plane step so needs 2 x 256 bytes per leaf instead of a second pair of 2 KiB leaves.
struct StagedValues {
    float *p0 = nullptr, *t0 = nullptr;
    int shift = 0;
    size_t slots = 0;
    StagedValues(std::vector<float>& p, std::vector<float>& t, size_t leaves, bool plane)
        : shift(plane ? 3 : 0), slots(plane ? size_t(kDim * kDim) : size_t(kDim * kDim * kDim))
    {
        p.resize(leaves * slots); // resize, not assign: every slot the commit reads is written
        t.resize(leaves * slots);
        p0 = p.data();
        t0 = t.data();
    }
    float* p(size_t li) const { return p0 + li * slots; }
    float* t(size_t li) const { return t0 + li * slots; }
    /// Folded p and T: the values are staged per region plane leaf (64 slots, row by row:
    /// slot (y << 3) | x, so the row writer copies runs of 8), not per folded leaf (512): a folded
    /// leaf the region covers in part stages only its region's chunks. Chunk g of p's folded leaf
    /// fi is region leaf chunkLeaf[fi * 8 + g] (FoldedLayout::chunkLeaf).
    const std::vector<uint32_t>* chunkLeaf = nullptr;
};

/// Copies @a N floats: a memcpy of constant size, inlined as vector moves (std::copy_n of a few
/// floats compiled to a call to memmove per row, objdump).
template <size_t N>
inline void copyFloats(const float* src, float* dst)
{
    std::memcpy(dst, src, N * sizeof(float));
}

/// Folded staging: the slot of a region plane leaf's offset @a n (x * 64 + y * 8).
inline openvdb::Index rowSlot(openvdb::Index n) { return (((n >> 3) & 7) << 3) | (n >> 6); }

/// Folded staging: per chunk of the folded leaf @a fi, its region leaf's p and T slots (null
/// where the region has no leaf: the commit never reads them).
struct ChunkSlots {
    const float* p[8] = {};
    const float* t[8] = {};
    ChunkSlots(const StagedValues& sv, size_t fi)
    {
        for (size_t g = 0; g < 8; ++g) {
            const uint32_t r = (*sv.chunkLeaf)[fi * 8 + g];
            if (r == ~uint32_t(0)) continue;
            p[g] = sv.p(r);
            t[g] = sv.t(r);
        }
    }
    /// folded offset n = (y << 6) | (g << 3) | x: chunk g's slot (y << 3) | x
    static openvdb::Index slot(openvdb::Index n) { return ((n >> 6) << 3) | (n & 7); }
    float atP(openvdb::Index n) const { return p[(n >> 3) & 7][slot(n)]; }
    float atT(openvdb::Index n) const { return t[(n >> 3) & 7][slot(n)]; }
    /// A full mask word (row y of the folded leaf) is 8 runs of 8, one per chunk.
    bool copyWord(openvdb::Index w, float* pv, float* tv) const
    {
        for (openvdb::Index g = 0; g < 8; ++g) {
            copyFloats<8>(p[g] + w * 8, pv + w * 64 + g * 8);
            copyFloats<8>(t[g] + w * 8, tv + w * 64 + g * 8);
        }
        return true;
    }
};

/// truncateToTolerance (core/ActiveRegion.h) done by the commit on a retiring step: the same
/// test on the same values as they are written, so the leaves are not read a second time.
struct FusedTruncation {
    float tol = 0, bgP = 0, bgT = 0;
    std::atomic<bool> changedP{false}, changedT{false}, emptiedP{false}, emptiedT{false};
};

/// A leaf's staged values in its own slots (offset >> shift).
struct LeafSlots {
    const float *p, *t;
    int shift;
    float atP(openvdb::Index n) const { return p[n >> shift]; }
    float atT(openvdb::Index n) const { return t[n >> shift]; }
    /// A full mask word's 64 slots are one run only when slots are offsets.
    bool copyWord(openvdb::Index w, float* pv, float* tv) const
    {
        if (shift != 0) return false;
        copyFloats<64>(p + w * 64, pv + w * 64);
        copyFloats<64>(t + w * 64, tv + w * 64);
        return true;
    }
};

/// commitStaged on one leaf pair from its staged values @a s (LeafSlots or ChunkSlots).
template <typename Slots>
void commitLeaf(FloatLeaf& pl, FloatLeaf& tl, const Slots& s, FusedTruncation* trunc)
{
    float* pv = pl.buffer().data();
    float* tv = tl.buffer().data();
    auto& mask = pl.getValueMask();
    if (!trunc) {
        for (openvdb::Index w = 0; w < FloatLeaf::NodeMaskType::WORD_COUNT; ++w) {
            const uint64_t word = mask.template getWord<uint64_t>(w);
            if (word == ~uint64_t(0) && s.copyWord(w, pv, tv)) continue; // a full word: runs
            for (uint64_t bits = word; bits; bits &= bits - 1) {
                const openvdb::Index n = w * 64 + openvdb::Index(__builtin_ctzll(bits));
                pv[n] = s.atP(n);
                tv[n] = s.atT(n);
            }
        }
        return;
    }
    // p and T share the region's topology: one walk over the mask, two masks out.
    auto& tmask = tl.getValueMask();
    const float tol = trunc->tol, bgP = trunc->bgP, bgT = trunc->bgT;
    bool anyP = false, anyT = false, offP = false, offT = false;
    for (openvdb::Index w = 0; w < FloatLeaf::NodeMaskType::WORD_COUNT; ++w) {
        uint64_t& wp = mask.template getWord<uint64_t>(w);
        uint64_t& wt = tmask.template getWord<uint64_t>(w);
        uint64_t clearP = 0, clearT = 0;
        for (uint64_t bits = wp; bits; bits &= bits - 1) {
            const int b = __builtin_ctzll(bits);
            const openvdb::Index n = w * 64 + openvdb::Index(b);
            const float x = s.atP(n), y = s.atT(n);
            if (std::fabs(x - bgP) <= tol) { pv[n] = bgP; clearP |= uint64_t(1) << b; }
            else pv[n] = x;
            if (std::fabs(y - bgT) <= tol) { tv[n] = bgT; clearT |= uint64_t(1) << b; }
            else tv[n] = y;
        }
        wp &= ~clearP;
        wt &= ~clearT;
        anyP = anyP || wp;
        anyT = anyT || wt;
        offP = offP || clearP;
        offT = offT || clearT;
    }
    if (offP) trunc->changedP = true;
    if (offT) trunc->changedT = true;
    if (!anyP) trunc->emptiedP = true;
    if (!anyT) trunc->emptiedT = true;
}

/// Copies the staged values into the leaves' active voxels (the voxels the kernel wrote); with
/// @a trunc, values within its tolerance of the background are set to it and switched off.
void commitStaged(openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
                  openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves, const StagedValues& sv,
                  FusedTruncation* trunc = nullptr)
{
    tbb::parallel_for(tbb::blocked_range<size_t>(0, pLeaves.leafCount(), 64), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t li = r.begin(); li != r.end(); ++li) {
            if (sv.chunkLeaf) commitLeaf(pLeaves.leaf(li), tLeaves.leaf(li), ChunkSlots(sv, li), trunc);
            else commitLeaf(pLeaves.leaf(li), tLeaves.leaf(li), LeafSlots{sv.p(li), sv.t(li), sv.shift}, trunc);
        }
    });
}

/// The kernel over every leaf of the new grids (whose topology is the region), group by group:
/// gather, pass 1, pass 2. Accumulators and the failure report are optional (benchmarks pass none).
struct LeafKernel {
    const KobayashiParams& k;
    const Domain& domain;
    const openvdb::FloatGrid& p;
    const openvdb::FloatGrid& T;
    const openvdb::FloatGrid* melt = nullptr;
    int64_t stepIndex = 0;
    double tNext = 0;
    uint64_t seed = 0;
    Accumulators* acc = nullptr;
    Failure* failure = nullptr;
    /// In-place steps: new values go to a staging area (one slot per voxel a leaf can hold on
    /// this domain, leaf by leaf in LeafManager order), since p and T are read while the kernel
    /// runs; null: they go straight into the output leaves (separate output grids).
    StagedValues* staged = nullptr;
    /// Where the cells whose p crossed 1/2 go (null: nobody listens), see setCrossingLog.
    std::vector<openvdb::Coord>* crossings = nullptr;

    /// Folded p and T (core/PlaneFold.h): the kernel walks the region's plane leaves (region
    /// leaf li's values staged in its own 64 slots, StagedValues::chunkLeaf); its folded leaf is
    /// foldedLeaf[li] of p's leaves.
    const std::vector<uint32_t>* foldedLeaf = nullptr;

    /// Where leaf @a li's new values go: the staging slots or the leaf buffer itself, and the
    /// shift from a leaf offset to its slot (planes keep one z layer: 64 slots, offset >> 3);
    /// folded, the region leaf's row-by-row slot of plane offset n (rowSlot).
    struct Out {
        float *p, *t;
        int shift;
        bool fold;
        openvdb::Coord lo;
        openvdb::Index slot(openvdb::Index n) const
        {
            return fold ? rowSlot(n) : n >> shift;
        }
        float& atP(openvdb::Index n) const { return p[slot(n)]; }
        float& atT(openvdb::Index n) const { return t[slot(n)]; }
    };
    Out out(size_t li, const openvdb::Coord& lo, openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
            openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves) const
    {
        if (foldedLeaf) return {staged->p(li), staged->t(li), 0, true, lo};
        if (staged) return {staged->p(li), staged->t(li), staged->shift, false, lo};
        return {pLeaves.leaf(li).buffer().data(), tLeaves.leaf(li).buffer().data(), 0, false, lo};
    }

    /// Pass 1 on a plane block, by runs of needed cells along each row.
    static void auxRuns(Block& b, const FlatStencil& st, const Anisotropy& an, const EulerRows& rows)
    {
        for (int y = 1; y < b.by - 1; ++y) {
            uint64_t bits = b.need[size_t(y)];
            const size_t row = b.index(0, y, 0);
            while (bits) {
                const int x0 = __builtin_ctzll(bits);
                const uint64_t run = bits + (uint64_t(1) << x0); // clears the run of ones at x0
                const int x1 = run ? __builtin_ctzll(run & ~bits) : 64;
                bits &= run;
                rows.aux(b.p.data(), row + size_t(x0), row + size_t(x1), st, an, b.a.data(), b.cx.data(), b.cy.data(),
                         b.gx.data(), b.gy.data(), b.gz.data());
            }
        }
    }

    /// Pass 2 on a plane block's leaves that take the full update: the row code over runs of
    /// horizontally adjacent leaves (up to kPlaneGroup * 8 cells per call) into the block's
    /// scratch (pe, te, dp); planeLeaf then writes each leaf.
    template <typename LeafT>
    void planeRows(Block& b, const openvdb::Coord& go, int z0, const FlatStencil& st, const EulerRows& rows,
                   const LeafT* const* full, size_t nFull) const
    {
        const openvdb::Coord bo = b.origin(go);
        unsigned cols[kPlaneGroup] = {}; // per leaf row of the group: bit lx for each leaf
        for (size_t q = 0; q < nFull; ++q) {
            const openvdb::Coord lo = full[q]->origin();
            cols[(lo.y() - go.y()) / kDim] |= 1u << ((lo.x() - go.x()) / kDim);
            if (k.noise == 0) continue;
            const int ox = lo.x() - bo.x(), oy = lo.y() - bo.y();
            for (int y = 0; y < kDim; ++y)
                for (int x = 0; x < kDim; ++x)
                    b.chi[b.index(ox + x, oy + y, 0)] =
                        noiseDraw(k, seed, stepIndex, openvdb::Coord(lo.x() + x, lo.y() + y, z0));
        }
        forEachLeafRun(cols, [&](int ly, int x0, int x1) {
            for (int y = 0; y < kDim; ++y) {
                const size_t i0 = b.index(kHalo + x0 * kDim, kHalo + ly * kDim + y, 0);
                rows.euler(b.p.data(), b.T.data(), b.a.data(), b.cx.data(), b.cy.data(), b.gx.data(), b.gy.data(),
                           b.gz.data(), i0, i0 + size_t(x1 - x0) * kDim, st, k, melt ? b.melt.data() : nullptr,
                           k.noise != 0 ? b.chi.data() : nullptr, b.pe.data(), b.te.data(), b.dp.data());
            }
        });
    }

    /// Calls f(ly, x0, x1) for each run of horizontally adjacent leaves [x0, x1) in leaf row ly
    /// of a group (cols[ly]: bit lx for each leaf), left to right, rows in order.
    template <typename F>
    static void forEachLeafRun(const unsigned (&cols)[kPlaneGroup], const F& f)
    {
        for (int ly = 0; ly < kPlaneGroup; ++ly)
            for (unsigned bits = cols[ly]; bits;) {
                const int x0 = __builtin_ctz(bits);
                const unsigned run = bits + (1u << x0); // clears the run of ones at x0
                const int x1 = __builtin_ctz(run & ~bits);
                bits &= run;
                f(ly, x0, x1);
            }
    }

    /// Pass 2 on a plane block's heat-halo leaves (@a heat: p is 0 all around them): the heat
    /// rows into te over runs of horizontally adjacent such leaves.
    template <typename LeafT>
    static void heatRows(Block& b, const openvdb::Coord& go, const FlatStencil& st, const KobayashiParams& k,
                         const EulerRows& rows, const LeafT* const* heat, size_t nHeat)
    {
        unsigned cols[kPlaneGroup] = {}; // per leaf row of the group: bit lx for each leaf
        for (size_t q = 0; q < nHeat; ++q) {
            const openvdb::Coord lo = heat[q]->origin();
            cols[(lo.y() - go.y()) / kDim] |= 1u << ((lo.x() - go.x()) / kDim);
        }
        forEachLeafRun(cols, [&](int ly, int x0, int x1) {
            for (int y = 0; y < kDim; ++y) {
                const size_t i0 = b.index(kHalo + x0 * kDim, kHalo + ly * kDim + y, 0);
                rows.heat(b.T.data(), i0, i0 + size_t(x1 - x0) * kDim, st, k, b.te.data());
            }
        });
    }

    /// A plane leaf's active cells as 8 row masks (byte y, bit x) from its value mask (word x,
    /// bit (y << 3) | z): the transpose of the layer @a zb.
    template <typename LeafT>
    static uint64_t activeRows(const LeafT& leaf, int zb)
    {
        if constexpr (std::is_same_v<LeafT, plane::PlaneLeafView>) return leaf.rows; // held as rows
        uint64_t rows = 0;
        for (int x = 0; x < kDim; ++x)
            rows |= ((leaf.getValueMask().template getWord<uint64_t>(openvdb::Index(x)) >> zb) & 0x0101010101010101ull) << x;
        return rows;
    }

    /// Writes one plane leaf of a block into its staging and folded accumulators, a row of 8
    /// cells at a time: each row is contiguous in the block (pe, te, dp), in the staging (slots
    /// (y << 3) | x) and in the folded accumulator leaves (slots (y << 6) | (x & 63)), so its
    /// values are copied as runs and its accumulator mask
    /// bits set by one atomic OR per row (the folded leaf's mask word is shared with the leaves
    /// beside it). @a heatOnly: te holds the heat rows, p' is 0, dp 0. The same values, masks,
    /// bounds reports, queued writes and crossings (in planeLeaf's order) as planeLeaf.
    template <typename LeafT>
    void foldedLeafRows(Block& b, const openvdb::Coord& go, const LeafT& pl, bool heatOnly, const Out& o,
                        FloatLeaf* gl, FloatLeaf* fl, float tn1, std::vector<Accumulators::Pending>*& pending,
                        std::vector<openvdb::Coord>* cross) const
    {
        const openvdb::Coord bo = b.origin(go);
        const openvdb::Coord lo = pl.origin();
        const int ox = lo.x() - bo.x(), oy = lo.y() - bo.y(), sh = lo.x() & 63;
        const uint64_t active = activeRows(pl, 0);
        const bool growth = acc && acc->growth && !heatOnly, freeze = acc && acc->freeze && !heatOnly;
        float* gv = gl ? gl->buffer().data() : nullptr;
        float* fv = fl ? fl->buffer().data() : nullptr;
        uint64_t crossed = 0; // byte y, bit x, as active
        for (int y = 0; y < kDim; ++y) {
            const unsigned on = unsigned(active >> (8 * y)) & 0xffu;
            if (!on) continue;
            const size_t i = b.index(ox, oy + y, 0);
            const openvdb::Index s0 = openvdb::Index((y << 6) | sh);
            const float* pe = &b.pe[i];
            const float* te = &b.te[i];
            const double* dp = &b.dp[i];
            float* outP = &o.p[y << 3];
            float* outT = &o.t[y << 3];
            if (heatOnly) std::fill_n(outP, kDim, 0.f);
            else copyFloats<kDim>(pe, outP);
            copyFloats<kDim>(te, outT);
            unsigned bad = 0, grew = 0, iced = 0, flips = 0;
            for (int x = 0; x < kDim; ++x) {
                const float pn = heatOnly ? 0.f : pe[x];
                bad |= unsigned(!(pn >= -0.05f && pn <= 1.05f) || !std::isfinite(te[x])) << x;
                grew |= unsigned(dp[x] > 0) << x;
                iced |= unsigned(pn > 0.5f) << x;
                flips |= unsigned((b.p[i + size_t(x)] > 0.5f) != (pn > 0.5f)) << x;
            }
            if (failure && (bad & on)) reportRow(lo, y, bad & on, heatOnly ? nullptr : pe, te);
            if (cross && !heatOnly) crossed |= uint64_t(flips & on) << (8 * y);
            if (growth && (grew &= on)) {
                if (gv) {
                    for (unsigned bits = grew; bits; bits &= bits - 1) {
                        const int x = __builtin_ctz(bits);
                        gv[s0 + x] = gv[s0 + x] + float(dp[x]);
                    }
                    orRowBits(*gl, y, uint64_t(grew) << sh);
                } else {
                    for (unsigned bits = grew; bits; bits &= bits - 1) {
                        const int x = __builtin_ctz(bits);
                        acc->queue(pending).push_back({openvdb::Coord(lo.x() + x, lo.y() + y, lo.z()), float(dp[x]), true});
                    }
                }
            }
            if (freeze && (iced &= on)) {
                if (fv) {
                    const auto& word = fl->getValueMask().template getWord<uint64_t>(openvdb::Index(y));
                    iced &= ~unsigned(__atomic_load_n(&word, __ATOMIC_RELAXED) >> sh);
                    for (unsigned bits = iced; bits; bits &= bits - 1) fv[s0 + __builtin_ctz(bits)] = tn1;
                    if (iced) orRowBits(*fl, y, uint64_t(iced) << sh);
                } else {
                    for (unsigned bits = iced; bits; bits &= bits - 1)
                        acc->queue(pending).push_back({openvdb::Coord(lo.x() + __builtin_ctz(bits), lo.y() + y, lo.z()), tn1, false});
                }
            }
        }
        // planeLeaf's order: x outer, y inner (the walkers take the list as it comes)
        if (crossed)
            for (int x = 0; x < kDim; ++x)
                for (int y = 0; y < kDim; ++y)
                    if ((crossed >> (8 * y + x)) & 1) cross->push_back(openvdb::Coord(lo.x() + x, lo.y() + y, lo.z()));
    }
    /// Asks for the 8 rows of the plane leaf at @a lo in the folded accumulator leaf @a leaf
    /// while the group's rows are computed: the growth update's loads missed the cache and were
    /// a sixth of the writer's samples (perf annotate).
    static void prefetchChunk(const FloatLeaf& leaf, const openvdb::Coord& lo)
    {
        const float* v = leaf.buffer().data() + (lo.x() & 63);
        for (int y = 0; y < kDim; ++y) __builtin_prefetch(v + (y << 6), 1);
    }
    /// Sets @a bits in mask word @a y of a folded leaf atomically (plane::setOnAtomic, a row at
    /// once). The locked OR only when a bit is still off: a growing region's accumulator cells are
    /// on after their first step, and the lock cost a third of the writer (perf).
    static void orRowBits(FloatLeaf& leaf, int y, uint64_t bits)
    {
        auto& word = leaf.getValueMask().template getWord<uint64_t>(openvdb::Index(y));
        if ((__atomic_load_n(&word, __ATOMIC_RELAXED) & bits) != bits) __atomic_fetch_or(&word, bits, __ATOMIC_RELAXED);
    }
    /// The bounds failures of row @a y of the plane leaf at @a lo (cells @a bad); @a pe null: p' is 0.
    void reportRow(const openvdb::Coord& lo, int y, unsigned bad, const float* pe, const float* te) const
    {
        for (; bad; bad &= bad - 1) {
            const int x = __builtin_ctz(bad);
            const openvdb::Coord c(lo.x() + x, lo.y() + y, lo.z());
            const float pn = pe ? pe[x] : 0.f, tn = te[x];
            if (!std::isfinite(pn) || pn < -0.05f || pn > 1.05f) failure->report(c, "p (ice)", pn);
            if (!std::isfinite(tn)) failure->report(c, "T (temperature)", tn);
        }
    }

    /// Writes one leaf of a plane block from the scratch planeRows filled: its active voxels,
    /// with the bounds check and the accumulators.
    template <typename LeafT>
    void planeLeaf(Block& b, const openvdb::Coord& go, int z0, const LeafT& pl, const Out& o,
                   float tn1, std::vector<Accumulators::Pending>*& pending, std::vector<openvdb::Coord>* cross) const
    {
        const openvdb::Coord bo = b.origin(go);
        const openvdb::Coord lo = pl.origin();
        const int ox = lo.x() - bo.x(), oy = lo.y() - bo.y();
        const bool foldG = acc && acc->foldG, foldF = acc && acc->foldF;
        FloatLeaf* gl = acc ? Accumulators::leafFor(acc->growth, foldG, lo) : nullptr;
        FloatLeaf* fl = acc ? Accumulators::leafFor(acc->freeze, foldF, lo) : nullptr;
        // The accumulator leaves' buffers and masks directly: what setValueOn does, per voxel
        // (at the folded slot when folded).
        float* gv = gl ? gl->buffer().data() : nullptr;
        float* fv = fl ? fl->buffer().data() : nullptr;
        const bool growth = acc && acc->growth, freeze = acc && acc->freeze;
        const int zz = z0 - lo.z();
        const auto& mask = pl.getValueMask();
        for (int x = 0; x < kDim; ++x) {
            uint64_t bits = mask.template getWord<uint64_t>(openvdb::Index(x));
            while (bits) {
                const int bit = __builtin_ctzll(bits);
                bits &= bits - 1;
                const int y = bit >> 3;
                const size_t i = b.index(ox + x, oy + y, 0);
                const openvdb::Index n = openvdb::Index(x * 64 + bit);
                const float pn = b.pe[i], tn = b.te[i];
                if (cross && ((b.p[i] > 0.5f) != (pn > 0.5f))) cross->push_back(openvdb::Coord(lo.x() + x, lo.y() + y, lo.z() + zz));
                if (failure && (!std::isfinite(pn) || pn < -0.05f || pn > 1.05f || !std::isfinite(tn))) {
                    const openvdb::Coord c(lo.x() + x, lo.y() + y, lo.z() + zz);
                    if (!std::isfinite(pn) || pn < -0.05f || pn > 1.05f) failure->report(c, "p (ice)", pn);
                    if (!std::isfinite(tn)) failure->report(c, "T (temperature)", tn);
                }
                o.atP(n) = pn;
                o.atT(n) = tn;
                const double dp = b.dp[i];
                if (growth && dp > 0) {
                    if (gv) {
                        const openvdb::Index s = Accumulators::slot(foldG, lo, n);
                        gv[s] = gv[s] + float(dp);
                        Accumulators::markOn(*gl, foldG, s);
                    } else acc->queue(pending).push_back({openvdb::Coord(lo.x() + x, lo.y() + y, lo.z() + zz), float(dp), true});
                }
                if (freeze && pn > 0.5f) {
                    if (fv) {
                        const openvdb::Index s = Accumulators::slot(foldF, lo, n);
                        if (!Accumulators::isOn(*fl, foldF, s)) {
                            fv[s] = tn1;
                            Accumulators::markOn(*fl, foldF, s);
                        }
                    } else acc->queue(pending).push_back({openvdb::Coord(lo.x() + x, lo.y() + y, lo.z() + zz), tn1, false});
                }
            }
        }
    }

    /// p, T (and the melt map) over the rectangle of a group's present leaves and their halo:
    /// nothing else is read (most groups at a front hold a few of their 16 leaves).
    template <typename LeafT>
    void gatherGroup(Block& b, const openvdb::Coord& go, int z0, const LeafT* const* present, size_t count,
                     const ConstAcc& pAcc, const ConstAcc& tAcc, const ConstAcc* mAcc) const
    {
        const BlockRect rect = presentRect(b, go, present, count);
        if (foldedLeaf) {
            gatherFolded(pAcc, b, go, b.p, rect.x0, rect.x1, rect.y0, rect.y1);
            gatherFolded(tAcc, b, go, b.T, rect.x0, rect.x1, rect.y0, rect.y1);
        } else {
            gatherRect(pAcc, b, go, z0, rect, b.p);
            gatherRect(tAcc, b, go, z0, rect, b.T);
        }
        if (mAcc) gatherRect(*mAcc, b, go, z0, rect, b.melt);
    }

    /// The kernel over the region's leaves: p's own leaves, or with folded p and T the folded
    /// region's plane leaves (@a regionLeaves: the leaves and masks p has unfolded).
    void run(openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
             openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves, const LeafGroups& groups,
             const plane::PlaneLeaves* regionLeaves = nullptr) const
    {
        if (regionLeaves) runOn(*regionLeaves, pLeaves, tLeaves, groups);
        else runOn(pLeaves, pLeaves, tLeaves, groups);
    }

    template <typename PlaneLeavesT>
    void runOn(const PlaneLeavesT& planeLeaves, openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
               openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves, const LeafGroups& groups) const
    {
        using LeafT = std::decay_t<decltype(planeLeaves.leaf(0))>;
        const bool plane = domain.flat();
        const int z0 = domain.bbox().min().z();
        const Block proto(plane);
        FlatStencil st(domain.stencil(), proto.bx, std::ptrdiff_t(proto.bx) * proto.by);
        const Anisotropy an(k);
        useD6Forms(st, an);
        const EulerRows rows = fastestEulerRows(st, an);
        const float tn1 = float(tNext);
        // Folded p and T (and folded accumulators, or none): leaves are written row by row
        // (foldedLeafRows); otherwise voxel by voxel.
        const bool byRows = plane && foldedLeaf && staged &&
                            (!acc || ((!acc->growth || acc->foldG) && (!acc->freeze || acc->foldF)));
        using MutableAcc = openvdb::tree::ValueAccessor<openvdb::FloatTree, /*IsSafe=*/false>;
        tbb::enumerable_thread_specific<Block> blocks([plane] { return Block(plane); });
        tbb::enumerable_thread_specific<std::vector<openvdb::Coord>> crossed;
        tbb::parallel_for(tbb::blocked_range<size_t>(0, groups.count(), 1), [&](const tbb::blocked_range<size_t>& r) {
            Block& b = blocks.local();
            std::vector<openvdb::Coord>* cross = crossings ? &crossed.local() : nullptr;
            // Unregistered accessors: the trees do not change while the kernel runs.
            const ConstAcc pAcc(p.tree()), tAcc(T.tree());
            std::unique_ptr<ConstAcc> mAcc;
            if (melt) mAcc = std::make_unique<ConstAcc>(melt->tree());
            std::vector<Accumulators::Pending>* pending = nullptr;
            std::unique_ptr<MutableAcc> gAcc, fAcc; // the folded accumulators (byRows)
            if (byRows && acc && acc->growth) gAcc = std::make_unique<MutableAcc>(*acc->growth);
            if (byRows && acc && acc->freeze) fAcc = std::make_unique<MutableAcc>(*acc->freeze);
            const LeafT* present[kPlaneGroup * kPlaneGroup];
            for (size_t g = r.begin(); g != r.end(); ++g) {
                const openvdb::Coord go = groups.origin[g];
                const size_t first = groups.start[g], count = groups.start[g + 1] - first;
                for (size_t q = 0; q < count; ++q) present[q] = &planeLeaves.leaf(groups.leaves[first + q]);
                gatherGroup(b, go, z0, present, count, pAcc, tAcc, mAcc.get());
                // Leaves in the heat halo, where p is 0 all around, take the heat step alone;
                // pass 1 covers only the others.
                bool heatOnly[kPlaneGroup * kPlaneGroup];
                const LeafT* full[kPlaneGroup * kPlaneGroup];
                const LeafT* heat[kPlaneGroup * kPlaneGroup];
                size_t nFull = 0, nHeat = 0;
                for (size_t q = 0; q < count; ++q) {
                    heatOnly[q] = phaseZeroAround(b, go, *present[q]);
                    if (!heatOnly[q]) full[nFull++] = present[q];
                    else heat[nHeat++] = present[q];
                }
                markNeeded(b, go, full, nFull);
                if (byRows) { // folded fields: rows in, rows out
                    FloatLeaf* gl[kPlaneGroup * kPlaneGroup];
                    FloatLeaf* fl[kPlaneGroup * kPlaneGroup];
                    for (size_t q = 0; q < count; ++q) {
                        const openvdb::Coord fo = plane::foldedLeafOrigin(present[q]->origin());
                        gl[q] = gAcc ? gAcc->probeLeaf(fo) : nullptr;
                        fl[q] = fAcc ? fAcc->probeLeaf(fo) : nullptr;
                        if (gl[q] && !heatOnly[q]) prefetchChunk(*gl[q], present[q]->origin());
                    }
                    if (nFull) {
                        auxRuns(b, st, an, rows);
                        planeRows(b, go, z0, st, rows, full, nFull);
                    }
                    heatRows(b, go, st, k, rows, heat, nHeat);
                    for (size_t q = 0; q < count; ++q) {
                        const size_t li = groups.leaves[first + q];
                        const LeafT& pl = *present[q];
                        foldedLeafRows(b, go, pl, heatOnly[q], out(li, pl.origin(), pLeaves, tLeaves), gl[q], fl[q],
                                       tn1, pending, cross);
                    }
                    continue;
                }
                if (nFull) {
                    if (plane) {
                        auxRuns(b, st, an, rows);
                        planeRows(b, go, z0, st, rows, full, nFull);
                    } else auxPass(b, b.p, st, an);
                }
                for (size_t q = 0; q < count; ++q) {
                    const size_t li = groups.leaves[first + q];
                    const LeafT& pl = planeLeaves.leaf(li);
                    const Out o = out(li, pl.origin(), pLeaves, tLeaves);
                    if (!heatOnly[q] && plane) {
                        planeLeaf(b, go, z0, pl, o, tn1, pending, cross);
                        continue;
                    }
                    if (heatOnly[q]) {
                        forActiveVoxels(b, go, z0, *present[q], [&](openvdb::Index n, size_t i, const openvdb::Coord& c) {
                            float pn, tn;
                            kobayashiEulerHeatOnly(b.T.data(), i, st, k, pn, tn);
                            if (failure && !std::isfinite(tn)) failure->report(c, "T (temperature)", tn);
                            o.atP(n) = pn;
                            o.atT(n) = tn;
                        });
                        continue;
                    }
                    // folded accumulators take the queue here (record() writes plane offsets)
                    FloatLeaf* gl = acc && acc->growth && !acc->foldG ? acc->growth->probeLeaf(pl.origin()) : nullptr;
                    FloatLeaf* fl = acc && acc->freeze && !acc->foldF ? acc->freeze->probeLeaf(pl.origin()) : nullptr;
                    forActiveVoxels(b, go, z0, pl, [&](openvdb::Index n, size_t i, const openvdb::Coord& c) {
                        const double chi = noiseDraw(k, seed, stepIndex, c);
                        float pn, tn;
                        const double dp = kobayashiEuler(b.p.data(), b.T.data(), b.a.data(), b.cx.data(), b.cy.data(),
                                                         b.gx.data(), b.gy.data(), b.gz.data(), i, st, k,
                                                         meltTemperatureAt(k, b, i, melt != nullptr), chi, pn, tn);
                        if (failure) {
                            if (!std::isfinite(pn) || pn < -0.05f || pn > 1.05f) failure->report(c, "p (ice)", pn);
                            if (!std::isfinite(tn)) failure->report(c, "T (temperature)", tn);
                        }
                        if (cross && ((b.p[i] > 0.5f) != (pn > 0.5f))) cross->push_back(c);
                        o.atP(n) = pn;
                        o.atT(n) = tn;
                        if (acc) acc->record(gl, fl, n, c, dp, pn, tn1, pending);
                    });
                }
            }
        });
        if (acc) acc->apply();
        if (crossings)
            for (auto& list : crossed) crossings->insert(crossings->end(), list.begin(), list.end());
    }
};

} // namespace

/// Folded p and T (core/PlaneFold.h) on the current region (a folded mask, what p and T are
/// matched to): its plane leaves, which the kernels walk, and per plane leaf, in that order, the
/// index of its folded leaf among p's leaves (the region's folded leaf order, once p is matched
/// to it). Made once per region generation, from the folded region alone.
struct PhaseFieldSolver::FoldedLayout {
    plane::PlaneLeaves leaves;
    std::vector<uint32_t> leafOf;
    std::vector<uint32_t> chunkLeaf; ///< per folded leaf and chunk g (x >> 3 & 7): its plane leaf, or ~0
    uint64_t generation = 0;
    size_t foldedLeaves = 0;

    FoldedLayout(const openvdb::MaskGrid& region, uint64_t gen, plane::PlaneLeaves::Order order)
        : leaves(region, order), generation(gen)
    {
        number(region);
    }
    /// leafOf, chunkLeaf and foldedLeaves for the folded region.
    void number(const openvdb::MaskGrid& region)
    {
        openvdb::tree::LeafManager<const openvdb::MaskTree> folded(region.tree());
        foldedLeaves = folded.leafCount();
        // A folded leaf holds plane rows y .. y+7, columns x .. x+63: the key (y >> 3, x >> 6)
        // in a dense table over the folded leaves' box numbers them, read by every plane leaf.
        openvdb::CoordBBox box;
        for (size_t i = 0; i < foldedLeaves; ++i) box.expand(tableKey(folded.leaf(i).origin()));
        const openvdb::Coord dim = box.empty() ? openvdb::Coord(0) : box.dim();
        constexpr uint32_t kNone = ~uint32_t(0);
        std::vector<uint32_t> indexAt(size_t(dim.x()) * size_t(dim.y()), kNone);
        auto slot = [&](const openvdb::Coord& key) {
            return size_t(key.y() - box.min().y()) * size_t(dim.x()) + size_t(key.x() - box.min().x());
        };
        for (size_t i = 0; i < foldedLeaves; ++i) indexAt[slot(tableKey(folded.leaf(i).origin()))] = uint32_t(i);
        leafOf.assign(leaves.leafCount(), kNone);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, leafOf.size(), 1024), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t i = r.begin(); i != r.end(); ++i) {
                const openvdb::Coord key = tableKey(plane::foldedLeafOrigin(leaves.leaf(i).origin()));
                if (box.isInside(key)) leafOf[i] = indexAt[slot(key)];
            }
        });
        if (std::find(leafOf.begin(), leafOf.end(), kNone) != leafOf.end())
            throw std::logic_error("FoldedLayout: a region leaf has no folded leaf");
        chunkLeaf.assign(foldedLeaves * 8, kNone);
        for (size_t i = 0; i < leafOf.size(); ++i)
            chunkLeaf[size_t(leafOf[i]) * 8 + size_t((leaves.leaf(i).origin().x() >> 3) & 7)] = uint32_t(i);
    }
    /// A folded leaf origin as its 8 x 64 tile of the plane, in tile units (z 0).
    static openvdb::Coord tableKey(const openvdb::Coord& foldedOrigin)
    {
        return openvdb::Coord(foldedOrigin.x() >> 3, plane::planeX(foldedOrigin.y(), foldedOrigin.z()) >> 6, 0);
    }
    uint64_t bytes() const { return leaves.bytes() + (leafOf.capacity() + chunkLeaf.capacity()) * sizeof(uint32_t); }
};

uint64_t PhaseFieldSolver::regionBytes() const { return mRegionMask ? mRegionMask->memUsage() : 0; }
uint64_t PhaseFieldSolver::regionViewBytes() const { return mFolded ? mFolded->bytes() : 0; }

const PhaseFieldSolver::FoldedLayout& PhaseFieldSolver::foldedLayout()
{
    if (!mFolded || mFolded->generation != mGeneration) {
        mFolded.reset(); // the last one's memory first
        // the second-order scheme numbers its rows in the plane-layout tree's leaf order
        const auto order = mParams.scheme == PhaseFieldScheme::SecondOrder ? plane::PlaneLeaves::Order::Plane
                                                                           : plane::PlaneLeaves::Order::Folded;
        mFolded = std::make_unique<FoldedLayout>(*mRegionMask, mGeneration, order);
    }
    return *mFolded;
}

void PhaseFieldSolver::layRegionOut(bool folded)
{
    if (!mRegionMask || plane::isFolded(*mRegionMask) == folded) return;
    mRegionMask = folded ? plane::foldTopology(*mRegionMask) : plane::unfoldTopology(*mRegionMask);
    ++mGeneration; // the same cells in another tree: cached groups and layouts are stale
}

void PhaseFieldSolver::rebuildRegionOf(openvdb::FloatGrid& p, openvdb::FloatGrid& T, bool ours,
                                       uint64_t& inputGeneration, PhaseFieldStepStats* stats)
{
    const auto t0 = Clock::now();
    if (!mRegion.dense && !mInputsTruncated) {
        // Values within the tolerance since the last truncation (an out-of-turn rebuild).
        truncateToTolerance(p, mRegion.tolerance);
        truncateToTolerance(T, mRegion.tolerance);
        inputGeneration = 0;
    }
    const int k = mCadence.begin(mRegionMask && !ours);
    // Folded fields: the standing (folded) region is edited into the new one when nobody else
    // holds it (a checkpoint may).
    RegionEdit edit;
    const bool editable = plane::isFolded(p) && mRegionMask && mRegionMask.use_count() == 1;
    auto region = rebuildRegion(p, T, k, editable ? &edit : nullptr);
    const bool edited = !edit.empty();
    // the standing region's count when it is returned as it was (a walk over every leaf)
    const uint64_t voxels = region == mRegionMask && !edited ? mRegionVoxels : region->tree().activeVoxelCount();
    if (voxels == mDomain.voxelCount()) mCadence.filledDomain(); // regionFillsDomain, from the count at hand
    if (edited) {
        ++mGeneration; // a new topology: cached groups and layouts are stale
        mRegionVoxels = voxels;
    } else if (!mRegionMask || (region != mRegionMask && !region->tree().hasSameTopology(mRegionMask->tree()))) {
        ++mGeneration; // a new topology: cached groups and layouts are stale
        mRegionMask = region;
        mRegionVoxels = voxels;
    }
    if (stats) {
        stats->rebuilds += 1;
        stats->regionBuildSeconds += since(t0);
    }
}

openvdb::MaskGrid::Ptr PhaseFieldSolver::rebuildRegion(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T, int steps,
                                                       RegionEdit* edit) const
{
    if (!plane::isFolded(p))
        return buildActiveRegion({&p, &T}, mRegion, kHalo, mDomain, steps, mRegionMask);
    // folded p and T: the same region, folded, read from their folded leaves chunk by chunk
    return buildActiveRegionOfFolded({&p, &T}, mRegion, kHalo, mDomain, steps, mRegionMask, edit);
}

PhaseFieldSolver::PhaseFieldSolver(const KobayashiParams& params, const Domain& domain, const RegionSettings& region)
    : mParams(params), mDomain(domain), mRegion(region), mCadence(region, kHalo)
{
}

PhaseFieldSolver::~PhaseFieldSolver() = default;

bool PhaseFieldSolver::inputsAreOurs(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T) const
{
    if (&p != mOutP || &T != mOutT) return false;
    if (mSoleWriter) return true; // nobody else writes them: no need to look at the values
    // every other write is listed: ours up to the listed cells (grown around in stepOnce)
    if (editsReported()) return true;
    return gridFingerprint(p) == mPrintP && gridFingerprint(T) == mPrintT; // T only when p matched
}

void PhaseFieldSolver::restoreCadence(const CadenceState& state, const openvdb::FloatGrid& p,
                                      const openvdb::FloatGrid& T)
{
    mRegionMask = state.region;
    mRegionVoxels = mRegionMask ? mRegionMask->tree().activeVoxelCount() : 0;
    ++mGeneration; // the restored topology is new to every cache
    mCadence.setStepsLeft(state.stepsLeft);
    mInputsTruncated = state.inputsTruncated;
    mOutP = state.inputsOurs ? &p : nullptr;
    mOutT = state.inputsOurs ? &T : nullptr;
    mPrintP = gridFingerprint(p);
    mPrintT = gridFingerprint(T);
    mOutGeneration = 0; // their topology is not known to match the region
    mSpareP.reset();
    mSpareT.reset();
    mSpareGeneration = 0;
    mSpareOurs = false;
}

void PhaseFieldSolver::adoptRelaidFields(const openvdb::FloatGrid& oldP, const openvdb::FloatGrid& oldT,
                                         const openvdb::FloatGrid& p, const openvdb::FloatGrid& T)
{
    if (!mRegionMask || !inputsAreOurs(oldP, oldT)) return;
    mOutP = &p;
    mOutT = &T;
    mPrintP = gridFingerprint(p);
    mPrintT = gridFingerprint(T);
    mOutGeneration = 0; // matched to the region again in the new layout
}

bool PhaseFieldSolver::growRegionAroundEdits()
{
    if (mEditsP->empty() && mEditsT->empty()) return false;
    std::vector<openvdb::Coord> cells;
    cells.reserve(mEditsP->size() + mEditsT->size());
    cells.insert(cells.end(), mEditsP->begin(), mEditsP->end());
    cells.insert(cells.end(), mEditsT->begin(), mEditsT->end());
    // The standing region serves stepsLeft more steps: what the new values can reach in them.
    const int radius = std::max(1, mCadence.stepsLeft()) * (kHalo + mRegion.frontTravel);
    if (mRegionMask.use_count() > 1) mRegionMask = mRegionMask->deepCopy(); // a checkpoint may hold it
    if (!growActiveRegion(*mRegionMask, cells, radius, mDomain)) return false;
    ++mGeneration; // a new topology: cached groups and layouts are stale
    mRegionVoxels = mRegionMask->tree().activeVoxelCount();
    return true;
}

openvdb::FloatGrid::Ptr PhaseFieldSolver::outputGrid(openvdb::FloatGrid::Ptr& spare, uint64_t spareGeneration,
                                                     openvdb::FloatGrid& like)
{
    openvdb::FloatGrid::Ptr g;
    const bool folded = plane::isFolded(like); // the output takes the input's layout (core/PlaneFold.h)
    // Reused only when nobody else holds the grid or its tree (a frame, a shallow copy).
    if (spare && spare.use_count() == 1 && spare->treePtr().use_count() == 2 &&
        spare->background() == like.background() && plane::isFolded(*spare) == folded)
        g = spare;
    spare.reset();
    const openvdb::MaskGrid& topology = *mRegionMask; // in the fields' layout (layRegionOut)
    if (!g) {
        g = openvdb::FloatGrid::create(like.background());
        g->tree().topologyUnion(topology.tree());
        if (folded) plane::markFolded(*g);
    } else if (spareGeneration != mGeneration) {
        matchTopology(*g, topology, mSpareOurs);
    }
    g->setTransform(like.transformPtr());
    g->setGridClass(like.getGridClass());
    return g;
}

void PhaseFieldSolver::step(openvdb::FloatGrid::Ptr& p, openvdb::FloatGrid::Ptr& T, openvdb::FloatGrid* growth,
                            openvdb::FloatGrid* freezeTime, int64_t stepIndex, double time, uint64_t seed,
                            PhaseFieldStepStats* stats)
{
    if (mParams.scheme == PhaseFieldScheme::SecondOrder && !mLastInP) {
        // Rannacher start-up: the sharp seed (p jumps from 0 to 1 within a cell) excites modes
        // that Crank-Nicolson does not damp (its amplification tends to -1 for stiff modes),
        // which costs the observed order. The first step is two implicit-Euler half-steps,
        // which damp them; their O(dt^2) error does not accumulate over the run.
        const double dt = mParams.dt;
        mParams.dt = 0.5 * dt;
        mTheta = 1.0;
        stepOnce(p, T, growth, freezeTime, stepIndex, time, seed, stats);
        stepOnce(p, T, growth, freezeTime, stepIndex, time + 0.5 * dt, seed, stats);
        mParams.dt = dt;
        mTheta = 0.5;
        return;
    }
    stepOnce(p, T, growth, freezeTime, stepIndex, time, seed, stats);
}

namespace {

// stepOnce's stages that need no solver state.

/// Forward Euler writes p and T in place: the trees are made this solver's own (a frame may
/// share them) and given the region's topology when they do not have it yet.
void prepareInPlace(openvdb::FloatGrid& p, openvdb::FloatGrid& T, const openvdb::MaskGrid& region, bool match, bool ours,
                    PhaseFieldStepStats* stats)
{
    const auto t0 = Clock::now();
    ownTree(p);
    ownTree(T);
    if (match) {
        matchTopology(p, region, ours);
        matchTopology(T, region, ours);
    }
    if (stats) stats->regionMatchSeconds += since(t0);
}

/// The accumulators written in place by the step (a frame may share their trees).
void bindAccumulators(Accumulators& acc, openvdb::FloatGrid* growth, openvdb::FloatGrid* freezeTime)
{
    if (growth) ownTree(*growth);
    if (freezeTime) ownTree(*freezeTime);
    acc.growth = growth ? &growth->tree() : nullptr;
    acc.freeze = freezeTime ? &freezeTime->tree() : nullptr;
    acc.foldG = growth && plane::isFolded(*growth);
    acc.foldF = freezeTime && plane::isFolded(*freezeTime);
}

[[noreturn]] void throwBoundsFailure(const Failure& failure, const KobayashiParams& k, const Domain& domain,
                                     int64_t stepIndex, double tNext)
{
    std::ostringstream os;
    os << "phase field left its bounds: " << failure.field << " = " << failure.value << " at voxel "
       << failure.where << " in step " << stepIndex + 1 << " (t = " << tNext << "); dt = " << k.dt
       << ", stability limit " << k.stabilityLimit(domain.stencil(), !domain.flat())
       << ". Lower phase_field.dt or the anisotropy/latent heat; nothing of this step was written.";
    throw SimulationError(os.str());
}

/// The commit of a retiring step truncates (FusedTruncation), unless
/// FROSTVDB_NO_FUSED_TRUNCATION=1 asks for the separate pass (tests compare the two).
void armFusedTruncation(std::optional<FusedTruncation>& fused, double tolerance, const openvdb::FloatGrid& pNew,
                        const openvdb::FloatGrid& tNew)
{
    const char* separate = std::getenv("FROSTVDB_NO_FUSED_TRUNCATION");
    if (separate && *separate && std::string(separate) != "0") return;
    fused.emplace();
    fused->tol = float(tolerance);
    fused->bgP = pNew.background();
    fused->bgT = tNew.background();
}

/// The truncation of a retiring step: what the fused commit found, or the separate pass.
bool truncateRetired(const FusedTruncation* fused, openvdb::FloatGrid& pNew, openvdb::FloatGrid& tNew, double tolerance)
{
    bool truncated = false;
    if (fused) {
        if (fused->emptiedP) openvdb::tools::pruneInactive(pNew.tree());
        if (fused->emptiedT) openvdb::tools::pruneInactive(tNew.tree());
        truncated = fused->changedP || fused->changedT;
    } else {
        truncated = truncateToTolerance(pNew, tolerance);
        truncated = truncateToTolerance(tNew, tolerance) || truncated;
    }
    return truncated;
}

} // namespace

void PhaseFieldSolver::stepOnce(openvdb::FloatGrid::Ptr& p, openvdb::FloatGrid::Ptr& T, openvdb::FloatGrid* growth,
                                openvdb::FloatGrid* freezeTime, int64_t stepIndex, double time, uint64_t seed,
                                PhaseFieldStepStats* stats)
{
    auto t0 = Clock::now();
    const bool folded = plane::isFolded(*p); // then the region is folded and its plane leaves drive the kernel
    if (folded != plane::isFolded(*T)) throw std::logic_error("PhaseFieldSolver: p and T differ in layout");
    layRegionOut(folded);
    // The region is kept for k steps while the fields are what this solver last returned; any
    // other writer (walkers sticking, heat advection) forces a rebuild, as every step did before.
    const bool ours = mRegionMask && inputsAreOurs(*p, *T);
    // Dense mode: the region is the whole domain whoever writes the fields.
    const bool rebuild = !mRegionMask || (!ours && !mRegion.dense) || mCadence.due();
    uint64_t inputGeneration = ours ? mOutGeneration : 0;
    if (!rebuild && ours && editsReported() && !mRegion.dense && growRegionAroundEdits()) {
        inputGeneration = 0; // the inputs lack the new leaves
        if (stats) stats->regionGrowths += 1;
    }
    if (editsReported()) { // read (a rebuild reads the fields themselves): start the next lists
        mEditsP->clear();
        mEditsT->clear();
    }
    if (rebuild) rebuildRegionOf(*p, *T, ours, inputGeneration, stats);
    // Forward Euler updates p and T in place (its new values staged until the kernel is done),
    // so the fields exist once; the second-order scheme writes new grids (it keeps the start
    // values as history anyway).
    const bool inPlace = mParams.scheme == PhaseFieldScheme::Euler;
    openvdb::FloatGrid::Ptr pNew, tNew;
    if (inPlace) {
        prepareInPlace(*p, *T, *mRegionMask, inputGeneration != mGeneration, ours, stats);
        pNew = p;
        tNew = T;
        mSpareP.reset();
        mSpareT.reset();
    } else {
        pNew = outputGrid(mSpareP, mSpareGeneration, *p);
        tNew = outputGrid(mSpareT, mSpareGeneration, *T);
    }
    const auto tLayout = Clock::now();

    openvdb::tree::LeafManager<openvdb::FloatTree> pLeaves(pNew->tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> tLeaves(tNew->tree());
    const plane::PlaneLeaves* regionLeaves = folded ? &foldedLayout().leaves : nullptr;
    if (!mGroups || mGroupsGeneration != mGeneration) {
        mGroups = folded ? std::make_unique<LeafGroups>(*regionLeaves, true)
                         : std::make_unique<LeafGroups>(pLeaves, mDomain.flat());
        mGroupsGeneration = mGeneration;
    }
    Accumulators acc;
    bindAccumulators(acc, growth, freezeTime);
    if (stats) {
        stats->regionVoxels = mRegionVoxels;
        stats->voxelUpdates += mRegionVoxels;
        stats->regionSeconds += since(t0);
        stats->regionLayoutSeconds += since(tLayout);
    }

    t0 = Clock::now();
    const KobayashiParams& k = mParams;
    const double tNext = time + k.dt;
    Failure failure;
    std::optional<StagedValues> staged;
    if (k.scheme == PhaseFieldScheme::Euler) {
        // folded: 64 slots per region plane leaf, committed into p's folded leaves by chunk
        staged.emplace(mStageP, mStageT, folded ? regionLeaves->leafCount() : pLeaves.leafCount(), mDomain.flat());
        if (folded) staged->chunkLeaf = &mFolded->chunkLeaf;
        if (stats)
            stats->stagingPeakBytes = std::max<uint64_t>(stats->stagingPeakBytes,
                                                         (mStageP.capacity() + mStageT.capacity()) * sizeof(float));
        LeafKernel kernel{k, mDomain, *p, *T, mMelt, stepIndex, tNext, seed, &acc, &failure, &*staged};
        kernel.crossings = mCrossings;
        if (folded) {
            if (pLeaves.leafCount() != mFolded->foldedLeaves || tLeaves.leafCount() != mFolded->foldedLeaves)
                throw std::logic_error("PhaseFieldSolver: folded p or T does not have the region's topology");
            kernel.foldedLeaf = &mFolded->leafOf;
        }
        kernel.run(pLeaves, tLeaves, *mGroups, regionLeaves);
    } else {
        stepSecondOrder(*p, *T, pLeaves, tLeaves, acc, stepIndex, tNext, seed, failure, stats, regionLeaves);
    }
    if (stats) stats->kernelSeconds += since(t0);
    if (failure.any) {
        mRegionMask.reset(); // the caller's grids are untouched; start afresh if called again
        throwBoundsFailure(failure, k, mDomain, stepIndex, tNext);
    }
    // The region retires after this step when it has one step left: the commit truncates then
    // (p and T are in place and share the region's topology).
    std::optional<FusedTruncation> fused;
    if (staged && mCadence.stepsLeft() <= 1 && !mRegion.dense && tLeaves.leafCount() == pLeaves.leafCount())
        armFusedTruncation(fused, mRegion.tolerance, *pNew, *tNew);
    if (staged) {
        t0 = Clock::now();
        commitStaged(pLeaves, tLeaves, *staged, fused ? &*fused : nullptr);
        if (stats) stats->kernelSeconds += since(t0);
    }

    t0 = Clock::now();
    // Truncate when the region is retired: the next step rebuilds from what is left.
    const bool retire = mCadence.stepTaken();
    bool truncated = false;
    if (retire && !mRegion.dense) truncated = truncateRetired(fused ? &*fused : nullptr, *pNew, *tNew, mRegion.tolerance);
    mInputsTruncated = retire || mRegion.dense;
    mOutP = pNew.get();
    mOutT = tNew.get();
    if (!mSoleWriter && !editsReported()) {
        mPrintP = gridFingerprint(*pNew);
        mPrintT = gridFingerprint(*tNew);
    }
    mOutGeneration = truncated ? 0 : mGeneration;
    if (!inPlace) {
        // The inputs become the next step's output buffers (same topology while the region stands).
        mSpareP = p;
        mSpareT = T;
        mSpareGeneration = inputGeneration;
        mSpareOurs = ours;
    }
    if (stats) stats->truncateSeconds += since(t0);
    p = pNew;
    T = tNew;
}

namespace {

/// What the second-order rows of a step read: the fields at the step's start, the last step's
/// start values (the midpoint extrapolation), the region's leaf groups and rows.
struct SecondOrderInputs {
    const KobayashiParams& k;
    const Stencil& stencil;
    bool plane;
    int z0;
    double theta;
    float extrapolate;
    const openvdb::FloatGrid &p, &T;
    const openvdb::FloatGrid *melt, *dP, *dT; ///< null: no melt map, no last step
    bool folded; ///< p, T and the last step's start values are folded (core/PlaneFold.h)
    const LeafGroups& groups;
    const SlotLayout& layout;
    int64_t stepIndex;
    uint64_t seed;
};

/// The vector rows' outputs over @a store: 10 arrays of @a cells doubles.
SecondOrderRowsOut rowViews(double* store, size_t cells)
{
    SecondOrderRowsOut out{};
    out.diag = store;
    out.rhs = store + cells;
    out.predictor = store + 2 * cells;
    out.lapT = store + 3 * cells;
    for (int t = 0; t < 6; ++t) out.coef[t] = store + size_t(4 + t) * cells;
    return out;
}

/// eps^2 of the extrapolated phase over the runs of needed cells of each block row (a union of
/// leaf spans and their ring), by the vector rows.
void epsSquaredRuns(Block& b, const SecondOrderRows& soRows, const FlatStencil& st, const Anisotropy& an)
{
    for (int y = 1; y < b.by - 1; ++y) {
        uint64_t bits = b.need[size_t(y)];
        const size_t row = b.index(0, y, 0);
        while (bits) {
            const int x0 = __builtin_ctzll(bits);
            const uint64_t rest = ~(bits >> x0);
            const int len = rest ? __builtin_ctzll(rest) : 64 - x0;
            soRows.epsSquared(b.pe.data(), row + size_t(x0), row + size_t(x0 + len), st, an, b.a.data());
            bits &= len + x0 >= 64 ? 0 : ~((uint64_t(1) << (x0 + len)) - 1);
        }
    }
}

/// The second-order rows of one plane group by the vector rows (SecondOrderRows.h): each present
/// leaf's block rows that hold an active voxel, over the span of x its active voxels cover, into
/// the per-thread row arrays @a rowOut; then the voxels' rows are copied into the systems as the
/// plain path does.
template <typename LeafT>
void vectorRowsOfGroup(const SecondOrderInputs& in, Block& b, const SecondOrderRows& soRows, const FlatStencil& st,
                       const SecondOrderRowsOut& rowOut, const openvdb::Coord& origin, const LeafT* const* present,
                       const size_t* leafIndex, size_t count, ImplicitSystem& ps, ImplicitSystem& ts,
                       std::vector<double>& p0, std::vector<double>& T0)
{
    const KobayashiParams& k = in.k;
    const SlotLayout& layout = in.layout;
    const int z0 = in.z0, taps = ps.taps();
    const double theta = in.theta;
    const int64_t stepIndex = in.stepIndex;
    const uint64_t seed = in.seed;
    const bool melt = in.melt != nullptr;
    // Vector rows: each present leaf's block rows that hold an active voxel, over the
    // span of x its active voxels cover, into the block's row arrays; then the
    // voxels' rows are copied out as the plain path does.
    const openvdb::Coord bo = b.origin(origin);
    for (size_t q = 0; q < count; ++q) {
        const LeafT& leaf = *present[q];
        const openvdb::Coord lo = leaf.origin() - bo;
        const auto& mask = leaf.getValueMask();
        uint8_t rowBits[kDim] = {};
        const int zb = z0 & (kDim - 1);
        for (int x = 0; x < kDim; ++x) {
            const uint64_t word = mask.template getWord<uint64_t>(openvdb::Index(x));
            for (int y = 0; y < kDim; ++y)
                if ((word >> (y * kDim + zb)) & 1) rowBits[y] |= uint8_t(1u << x);
        }
        for (int y = 0; y < kDim; ++y) {
            if (!rowBits[y]) continue;
            const int xa = __builtin_ctz(rowBits[y]), xb = 32 - __builtin_clz(uint32_t(rowBits[y]));
            const size_t row = b.index(lo.x(), lo.y() + y, 0);
            const size_t i0 = row + size_t(xa), i1 = row + size_t(xb);
            const double* chi = nullptr;
            if (k.noise != 0) {
                for (int x = xa; x < xb; ++x)
                    b.chi[row + size_t(x)] =
                        noiseDraw(k, seed, stepIndex, openvdb::Coord(bo.x() + lo.x() + x, bo.y() + lo.y() + y, z0));
                chi = b.chi.data();
            }
            soRows.rows(b.p.data(), b.T.data(), b.pe.data(), b.te.data(), b.gz.data(), b.a.data(),
                        melt ? b.melt.data() : nullptr, chi, i0, i1, st, k, theta, rowOut);
        }
        const size_t li = leafIndex[q];
        forActiveVoxels(b, origin, z0, leaf, [&](openvdb::Index n, size_t i, const openvdb::Coord&) {
            const size_t s = size_t(layout.rowAt(li, n));
            ps.diag[s] = rowOut.diag[i];
            double* coefOut = &ps.coef[s * size_t(taps)];
            for (int t = 0; t < 6; ++t) coefOut[t] = rowOut.coef[t][i];
            ps.rhs[s] = rowOut.rhs[i];
            ps.x[s] = rowOut.predictor[i];
            p0[s] = b.p[i];
            T0[s] = b.T[i];
            ts.rhs[s] = b.T[i] + (1.0 - theta) * k.dt * rowOut.lapT[i];
        });
    }
}

/// Second-order stage 1, the explicit parts: per leaf group on the padded block, p and T with
/// their extrapolation to theta of the step, then each active voxel's row of the p system, the
/// explicit half of the T rows and the start values p0, T0.
/// @a planeLeaves: p's leaves, or with folded fields the region's plane leaves (same order and masks).
template <typename PlaneLeavesT>
void assembleSecondOrderRows(const SecondOrderInputs& in, const PlaneLeavesT& planeLeaves,
                             ImplicitSystem& ps, ImplicitSystem& ts, std::vector<double>& p0, std::vector<double>& T0)
{
    const KobayashiParams& k = in.k;
    const bool plane = in.plane;
    const Stencil& stencil = in.stencil;
    const SlotLayout& layout = in.layout;
    const openvdb::FloatGrid &p = in.p, &T = in.T;
    const openvdb::FloatGrid *melt = in.melt, *dP = in.dP, *dT = in.dT;
    const int z0 = in.z0;
    const double theta = in.theta;
    const float extrapolate = in.extrapolate;
    const int64_t stepIndex = in.stepIndex;
    const uint64_t seed = in.seed;
    const int taps = ps.taps();

    const Block proto(plane);
    const FlatStencil st(stencil, proto.bx, std::ptrdiff_t(proto.bx) * proto.by);
    const Anisotropy an(k);
    tbb::enumerable_thread_specific<Block> blocks([plane] { return Block(plane); });
    const LeafGroups& groups = in.groups;
    // The hexagonal plane's vector rows (SecondOrderRows.h) where they apply; their outputs go to
    // per-thread row arrays over the block's cells.
    FlatStencil stD6 = st;
    useD6Forms(stD6, an);
    const SecondOrderRows soRows =
        plane && taps == 6 && stD6.d6 ? fastestSecondOrderRows(st, an) : plainSecondOrderRows();
    const size_t blockCells = size_t(proto.bx) * size_t(proto.by) * size_t(proto.bz);
    tbb::enumerable_thread_specific<std::vector<double>> rowStore(
        [&] { return std::vector<double>(soRows.vector ? blockCells * 10 : 0); });
    tbb::parallel_for(tbb::blocked_range<size_t>(0, groups.count(), 1), [&](const tbb::blocked_range<size_t>& r) {
        Block& b = blocks.local();
        const SecondOrderRowsOut rowOut = soRows.vector ? rowViews(rowStore.local().data(), blockCells) : SecondOrderRowsOut{};
        std::vector<float>& incP = b.cx;
        std::vector<float>& incT = b.cy;
        const ConstAcc pAcc(p.tree()), tAcc(T.tree());
        std::unique_ptr<ConstAcc> mAcc, dpAcc, dtAcc;
        if (melt) mAcc = std::make_unique<ConstAcc>(melt->tree());
        if (dP) dpAcc = std::make_unique<ConstAcc>(dP->tree());
        if (dT) dtAcc = std::make_unique<ConstAcc>(dT->tree());
        const std::decay_t<decltype(planeLeaves.leaf(0))>* present[kPlaneGroup * kPlaneGroup];
        for (size_t g = r.begin(); g != r.end(); ++g) {
            const openvdb::Coord origin = groups.origin[g];
            const size_t first = groups.start[g], count = groups.start[g + 1] - first;
            for (size_t q = 0; q < count; ++q) present[q] = &planeLeaves.leaf(groups.leaves[first + q]);
            markNeeded(b, origin, present, count);
            const BlockRect rect = presentRect(b, origin, present, count);
            auto gatherField = [&](const ConstAcc& acc, std::vector<float>& out) { // p, T and their history
                if (in.folded) gatherFolded(acc, b, origin, out, rect.x0, rect.x1, rect.y0, rect.y1);
                else gatherRect(acc, b, origin, z0, rect, out);
            };
            gatherField(pAcc, b.p);
            gatherField(tAcc, b.T);
            if (mAcc) gatherRect(*mAcc, b, origin, z0, rect, b.melt);
            // the block loops below: the rows of the rectangle (all of the block in a box)
            auto forRect = [&](auto&& f) {
                for (int z = 0; z < b.bz; ++z)
                    for (int y = rect.y0; y < rect.y1; ++y) {
                        const size_t row = b.index(0, y, z);
                        f(row + size_t(rect.x0), row + size_t(rect.x1));
                    }
            };
            // cx, cy are free in this scheme and hold the increments since the last step's
            // start, p - p^{n-1}: the last step's own change plus whatever other effects did
            // since (a walker froze the cell, the flow carried heat), so the extrapolation
            // starts from the p the step really sees (the last step's dp alone, after a walker
            // set p = 1, put the reaction's tangent at the old p and pushed p to 1.013).
            if (dpAcc) {
                gatherField(*dpAcc, incP);
                forRect([&](size_t i0, size_t i1) { for (size_t i = i0; i < i1; ++i) incP[i] = b.p[i] - incP[i]; });
            } else std::fill(incP.begin(), incP.end(), 0.f);
            if (dtAcc) {
                gatherField(*dtAcc, incT);
                forRect([&](size_t i0, size_t i1) { for (size_t i = i0; i < i1; ++i) incT[i] = b.T[i] - incT[i]; });
            } else std::fill(incT.begin(), incT.end(), 0.f);
            // pf (in gz, free in this scheme): p extrapolated to the end of the step.
            forRect([&](size_t i0, size_t i1) {
                for (size_t i = i0; i < i1; ++i) {
                    b.pe[i] = std::min(1.f, std::max(0.f, b.p[i] + extrapolate * incP[i]));
                    b.te[i] = b.T[i] + extrapolate * incT[i];
                    b.gz[i] = std::min(1.f, std::max(0.f, b.p[i] + extrapolate / float(theta) * incP[i]));
                }
            });
            // eps^2 of the extrapolated phase on the cells the rows read (the voxels and their
            // ring, for its gradient).
            if (soRows.vector) {
                epsSquaredRuns(b, soRows, st, an);
            } else {
                forNeeded(b, [&](size_t i) { b.a[i] = float(kobayashiEpsSquared(b.pe.data(), i, st, an)); });
            }
            if (soRows.vector) {
                vectorRowsOfGroup(in, b, soRows, st, rowOut, origin, present, &groups.leaves[first], count, ps, ts, p0, T0);
                continue;
            }
            for (size_t q = 0; q < count; ++q) {
              const size_t li = groups.leaves[first + q];
              forActiveVoxels(b, origin, z0, *present[q], [&](openvdb::Index n, size_t i, const openvdb::Coord& c) {
                const double chi = noiseDraw(k, seed, stepIndex, c);
                const SecondOrderRow row = kobayashiSecondOrderRow(
                    b.p.data(), b.T.data(), b.pe.data(), b.te.data(), b.gz.data(), b.a.data(), i, st, k,
                    meltTemperatureAt(k, b, i, melt != nullptr), chi, theta);
                const size_t s = size_t(layout.rowAt(li, n));
                ps.diag[s] = row.diag;
                // fixed-length copies: a memcpy call per row cost 3 % of the run
                double* coefOut = &ps.coef[s * size_t(taps)];
                if (taps == 6) for (int q = 0; q < 6; ++q) coefOut[q] = row.coef[q];
                else if (taps == 4) for (int q = 0; q < 4; ++q) coefOut[q] = row.coef[q];
                else std::copy(row.coef, row.coef + taps, coefOut);
                ps.rhs[s] = row.rhs;
                ps.x[s] = row.predictor;
                p0[s] = b.p[i];
                T0[s] = b.T[i];
                // Temperature: theta-weighted lap T; the latent heat is added once p' is known.
                ts.rhs[s] = b.T[i] + (1.0 - theta) * k.dt * row.lapT;
              });
            }
        }
    });
}

/// Second-order stage 3, after the p solve: p' clipped back into [0, 1] where it left it by
/// rounding or a stopped solve (returns how many voxels beyond rounding), and the latent heat of
/// the clipped change, K (p' - p^n), added to the T rows and to the T solve's start.
int64_t clipAndAddLatentHeat(const KobayashiParams& k, ImplicitSystem& ps, ImplicitSystem& ts,
                             const std::vector<double>& p0, const std::vector<double>& T0)
{
    constexpr double kRounding = 1e-12;
    std::atomic<int64_t> outside{0};
    tbb::parallel_for(tbb::blocked_range<size_t>(0, ps.rows(), 4096), [&](const tbb::blocked_range<size_t>& r) {
        int64_t local = 0;
        for (size_t s = r.begin(); s != r.end(); ++s) {
            double& v = ps.x[s];
            if (v < 0.0 && v >= -0.25) local += v < -kRounding, v = 0.0;
            else if (v > 1.0 && v <= 1.25) local += v > 1.0 + kRounding, v = 1.0;
            const double heat = k.latentHeat * (v - p0[s]);
            ts.rhs[s] += heat;
            ts.x[s] = T0[s] + heat;
        }
        outside += local;
    });
    return outside;
}

/// Second-order stage 5, the write-back: the solutions into p and T (bounds checked), this
/// step's start values into the history grids, growth and freeze time recorded, crossings of
/// p = 1/2 listed.
/// @a planeLeaves: p's leaves, or with folded fields the region's plane leaves, whose voxels are
/// written in their folded leaves (@a foldedLeaf[li] of pLeaves, at plane::foldedOffset).
/// Leaves are visited in @a order (the layout's: each leaf's rows follow the last one's).
template <typename PlaneLeavesT>
void writeBackSecondOrder(const PlaneLeavesT& planeLeaves, const std::vector<size_t>& order,
                          const std::vector<uint32_t>* foldedLeaf,
                          openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
                          openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves,
                          openvdb::tree::LeafManager<openvdb::FloatTree>& dpLeaves,
                          openvdb::tree::LeafManager<openvdb::FloatTree>& dtLeaves, const SlotLayout& layout,
                          const ImplicitSystem& ps, const ImplicitSystem& ts, const std::vector<double>& p0,
                          const std::vector<double>& T0, Accumulators& acc, Failure& failure, float tn1,
                          std::vector<openvdb::Coord>* crossings)
{
    tbb::enumerable_thread_specific<std::vector<openvdb::Coord>> crossed;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, order.size(), 16), [&](const tbb::blocked_range<size_t>& r) {
        std::vector<Accumulators::Pending>* pending = nullptr;
        std::vector<openvdb::Coord>* cross = crossings ? &crossed.local() : nullptr;
        for (size_t q = r.begin(); q != r.end(); ++q) {
            const size_t li = order[q];
            const auto& pl = planeLeaves.leaf(li);
            const size_t fi = foldedLeaf ? (*foldedLeaf)[li] : li;
            float* pv = pLeaves.leaf(fi).buffer().data();
            float* tv = tLeaves.leaf(fi).buffer().data();
            float* dpv = dpLeaves.leaf(fi).buffer().data();
            float* dtv = dtLeaves.leaf(fi).buffer().data();
            FloatLeaf* gl = Accumulators::leafFor(acc.growth, acc.foldG, pl.origin());
            FloatLeaf* fl = Accumulators::leafFor(acc.freeze, acc.foldF, pl.origin());
            // The accumulator leaves' buffers and masks directly (what Accumulators::record does
            // through the leaf's per-voxel accessors, whose buffer checks cost more than the add).
            float* gv = gl ? gl->buffer().data() : nullptr;
            float* fv = fl ? fl->buffer().data() : nullptr;
            // word by word over the value mask (the value iterator and its coordinates cost
            // more than the writes); coordinates only where they are needed
            const auto& mask = pl.getValueMask();
            for (openvdb::Index w = 0; w < FloatLeaf::NodeMaskType::WORD_COUNT; ++w) {
              for (uint64_t bits = mask.template getWord<uint64_t>(w); bits; bits &= bits - 1) {
                const openvdb::Index n = w * 64 + openvdb::Index(__builtin_ctzll(bits));
                const openvdb::Index v = foldedLeaf ? plane::foldedOffset(pl.origin(), int(n >> 6), int((n >> 3) & 7)) : n;
                const size_t s = size_t(layout.rowAt(li, n));
                const float pn = float(ps.x[s]), tn = float(ts.x[s]);
                if (!std::isfinite(pn) || pn < -0.05f || pn > 1.05f) failure.report(pl.offsetToGlobalCoord(n), "p (ice)", pn);
                if (!std::isfinite(tn)) failure.report(pl.offsetToGlobalCoord(n), "T (temperature)", tn);
                if (cross && ((float(p0[s]) > 0.5f) != (pn > 0.5f))) cross->push_back(pl.offsetToGlobalCoord(n));
                pv[v] = pn;
                tv[v] = tn;
                const double dp = ps.x[s] - p0[s];
                dpv[v] = float(p0[s]);
                dtv[v] = float(T0[s]);
                if (acc.growth && dp > 0) {
                    if (gv) {
                        const openvdb::Index gs = Accumulators::slot(acc.foldG, pl.origin(), n);
                        gv[gs] = gv[gs] + float(dp);
                        // mostly on already: a plain test spares the locked OR of a folded mask
                        if (!Accumulators::isOn(*gl, acc.foldG, gs)) Accumulators::markOn(*gl, acc.foldG, gs);
                    } else acc.queue(pending).push_back({pl.offsetToGlobalCoord(n), float(dp), true});
                }
                if (acc.freeze && pn > 0.5f) {
                    if (fv) {
                        const openvdb::Index fs = Accumulators::slot(acc.foldF, pl.origin(), n);
                        if (!Accumulators::isOn(*fl, acc.foldF, fs)) {
                            fv[fs] = tn1;
                            Accumulators::markOn(*fl, acc.foldF, fs);
                        }
                    } else acc.queue(pending).push_back({pl.offsetToGlobalCoord(n), tn1, false});
                }
              }
            }
        }
    });
    acc.apply();
    if (crossings)
        for (auto& list : crossed) crossings->insert(crossings->end(), list.begin(), list.end());
}

} // namespace

void PhaseFieldSolver::stepSecondOrder(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T,
                                       openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
                                       openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves,
                                       Accumulators& acc, int64_t stepIndex, double tNext, uint64_t seed,
                                       Failure& failure, PhaseFieldStepStats* stats,
                                       const plane::PlaneLeaves* regionLeaves)
{
    const KobayashiParams& k = mParams;
    const bool plane = mDomain.flat();
    const Stencil stencil = mDomain.stencil();
    const bool folded = regionLeaves != nullptr; // rows by the region's plane leaves
    // Gauss-Seidel's rows are numbered group by group (the kernel's blocks), as the assembly
    // writes them; BiCGSTAB's stay in leaf order (its dot products sum in row order).
    const bool groupOrder = !k.useBiCGSTAB;
    // The layout depends only on the region's topology: built once per region.
    if (!mLayout || mLayoutGeneration != mGeneration || mLayoutGroupOrder != groupOrder) {
        // last step's layout lends its arrays (the systems that refer to it only lend theirs below)
        const std::vector<size_t>* order = groupOrder ? &mGroups->leaves : nullptr;
        if (folded) { // rows by the region's plane leaves (in the plane tree's order), as unfolded p's would be
            mLayout = std::make_unique<SlotLayout>(*regionLeaves, stencil, plane, mLayout.get(), order);
        } else {
            mLayout = std::make_unique<SlotLayout>(pLeaves, stencil, plane, mLayout.get(), order);
        }
        mLayoutGeneration = mGeneration;
        mLayoutGroupOrder = groupOrder;
    }
    const SlotLayout& layout = *mLayout;
    const int z0 = mDomain.bbox().min().z();
    // Last step's systems lend their arrays (every row is set below).
    auto psOwned = mSystemP ? std::make_unique<ImplicitSystem>(layout, *mSystemP) : std::make_unique<ImplicitSystem>(layout);
    auto tsOwned = mSystemT ? std::make_unique<ImplicitSystem>(layout, *mSystemT) : std::make_unique<ImplicitSystem>(layout);
    ImplicitSystem &ps = *psOwned, &ts = *tsOwned;
    ps.useCoefficients();
    ps.setOutside(p.background());
    ts.setOutside(T.background());
    std::vector<double>& p0 = mStartP;
    std::vector<double>& T0 = mStartT;
    p0.resize(ps.rows());
    T0.resize(ps.rows());
    const double theta = mTheta;
    ts.setUniform(1.0 + theta * k.dt * -stencil.wLapCentre, theta * k.dt); // every row: diag, scale
    const openvdb::FloatGrid* dP = mLastInP.get();
    const openvdb::FloatGrid* dT = mLastInT.get();
    // Coefficients at theta of the step (the midpoint for Crank-Nicolson, the end for implicit
    // Euler), extrapolated along the last step's increment, scaled to this step's dt.
    const float extrapolate = dP ? float(theta * k.dt / mLastStepDt) : 0.f;

    // Explicit parts, per leaf on the padded block.
    const SecondOrderInputs in{k, stencil, plane, z0, theta, extrapolate, p, T, mMelt, dP, dT, folded, *mGroups,
                               layout, stepIndex, seed};
    if (folded) assembleSecondOrderRows(in, *regionLeaves, ps, ts, p0, T0);
    else assembleSecondOrderRows(in, pLeaves, ps, ts, p0, T0);
    auto t0 = Clock::now();
    const LinearSolverKind kind = k.useBiCGSTAB ? LinearSolverKind::BiCGSTAB : LinearSolverKind::GaussSeidel;
    const SolveReport rp = ps.solve(kind, k.solverTolerance, k.solverMaxIterations);
    // Each row is a convex combination of in-bound values (positive coefficients, the bounded
    // reaction split, Kobayashi.h), and so is every Gauss-Seidel sweep from the bounded
    // predictor: p' leaves [0, 1] only by the rounding of that combination (1 + 2e-16, set back
    // silently), or where a solve is not a positive scheme (BiCGSTAB stopped early): such p is
    // clipped back within [-0.25, 1.25] and counted (the latent heat below uses the clipped change);
    // beyond that the guard stops the run.
    const auto tHeat = Clock::now();
    // Latent heat, energy-consistent at any solver tolerance: K (p' - p^n) of the p actually
    // taken enters T once, and the T solve starts from T^n + K dp. Its iterates are then convex
    // combinations of that start, the explicit half's old values (positive weights below the
    // stability limit) and the far field, so T never exceeds T^n + K max dp, even after one
    // sweep at reduced precision (a forward-Euler start, dt |w0| > 1, did: frozen cells thawed).
    // One pass with the clip above (a row's heat reads only its own clipped p').
    const int64_t outside = clipAndAddLatentHeat(k, ps, ts, p0, T0);
    const SolveReport rt = ts.solve(kind, k.solverTolerance, k.solverMaxIterations);
    if (stats) {
        stats->solveSeconds += since(t0);
        stats->heatSeconds += since(tHeat);
        stats->solverIterationsP += rp.iterations;
        stats->solverIterationsT += rt.iterations;
        stats->solves += 1;
        if (!rp.converged || !rt.converged) stats->unconverged += 1;
        stats->lastResidual = std::max(rp.residual, rt.residual);
        stats->clippedVoxels += outside;
    }

    // Write back, record growth and freezing, remember this step's start values.
    // Into last step's start-value grids when nobody else holds them (a checkpoint being written
    // may), else fresh ones: only active voxels are written, off voxels keep the background.
    auto startGrid = [&](openvdb::FloatGrid::Ptr& old, const openvdb::FloatGrid* ours, float background) {
        openvdb::FloatGrid::Ptr g;
        if (old && old.get() == ours && old.use_count() == 1 && old->treePtr().use_count() == 2 &&
            plane::isFolded(*old) == folded)
            g = old;
        if (!g) {
            g = openvdb::FloatGrid::create(background);
            g->tree().topologyUnion(pLeaves.tree()); // p's layout, folded or not
            if (folded) plane::markFolded(*g);
        } else if (mLastInGeneration != mGeneration) {
            matchTopology(*g, *mRegionMask);
        }
        return g;
    };
    auto lastDp = startGrid(mLastInP, mLastInOwned, p.background());
    auto lastDt = startGrid(mLastInT, mLastInOwnedT, T.background());
    openvdb::tree::LeafManager<openvdb::FloatTree> dpLeaves(lastDp->tree()), dtLeaves(lastDt->tree());
    const float tn1 = float(tNext);
    if (folded)
        writeBackSecondOrder(*regionLeaves, mGroups->leaves, &foldedLayout().leafOf, pLeaves, tLeaves, dpLeaves, dtLeaves, layout, ps,
                             ts, p0, T0, acc, failure, tn1, mCrossings);
    else
        writeBackSecondOrder(pLeaves, mGroups->leaves, nullptr, pLeaves, tLeaves, dpLeaves, dtLeaves, layout, ps, ts, p0, T0, acc,
                             failure, tn1, mCrossings);
    mLastInP = lastDp;
    mLastInT = lastDt;
    mLastInOwned = mLastInP.get();
    mLastInOwnedT = mLastInT.get();
    mLastInGeneration = mGeneration;
    mLastStepDt = k.dt;
    mSystemP = std::move(psOwned);
    mSystemT = std::move(tsOwned);
}

uint64_t PhaseFieldSolver::kernelOnly(const openvdb::MaskGrid& region, const openvdb::FloatGrid& p,
                                      const openvdb::FloatGrid& T, openvdb::FloatGrid& pOut,
                                      openvdb::FloatGrid& tOut) const
{
    pOut.tree().topologyUnion(region.tree());
    tOut.tree().topologyUnion(region.tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> pLeaves(pOut.tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> tLeaves(tOut.tree());
    const LeafGroups groups(pLeaves, mDomain.flat());
    LeafKernel{mParams, mDomain, p, T, mMelt}.run(pLeaves, tLeaves, groups);
    return pOut.activeVoxelCount();
}

DensePhaseField::DensePhaseField(const KobayashiParams& params, const Lattice& lattice, int nx, int ny)
    : mParams(params), mStencil(lattice.stencil(false)), mNx(nx), mNy(ny), mStride(size_t(nx + 2 * kHalo))
{
    const size_t n = mStride * size_t(ny + 2 * kHalo);
    mP.assign(n, 0.f);
    mT.assign(n, float(params.farTemperature));
    mTn.assign(n, float(params.farTemperature));
    for (auto* v : {&mPn, &mA, &mCx, &mCy, &mGx, &mGy, &mGz}) v->assign(n, 0.f);
}

void DensePhaseField::step()
{
    FlatStencil st(mStencil, std::ptrdiff_t(mStride), 0);
    const Anisotropy an(mParams);
    useD6Forms(st, an);
    const EulerRows rows = mVectorRows ? fastestEulerRows(st, an) : plainEulerRows();
    const int W = mNx + 2 * kHalo;
    // Pass 1 on every cell with a full ring of neighbours, pass 2 on the domain cells; the halo
    // keeps the far-field values (Dirichlet), as the sparse solver's reads outside the domain do.
    tbb::parallel_for(tbb::blocked_range<int>(1, mNy + 2 * kHalo - 1, 16), [&](const tbb::blocked_range<int>& r) {
        for (int y = r.begin(); y != r.end(); ++y)
            rows.aux(mP.data(), size_t(y) * mStride + 1, size_t(y) * mStride + size_t(W - 1), st, an, mA.data(),
                   mCx.data(), mCy.data(), mGx.data(), mGy.data(), mGz.data());
    });
    tbb::parallel_for(tbb::blocked_range<int>(0, mNy, 16), [&](const tbb::blocked_range<int>& r) {
        for (int j = r.begin(); j != r.end(); ++j)
            rows.euler(mP.data(), mT.data(), mA.data(), mCx.data(), mCy.data(), mGx.data(), mGy.data(), mGz.data(),
                     index(0, j), index(mNx, j), st, mParams, nullptr, nullptr, mPn.data(), mTn.data(), nullptr);
    });
    // Halo cells are never written, so both buffer pairs keep the far field there.
    std::swap(mP, mPn);
    std::swap(mT, mTn);
}

} // namespace frostvdb
