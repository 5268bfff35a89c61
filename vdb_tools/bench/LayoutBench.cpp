/// @file LayoutBench.cpp
/// @brief `frostvdb bench layout [n]`: the measurement behind the plane storage layout (issue 24).
/// A plane stored in OpenVDB's 8^3 leaves uses one z layer of each leaf: 64 floats of 512. Two
/// ways to store it densely are measured against that, on an n x n plane (default 2048) with
/// every voxel active, one thread, best of 5:
///  - today:  FloatGrid, voxel (x, y) at Coord(x, y, 0): leaf offset x*64 + y*8 (2 floats of 16
///            per cache line);
///  - fold:   FloatGrid, voxel (x, y) at Coord(y, x >> 3, x & 7): a leaf is a dense 64 x 8 tile
///            of the plane, offset (y & 7)*64 + (x & 63), rows of x contiguous;
///  - tiles:  a dense table of 64 x 64 float tiles (no tree), rows of x contiguous.
/// Per layout: bytes per voxel of one field; the engine's memory-bound work per voxel-step: the
/// gather of a 32 x 32 group's p and T with a halo of 2 (36 x 36 cells), the commit of the
/// group's new p and T, and a truncation-style scan of every active value; next to the
/// compute of the same group (the engine's row code, pass 1 + pass 2) and the vector dense loop.
#include <frostvdb/core/Bench.h>
#include <frostvdb/core/Domain.h>
#include <frostvdb/icephysics/EulerRows.h>
#include <frostvdb/ice/PhaseFieldSolver.h>

#include <openvdb/openvdb.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <array>
#include <memory>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <string>
#include <vector>

namespace frostvdb {
namespace {

using FloatLeaf = openvdb::FloatTree::LeafNodeType;
using Acc = openvdb::tree::ValueAccessor<const openvdb::FloatTree, false>;
constexpr int kGroup = 32, kHalo = 2, kB = kGroup + 2 * kHalo; // block side 36

double best(int reps, const std::function<void()>& f)
{
    double b = 1e30;
    for (int r = 0; r < reps; ++r) {
        const auto t0 = bench::Clock::now();
        f();
        b = std::min(b, bench::since(t0));
    }
    return b;
}

float valueAt(int x, int y, int n) // a smooth field with a front, deterministic
{
    const double r = std::hypot(x - 0.5 * n, y - 0.5 * n);
    return float(0.5 + 0.5 * std::tanh((0.3 * n - r) / 3.0));
}

/// The three layouts behind one interface: row reads and writes of the plane.
struct Layout {
    virtual ~Layout() = default;
    virtual const char* name() const = 0;
    virtual double bytes() const = 0;
    /// out[0 .. x1-x0) = plane row y over [x0, x1); cells outside the plane give @a bg.
    virtual void readRow(int y, int x0, int x1, float* out) const = 0;
    virtual void writeRow(int y, int x0, int x1, const float* in) = 0;
    /// Number of active values within tol of bg (what truncation reads).
    virtual size_t scan(float bg, float tol) const = 0;
};

struct TreeLayout : Layout {
    openvdb::FloatGrid::Ptr g;
    bool fold;
    int n;
    float bg;
    std::unique_ptr<Acc> racc; ///< one accessor for the run (one thread), as the engine keeps one per task
    std::unique_ptr<openvdb::tree::ValueAccessor<openvdb::FloatTree, false>> wacc;
    TreeLayout(int n_, bool fold_, float bg_) : g(openvdb::FloatGrid::create(bg_)), fold(fold_), n(n_), bg(bg_)
    {
        {
            auto acc = g->getAccessor();
            for (int y = 0; y < n; ++y)
                for (int x = 0; x < n; ++x) acc.setValueOn(at(x, y), valueAt(x, y, n));
        }
        racc = std::make_unique<Acc>(g->tree());
        wacc = std::make_unique<openvdb::tree::ValueAccessor<openvdb::FloatTree, false>>(g->tree());
    }
    openvdb::Coord at(int x, int y) const { return fold ? openvdb::Coord(y, x >> 3, x & 7) : openvdb::Coord(x, y, 0); }
    const char* name() const override { return fold ? "fold (64x8 tile per leaf)" : "today (one z layer per leaf)"; }
    double bytes() const override { return double(g->memUsage()); }
    void readRow(int y, int x0, int x1, float* out) const override
    {
        Acc& acc = *racc;
        if (y < 0 || y >= n) { std::fill(out, out + (x1 - x0), bg); return; }
        int x = x0;
        while (x < x1) {
            if (x < 0 || x >= n) { *out++ = bg; ++x; continue; }
            const openvdb::Coord c = at(x, y);
            const FloatLeaf* leaf = acc.probeConstLeaf(c);
            if (fold) {
                const int end = std::min({x1, (x | 63) + 1, n});
                if (leaf) std::memcpy(out, leaf->buffer().data() + ((y & 7) << 6) + (x & 63), size_t(end - x) * 4);
                else std::fill(out, out + (end - x), bg);
                out += end - x;
                x = end;
            } else {
                const int end = std::min({x1, (x | 7) + 1, n});
                const float* src = leaf ? leaf->buffer().data() + (((x & 7) << 6) | ((y & 7) << 3)) : nullptr;
                for (; x < end; ++x, src += 64) *out++ = src ? *src : bg;
            }
        }
    }
    void writeRow(int y, int x0, int x1, const float* in) override
    {
        auto& acc = *wacc;
        int x = x0;
        while (x < x1) {
            FloatLeaf* leaf = acc.probeLeaf(at(x, y));
            if (fold) {
                const int end = std::min(x1, (x | 63) + 1);
                std::memcpy(leaf->buffer().data() + ((y & 7) << 6) + (x & 63), in, size_t(end - x) * 4);
                in += end - x;
                x = end;
            } else {
                const int end = std::min(x1, (x | 7) + 1);
                float* dst = leaf->buffer().data() + (((x & 7) << 6) | ((y & 7) << 3));
                for (; x < end; ++x, dst += 64) *dst = *in++;
            }
        }
    }
    size_t scan(float b, float tol) const override
    {
        size_t count = 0;
        for (auto it = g->tree().cbeginLeaf(); it; ++it) {
            const float* v = it->buffer().data();
            const auto& mask = it->getValueMask();
            for (openvdb::Index w = 0; w < FloatLeaf::NodeMaskType::WORD_COUNT; ++w)
                for (uint64_t bits = mask.template getWord<uint64_t>(w); bits; bits &= bits - 1)
                    count += std::fabs(v[w * 64 + __builtin_ctzll(bits)] - b) <= tol;
        }
        return count;
    }
};

struct TileLayout : Layout {
    static constexpr int kT = 64;
    int n, nt;
    float bg;
    std::vector<std::unique_ptr<float[]>> tiles;
    std::vector<std::array<uint64_t, kT * kT / 64>> masks;
    TileLayout(int n_, float bg_) : n(n_), nt((n_ + kT - 1) / kT), bg(bg_), tiles(size_t(nt) * nt), masks(size_t(nt) * nt)
    {
        for (auto& t : tiles) {
            t.reset(new float[kT * kT]);
            std::fill(t.get(), t.get() + kT * kT, bg);
        }
        for (auto& m : masks) m.fill(~0ull);
        for (int y = 0; y < n; ++y)
            for (int x = 0; x < n; ++x) tiles[size_t(y / kT) * nt + size_t(x / kT)][(y % kT) * kT + x % kT] = valueAt(x, y, n);
    }
    const char* name() const override { return "tiles (64x64 dense, table)"; }
    double bytes() const override { return double(tiles.size()) * (kT * kT * 4 + sizeof(masks[0]) + sizeof(void*)); }
    void readRow(int y, int x0, int x1, float* out) const override
    {
        if (y < 0 || y >= n) { std::fill(out, out + (x1 - x0), bg); return; }
        int x = x0;
        while (x < x1) {
            if (x < 0 || x >= n) { *out++ = bg; ++x; continue; }
            const int end = std::min({x1, (x | (kT - 1)) + 1, n});
            std::memcpy(out, tiles[size_t(y / kT) * nt + size_t(x / kT)].get() + (y % kT) * kT + x % kT, size_t(end - x) * 4);
            out += end - x;
            x = end;
        }
    }
    void writeRow(int y, int x0, int x1, const float* in) override
    {
        int x = x0;
        while (x < x1) {
            const int end = std::min(x1, (x | (kT - 1)) + 1);
            std::memcpy(tiles[size_t(y / kT) * nt + size_t(x / kT)].get() + (y % kT) * kT + x % kT, in, size_t(end - x) * 4);
            in += end - x;
            x = end;
        }
    }
    size_t scan(float b, float tol) const override
    {
        size_t count = 0;
        for (size_t t = 0; t < tiles.size(); ++t) {
            const float* v = tiles[t].get();
            for (int w = 0; w < kT * kT / 64; ++w)
                for (uint64_t bits = masks[t][w]; bits; bits &= bits - 1)
                    count += std::fabs(v[w * 64 + __builtin_ctzll(bits)] - b) <= tol;
        }
        return count;
    }
};

int benchLayout(const BenchArgs& args)
{
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    const int n = args.args.empty() ? (args.quick ? 512 : 2048) : std::stoi(args.args[0]);
    const int reps = 5;
    KobayashiParams k;
    k.delta = 0.04;
    const float farT = float(k.farTemperature);
    std::printf("frostvdb bench layout: %dx%d plane, every voxel active, one thread, best of %d; per voxel-step "
                "(ns) of two fields p and T\n\n", n, n, reps);
    std::printf("| layout | bytes/voxel (one field) | gather p,T 36x36 per 32x32 group | commit p,T | "
                "truncation scan p,T | memory-bound sum |\n|---|---:|---:|---:|---:|---:|\n");
    const double voxels = double(n) * n;
    std::vector<float> blk(size_t(kB) * kB);
    double lastSum = 0;
    for (int which = 0; which < 3; ++which) {
        std::unique_ptr<Layout> P, T;
        if (which < 2) {
            P = std::make_unique<TreeLayout>(n, which == 1, 0.f);
            T = std::make_unique<TreeLayout>(n, which == 1, farT);
        } else {
            P = std::make_unique<TileLayout>(n, 0.f);
            T = std::make_unique<TileLayout>(n, farT);
        }
        double sink = 0;
        const double g = best(reps, [&] {
            for (int gy = 0; gy < n; gy += kGroup)
                for (int gx = 0; gx < n; gx += kGroup)
                    for (Layout* L : {P.get(), T.get()})
                        for (int y = 0; y < kB; ++y) L->readRow(gy - kHalo + y, gx - kHalo, gx - kHalo + kB, &blk[size_t(y) * kB]);
            sink += blk[0];
        });
        const double c = best(reps, [&] {
            for (int gy = 0; gy < n; gy += kGroup)
                for (int gx = 0; gx < n; gx += kGroup)
                    for (Layout* L : {P.get(), T.get()})
                        for (int y = 0; y < kGroup; ++y)
                            L->writeRow(gy + y, gx, std::min(n, gx + kGroup), &blk[size_t(y + kHalo) * kB + kHalo]);
        });
        size_t cnt = 0;
        const double s = best(reps, [&] { cnt = P->scan(0.f, 1e-6f) + T->scan(farT, 1e-6f); });
        const double sum = g + c + s;
        std::printf("| %s | %.2f | %.2f | %.2f | %.2f | %.2f |\n", P->name(), P->bytes() / voxels, 1e9 * g / voxels,
                    1e9 * c / voxels, 1e9 * s / voxels, 1e9 * sum / voxels);
        std::fflush(stdout);
        lastSum = sum + 0 * sink + 0 * double(cnt);
    }
    (void)lastSum;
    // The compute the memory-bound work sits next to: the engine's rows on a 36x36 block (the
    // square plane's vector rows where the CPU has them), and the dense loop on the same rows.
    {
        const Lattice lat(LatticeKind::Square, 0.03);
        Anisotropy an(k);
        FlatStencil st(lat.stencil(false), kB, 0);
        useD6Forms(st, an);
        const EulerRows rows = fastestEulerRows(st, an);
        std::vector<float> p(size_t(kB) * kB), t(p.size(), farT), a(p.size()), cx(p.size()), cy(p.size()), gx(p.size()),
            gy(p.size()), gz(p.size()), pe(p.size()), te(p.size());
        std::vector<double> dp(p.size());
        for (int y = 0; y < kB; ++y)
            for (int x = 0; x < kB; ++x) p[size_t(y) * kB + x] = valueAt(x + n / 2 - 600, y + n / 2, n);
        const int groups = (n / kGroup) * (n / kGroup);
        const double comp = best(reps, [&] {
            for (int q = 0; q < groups; ++q) {
                for (int y = 1; y < kB - 1; ++y)
                    rows.aux(p.data(), size_t(y) * kB + 1, size_t(y) * kB + kB - 1, st, an, a.data(), cx.data(), cy.data(),
                             gx.data(), gy.data(), gz.data());
                for (int y = kHalo; y < kB - kHalo; ++y)
                    rows.euler(p.data(), t.data(), a.data(), cx.data(), cy.data(), gx.data(), gy.data(), gz.data(),
                               size_t(y) * kB + kHalo, size_t(y) * kB + kB - kHalo, st, k, nullptr, nullptr, pe.data(),
                               te.data(), dp.data());
            }
        });
        DensePhaseField dense(k, lat, n, n);
        dense.setVectorRows(true);
        for (int y = 0; y < n; ++y)
            for (int x = 0; x < n; ++x) dense.p()[dense.index(x, y)] = valueAt(x, y, n);
        const double dl = best(reps, [&] { dense.step(); });
        std::printf("\ncompute of the same groups (%s rows, pass 1 + pass 2 on 36x36 blocks): %.2f ns/voxel; "
                    "dense loop on the same rows: %.2f ns/voxel\n",
                    rows.vector ? "AVX2 vector" : "plain", 1e9 * comp / voxels, 1e9 * dl / voxels);
    }
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(layout, "layout",
                        "plane storage layouts (today's z layer, folded 64x8 leaves, dense 64x64 tiles): bytes per "
                        "voxel, gather/commit/scan cost next to the kernel's compute (issue 24)",
                        benchLayout);

} // namespace frostvdb
