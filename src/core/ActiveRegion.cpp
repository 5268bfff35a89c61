#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/core/RegionOfTopology.h>
#include <frostvdb/core/RemoveLeaves.h>

#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tree/ValueAccessor.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <stdexcept>

namespace frostvdb {

namespace {

using MaskLeaf = openvdb::MaskTree::LeafNodeType;
constexpr int kLeafDim = int(MaskLeaf::DIM);

/// A plane region's leaf masks as flat arrays with a dense leaf table over the part of the domain
/// the dilation can reach: the dilation then reads neighbour masks by index instead of copying
/// the tree each iteration (the tree copies, with their 32^3-entry internal nodes, were 4/5 of
/// the region rebuild in the profile).
struct PlaneLeafMasks {
    int lx0 = 0, ly0 = 0, nx = 0, ny = 0, z = 0;
    std::vector<int32_t> table;
    std::vector<openvdb::Coord> origin;
    std::vector<std::array<uint64_t, 8>> m;

    int32_t find(int lx, int ly) const
    {
        if (lx < lx0 || ly < ly0 || lx >= lx0 + nx || ly >= ly0 + ny) return -1;
        return table[size_t(ly - ly0) * size_t(nx) + size_t(lx - lx0)];
    }
    void touch(int lx, int ly)
    {
        if (lx < lx0 || ly < ly0 || lx >= lx0 + nx || ly >= ly0 + ny) return; // outside the domain
        int32_t& t = table[size_t(ly - ly0) * size_t(nx) + size_t(lx - lx0)];
        if (t >= 0) return;
        t = int32_t(origin.size());
        origin.emplace_back(lx * kLeafDim, ly * kLeafDim, z);
        m.push_back({});
    }

    /// One pass: along x (axis 0), y (axis 1) or both from the same source (axis 2: diamond).
    void dilate(int axis)
    {
        const size_t n0 = origin.size();
        for (size_t i = 0; i < n0; ++i) {
            const std::array<uint64_t, 8> c = m[i]; // a copy: touch() may grow m
            const int lx = origin[i].x() / kLeafDim, ly = origin[i].y() / kLeafDim;
            uint64_t any = 0, lowY = 0, highY = 0;
            for (int w = 0; w < 8; ++w) { any |= c[w]; lowY |= c[w] & 0xFFull; highY |= c[w] >> 56; }
            if (!any) continue;
            if (axis != 1) { if (c[0]) touch(lx - 1, ly); if (c[7]) touch(lx + 1, ly); }
            if (axis != 0) { if (lowY) touch(lx, ly - 1); if (highY) touch(lx, ly + 1); }
        }
        const std::vector<std::array<uint64_t, 8>> src(m); // flat copy: 64 bytes a leaf
        static const std::array<uint64_t, 8> kZero{};
        auto at = [&](int lx, int ly) -> const std::array<uint64_t, 8>& {
            const int32_t j = find(lx, ly);
            return j >= 0 && size_t(j) < src.size() ? src[size_t(j)] : kZero;
        };
        tbb::parallel_for(tbb::blocked_range<size_t>(0, origin.size(), 256), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t i = r.begin(); i != r.end(); ++i) {
                const int lx = origin[i].x() / kLeafDim, ly = origin[i].y() / kLeafDim;
                const auto& c = src[i];
                auto& out = m[i];
                if (axis != 1) {
                    const auto& l = at(lx - 1, ly);
                    const auto& h = at(lx + 1, ly);
                    for (int w = 0; w < 8; ++w) out[w] |= (w > 0 ? c[w - 1] : l[7]) | (w < 7 ? c[w + 1] : h[0]);
                }
                if (axis != 0) {
                    const auto& l = at(lx, ly - 1);
                    const auto& h = at(lx, ly + 1);
                    for (int w = 0; w < 8; ++w) out[w] |= (c[w] << 8) | (c[w] >> 8) | (h[w] << 56) | (l[w] >> 56);
                }
            }
        });
    }
};

/// Dilates a plane region @a iterations times (4-neighbourhood, or with the hexagonal lattice's
/// diagonal the 3x3 neighbourhood) within the domain's leaves.
void dilatePlaneRegion(openvdb::MaskTree& tree, int iterations, bool eightNeighbours, const Domain& domain)
{
    PlaneLeafMasks s;
    const openvdb::CoordBBox& box = domain.bbox();
    auto floorDiv = [](int v) { return v >= 0 ? v / kLeafDim : -((-v + kLeafDim - 1) / kLeafDim); };
    openvdb::CoordBBox leaves; // leaf units
    for (auto it = tree.cbeginLeaf(); it; ++it) leaves.expand(openvdb::Coord(floorDiv(it->origin().x()), floorDiv(it->origin().y()), 0));
    if (leaves.empty()) return;
    const int margin = iterations / kLeafDim + 1;
    s.lx0 = std::max(leaves.min().x() - margin, floorDiv(box.min().x()));
    s.ly0 = std::max(leaves.min().y() - margin, floorDiv(box.min().y()));
    s.nx = std::min(leaves.max().x() + margin, floorDiv(box.max().x())) - s.lx0 + 1;
    s.ny = std::min(leaves.max().y() + margin, floorDiv(box.max().y())) - s.ly0 + 1;
    s.z = box.min().z() & ~(kLeafDim - 1);
    s.table.assign(size_t(s.nx) * size_t(s.ny), -1);
    for (auto it = tree.cbeginLeaf(); it; ++it) {
        const int lx = floorDiv(it->origin().x()), ly = floorDiv(it->origin().y());
        s.touch(lx, ly);
        const int32_t j = s.find(lx, ly);
        if (j < 0) continue;
        for (int w = 0; w < 8; ++w) s.m[size_t(j)][w] |= it->getValueMask().template getWord<uint64_t>(openvdb::Index(w));
    }
    for (int i = 0; i < iterations; ++i) {
        if (eightNeighbours) { s.dilate(0); s.dilate(1); }
        else s.dilate(2);
    }
    tree.clear();
    for (size_t i = 0; i < s.origin.size(); ++i) {
        MaskLeaf* leaf = tree.touchLeaf(s.origin[i]);
        for (int w = 0; w < 8; ++w) leaf->getValueMask().template getWord<uint64_t>(openvdb::Index(w)) = s.m[i][w];
    }
}

/// Switches on every voxel of each leaf that lies in the domain's slab (a plane's one z, a box's all).
void fillLeaves(openvdb::MaskTree& tree, const Domain& domain)
{
    openvdb::tree::LeafManager<openvdb::MaskTree> leaves(tree);
    const bool plane = domain.flat();
    const int z0 = domain.bbox().min().z();
    const uint64_t planeBits = 0x0101010101010101ull << (z0 & (kLeafDim - 1));
    leaves.foreach([&](MaskLeaf& leaf, size_t) {
        auto& mask = leaf.getValueMask();
        if (!plane) { mask.setOn(); return; }
        if ((leaf.origin().z() & ~(kLeafDim - 1)) != (z0 & ~(kLeafDim - 1))) return;
        for (openvdb::Index w = 0; w < 8; ++w) mask.template getWord<uint64_t>(w) |= planeBits;
    });
}

/// True when some field stores an active tile (a pruned block): the leaf-level plane path
/// reads leaves only.
template <typename GridT>
bool anyActiveTile(const std::vector<const GridT*>& fields)
{
    for (const auto* f : fields) {
        auto it = f->tree().cbeginValueOn();
        it.setMaxDepth(GridT::TreeType::ValueOnCIter::LEAF_DEPTH - 1);
        if (it) return true;
    }
    return false;
}

/// The plane leaves marked in a leaf table (leaf units, nx x ny from (lx0, ly0), layer zLeaf).
struct LeafTable {
    std::vector<uint8_t> marks;
    int lx0, ly0, nx, ny, zLeaf;
    size_t marked = 0; ///< leaves marked (counted as the marks are set)
    uint8_t* at(const openvdb::Coord& origin)
    {
        auto floorDiv = [](int v) { return v >= 0 ? v / kLeafDim : -((-v + kLeafDim - 1) / kLeafDim); };
        const int x = floorDiv(origin.x()) - lx0, y = floorDiv(origin.y()) - ly0;
        if (origin.z() != zLeaf || x < 0 || y < 0 || x >= nx || y >= ny) return nullptr;
        return &marks[size_t(y) * size_t(nx) + size_t(x)];
    }
};

/// Calls f(x) for each of the @a n marks of @a row that has a bit of @a keepBits, eight marks at
/// a time: most of a table is 0 (or, when a region is edited, held), and a byte loop over the
/// whole table was most of an edit's time.
template <typename F>
void forKeptMarks(const uint8_t* row, int n, uint8_t keepBits, F&& f)
{
    const uint64_t wordBits = 0x0101010101010101ull * keepBits;
    int x = 0;
    for (; x + 8 <= n; x += 8) {
        uint64_t w;
        std::memcpy(&w, row + x, 8);
        if (!(w & wordBits)) continue;
        for (int k = 0; k < 8; ++k)
            if (row[x + k] & keepBits) f(x + k);
    }
    for (; x < n; ++x)
        if (row[x] & keepBits) f(x);
}

/// The cells of the plane leaf at @a lo as a region build makes it: a whole leaf (fillLeaves)
/// clipped to the domain's box (clipToSupport; a lattice plane's support is its box, and only
/// lattice planes have folded fields, plane::foldsPlaneFields). Byte dy, bit dx.
uint64_t clippedLeafRows(const openvdb::Coord& lo, const openvdb::CoordBBox& box)
{
    const int x0 = std::max(0, box.min().x() - lo.x()), x1 = std::min(kLeafDim - 1, box.max().x() - lo.x());
    const int y0 = std::max(0, box.min().y() - lo.y()), y1 = std::min(kLeafDim - 1, box.max().y() - lo.y());
    if (x0 > x1 || y0 > y1) return 0;
    const uint64_t row = ((uint64_t(2) << x1) - 1) & ~((uint64_t(1) << x0) - 1);
    uint64_t rows = 0;
    for (int dy = y0; dy <= y1; ++dy) rows |= row << (8 * dy);
    return rows;
}

/// Folds into @a folded the table's leaves whose mark has a bit of @a keepBits, each as
/// clippedLeafRows makes it, and lists them in @a added. Written straight into their folded
/// leaves: transient plane-layout trees, 16 leaf rows at a time, allocated and cleared about
/// 1 MB of internal nodes a band, which was most of an edit's time.
void foldMarkedLeaves(const LeafTable& t, uint8_t keepBits, const openvdb::CoordBBox& box, openvdb::MaskTree& folded,
                      std::vector<openvdb::Coord>* added)
{
    openvdb::tree::ValueAccessor<openvdb::MaskTree> acc(folded);
    for (int y = 0; y < t.ny; ++y)
        forKeptMarks(&t.marks[size_t(y) * size_t(t.nx)], t.nx, keepBits, [&](int x) {
            const openvdb::Coord lo((t.lx0 + x) * kLeafDim, (t.ly0 + y) * kLeafDim, t.zLeaf);
            const uint64_t rows = clippedLeafRows(lo, box);
            if (!rows) return; // no cell in the domain: the clip drops the leaf
            auto& mask = acc.touchLeaf(plane::foldedLeafOrigin(lo))->getValueMask();
            for (int dy = 0; dy < kLeafDim; ++dy)
                mask.template getWord<uint64_t>(openvdb::Index(dy)) |= ((rows >> (8 * dy)) & 0xffu) << (lo.x() & 63);
            if (added) added->push_back(lo);
        });
}

constexpr uint8_t kMarked = 1, kHeld = 2; // a table's marks: marked; marked and already in the region

/// Marks kHeld the table's leaves that the folded region @a previous holds, in parallel (each of
/// its chunks is a distinct plane leaf, so a distinct mark); returns how many, and lists in
/// @a gone, in @a previous's leaf order, the plane leaves it holds that are not marked.
size_t markHeld(LeafTable& t, const openvdb::MaskTree& previous, std::vector<openvdb::Coord>& gone)
{
    openvdb::tree::LeafManager<const openvdb::MaskTree> leaves(previous);
    std::vector<uint8_t> lost(leaves.leafCount(), 0); // per folded leaf: bit g, its chunk g is gone
    std::atomic<size_t> held{0};
    tbb::parallel_for(tbb::blocked_range<size_t>(0, leaves.leafCount(), 256), [&](const tbb::blocked_range<size_t>& r) {
        size_t n = 0;
        for (size_t i = r.begin(); i != r.end(); ++i) {
            const MaskLeaf& leaf = leaves.leaf(i);
            for (int g = 0; g < 8; ++g) {
                if (!plane::chunkRows(leaf.getValueMask(), g)) continue;
                uint8_t* m = t.at(plane::planeLeafOfChunk(leaf.origin(), g));
                if (m && *m) { *m = kHeld; ++n; }
                else lost[i] |= uint8_t(1u << g);
            }
        }
        held += n;
    });
    for (size_t i = 0; i < lost.size(); ++i)
        for (unsigned b = lost[i]; b; b &= b - 1)
            gone.push_back(plane::planeLeafOfChunk(leaves.leaf(i).origin(), __builtin_ctz(b)));
    return held;
}

/// The leaf table's region as a folded mask (plane::foldTopology of the plane region): @a previous
/// itself when its plane leaves are the marked ones; with @a edit, @a previous edited in place
/// into it (the plane leaves it lost and gained listed), else a new grid.
openvdb::MaskGrid::Ptr foldedRegionOf(LeafTable& t, const Domain& domain, const openvdb::MaskGrid::Ptr& previous,
                                      RegionEdit* edit)
{
    std::vector<openvdb::Coord> gone;
    const size_t held = previous ? markHeld(t, previous->tree(), gone) : 0;
    if (previous && gone.empty() && held == t.marked) return previous; // the same plane leaves
    if (edit && previous) {
        plane::clearFoldedChunks(previous->tree(), gone);
        foldMarkedLeaves(t, kMarked, domain.bbox(), previous->tree(), &edit->added);
        edit->removed = std::move(gone);
        return previous;
    }
    auto region = openvdb::MaskGrid::create(false);
    region->setTransform(domain.transform()->copy());
    plane::markFolded(*region);
    foldMarkedLeaves(t, kMarked | kHeld, domain.bbox(), region->tree(), nullptr);
    return region;
}

/// A field's plane leaves as the leaf-level region path reads them: per plane leaf its origin
/// and, per x, the active y's of the plane layer (bit y). A plane-layout tree gives one per
/// leaf; a folded tree (core/PlaneFold.h) one per 8 x 8 chunk of each folded leaf, so the
/// region is built from folded fields without unfolding them.
template <typename TreeT>
struct PlaneLeafRows {
    using LeafT = typename TreeT::LeafNodeType;
    const openvdb::tree::LeafManager<const TreeT>& leaves;
    bool folded;
    int zLeaf, zBit;

    size_t count() const { return leaves.leafCount() * (folded ? 8 : 1); }
    /// Origin of plane leaf @a i and its rows; false when it has no voxel on the plane layer.
    bool rows(size_t i, openvdb::Coord& o, uint8_t r[kLeafDim]) const
    {
        if (!folded) {
            const LeafT& leaf = leaves.leaf(i);
            o = leaf.origin();
            if (o.z() != zLeaf) return false;
            bool any = false;
            for (int x = 0; x < kLeafDim; ++x) {
                const uint64_t w = leaf.getValueMask().template getWord<uint64_t>(openvdb::Index(x)) >> zBit;
                uint8_t b = 0;
                for (int y = 0; y < kLeafDim; ++y)
                    if ((w >> (y * 8)) & 1u) b |= uint8_t(1u << y);
                r[x] = b;
                any = any || b;
            }
            return any;
        }
        // folded leaf i / 8, chunk g: word dy's byte g holds (dx, dy) at bit dx
        const LeafT& leaf = leaves.leaf(i / 8);
        const int g = int(i % 8);
        const openvdb::Coord fo = leaf.origin();
        if (!plane::isFoldedLeafOrigin(fo)) throw std::logic_error("planeRegionByLeaves: a folded plane field has a leaf off its layers");
        o = plane::planeLeafOfChunk(fo, g);
        uint64_t bytes = 0; // byte dy: the chunk's row dy (bit dx)
        for (int dy = 0; dy < kLeafDim; ++dy)
            bytes |= ((leaf.getValueMask().template getWord<uint64_t>(openvdb::Index(dy)) >> (g * 8)) & 0xffu) << (dy * 8);
        if (!bytes) return false;
        for (int x = 0; x < kLeafDim; ++x) {
            uint8_t b = 0;
            for (int y = 0; y < kLeafDim; ++y) b |= uint8_t(((bytes >> (y * 8 + x)) & 1u) << y);
            r[x] = b;
        }
        return true;
    }
};

/// The plane region computed leaf by leaf, the same set of whole leaves the voxel dilation
/// gives (a leaf is in when one of its cells lies within `iterations` of a source voxel: L1
/// for the 4-neighbour dilation, Chebyshev for the hexagonal 3x3 one), without building or
/// dilating a voxel mask: each source leaf marks the neighbour leaves its voxels reach. Cost
/// follows the fields' leaves. Returns @a previous itself when the leaf set is unchanged.
/// Null when the reach spans more than two leaves (the voxel dilation handles that).
/// @a folded: the fields are folded plane fields (core/PlaneFold.h), read chunk by chunk.
template <typename GridT>
openvdb::MaskGrid::Ptr planeRegionByLeaves(const std::vector<const GridT*>& fields, int iterations,
                                           bool chebyshev, const Domain& domain,
                                           const openvdb::MaskGrid::Ptr& previous, bool folded = false,
                                           RegionEdit* edit = nullptr)
{
    constexpr int kMaxLeaves = 3; // neighbour leaves reached along an axis
    const int R = (iterations + kLeafDim - 1) / kLeafDim;
    if (R > kMaxLeaves) return nullptr;
    constexpr int kSide = 2 * kMaxLeaves + 1; // (2 kMaxLeaves + 1)^2 <= 64 bits
    const openvdb::CoordBBox& box = domain.bbox();
    auto floorDiv = [](int v) { return v >= 0 ? v / kLeafDim : -((-v + kLeafDim - 1) / kLeafDim); };
    const int lx0 = floorDiv(box.min().x()), ly0 = floorDiv(box.min().y());
    const int nx = floorDiv(box.max().x()) - lx0 + 1, ny = floorDiv(box.max().y()) - ly0 + 1;
    const int z0 = box.min().z(), zLeaf = z0 & ~(kLeafDim - 1), zBit = z0 & (kLeafDim - 1);
    if (folded && z0 != 0) return nullptr; // folded fields live on layer 0
    // gap from local coordinate v (0..7) to the cells of the leaf d leaves away along that axis
    auto gap = [](int v, int d) { return d == 0 ? 0 : d > 0 ? d * kLeafDim - v : v + 1 + (-d - 1) * kLeafDim; };
    std::vector<uint8_t> table(size_t(nx) * size_t(ny), 0);
    size_t marked = 0;
    for (const auto* f : fields) {
        using TreeT = typename GridT::TreeType;
        openvdb::tree::LeafManager<const TreeT> leaves(f->tree());
        const PlaneLeafRows<TreeT> source{leaves, folded, zLeaf, zBit};
        // Per source plane leaf: which of the (2R+1)^2 leaves around it its voxels reach (bit per leaf).
        std::vector<uint64_t> reached(source.count(), 0);
        std::vector<openvdb::Coord> origins(source.count());
        tbb::parallel_for(tbb::blocked_range<size_t>(0, source.count(), 64), [&](const tbb::blocked_range<size_t>& range) {
          for (size_t i = range.begin(); i != range.end(); ++i) {
            openvdb::Coord o;
            uint8_t rows[kLeafDim];
            if (!source.rows(i, o, rows)) continue;
            origins[i] = o;
            // per x: the plane layer's active y's inside the domain (bit y)
            const bool inside = box.isInside(openvdb::CoordBBox(openvdb::Coord(o.x(), o.y(), z0),
                                                                openvdb::Coord(o.x() + kLeafDim - 1, o.y() + kLeafDim - 1, z0)));
            bool any = false;
            for (int x = 0; x < kLeafDim; ++x) {
                uint8_t r = rows[x];
                if (r && !inside)
                    for (int y = 0; y < kLeafDim; ++y)
                        if (!box.isInside(openvdb::Coord(o.x() + x, o.y() + y, z0))) r &= uint8_t(~(1u << y));
                rows[x] = r;
                any = any || r;
            }
            if (!any) continue;
            uint64_t bits = 0;
            for (int dy = -R; dy <= R; ++dy)
                for (int dx = -R; dx <= R; ++dx) {
                    // the nearest row cell: its lowest y for leaves below, highest for above
                    int best = 1 << 20;
                    for (int x = 0; x < kLeafDim; ++x) {
                        if (!rows[x]) continue;
                        const int y = dy < 0 ? __builtin_ctz(rows[x]) : 31 - __builtin_clz(rows[x]);
                        const int gx = gap(x, dx), gy = gap(y, dy);
                        best = std::min(best, chebyshev ? std::max(gx, gy) : gx + gy);
                    }
                    if (best <= iterations) bits |= uint64_t(1) << ((dy + kMaxLeaves) * kSide + dx + kMaxLeaves);
                }
            reached[i] = bits;
          }
        });
        for (size_t i = 0; i < reached.size(); ++i) {
            if (!reached[i]) continue;
            const int lx = floorDiv(origins[i].x()), ly = floorDiv(origins[i].y());
            for (uint64_t b = reached[i]; b; b &= b - 1) {
                const int k = __builtin_ctzll(b);
                const int x = lx + k % kSide - kMaxLeaves - lx0, y = ly + k / kSide - kMaxLeaves - ly0;
                if (x < 0 || y < 0 || x >= nx || y >= ny) continue;
                uint8_t& m = table[size_t(y) * size_t(nx) + size_t(x)];
                marked += m == 0;
                m = kMarked;
            }
        }
    }
    if (folded) {
        LeafTable t{std::move(table), lx0, ly0, nx, ny, zLeaf, marked};
        return foldedRegionOf(t, domain, previous, edit);
    }
    if (previous && previous->tree().leafCount() == marked) { // unchanged? (whole leaves: same set, same mask)
        bool same = true;
        for (auto it = previous->tree().cbeginLeaf(); it && same; ++it) {
            const int x = floorDiv(it->origin().x()) - lx0, y = floorDiv(it->origin().y()) - ly0;
            same = it->origin().z() == zLeaf && x >= 0 && y >= 0 && x < nx && y < ny &&
                   table[size_t(y) * size_t(nx) + size_t(x)];
        }
        if (same) return previous;
    }
    auto region = openvdb::MaskGrid::create(false);
    region->setTransform(domain.transform()->copy());
    {
        openvdb::tree::ValueAccessor<openvdb::MaskTree> acc(region->tree());
        for (int y = 0; y < ny; ++y)
            for (int x = 0; x < nx; ++x)
                if (table[size_t(y) * size_t(nx) + size_t(x)])
                    acc.touchLeaf(openvdb::Coord((lx0 + x) * kLeafDim, (ly0 + y) * kLeafDim, zLeaf));
    }
    fillLeaves(region->tree(), domain);
    domain.clipToSupport(region->tree());
    return region;
}

/// buildActiveRegion over the fields' topology (float fields, or plane-layout masks of folded ones).
template <typename GridT>
openvdb::MaskGrid::Ptr regionOf(const std::vector<const GridT*>& fields, const RegionSettings& settings, int reach,
                                const Domain& domain, int steps, const openvdb::MaskGrid::Ptr& previous)
{
    if (!settings.dense && domain.flat() && !anyActiveTile(fields)) {
        const int iterations = std::max(1, steps) * (reach + settings.frontTravel);
        const bool hex = domain.lattice().kind() == LatticeKind::Hexagonal;
        if (auto r = planeRegionByLeaves(fields, iterations, hex, domain, previous)) return r;
    }
    auto region = openvdb::MaskGrid::create(false);
    region->setTransform(domain.transform()->copy());
    if (settings.dense) {
        domain.fillSupport(region->tree());
        region->tree().voxelizeActiveTiles(); // leaves, so kernels can iterate leaf by leaf
        return region;
    }
    // Union of the fields' topology: values already within tolerance of the far field were
    // removed by truncateToTolerance when the last region was retired.
    for (const auto* f : fields) region->tree().topologyUnion(f->tree());
    region->tree().voxelizeActiveTiles();
    domain.clipToSupport(region->tree());
    // A support that fills the domain needs no dilation (it would be clipped away again).
    if (regionFillsDomain(*region, domain)) return region;
    const int iterations = std::max(1, steps) * (reach + settings.frontTravel);
    // Hexagonal lattices reach (1,-1) and (-1,1): edge neighbours in index space.
    const bool hex = domain.lattice().kind() == LatticeKind::Hexagonal;
    if (iterations > 0 && !region->tree().empty()) {
        if (domain.flat()) { // support and stencil in one z layer: planar dilation
            dilatePlaneRegion(region->tree(), iterations, hex, domain);
        } else {
            openvdb::tools::dilateActiveValues(region->tree(), iterations, openvdb::tools::NN_FACE,
                                               openvdb::tools::IGNORE_TILES);
        }
    }
    // Whole leaves: the kernels pay per leaf anyway, and a region that only changes when the
    // front enters a new leaf keeps its topology for many rebuilds, so the output buffers, leaf
    // groups and implicit-system layouts of the last region are reused as they are.
    fillLeaves(region->tree(), domain);
    domain.clipToSupport(region->tree());
    if (previous && region->tree().hasSameTopology(previous->tree())) return previous;
    return region;
}

} // namespace

openvdb::MaskGrid::Ptr buildActiveRegion(const std::vector<const openvdb::FloatGrid*>& fields,
                                         const RegionSettings& settings, int reach, const Domain& domain, int steps,
                                         const openvdb::MaskGrid::Ptr& previous)
{
    return regionOf(fields, settings, reach, domain, steps, previous);
}

openvdb::MaskGrid::Ptr buildActiveRegionOfTopology(const std::vector<const openvdb::MaskGrid*>& topologies,
                                                   const RegionSettings& settings, int reach, const Domain& domain,
                                                   int steps, const openvdb::MaskGrid::Ptr& previous)
{
    return regionOf(topologies, settings, reach, domain, steps, previous);
}

openvdb::MaskGrid::Ptr buildActiveRegionOfFolded(const std::vector<const openvdb::FloatGrid*>& folded,
                                                 const RegionSettings& settings, int reach, const Domain& domain,
                                                 int steps, const openvdb::MaskGrid::Ptr& previous, RegionEdit* edit)
{
    if (edit) *edit = RegionEdit{};
    if (previous && !plane::isFolded(*previous)) throw std::logic_error("buildActiveRegionOfFolded: a plane-layout previous region");
    if (!settings.dense && domain.flat() && !anyActiveTile(folded)) {
        const int iterations = std::max(1, steps) * (reach + settings.frontTravel);
        const bool hex = domain.lattice().kind() == LatticeKind::Hexagonal;
        if (auto r = planeRegionByLeaves(folded, iterations, hex, domain, previous, true, edit)) return r;
    }
    // dense, a reach beyond the leaf-level path, or active tiles: the plane-layout region, folded
    std::vector<openvdb::MaskGrid::Ptr> held;
    std::vector<const openvdb::MaskGrid*> topologies;
    if (!settings.dense) // the whole support: the fields are not read
        for (const auto* f : folded) {
            held.push_back(plane::unfoldTopology(*f));
            topologies.push_back(held.back().get());
        }
    auto region = plane::foldTopology(*regionOf(topologies, settings, reach, domain, steps, nullptr));
    if (previous && region->tree().hasSameTopology(previous->tree())) return previous;
    return region;
}

bool growActiveRegion(openvdb::MaskGrid& region, const std::vector<openvdb::Coord>& cells, int radius,
                      const Domain& domain)
{
    if (cells.empty()) return false;
    const openvdb::CoordBBox& dom = domain.bbox();
    const bool flat = domain.flat();
    const bool folded = plane::isFolded(region); // then a plane leaf is in when its chunk has a cell
    openvdb::tree::ValueAccessor<const openvdb::MaskTree> racc(region.tree());
    auto inRegion = [&](const openvdb::Coord& o) {
        if (!folded) return racc.probeConstLeaf(o) != nullptr;
        const MaskLeaf* fl = racc.probeConstLeaf(plane::foldedLeafOrigin(o));
        return fl && plane::chunkRows(fl->getValueMask(), (o.x() >> 3) & 7) != 0;
    };
    openvdb::MaskTree added(false);
    openvdb::tree::ValueAccessor<openvdb::MaskTree> aacc(added);
    const int m = ~(kLeafDim - 1);
    for (const openvdb::Coord& c : cells) {
        const openvdb::Coord r(radius, radius, flat ? 0 : radius);
        openvdb::CoordBBox box(c - r, c + r);
        box.intersect(dom);
        if (box.empty()) continue;
        for (int x = box.min().x() & m; x <= box.max().x(); x += kLeafDim)
            for (int y = box.min().y() & m; y <= box.max().y(); y += kLeafDim)
                for (int z = box.min().z() & m; z <= box.max().z(); z += kLeafDim) {
                    const openvdb::Coord o(x, y, z);
                    if (!aacc.probeConstLeaf(o) && !inRegion(o)) aacc.touchLeaf(o);
                }
    }
    if (added.leafCount() == 0) return false;
    fillLeaves(added, domain); // whole leaves, as the rebuild makes them
    domain.clipToSupport(added);
    if (added.leafCount() == 0) return false;
    if (folded) plane::foldLeavesInto(region.tree(), added);
    else region.tree().topologyUnion(added);
    return true;
}

bool regionFillsDomain(const openvdb::MaskGrid& region, const Domain& domain)
{
    return region.tree().activeVoxelCount() == domain.voxelCount();
}

namespace {

/// The origins of the leaves of @a tree that @a other does not have, in @a tree's leaf order,
/// looked up in parallel (a serial walk over both trees was most of matchTopology).
template <typename TreeT, typename OtherT>
std::vector<openvdb::Coord> leavesMissingFrom(const TreeT& tree, const OtherT& other)
{
    openvdb::tree::LeafManager<const TreeT> leaves(tree);
    std::vector<uint8_t> missing(leaves.leafCount(), 0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, leaves.leafCount(), 512), [&](const tbb::blocked_range<size_t>& r) {
        const openvdb::tree::ValueAccessor<const OtherT, /*IsSafe=*/false> acc(other); // neither tree changes here
        for (size_t i = r.begin(); i != r.end(); ++i) missing[i] = acc.probeConstLeaf(leaves.leaf(i).origin()) == nullptr;
    });
    std::vector<openvdb::Coord> out;
    for (size_t i = 0; i < missing.size(); ++i)
        if (missing[i]) out.push_back(leaves.leaf(i).origin());
    return out;
}

} // namespace

void matchTopology(openvdb::FloatGrid& grid, const openvdb::MaskGrid& region, bool offHoldsBackground)
{
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    auto& tree = grid.tree();
    const float bg = grid.background();
    // Leaves the region no longer has (found in parallel; only the changes are serial).
    for (const auto& o : leavesMissingFrom(tree, region.tree())) delete tree.stealNode<FloatLeaf>(o, bg, false);
    // Tiles are not expected (kernels write leaves); a tile would hide voxels, so voxelize
    // (looking first: the voxelize pass visits every internal node).
    if (anyActiveTile(std::vector<const openvdb::FloatGrid*>{&grid})) tree.voxelizeActiveTiles();
    // Leaves it gains (added serially: topology changes), then masks and background values in parallel.
    {
        openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(tree);
        for (const auto& o : leavesMissingFrom(region.tree(), tree)) acc.touchLeaf(o);
    }
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(tree);
    leaves.foreach([&](FloatLeaf& leaf, size_t) {
        // the tree itself, not an accessor per leaf (registering one costs more than the lookup)
        const MaskLeaf* m = region.tree().probeConstLeaf(leaf.origin());
        const auto& want = m->getValueMask();
        if (leaf.getValueMask() == want) return; // off voxels already hold the background
        // Word by word; when off voxels are known to hold the background, only the voxels that
        // leave the region are written (a plane leaf's other 448 are never touched).
        float* v = leaf.buffer().data();
        for (openvdb::Index w = 0; w < MaskLeaf::NodeMaskType::WORD_COUNT; ++w) {
            uint64_t bits = ~want.template getWord<uint64_t>(w);
            if (offHoldsBackground) bits &= leaf.getValueMask().template getWord<uint64_t>(w);
            for (; bits; bits &= bits - 1) v[w * 64 + openvdb::Index(__builtin_ctzll(bits))] = bg;
        }
        leaf.setValueMask(want);
    });
}

namespace {
inline uint64_t mix64(uint64_t x)
{
    x ^= x >> 33;
    x *= 0xff51afd7ed558ccdull;
    x ^= x >> 33;
    x *= 0xc4ceb9fe1a85ec53ull;
    x ^= x >> 33;
    return x;
}
} // namespace

uint64_t gridFingerprint(const openvdb::FloatGrid& grid)
{
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    openvdb::tree::LeafManager<const openvdb::FloatTree> leaves(grid.tree());
    std::atomic<uint64_t> sum{0};
    leaves.foreach([&](const FloatLeaf& leaf, size_t) {
        const openvdb::Coord o = leaf.origin();
        uint64_t h = (uint64_t(uint32_t(o.x())) << 32) ^ (uint64_t(uint32_t(o.y())) << 16) ^ uint32_t(o.z());
        const auto& mask = leaf.getValueMask();
        const float* v = leaf.buffer().data();
        // A sum of (offset, value bits) products over the active voxels plus the mask words:
        // independent terms, so the loop runs at memory speed; changing one value or one mask
        // bit changes the sum. Mixed once per leaf.
        constexpr uint64_t kOdd = 0x9e3779b97f4a7c15ull;
        for (openvdb::Index w = 0; w < FloatLeaf::NodeMaskType::WORD_COUNT; ++w) {
            uint64_t word = mask.template getWord<uint64_t>(w);
            h += mix64(word + w);
            while (word) {
                const openvdb::Index n = w * 64 + openvdb::Index(__builtin_ctzll(word));
                word &= word - 1;
                uint32_t bits;
                std::memcpy(&bits, v + n, 4);
                h += ((uint64_t(n) << 32) | bits) * kOdd;
            }
        }
        h = mix64(h);
        sum.fetch_add(h, std::memory_order_relaxed); // a sum: the same whatever the order
    });
    uint32_t bgBits;
    const float bg = grid.background();
    std::memcpy(&bgBits, &bg, 4);
    return sum.load() + mix64(bgBits) + grid.tree().leafCount();
}

int RegionCadence::automaticSteps(bool forced) const
{
    if (forced) return 1;
    const int perStep = std::max(1, mReach + mSettings.frontTravel);
    return std::max(1, int(MaskLeaf::DIM) / perStep);
}

int RegionCadence::begin(bool forced)
{
    const int k = mSettings.dense ? RegionCadence::kFullDomainSteps
                : mSettings.rebuildEvery > 0 ? mSettings.rebuildEvery
                                             : automaticSteps(forced);
    mLeft = k;
    return k;
}

void RegionCadence::filledDomain()
{
    if (mSettings.rebuildEvery == 0) mLeft = std::max(mLeft, kFullDomainSteps);
}

bool truncateToTolerance(openvdb::FloatGrid& grid, double tolerance)
{
    std::atomic<bool> changed{false};
    const float bg = grid.background();
    const float tol = float(tolerance);
    std::atomic<bool> emptied{false};
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(grid.tree());
    // Word by word over the value mask: most voxels stay on, so only the ones to switch off are
    // touched (the per-voxel iterator was the truncation's cost).
    leaves.foreach([bg, tol, &emptied, &changed](openvdb::FloatTree::LeafNodeType& leaf, size_t) {
        auto& mask = leaf.getValueMask();
        float* v = leaf.buffer().data();
        bool any = false;
        for (openvdb::Index w = 0; w < openvdb::FloatTree::LeafNodeType::NodeMaskType::WORD_COUNT; ++w) {
            uint64_t& word = mask.template getWord<uint64_t>(w);
            uint64_t bits = word, off = 0;
            while (bits) {
                const int b = __builtin_ctzll(bits);
                bits &= bits - 1;
                float& x = v[w * 64 + b];
                if (std::fabs(x - bg) <= tol) { x = bg; off |= uint64_t(1) << b; }
            }
            word &= ~off;
            any = any || word;
            if (off) changed = true;
        }
        if (!any) emptied = true;
    });
    if (emptied) openvdb::tools::pruneInactive(grid.tree());
    return changed;
}

} // namespace frostvdb
