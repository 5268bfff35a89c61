// The band-limited MAC stable fluid in 2D/3D (see fluid/SparseFluid.h). Every loop writes its own
// faces or cells only and the pressure solve is deterministic, so a step gives the same bits at
// any thread count.
#include <frostvdb/core/Stopwatch.h>
#include <frostvdb/fluid/SparseFluid.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace frostvdb {
namespace fluid {

namespace {

using Clock = SteadyClock;

/// f(i, j, k) over a box, rows (j, k) in parallel.
template <typename F>
void forBox(const openvdb::Coord& d, const F& f)
{
    const int rows = d.y() * d.z();
    tbb::parallel_for(tbb::blocked_range<int>(0, rows, std::max(1, 4096 / std::max(1, d.x()))),
                      [&](const tbb::blocked_range<int>& r) {
                          for (int row = r.begin(); row != r.end(); ++row) {
                              const int j = row % d.y(), k = row / d.y();
                              for (int i = 0; i < d.x(); ++i) f(i, j, k);
                          }
                      });
}

/// f(t) for t in [0, n), in parallel (each t writes its own entries only).
template <typename F>
void forList(size_t n, const F& f)
{
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t t = r.begin(); t != r.end(); ++t) f(t);
    });
}

/// Clamped (zero-gradient) cell and weight of coordinate @a y on an axis of @a d samples.
inline void clampAxis(double y, int d, int& i0, double& t)
{
    y = std::min(std::max(y, 0.0), double(d - 1));
    i0 = std::min(int(y), d - 2);
    t = y - i0;
}

/// What a staggered field is read through: the box, and either the block table (entries
/// slot << logVol | local) or, for a dense store, the row and plane strides of the (n + 1) box.
struct Layout {
    openvdb::Coord n;
    int dim;
    openvdb::Coord blocks;
    const int32_t* slot;
    int logVol;
    int64_t sy, sz; ///< dense strides (0: blocked)
    int64_t slotOf(int i, int j, int k) const
    {
        return slot[(size_t(k >> 3) * blocks.y() + size_t(j >> 3)) * blocks.x() + size_t(i >> 3)];
    }
    static size_t local(int i, int j, int k) { return size_t((i & 7) | (j & 7) << 3 | (k & 7) << 6); }
    /// Entry of (i, j, k), or -1 if in no allocated block.
    int64_t entry(int i, int j, int k) const
    {
        if (sy) return i + j * sy + k * sz;
        const int64_t s = slotOf(i, j, k);
        return s < 0 ? -1 : int64_t((size_t(s) << logVol) | local(i, j, k));
    }
};

/// The value of face (c, i, j, k) in no allocated block: the free stream, 0 on a wall side.
struct FaceBackground {
    openvdb::Coord n;
    int flowAxis, profileAxis;
    double sign, speed;
    Profile profile;
    bool wall[6];
    double stream(int c, int i, int j, int k) const
    {
        if (c != flowAxis) return 0.0;
        const int pos[3] = {i, j, k};
        const double s = std::min(1.0, std::max(0.0, (pos[profileAxis] + 0.5) / n[profileAxis]));
        switch (profile) {
        case Profile::Uniform: return sign * speed;
        case Profile::Linear: return sign * s * speed;
        case Profile::Quadratic: return sign * s * s * speed;
        case Profile::Parabolic: return sign * 4.0 * s * (1.0 - s) * speed;
        }
        return sign * speed;
    }
    double operator()(int c, int i, int j, int k) const
    {
        const int q = c == 0 ? i : c == 1 ? j : k;
        if ((q == 0 && wall[2 * c]) || (q == n[c] && wall[2 * c + 1])) return 0.0;
        return stream(c, i, j, k);
    }
};

/// Component c (c < 0: cell-centred) of the blocked field @a f at x (cell coordinates):
/// tri/bilinear, clamped to the field's box (zero gradient); corners in no allocated block are
/// @a outside(c, i, j, k). @a lo and @a hi, if given, receive the range of the corners used.
template <typename Outside>
__attribute__((always_inline)) inline double sampleArray(const Layout& L, const std::vector<double>& f, int c, const openvdb::Vec3d& x,
                          const Outside& outside, double* lo, double* hi)
{
    // Component c sits at x - e_c / 2.
    const int dx = L.n.x() + (c == 0), dy = L.n.y() + (c == 1);
    int i, j, k = 0;
    double tx, ty, tz = 0;
    clampAxis(x[0] + (c == 0 ? 0.5 : 0.0), dx, i, tx);
    clampAxis(x[1] + (c == 1 ? 0.5 : 0.0), dy, j, ty);
    const bool z2 = L.dim == 3;
    if (z2) clampAxis(x[2] + (c == 2 ? 0.5 : 0.0), L.n.z() + (c == 2), k, tz);
    double v[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    if (L.sy) {
        // Dense store: the box's strides.
        const double* p = f.data() + (i + j * L.sy + k * L.sz);
        const int64_t y = L.sy, z = L.sz;
        v[0] = p[0], v[1] = p[1], v[2] = p[y], v[3] = p[y + 1];
        if (z2) v[4] = p[z], v[5] = p[z + 1], v[6] = p[z + y], v[7] = p[z + y + 1];
    } else if (const int64_t s = L.slotOf(i, j, k); s >= 0 && (i & 7) != 7 && (j & 7) != 7 && (!z2 || (k & 7) != 7)) {
        // The whole stencil in one block: strides 1, 8, 64.
        const double* p = f.data() + (size_t(s) << L.logVol) + Layout::local(i, j, k);
        v[0] = p[0], v[1] = p[1], v[2] = p[8], v[3] = p[9];
        if (z2) v[4] = p[64], v[5] = p[65], v[6] = p[72], v[7] = p[73];
    } else {
        // The stencil crosses into neighbouring blocks (or lies in none): one table read per
        // corner, the block steps found once per axis.
        const size_t bx = size_t(L.blocks.x()), bxy = bx * size_t(L.blocks.y());
        const size_t base = size_t(k >> 3) * bxy + size_t(j >> 3) * bx + size_t(i >> 3);
        const size_t step[3] = {size_t((i & 7) == 7), size_t((j & 7) == 7) * bx, size_t(z2 && (k & 7) == 7) * bxy};
        const size_t lx[2] = {size_t(i & 7), size_t((i + 1) & 7)}, ly[2] = {size_t(j & 7) << 3, size_t((j + 1) & 7) << 3},
                     lz[2] = {size_t(k & 7) << 6, size_t((k + 1) & 7) << 6};
        auto at = [&](int a, int b, int e) {
            const int64_t t = L.slot[base + (a ? step[0] : 0) + (b ? step[1] : 0) + (e ? step[2] : 0)];
            return t >= 0 ? f[(size_t(t) << L.logVol) | (lx[a] | ly[b] | lz[e])] : outside(c, i + a, j + b, k + e);
        };
        v[0] = at(0, 0, 0), v[1] = at(1, 0, 0), v[2] = at(0, 1, 0), v[3] = at(1, 1, 0);
        if (z2) v[4] = at(0, 0, 1), v[5] = at(1, 0, 1), v[6] = at(0, 1, 1), v[7] = at(1, 1, 1);
    }
    auto lerp = [](double a, double b, double t) { return a + t * (b - a); };
    const double a0 = lerp(lerp(v[0], v[1], tx), lerp(v[2], v[3], tx), ty);
    if (!z2) {
        if (lo) {
            *lo = std::min(std::min(v[0], v[1]), std::min(v[2], v[3]));
            *hi = std::max(std::max(v[0], v[1]), std::max(v[2], v[3]));
        }
        return a0;
    }
    if (lo) {
        *lo = std::min(std::min(std::min(v[0], v[1]), std::min(v[2], v[3])), std::min(std::min(v[4], v[5]), std::min(v[6], v[7])));
        *hi = std::max(std::max(std::max(v[0], v[1]), std::max(v[2], v[3])), std::max(std::max(v[4], v[5]), std::max(v[6], v[7])));
    }
    const double a1 = lerp(lerp(v[4], v[5], tx), lerp(v[6], v[7], tx), ty);
    return lerp(a0, a1, tz);
}

inline openvdb::Vec3d velocityAt(const Layout& L, const std::array<std::vector<double>, 3>& u, const FaceBackground& bg,
                                 const openvdb::Vec3d& x)
{
    openvdb::Vec3d v(0.0);
    for (int c = 0; c < L.dim; ++c) v[c] = sampleArray(L, u[size_t(c)], c, x, bg, nullptr, nullptr);
    return v;
}

/// Face (c; i, j, k) of the blocked field @a f (the background if in no block).
inline double faceAt(const Layout& L, const std::vector<double>& f, int c, int i, int j, int k, const FaceBackground& bg)
{
    const int64_t e = L.entry(i, j, k);
    return e >= 0 ? f[size_t(e)] : bg(c, i, j, k);
}

/// The velocity at face (C; q), as the clamped trilinear sample gives it but with only the taps
/// that carry weight: component C is the face itself; another component c2 is the mean of its
/// four faces around (cells q - 1 and q along C, clamped to the box; faces q and q + 1 along c2).
/// C is a template argument so that every index is fixed at compile time.
template <int C>
inline openvdb::Vec3d velocityAtFaceT(const Layout& L, const std::array<std::vector<double>, 3>& u,
                                      const FaceBackground& bg, const int q[3])
{
    openvdb::Vec3d v(0.0);
    v[C] = faceAt(L, u[C], C, q[0], q[1], q[2], bg);
    const int lo = std::max(q[C] - 1, 0), hi = std::min(q[C], L.n[C] - 1);
    for (int c2 = 0; c2 < L.dim; ++c2) {
        if (c2 == C) continue;
        int a[3] = {q[0], q[1], q[2]}, b[3] = {q[0], q[1], q[2]};
        a[C] = lo;
        b[C] = hi;
        const auto& f = u[size_t(c2)];
        const double s0 = faceAt(L, f, c2, a[0], a[1], a[2], bg) + faceAt(L, f, c2, b[0], b[1], b[2], bg);
        const int e0 = c2 == 0, e1 = c2 == 1, e2 = c2 == 2;
        const double s1 = faceAt(L, f, c2, a[0] + e0, a[1] + e1, a[2] + e2, bg) + faceAt(L, f, c2, b[0] + e0, b[1] + e1, b[2] + e2, bg);
        v[c2] = 0.25 * (s0 + s1);
    }
    return v;
}

inline openvdb::Vec3d velocityAtFace(const Layout& L, const std::array<std::vector<double>, 3>& u, const FaceBackground& bg,
                                     int c, const openvdb::Coord& q)
{
    const int qi[3] = {q.x(), q.y(), q.z()};
    return c == 0 ? velocityAtFaceT<0>(L, u, bg, qi) : c == 1 ? velocityAtFaceT<1>(L, u, bg, qi) : velocityAtFaceT<2>(L, u, bg, qi);
}

/// The velocity at the centre of cell q: per component the mean of its two faces.
inline openvdb::Vec3d velocityAtCell(const Layout& L, const std::array<std::vector<double>, 3>& u, const FaceBackground& bg,
                                     const openvdb::Coord& q)
{
    openvdb::Vec3d v(0.0);
    for (int c = 0; c < L.dim; ++c)
        v[c] = 0.5 * (faceAt(L, u[size_t(c)], c, q.x(), q.y(), q.z(), bg) +
                      faceAt(L, u[size_t(c)], c, q.x() + (c == 0), q.y() + (c == 1), q.z() + (c == 2), bg));
    return v;
}

/// Second-order Runge-Kutta (midpoint) trace from x, whose velocity @a v0 is given, back through
/// @a u over dt; dt < 0 traces forward.
inline openvdb::Vec3d backtrace(const Layout& L, const std::array<std::vector<double>, 3>& u, const FaceBackground& bg,
                                const openvdb::Vec3d& x, const openvdb::Vec3d& v0, double dt)
{
    const openvdb::Vec3d mid = x - 0.5 * dt * v0;
    return x - dt * velocityAt(L, u, bg, mid);
}

/// out[x] = any(in[x + lo .. x + hi]) along @a axis, per line, clipped to the box.
std::vector<uint8_t> dilateAlong(const std::vector<uint8_t>& in, const openvdb::Coord& n, int axis, int lo, int hi)
{
    std::vector<uint8_t> out(in.size(), 0);
    const int len = n[axis];
    const size_t stride = axis == 0 ? 1 : axis == 1 ? size_t(n.x()) : size_t(n.x()) * n.y();
    const openvdb::Coord lines(axis == 0 ? 1 : n.x(), axis == 1 ? 1 : n.y(), axis == 2 ? 1 : n.z());
    forBox(lines, [&](int i, int j, int k) {
        const size_t base = (size_t(k) * n.y() + j) * n.x() + i;
        std::vector<int> prefix(size_t(len) + 1, 0);
        for (int t = 0; t < len; ++t) prefix[size_t(t) + 1] = prefix[size_t(t)] + in[base + t * stride];
        for (int t = 0; t < len; ++t) {
            const int a = std::max(0, t + lo), b = std::min(len - 1, t + hi);
            if (a <= b && prefix[size_t(b) + 1] - prefix[size_t(a)] > 0) out[base + t * stride] = 1;
        }
    });
    return out;
}

} // namespace

SparseFluid::SparseFluid(const SparseFluidParams& params, const openvdb::Coord& dims, int dim)
    : mP(params), mN(std::max(2, dims.x()), std::max(2, dims.y()), dim == 3 ? std::max(2, dims.z()) : 1), mDim(dim)
{
    if (dim != 2 && dim != 3) throw std::invalid_argument("SparseFluid: dim must be 2 or 3");
    if (mP.inflowSide < 0 || mP.inflowSide >= 2 * dim) throw std::invalid_argument("SparseFluid: inflow side out of range");
    if (double(mN.x() + 1) * (mN.y() + 1) * (mN.z() + 1) >= 2.0e9)
        throw std::invalid_argument("SparseFluid: box too large (face lists are 32-bit)");
    for (int s = 0; s < 6; ++s)
        mSide[size_t(s)] = mP.sides[size_t(s)] < 0 ? mP.lateral : mP.sides[size_t(s)] == 1 ? SideKind::Wall : SideKind::Outflow;
    mSide[size_t(mP.inflowSide)] = SideKind::Inflow;
    mSide[size_t(mP.inflowSide ^ 1)] = SideKind::Outflow;
    // Blocks cover the faces (n + 1 along each axis).
    mBlocks = openvdb::Coord((mN.x() + 8) >> 3, (mN.y() + 8) >> 3, dim == 3 ? (mN.z() + 8) >> 3 : 1);
    mLogVol = dim == 3 ? 9 : 6;
    mSlot.assign(size_t(mBlocks.x()) * mBlocks.y() * mBlocks.z(), -1);
    mSolid.assign(size_t(mN.x()) * mN.y() * mN.z(), 0);
    mCell.assign(mSolid.size(), kInactiveCell);
    updateBand();
}

namespace {
FaceBackground backgroundOf(const SparseFluidParams& p, const openvdb::Coord& n, int dim, const std::array<SideKind, 6>& side)
{
    FaceBackground bg;
    bg.n = n;
    bg.flowAxis = p.inflowSide / 2;
    int pa = p.profileAxis;
    if (pa < 0 || pa >= dim || pa == bg.flowAxis) pa = bg.flowAxis == 0 ? 1 : 0;
    bg.profileAxis = pa;
    bg.sign = (p.inflowSide & 1) ? -1.0 : 1.0;
    bg.speed = p.inflowSpeed;
    bg.profile = p.profile;
    for (int s = 0; s < 6; ++s) bg.wall[s] = side[size_t(s)] == SideKind::Wall;
    return bg;
}
} // namespace

double SparseFluid::freeStream(int c, double i, double j, double k) const
{
    const int a = mP.inflowSide / 2;
    if (c != a) return 0.0;
    const double sign = (mP.inflowSide & 1) ? -1.0 : 1.0;
    int pa = mP.profileAxis;
    if (pa < 0 || pa >= mDim || pa == a) pa = a == 0 ? 1 : 0;
    const double pos[3] = {i, j, k};
    const double s = std::min(1.0, std::max(0.0, (pos[pa] + 0.5) / mN[pa]));
    const double U = mP.inflowSpeed;
    switch (mP.profile) {
    case Profile::Uniform: return sign * U;
    case Profile::Linear: return sign * s * U;
    case Profile::Quadratic: return sign * s * s * U;
    case Profile::Parabolic: return sign * 4.0 * s * (1.0 - s) * U;
    }
    return sign * U;
}

double SparseFluid::background(int c, int i, int j, int k) const
{
    return backgroundOf(mP, mN, mDim, mSide)(c, i, j, k);
}

double SparseFluid::face(int c, int i, int j, int k) const
{
    const int64_t e = entryOf(i, j, k);
    return e >= 0 ? mU[size_t(c)][size_t(e)] : background(c, i, j, k);
}

bool SparseFluid::faceFixed(int c, int i, int j, int k, double& value) const
{
    const int q = c == 0 ? i : c == 1 ? j : k;
    const bool hasLo = q > 0, hasHi = q < mN[c];
    const int li = i - (c == 0), lj = j - (c == 1), lk = k - (c == 2);
    const uint8_t lo = hasLo ? mCell[cellIndex(li, lj, lk)] : kInactiveCell;
    const uint8_t hi = hasHi ? mCell[cellIndex(i, j, k)] : kInactiveCell;
    if (lo == kSolidCell || hi == kSolidCell) { value = 0; return true; }
    if (!hasLo || !hasHi) {
        switch (mSide[size_t(2 * c + (hasLo ? 1 : 0))]) {
        case SideKind::Inflow: value = freeStream(c, i, j, k); return true;
        case SideKind::Wall: value = 0; return true;
        case SideKind::Outflow:
            if ((hasLo ? lo : hi) == kInactiveCell) { value = freeStream(c, i, j, k); return true; }
            return false;
        }
    }
    if (lo == kInactiveCell && hi == kInactiveCell) { value = freeStream(c, i, j, k); return true; }
    return false;
}

/// f(i, j, k, entry) for every face (or cell) inside the box @a d in the block at @a o (x fastest).
template <typename F>
static inline void forBlockFaces(const openvdb::Coord& o, const openvdb::Coord& d, const Layout& L, const F& f)
{
    const int kEnd = L.dim == 3 ? 8 : 1;
    for (int dk = 0; dk < kEnd; ++dk) {
        const int k = o.z() + dk;
        if (k >= d.z()) break;
        for (int dj = 0; dj < 8; ++dj) {
            const int j = o.y() + dj;
            if (j >= d.y()) break;
            for (int di = 0; di < 8; ++di) {
                const int i = o.x() + di;
                if (i >= d.x()) break;
                f(i, j, k, uint32_t(L.entry(i, j, k)));
            }
        }
    }
}

void SparseFluid::applyBoundaries()
{
    const Layout L{mN, mDim, mBlocks, mSlot.data(), mLogVol, mDenseY, mDenseZ};
    for (int c = 0; c < mDim; ++c) {
        auto& u = mU[size_t(c)];
        const openvdb::Coord d = faceDims(c);
        forList(mBlockOrigin.size(), [&](size_t b) {
            forBlockFaces(mBlockOrigin[b], d, L, [&](int i, int j, int k, uint32_t e) {
                double v;
                if (faceFixed(c, i, j, k, v)) u[e] = v;
            });
        });
    }
}

void SparseFluid::allocateBlocks()
{
    // A block is allocated if any face in it touches a band or solid cell: cells 8b - 1 .. 8b + 7
    // along each axis (face q lies between cells q - 1 and q).
    const size_t nb = mSlot.size();
    std::vector<uint8_t> need(nb, 0);
    forList(nb, [&](size_t b) {
        const int bx = int(b % size_t(mBlocks.x())), by = int((b / size_t(mBlocks.x())) % size_t(mBlocks.y())),
                  bz = int(b / (size_t(mBlocks.x()) * mBlocks.y()));
        const int i0 = std::max(0, 8 * bx - 1), i1 = std::min(mN.x() - 1, 8 * bx + 7);
        const int j0 = std::max(0, 8 * by - 1), j1 = std::min(mN.y() - 1, 8 * by + 7);
        const int k0 = mDim == 3 ? std::max(0, 8 * bz - 1) : 0, k1 = mDim == 3 ? std::min(mN.z() - 1, 8 * bz + 7) : 0;
        for (int k = k0; k <= k1; ++k)
            for (int j = j0; j <= j1; ++j)
                for (int i = i0; i <= i1; ++i)
                    if (mCell[cellIndex(i, j, k)] != kInactiveCell) { need[b] = 1; return; }
    });
    // Where the band covers most of the box, one array over the (n + 1) box is smaller than the
    // blocks (and its samples need no table): store the faces densely then.
    size_t needed = 0;
    for (uint8_t x : need) needed += x;
    const int64_t sy = mN.x() + 1, sz = mDim == 3 ? sy * (mN.y() + 1) : 0;
    const size_t denseSize = size_t(mDim == 3 ? sz * (mN.z() + 1) : sy * (mN.y() + 1));
    const bool dense = double(needed << mLogVol) >= 0.7 * double(denseSize);
    std::vector<int32_t> slot(nb, -1);
    std::vector<openvdb::Coord> origin;
    for (size_t b = 0; b < nb; ++b)
        if (need[b] || dense) {
            slot[b] = int32_t(origin.size());
            origin.emplace_back(int(b % size_t(mBlocks.x())) * 8, int((b / size_t(mBlocks.x())) % size_t(mBlocks.y())) * 8,
                                int(b / (size_t(mBlocks.x()) * mBlocks.y())) * 8);
        }
    // Faces that were stored keep their values; the others start at the background (what the
    // fixed faces there held); applyBoundaries then writes the fixed faces of the new band.
    const Layout before{mN, mDim, mBlocks, mSlot.data(), mLogVol, mDenseY, mDenseZ};
    const Layout after{mN, mDim, mBlocks, slot.data(), mLogVol, dense ? sy : 0, dense ? sz : 0};
    const size_t size = dense ? denseSize : origin.size() << mLogVol;
    const openvdb::Coord faceBox = mN + openvdb::Coord(1, 1, mDim == 3 ? 1 : 0);
    const FaceBackground bg = backgroundOf(mP, mN, mDim, mSide);
    for (int c = 0; c < mDim; ++c) {
        std::vector<double> u(size, 0.0);
        const auto& old = mU[size_t(c)];
        forList(origin.size(), [&](size_t b) {
            forBlockFaces(origin[b], faceBox, after, [&](int i, int j, int k, uint32_t e) {
                const int64_t o = old.empty() ? -1 : before.entry(i, j, k);
                u[e] = o >= 0 ? old[size_t(o)] : bg(c, i, j, k);
            });
        });
        mU[size_t(c)].swap(u);
        mFwd[size_t(c)].clear();
        mFwd[size_t(c)].shrink_to_fit();
    }
    mSlot.swap(slot);
    mBlockOrigin.swap(origin);
    mDenseY = dense ? sy : 0;
    mDenseZ = dense ? sz : 0;
}

size_t SparseFluid::faceBytes() const
{
    return size_t(mDim) * 2 * mU[0].size() * sizeof(double);
}

size_t SparseFluid::boxBytes() const
{
    const size_t cells = mSolid.size() + mCell.size() + mSlot.size() * sizeof(int32_t);
    // The multigrid's fine padded index over the band's bounding box (4 bytes per cell) and its
    // coarse levels (an eighth each).
    const openvdb::Coord& d = mPoissonDims;
    const double padded = double(d.x() + 2) * (d.y() + 2) * (mDim == 3 ? d.z() + 2 : 1);
    return cells + size_t(4.0 * padded * (mDim == 3 ? 8.0 / 7.0 : 4.0 / 3.0));
}

void SparseFluid::updateBand()
{
    std::vector<uint8_t> act;
    if (mP.bandWidth <= 0) {
        act.assign(mSolid.size(), 1);
    } else {
        const int w = int(std::ceil(mP.bandWidth));
        act = mSolid;
        for (int a = 0; a < mDim; ++a) act = dilateAlong(act, mN, a, -w, w);
        const int flow = mP.inflowSide / 2, L = int(std::ceil(std::max(0.0, mP.wakeLength)));
        // Downstream of a band cell is band too: look upstream by up to L cells.
        act = (mP.inflowSide & 1) ? dilateAlong(act, mN, flow, 0, L) : dilateAlong(act, mN, flow, -L, 0);
    }
    // act becomes the cell kinds in place (no second box array); the band's bounding box too.
    size_t count = 0;
    openvdb::CoordBBox bbox;
    for (int k = 0; k < mN.z(); ++k)
        for (int j = 0; j < mN.y(); ++j) {
            int lo = -1, hi = -1;
            for (int i = 0; i < mN.x(); ++i) {
                const size_t x = cellIndex(i, j, k);
                act[x] = mSolid[x] ? kSolidCell : act[x] ? kFluidCell : kInactiveCell;
                count += act[x] == kFluidCell;
                if (act[x] != kInactiveCell) {
                    if (lo < 0) lo = i;
                    hi = i;
                }
            }
            if (lo >= 0) {
                bbox.expand(openvdb::Coord(lo, j, k));
                bbox.expand(openvdb::Coord(hi, j, k));
            }
        }
    if (bbox.empty()) bbox = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(0));
    if (mPoisson && act == mCell) return;
    mCell.swap(act);
    act = std::vector<uint8_t>();
    mActive = count;
    allocateBlocks();
    listActive();
    applyBoundaries(); // the fixed faces change only here (and in setFreeStream)
    // The pressure system lives on the band's bounding box: cells beyond it are inactive, so its
    // sides inside the domain are Dirichlet (p = 0) and the multigrid's box-sized index follows
    // the band's extent, not the domain's.
    std::unique_ptr<MultigridPoisson> old = std::move(mPoisson);
    const openvdb::Coord oldOrigin = mPoissonOrigin;
    std::vector<double> oldPressure = std::move(mPressure);
    const openvdb::Coord o = bbox.min(), dims = bbox.dim();
    std::array<bool, 6> dirichlet{};
    for (int a = 0; a < 3; ++a) {
        dirichlet[size_t(2 * a)] = bbox.min()[a] > 0 || mSide[size_t(2 * a)] == SideKind::Outflow;
        dirichlet[size_t(2 * a + 1)] = bbox.max()[a] < mN[a] - 1 || mSide[size_t(2 * a + 1)] == SideKind::Outflow;
    }
    mPoissonOrigin = o;
    mPoissonDims = dims;
    mPoisson = std::make_unique<MultigridPoisson>(
        mDim, dims,
        [this, o](int i, int j, int k) {
            const uint8_t c = mCell[cellIndex(i + o.x(), j + o.y(), k + o.z())];
            return c == kSolidCell ? CellKind::Solid : c == kFluidCell ? CellKind::Fluid : CellKind::Dirichlet;
        },
        dirichlet);
    // Keep the warm start where a cell stays an unknown (new cells start at 0).
    mPressure.assign(mPoisson->unknowns(), 0.0);
    if (old)
        for (size_t u = 0; u < mPressure.size(); ++u) {
            const openvdb::Coord c = mPoisson->cellOf(u) + o - oldOrigin;
            const int64_t v = old->unknownIndex(c.x(), c.y(), c.z());
            if (v >= 0) mPressure[u] = oldPressure[size_t(v)];
        }
}

void SparseFluid::listActive()
{
    // Per block, in parallel, then concatenated in block order (so the lists do not depend on the
    // thread count).
    const Layout L{mN, mDim, mBlocks, mSlot.data(), mLogVol, mDenseY, mDenseZ};
    auto build = [&](const openvdb::Coord& d, const auto& keep, std::vector<uint32_t>& out) {
        std::vector<std::vector<uint32_t>> perBlock(mBlockOrigin.size());
        forList(mBlockOrigin.size(), [&](size_t b) {
            forBlockFaces(mBlockOrigin[b], d, L, [&](int i, int j, int k, uint32_t e) {
                if (keep(i, j, k)) perBlock[b].push_back(e);
            });
        });
        size_t total = 0;
        for (auto& v : perBlock) total += v.size();
        out.clear();
        out.reserve(total);
        for (auto& v : perBlock) out.insert(out.end(), v.begin(), v.end());
    };
    for (int c = 0; c < mDim; ++c)
        build(faceDims(c), [&](int i, int j, int k) { double v; return !faceFixed(c, i, j, k, v); }, mFaces[size_t(c)]);
    build(mN, [&](int i, int j, int k) { return mCell[cellIndex(i, j, k)] == kFluidCell; }, mCells);
}

double SparseFluid::maxSpeed() const
{
    double m = 0;
    for (int c = 0; c < mDim; ++c)
        for (double v : mU[size_t(c)]) {
            if (!std::isfinite(v)) return std::numeric_limits<double>::quiet_NaN();
            m = std::max(m, std::fabs(v));
        }
    if (mBlockOrigin.size() < mSlot.size()) {
        // Faces in no block hold the free stream: its largest value along the profile.
        const FaceBackground bg = backgroundOf(mP, mN, mDim, mSide);
        const int a = bg.flowAxis, pa = bg.profileAxis;
        for (int q = 0; q < mN[pa]; ++q) {
            int pos[3] = {0, 0, 0};
            pos[pa] = q;
            m = std::max(m, std::fabs(bg.stream(a, pos[0], pos[1], pos[2])));
        }
    }
    return m;
}

void SparseFluid::setSolid(const std::function<bool(int, int, int)>& solid)
{
    forBox(mN, [&](int i, int j, int k) { mSolid[cellIndex(i, j, k)] = solid(i, j, k) ? 1 : 0; });
    updateBand();
}

void SparseFluid::setFreeStream()
{
    const Layout L{mN, mDim, mBlocks, mSlot.data(), mLogVol, mDenseY, mDenseZ};
    for (int c = 0; c < mDim; ++c) {
        auto& u = mU[size_t(c)];
        const openvdb::Coord d = faceDims(c);
        forList(mBlockOrigin.size(), [&](size_t b) {
            forBlockFaces(mBlockOrigin[b], d, L, [&](int i, int j, int k, uint32_t e) { u[e] = freeStream(c, i, j, k); });
        });
    }
    applyBoundaries();
}

openvdb::Vec3d SparseFluid::sample(const openvdb::Vec3d& x) const
{
    const Layout L{mN, mDim, mBlocks, mSlot.data(), mLogVol, mDenseY, mDenseZ};
    return velocityAt(L, mU, backgroundOf(mP, mN, mDim, mSide), x);
}

double SparseFluid::divergence(int i, int j, int k) const
{
    double d = 0;
    for (int c = 0; c < mDim; ++c)
        d += face(c, i + (c == 0), j + (c == 1), k + (c == 2)) - face(c, i, j, k);
    return d;
}

double SparseFluid::maxDivergence() const
{
    double m = 0;
    for (uint32_t e : mCells) {
        const openvdb::Coord q = entryCoord(e);
        m = std::max(m, std::fabs(divergence(q.x(), q.y(), q.z())));
    }
    return m;
}

void SparseFluid::project()
{
    // The fixed faces already hold their values (applyBoundaries runs when the band changes).
    // Every unknown is a listed fluid cell (a pocket's pinned cell is not an unknown).
    const MultigridPoisson::IndexView index = mPoisson->indexView();
    const openvdb::Coord po = mPoissonOrigin; // the multigrid's box starts here
    const Layout L{mN, mDim, mBlocks, mSlot.data(), mLogVol, mDenseY, mDenseZ};
    const FaceBackground bg = backgroundOf(mP, mN, mDim, mSide);
    mRhs.resize(mPoisson->unknowns());
    forList(mCells.size(), [&](size_t t) {
        const openvdb::Coord q = entryCoord(mCells[t]);
        const int64_t u = index.at(q.x() - po.x(), q.y() - po.y(), q.z() - po.z());
        if (u < 0) return;
        double d = 0;
        for (int c = 0; c < mDim; ++c)
            d += faceAt(L, mU[size_t(c)], c, q.x() + (c == 0), q.y() + (c == 1), q.z() + (c == 2), bg) -
                 faceAt(L, mU[size_t(c)], c, q.x(), q.y(), q.z(), bg);
        mRhs[size_t(u)] = -d;
    });
    mStats = mPoisson->solve(mRhs, mPressure, mP.poisson);
    // Faces reach one cell outside the box at most: the padded index answers there (not an unknown).
    auto p = [&](int i, int j, int k) {
        const int64_t u = index.at(i - po.x(), j - po.y(), k - po.z());
        return u >= 0 ? mPressure[size_t(u)] : 0.0;
    };
    for (int c = 0; c < mDim; ++c) {
        auto& u = mU[size_t(c)];
        const auto& faces = mFaces[size_t(c)];
        forList(faces.size(), [&](size_t t) {
            const openvdb::Coord q = entryCoord(faces[t]);
            u[faces[t]] -= p(q.x(), q.y(), q.z()) - p(q.x() - (c == 0), q.y() - (c == 1), q.z() - (c == 2));
        });
    }
}

void SparseFluid::step(double dt)
{
    auto t0 = Clock::now();
    // Only the listed (non-fixed) faces move; the fixed ones already hold their values.
    const bool mc = mP.advection == Advection::MacCormack;
    const Layout L{mN, mDim, mBlocks, mSlot.data(), mLogVol, mDenseY, mDenseZ};
    const FaceBackground bg = backgroundOf(mP, mN, mDim, mSide);
    for (int c = 0; c < mDim; ++c) {
        const auto& faces = mFaces[size_t(c)];
        const auto& u = mU[size_t(c)];
        auto& fwd = mFwd[size_t(c)];
        fwd = u; // reuses the buffer's capacity
        if (mc) {
            mLo.resize(std::max(mLo.size(), faces.size()));
            mHi.resize(mLo.size());
        }
        auto facePos = [&](const openvdb::Coord& q) {
            return openvdb::Vec3d(q.x() - 0.5 * (c == 0), q.y() - 0.5 * (c == 1), q.z() - 0.5 * (c == 2));
        };
        forList(faces.size(), [&](size_t t) {
            const openvdb::Coord q = entryCoord(faces[t]);
            const openvdb::Vec3d x = backtrace(L, mU, bg, facePos(q), velocityAtFace(L, mU, bg, c, q), dt);
            fwd[faces[t]] = sampleArray(L, u, c, x, bg, mc ? &mLo[t] : nullptr, mc ? &mHi[t] : nullptr);
        });
        if (!mc) continue;
        // MacCormack (Selle et al. 2008): trace the forward result back, correct by half the
        // round-trip error, and fall back to semi-Lagrangian where that leaves the bounds of the
        // cells sampled (so no new extrema, whatever the CFL number). The result goes to mLo[t]
        // (each face reads and writes only its own entry) and then into fwd.
        forList(faces.size(), [&](size_t t) {
            const uint32_t f = faces[t];
            const openvdb::Coord q = entryCoord(f);
            const openvdb::Vec3d x = backtrace(L, mU, bg, facePos(q), velocityAtFace(L, mU, bg, c, q), -dt);
            const double back = sampleArray(L, fwd, c, x, bg, nullptr, nullptr);
            const double corr = fwd[f] + 0.5 * (u[f] - back);
            mLo[t] = corr >= mLo[t] && corr <= mHi[t] ? corr : fwd[f];
        });
        forList(faces.size(), [&](size_t t) { fwd[faces[t]] = mLo[t]; });
    }
    for (int c = 0; c < mDim; ++c) mU[size_t(c)].swap(mFwd[size_t(c)]);
    advectSeconds += secondsSince(t0);
    t0 = Clock::now();
    project();
    projectSeconds += secondsSince(t0);
}

std::vector<SparseFluid::ScalarChange> SparseFluid::advectScalar(const openvdb::FloatGrid& grid,
                                                                 const openvdb::Coord& origin, double dt) const
{
    const bool mc = mP.advection == Advection::MacCormack;
    const Layout L{mN, mDim, mBlocks, mSlot.data(), mLogVol, mDenseY, mDenseZ};
    const FaceBackground bg = backgroundOf(mP, mN, mDim, mSide);
    const double gridBg = grid.background();
    const size_t n = mCells.size();
    // The scalar in the allocated blocks (the band and its edge); cells in no block are read from
    // the grid itself, through one accessor per chunk of work.
    auto read = [&](const openvdb::FloatGrid::ConstAccessor& acc, int i, int j, int k) {
        float v;
        return acc.probeValue(origin + openvdb::Coord(i, j, k), v) ? double(v) : gridBg;
    };
    auto& f = mScalar;
    f.assign(mU[0].size(), gridBg);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, mBlockOrigin.size(), 16), [&](const tbb::blocked_range<size_t>& r) {
        auto acc = grid.getConstAccessor();
        for (size_t b = r.begin(); b != r.end(); ++b)
            forBlockFaces(mBlockOrigin[b], mN, L, [&](int i, int j, int k, uint32_t e) { f[e] = read(acc, i, j, k); });
    });
    mScalarFwd = f;
    auto& fwd = mScalarFwd;
    if (mc) {
        mLo.resize(std::max(mLo.size(), n));
        mHi.resize(mLo.size());
    }
    auto chunks = [&](const auto& body) {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& r) {
            auto acc = grid.getConstAccessor();
            auto outside = [&](int, int i, int j, int k) { return read(acc, i, j, k); };
            for (size_t t = r.begin(); t != r.end(); ++t) body(t, outside);
        });
    };
    auto trace = [&](size_t t, double h) {
        const openvdb::Coord q = entryCoord(mCells[t]);
        return backtrace(L, mU, bg, q.asVec3d(), velocityAtCell(L, mU, bg, q), h);
    };
    chunks([&](size_t t, const auto& outside) {
        fwd[mCells[t]] = sampleArray(L, f, -1, trace(t, dt), outside, mc ? &mLo[t] : nullptr, mc ? &mHi[t] : nullptr);
    });
    if (mc) {
        // Outside the band fwd equals f, so the grid answers for it there too.
        chunks([&](size_t t, const auto& outside) {
            const uint32_t x = mCells[t];
            const double back = sampleArray(L, fwd, -1, trace(t, -dt), outside, nullptr, nullptr);
            const double corr = fwd[x] + 0.5 * (f[x] - back);
            mLo[t] = corr >= mLo[t] && corr <= mHi[t] ? corr : fwd[x];
        });
        forList(n, [&](size_t t) { fwd[mCells[t]] = mLo[t]; });
    }
    std::vector<ScalarChange> out;
    for (size_t t = 0; t < n; ++t) {
        const uint32_t x = mCells[t];
        if (fwd[x] != f[x]) out.push_back({entryCoord(x), fwd[x]});
    }
    return out;
}

} // namespace fluid
} // namespace frostvdb
