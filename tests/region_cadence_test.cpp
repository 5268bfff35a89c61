// Region cadence: the active region rebuilt every k steps (dilated for k steps of travel) gives
// the dense answer bit for bit at tolerance 0, rebuilds when another writer changed the fields,
// and rebuilds exactly as often as asked.
#include "test_util.h"

#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/ice/PhaseFieldSolver.h>

#include <catch2/catch.hpp>

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
    const Domain dom = makePlaneDomain(lat, openvdb::Coord(48, 48, 1), 1e-4);
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
