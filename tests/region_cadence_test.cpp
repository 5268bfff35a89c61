// Region cadence: the active region rebuilt every k steps (dilated for k steps of travel) gives
// the dense answer bit for bit at tolerance 0, rebuilds when another writer changed the fields,
// and rebuilds exactly as often as asked.
#include "test_util.h"

#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/ice/PhaseFieldSolver.h>

#include <catch2/catch.hpp>

#include <map>
#include <set>
#include <tuple>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

const char* kCadenceScene = R"(
[scene]
name = "cadence"
frames = 1
steps_per_frame = 200
[domain]
size = [64, 64]
[phase_field]
anisotropy_mode = 4
)";

std::pair<openvdb::FloatGrid::Ptr, openvdb::FloatGrid::Ptr> runScene(const std::vector<std::string>& extra, int steps)
{
    auto sim = makeSim(kCadenceScene, extra);
    sim.initialize();
    for (int s = 0; s < steps; ++s) sim.step();
    return {sim.world().fields.get<openvdb::FloatGrid>("p"), sim.world().fields.get<openvdb::FloatGrid>("T")};
}

struct Disc {
    KobayashiParams k;
    Lattice lat{LatticeKind::Square, 3.0 / 64.0};
    Domain dom = makePlaneDomain(lat, openvdb::Coord(48, 48, 1), 1e-4);
    openvdb::FloatGrid::Ptr p = openvdb::FloatGrid::create(0.f), T = openvdb::FloatGrid::create(0.f);
    Disc()
    {
        k.anisotropyMode = 4;
        for (int j = 21; j <= 26; ++j)
            for (int i = 21; i <= 26; ++i) p->tree().setValue(openvdb::Coord(i, j, 0), 1.f);
    }
};

} // namespace

TEST_CASE("Region cadence k > 1 at tolerance 0 equals the dense answer bit for bit", "[fast][phase_field][region]")
{
    // At 12 steps the region is still sparse; by 200 it has filled the domain (at tolerance 0
    // the heat's numerical tail spreads two cells a step).
    for (int steps : {12, 200}) {
        const auto dense = runScene({"region.dense=true"}, steps);
        for (const char* every : {"1", "3", "4", "0"}) {
            const auto sparse = runScene({"region.tolerance=0", std::string("region.rebuild_every=") + every}, steps);
            INFO("rebuild_every = " << every << ", steps " << steps);
            CHECK(maxAbsDiff(*sparse.first, *dense.first) == 0.0);
            CHECK(maxAbsDiff(*sparse.second, *dense.second) == 0.0);
            if (steps == 12) CHECK(sparse.second->activeVoxelCount() < dense.second->activeVoxelCount() / 2);
        }
    }
}

TEST_CASE("Region cadence rebuilds every k steps, and when another writer changed p", "[fast][phase_field][region]")
{
    for (int every : {1, 4, 5}) {
        Disc d;
        RegionSettings rs;
        rs.tolerance = 0;
        rs.rebuildEvery = every;
        PhaseFieldSolver solver(d.k, d.dom, rs);
        PhaseFieldStepStats stats;
        for (int s = 0; s < 40; ++s) solver.step(d.p, d.T, nullptr, nullptr, s, s * d.k.dt, 1, &stats);
        CHECK(stats.rebuilds == (40 + every - 1) / every);
    }

    // A voxel frozen far from the ice between steps (as the walkers do) must be seen at once:
    // the cadenced solver then matches the dense solver given the same write.
    Disc a, b;
    RegionSettings sparse, dense;
    sparse.tolerance = 0;
    sparse.rebuildEvery = 8;
    dense.dense = true;
    PhaseFieldSolver sa(a.k, a.dom, sparse), sb(b.k, b.dom, dense);
    PhaseFieldStepStats stats;
    for (int s = 0; s < 30; ++s) {
        if (s == 10) {
            a.p->tree().setValue(openvdb::Coord(3, 40, 0), 1.f); // in place: same grid object
            b.p->tree().setValue(openvdb::Coord(3, 40, 0), 1.f);
        }
        sa.step(a.p, a.T, nullptr, nullptr, s, s * a.k.dt, 1, &stats);
        sb.step(b.p, b.T, nullptr, nullptr, s, s * b.k.dt, 1);
    }
    CHECK(stats.rebuilds == 5); // steps 0, 8, 10 (the write), 18, 26
    CHECK(maxAbsDiff(*a.p, *b.p) == 0.0);
    CHECK(maxAbsDiff(*a.T, *b.T) == 0.0);
    CHECK(a.p->tree().getValue(openvdb::Coord(4, 40, 0)) > 0.f); // the write spread
}

TEST_CASE("Region cadence on the hexagonal lattice at tolerance 0 equals dense bit for bit", "[fast][phase_field][region]")
{
    const std::vector<std::string> hex{"domain.lattice=\"hexagonal\"", "phase_field.anisotropy_mode=6"};
    auto with = [&](std::vector<std::string> extra) {
        extra.insert(extra.end(), hex.begin(), hex.end());
        return extra;
    };
    const auto dense = runScene(with({"region.dense=true"}), 40);
    for (const char* every : {"1", "5", "0"}) {
        const auto sparse = runScene(with({"region.tolerance=0", std::string("region.rebuild_every=") + every}), 40);
        INFO("rebuild_every = " << every);
        CHECK(maxAbsDiff(*sparse.first, *dense.first) == 0.0);
        CHECK(maxAbsDiff(*sparse.second, *dense.second) == 0.0);
    }
}

namespace {

/// The region by definition: a domain voxel is in when its leaf holds a domain cell within
/// @a d of a source voxel (L1 for the square lattice's 4-neighbour dilation, Chebyshev for the
/// hexagonal 3x3 one). Brute force over the domain.
std::set<openvdb::Coord> regionByDefinition(const std::vector<openvdb::Coord>& sources, const Domain& dom, int d, bool hex)
{
    std::set<openvdb::Coord> leaves;
    const auto& b = dom.bbox();
    for (int y = b.min().y(); y <= b.max().y(); ++y)
        for (int x = b.min().x(); x <= b.max().x(); ++x)
            for (const auto& s : sources) {
                const int dx = std::abs(x - s.x()), dy = std::abs(y - s.y());
                if ((hex ? std::max(dx, dy) : dx + dy) <= d) {
                    leaves.insert(openvdb::Coord(x & ~7, y & ~7, b.min().z() & ~7));
                    break;
                }
            }
    std::set<openvdb::Coord> voxels;
    for (int y = b.min().y(); y <= b.max().y(); ++y)
        for (int x = b.min().x(); x <= b.max().x(); ++x)
            if (leaves.count(openvdb::Coord(x & ~7, y & ~7, b.min().z() & ~7))) voxels.insert(openvdb::Coord(x, y, b.min().z()));
    return voxels;
}

std::set<openvdb::Coord> voxelsOf(const openvdb::MaskGrid& g)
{
    std::set<openvdb::Coord> s;
    for (auto it = g.cbeginValueOn(); it; ++it) s.insert(it.getCoord());
    return s;
}

} // namespace

TEST_CASE("Plane region built leaf by leaf equals its definition, for every reach", "[fast][region]")
{
    // steps 1..3 reach 1-2 leaves (the leaf-level path), 9 reaches 4 (the voxel dilation path);
    // a domain origin off the leaf grid and sources on its edges exercise the clipping.
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        const Lattice lat{kind, 3.0 / 64.0};
        const Domain dom = makePlaneDomain(lat, openvdb::Coord(61, 45, 1), 1e-4, openvdb::Coord(-13, 5, 0));
        const int z = dom.bbox().min().z();
        auto p = openvdb::FloatGrid::create(0.f), T = openvdb::FloatGrid::create(0.f);
        std::vector<openvdb::Coord> sources{{-13, 5, z}, {47, 49, z}, {10, 20, z}, {11, 20, z}, {30, 7, z}};
        p->tree().setValue(sources[0], 1.f);
        p->tree().setValue(sources[1], 0.5f);
        p->tree().setValue(sources[2], 1.f);
        T->tree().setValue(sources[3], -0.2f);
        T->tree().setValue(sources[4], -0.1f);
        T->tree().setValue(openvdb::Coord(80, 20, z), -0.3f); // outside the domain: not a source
        RegionSettings rs;
        for (int steps : {1, 2, 3, 9}) {
            const auto region = buildActiveRegion({p.get(), T.get()}, rs, 2, dom, steps);
            INFO("lattice " << int(kind) << ", steps " << steps);
            CHECK(voxelsOf(*region) == regionByDefinition(sources, dom, steps * (2 + rs.frontTravel),
                                                          kind == LatticeKind::Hexagonal));
            // unchanged fields: the last region comes back as it is
            CHECK(buildActiveRegion({p.get(), T.get()}, rs, 2, dom, steps, region) == region);
        }
    }
}

TEST_CASE("Reported walker writes grow the standing region: no out-of-turn rebuild, dense bits at tolerance 0",
          "[fast][phase_field][region]")
{
    // A plane large enough that the tolerance-0 heat tail (two cells a step) does not fill it.
    const Lattice lat{LatticeKind::Square, 3.0 / 64.0};
    const Domain dom = makePlaneDomain(lat, openvdb::Coord(128, 128, 1), 1e-4);
    for (int every : {2, 4}) {
        Disc a, b;
        a.dom = dom;
        b.dom = dom;
        RegionSettings sparse, dense;
        sparse.tolerance = 0;
        sparse.rebuildEvery = every;
        dense.dense = true;
        PhaseFieldSolver sa(a.k, a.dom, sparse), sb(b.k, b.dom, dense);
        std::vector<openvdb::Coord> editsP, editsT;
        sa.setEditLogs(&editsP, &editsT);
        PhaseFieldStepStats stats;
        const int k = every;
        const std::vector<openvdb::Coord> writes{{110, 100, 0}, {27, 24, 0}, {100, 20, 0}, {20, 90, 0}};
        for (int s = 0; s < 30; ++s) {
            if (s >= 5 && s % 3 == 0) { // freeze a cell, release heat there, as the walkers do
                const openvdb::Coord c = writes[size_t(s / 3) % writes.size()] + openvdb::Coord(s % 2, 0, 0);
                for (Disc* d : {&a, &b}) {
                    d->p->tree().setValue(c, 1.f);
                    d->T->tree().setValue(c, d->T->tree().getValue(c) + 0.3f);
                }
                editsP.push_back(c);
                editsT.push_back(c);
            }
            sa.step(a.p, a.T, nullptr, nullptr, s, s * a.k.dt, 1, &stats);
            sb.step(b.p, b.T, nullptr, nullptr, s, s * b.k.dt, 1);
            CHECK(editsP.empty()); // read and cleared
        }
        INFO("rebuild_every = " << every);
        CHECK(stats.rebuilds == (30 + k - 1) / k); // the writes did not force rebuilds
        CHECK(stats.regionGrowths > 0);            // cells far from the ice grew the region
        CHECK(maxAbsDiff(*a.p, *b.p) == 0.0);
        CHECK(maxAbsDiff(*a.T, *b.T) == 0.0);
        CHECK(a.p->tree().getValue(openvdb::Coord(110, 101, 0)) != 0.f); // the far write spread
    }
}

TEST_CASE("A region grown around written cells covers the region a full rebuild gives", "[fast][region]")
{
    Disc d;
    RegionSettings rs;
    const int steps = 2, radius = steps * (2 + rs.frontTravel);
    auto grown = buildActiveRegion({d.p.get(), d.T.get()}, rs, 2, d.dom, steps);
    const std::vector<openvdb::Coord> cells{{3, 40, 0}, {27, 27, 0}, {47, 0, 0}, {16, 15, 0}};
    for (const auto& c : cells) d.p->tree().setValue(c, 1.f);
    const auto folded = plane::foldTopology(*grown); // the folded fields' region grows folded
    const auto before = grown->tree().leafCount();
    CHECK(growActiveRegion(*grown, cells, radius, d.dom));
    CHECK(grown->tree().leafCount() > before);
    CHECK_FALSE(growActiveRegion(*grown, cells, radius, d.dom)); // already there: nothing added
    CHECK(growActiveRegion(*folded, cells, radius, d.dom));
    CHECK_FALSE(growActiveRegion(*folded, cells, radius, d.dom));
    CHECK(folded->tree().hasSameTopology(plane::foldTopology(*grown)->tree()));
    const auto rebuilt = buildActiveRegion({d.p.get(), d.T.get()}, rs, 2, d.dom, steps);
    const auto g = voxelsOf(*grown);
    for (const auto& v : voxelsOf(*rebuilt)) CHECK(g.count(v) == 1);
    for (const auto& v : g) CHECK(d.dom.contains(v)); // clipped to the domain
}

TEST_CASE("Walkers and phase field: the region keeps its cadence and tolerance 0 equals dense bit for bit",
          "[fast][dla][region]")
{
    const char* scene = R"(
[scene]
name = "walkers"
frames = 1
steps_per_frame = 30
seed = 5
[domain]
lattice = "hexagonal"
size = [128, 128]
voxel_size = 0.0001
[[crystal.seed]]
shape = "point"
position = [0.5, 0.5]
radius = 3
[dla]
humidity = 400
batch = 64
[phase_field]
anisotropy_mode = 6
)";
    auto run = [&](const std::vector<std::string>& extra) {
        Simulation sim = makeSim(scene, extra);
        sim.initialize();
        for (int s = 0; s < 30; ++s) sim.step();
        std::map<std::string, double> counts;
        for (auto& [k, v] : sim.effect("phase_field")->counters()) counts[k] = v;
        return std::make_tuple(sim.world().fields.get<openvdb::FloatGrid>("p"),
                               sim.world().fields.get<openvdb::FloatGrid>("T"), counts);
    };
    const auto [pd, td, cd] = run({"region.dense=true"});
    const auto [ps, ts, cs] = run({"region.tolerance=0"});
    CHECK(maxAbsDiff(*ps, *pd) == 0.0);
    CHECK(maxAbsDiff(*ts, *td) == 0.0);
    // the walkers froze cells in every step, yet the region was not rebuilt every step
    CHECK(cs.at("region_rebuilds") <= 15);
    const auto [p6, t6, c6] = run({"region.tolerance=1e-6"});
    CHECK(c6.at("region_rebuilds") == 15); // automatic k = 2 over 30 steps
}

TEST_CASE("Region cadence: voxel_updates sums each step's region (the shell's counter, for the pane pair)",
          "[fast][phase_field][region]")
{
    // Dense: every step updates the whole 48 x 48 domain. Sparse: the sum of the regions the
    // steps report, which stays below the dense count while the region is smaller than the domain.
    Disc a, b;
    RegionSettings sparse, dense;
    sparse.tolerance = 0;
    dense.dense = true;
    PhaseFieldSolver sa(a.k, a.dom, sparse), sb(b.k, b.dom, dense);
    PhaseFieldStepStats sparseStats, denseStats;
    uint64_t regions = 0;
    for (int s = 0; s < 20; ++s) {
        sa.step(a.p, a.T, nullptr, nullptr, s, s * a.k.dt, 1, &sparseStats);
        regions += sparseStats.regionVoxels;
        sb.step(b.p, b.T, nullptr, nullptr, s, s * b.k.dt, 1, &denseStats);
    }
    CHECK(denseStats.voxelUpdates == 20u * 48u * 48u);
    CHECK(sparseStats.voxelUpdates == regions);
    CHECK(sparseStats.voxelUpdates > 0u);
    CHECK(sparseStats.voxelUpdates < denseStats.voxelUpdates);
}
