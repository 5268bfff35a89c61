// Issue 24 (planes): whole frames of a square and a hexagonal hybrid scene (walkers + phase
// field, both schemes) compared bit for bit between the session's new paths and the ones they
// replace, switched by environment variables read at every step:
//  - FROSTVDB_FULL_DISTANCE_SYNC=1: the walkers' distance map reads all of p each step instead
//    of the cells where the phase field moved p across 1/2;
//  - FROSTVDB_NO_VECTOR_ROWS=1: the plain rows instead of the vector ones (the hexagonal
//    lattice's D6 rows are new);
//  - FROSTVDB_NO_FUSED_TRUNCATION=1: truncation as its own pass instead of in forward Euler's commit.
// Session 10: FROSTVDB_NO_PLANE_FOLD=1 keeps the plane layout Coord(x, y, 0) for the fields
// core/PlaneFold.h folds (growth_acc, freeze_time, dla_hits); frames must not see the difference.
// Session 13: p and T are folded too, in both schemes (the kernels gather and write folded rows,
// the region is built from their plane-layout topology, the walkers read and write folded cells).
#include <catch2/catch.hpp>

#include "test_util.h"

#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/core/Export.h>
#include <frostvdb/core/FieldEdits.h>
#include <frostvdb/core/FieldWriters.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/core/RegionOfTopology.h>
#include <frostvdb/io/StreamedGrid.h>
#include <frostvdb/io/VdbIO.h>

#include <array>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

std::string hybridScene(const std::string& lattice, const std::string& scheme)
{
    return "[scene]\nname = \"hybrid\"\nframes = 2\nsteps_per_frame = 20\nseed = 9\n"
           "[domain]\nlattice = \"" + lattice + "\"\nsize = [128, 128]\nvoxel_size = 0.0001\n"
           "[[crystal.seed]]\nshape = \"point\"\nposition = [0.5, 0.5]\nradius = 3\n"
           "[[crystal.seed]]\nshape = \"point\"\nposition = [0.2, 0.7]\nradius = 2\n"
           "[dla]\nhumidity = 500\nhits = 2\nbatch = 64\n"
           "[phase_field]\nscheme = \"" + scheme + "\"\n" +
           (lattice == "hexagonal" ? "anisotropy_mode = 6\n" : "");
}

const char* const kOldPaths[] = {"FROSTVDB_FULL_DISTANCE_SYNC", "FROSTVDB_NO_VECTOR_ROWS", "FROSTVDB_NO_FUSED_TRUNCATION",
                                 "FROSTVDB_NO_PLANE_FOLD"};

/// Runs @a text writing every frame; with @a old the replaced paths (all of them, or only
/// @a only when given).
std::vector<std::string> runFrames(const std::string& text, bool old, const std::string& tag, int threads,
                                   const char* only = nullptr, bool* phaseFolded = nullptr)
{
    for (const char* v : kOldPaths) {
        if (old && (!only || std::string(only) == v)) ::setenv(v, "1", 1);
        else ::unsetenv(v);
    }
    auto sim = makeSim(text);
    RunOptions ro;
    ro.progress = false;
    ro.threads = threads;
    ro.outDir = tempDir(tag);
    sim.run(ro);
    for (const char* v : kOldPaths) ::unsetenv(v);
    // the listed path applies: [phase_field] reports its crossings and is the only other writer of p
    const auto& w = sim.world().state<FieldWriters>();
    CHECK(w.of("p") - 1 == sim.world().state<FieldEdits>().crossingReporters("p"));
    if (phaseFolded) {
        *phaseFolded = plane::isFolded(*sim.world().fields.grid("p"));
        CHECK(plane::isFolded(*sim.world().fields.grid("T")) == *phaseFolded);
    }
    return {ro.outDir + "/hybrid.0001.vdb", ro.outDir + "/hybrid.0002.vdb"};
}

/// Bytes of a file.
std::string fileBytes(const std::filesystem::path& path)
{
    std::ifstream in(path, std::ios::binary);
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

/// The PNGs beside frame @a a, each equal byte for byte to its namesake beside frame @a b; how many.
int samePngs(const std::string& a, const std::string& b)
{
    const auto da = std::filesystem::path(a).parent_path(), db = std::filesystem::path(b).parent_path();
    int n = 0;
    for (const auto& e : std::filesystem::directory_iterator(da)) {
        if (e.path().extension() != ".png") continue;
        INFO(e.path().filename());
        REQUIRE(std::filesystem::exists(db / e.path().filename()));
        CHECK(fileBytes(e.path()) == fileBytes(db / e.path().filename()));
        ++n;
    }
    return n;
}

} // namespace

TEST_CASE("Hybrid frames on the new paths equal the old paths' bit for bit, square and hexagonal",
          "[fast][dla][phase_field]")
{
    for (const std::string lattice : {"square", "hexagonal"})
        for (const std::string scheme : {"euler", "lw_cn"}) {
            const std::string text = hybridScene(lattice, scheme);
            const std::string tag = "cross_" + lattice + "_" + scheme;
            const auto full = runFrames(text, true, tag + "_full", 2);
            const auto listed = runFrames(text, false, tag + "_listed", 2);
            const auto listed1 = runFrames(text, false, tag + "_listed1", 1);
            for (size_t f = 0; f < full.size(); ++f) {
                std::string why;
                INFO(lattice << " " << scheme << " frame " << f + 1);
                CHECK(sameVdbContent(full[f], listed[f], &why));
                INFO(why);
                CHECK(sameVdbContent(full[f], listed1[f], &why));
                INFO(why);
            }
        }
}

TEST_CASE("Folded plane fields give the plane layout's frames bit for bit, square and hexagonal",
          "[fast][dla][phase_field][fold]")
{
    // The region variants reach the region's other paths on folded p and T: rebuilt every 16
    // steps (the voxel dilation: the leaf path covers 3 leaves at most) and dense.
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"square", "euler"}, {"square", "lw_cn"}, {"hexagonal", "euler"}, {"hexagonal", "lw_cn"},
        {"square", "euler rebuild_every"}, {"hexagonal", "euler dense"}};
    for (const auto& [lattice, variant] : cases) {
        const std::string scheme = variant.substr(0, variant.find(' '));
        std::string text = hybridScene(lattice, scheme);
        if (variant == "euler rebuild_every") text += "[region]\nrebuild_every = 16\n";
        if (variant == "euler dense") text += "[region]\ndense = true\n";
        const std::string tag = "fold_" + lattice + "_" + variant.substr(variant.rfind(' ') + 1);
        bool planeFolded = true, folded2 = false, folded1Phase = false;
        const auto unfolded = runFrames(text, true, tag + "_plane", 2, "FROSTVDB_NO_PLANE_FOLD", &planeFolded);
        const auto folded = runFrames(text, false, tag + "_folded", 2, nullptr, &folded2);
        const auto folded1 = runFrames(text, false, tag + "_folded1", 1, nullptr, &folded1Phase);
        INFO(lattice << " " << variant);
        CHECK(!planeFolded);
        CHECK(folded2); // the fold of p and T did run
        CHECK(folded1Phase == folded2);
        for (size_t f = 0; f < folded.size(); ++f) {
            std::string why;
            INFO(lattice << " " << scheme << " frame " << f + 1);
            CHECK(sameVdbContent(unfolded[f], folded[f], &why));
            INFO(why);
            CHECK(sameVdbContent(unfolded[f], folded1[f], &why));
            INFO(why);
        }
        // the PNGs (displacement map, preview) drawn from the folded copies in place
        CHECK(samePngs(unfolded[0], folded[0]) > 0);
    }
}

TEST_CASE("The fold is a permutation: fold and unfold give back every value and active state", "[fast][fold]")
{
    // x = -1: the last column of the last span (15) of band -1
    CHECK(plane::fold(openvdb::Coord(-1, 5, 0)) == openvdb::Coord(5, -1, 127));
    CHECK(plane::fold(openvdb::Coord(1024 + 9, 5, 0)) == openvdb::Coord(5, 1, 8 + 1));
    CHECK(plane::fold(openvdb::Coord(16384 + 64, 5, 0)) == openvdb::Coord(5, 128 + 8, 0));
    std::vector<int> xs; // every column near the 64-column tiles, 1024-column spans and bands
    for (int x = -70; x < 70; ++x) xs.push_back(x);
    for (int edge : {1024, -1024, 3 * 1024, 16384, -16384, 2 * 16384 + 5 * 1024, -3 * 16384 - 7 * 1024})
        for (int x = edge - 70; x < edge + 70; ++x) xs.push_back(x);
    for (int x : xs)
        for (int y = -9; y < 9; ++y) {
            const openvdb::Coord c(x, y, 0);
            REQUIRE(plane::unfold(plane::fold(c)) == c);
            const openvdb::Coord lo(x & ~7, y & ~7, 0);
            const openvdb::Coord f = plane::fold(c);
            REQUIRE((f & ~7) == plane::foldedLeafOrigin(lo));
            REQUIRE(openvdb::FloatTree::LeafNodeType::coordToOffset(f) == plane::foldedOffset(lo, x & 7, y & 7));
        }
    auto g = openvdb::FloatGrid::create(0.25f);
    g->setName("g");
    for (int i = 0; i < 5000; ++i) {
        const uint64_t h = hashCounters(7, uint64_t(i));
        const openvdb::Coord c(int(h % 700) - 350, int((h >> 20) % 300) - 150, 0);
        if (h >> 60 & 1) g->tree().setValueOn(c, float(h % 1000) * 0.001f);
        else g->tree().setValueOff(c, -float(h % 1000));
    }
    auto folded = plane::foldGrid(*g);
    CHECK(plane::isFolded(*folded));
    CHECK(folded->activeVoxelCount() == g->activeVoxelCount());
    CHECK(folded->memUsage() < g->memUsage());
    auto back = plane::unfoldGrid(*folded);
    CHECK(!plane::isFolded(*back));
    CHECK(back->getName() == "g");
    auto ga = g->getConstAccessor();
    for (auto it = back->cbeginValueOn(); it; ++it) {
        REQUIRE(ga.isValueOn(it.getCoord()));
        REQUIRE(*it == ga.getValue(it.getCoord()));
    }
    CHECK(back->activeVoxelCount() == g->activeVoxelCount());
    for (auto it = g->tree().cbeginLeaf(); it; ++it)
        for (auto v = it->cbeginValueAll(); v; ++v)
            if (it->isValueOn(v.pos()) || *v != 0.25f) {
                const auto* l = back->tree().probeConstLeaf(v.getCoord());
                if (!l && !it->isValueOn(v.pos())) continue; // a leaf of inactive values only is dropped
                REQUIRE(l);
                REQUIRE(l->getValue(v.getCoord()) == *v);
            }
}

TEST_CASE("The fold fills the internal nodes: scattered islands on a 16384^2 plane, node for node", "[fast][fold]")
{
    // 1000 islands of 3 x 3 plane leaves scattered over a 16384^2 plane (bench scale's seeds):
    // the first fold, Coord(y, x >> 3, x & 7), gave one 33 KiB level-1 node per island in every
    // folded tree (1/16 of its slots usable); this fold spans a node over 128 rows x 16384
    // columns, so the plane holds at most 128 of them.
    auto g = openvdb::FloatGrid::create(0.f);
    for (int i = 0; i < 1000; ++i) {
        const uint64_t h = hashCounters(24, uint64_t(i));
        const int cx = int(h % 16000) + 100, cy = int((h >> 24) % 16000) + 100;
        for (int y = cy - 12; y < cy + 12; ++y)
            for (int x = cx - 12; x < cx + 12; ++x) g->tree().setValueOn(openvdb::Coord(x, y, 0), float(x ^ y));
    }
    auto folded = plane::foldGrid(*g);
    const auto nodes = folded->tree().nodeCount(); // per level: leaves, level 1, level 2, root
    CHECK(nodes[1] <= 128);
    CHECK(nodes[2] <= 4);
    CHECK(folded->memUsage() * 4 < g->memUsage());
    // the same values and active states as the plane layout, voxel for voxel
    auto back = plane::unfoldGrid(*folded);
    CHECK(back->tree().hasSameTopology(g->tree()));
    auto ga = g->getConstAccessor();
    for (auto it = back->cbeginValueOn(); it; ++it) REQUIRE(*it == ga.getValue(it.getCoord()));
}

TEST_CASE("A grid of the first fold (a checkpoint's) is moved to this fold voxel for voxel", "[fast][fold][checkpoint]")
{
    // the first fold stored plane voxel (x, y) at Coord(y, x >> 3, x & 7), flagged by a bool
    auto plane = openvdb::FloatGrid::create(0.5f);
    auto legacy = openvdb::FloatGrid::create(0.5f);
    auto legacyHits = openvdb::Int32Grid::create(0);
    auto planeHits = openvdb::Int32Grid::create(0);
    for (int i = 0; i < 20000; ++i) {
        const uint64_t h = hashCounters(17, uint64_t(i));
        const openvdb::Coord c(int(h % 40000) - 20000, int((h >> 20) % 600) - 300, 0);
        const openvdb::Coord old(c.y(), c.x() >> 3, c.x() & 7);
        const float v = float(h % 1000) * 0.001f;
        if (h >> 60 & 1) {
            plane->tree().setValueOn(c, v);
            legacy->tree().setValueOn(old, v);
        } else {
            plane->tree().setValueOff(c, -v);
            legacy->tree().setValueOff(old, -v);
        }
        planeHits->tree().setValueOn(c, int(i));
        legacyHits->tree().setValueOn(old, int(i));
    }
    legacy->insertMeta(plane::kFoldMeta, openvdb::BoolMetadata(true));
    legacyHits->insertMeta(plane::kFoldMeta, openvdb::BoolMetadata(true));
    CHECK(!plane::isFolded(*legacy));
    plane::upgradeLegacyFold(*legacy);
    plane::upgradeLegacyFold(*legacyHits);
    REQUIRE(plane::isFolded(*legacy));
    REQUIRE(plane::isFolded(*legacyHits));
    // leaf for leaf the grid this fold makes of the plane layout (foldGrid drops the plane leaves
    // holding inactive values only; the legacy grid keeps them), and the same plane layout back
    auto expected = plane::foldGrid(*plane);
    size_t leaves = 0;
    for (auto it = legacy->tree().cbeginLeaf(); it; ++it) {
        if (it->isEmpty()) continue;
        ++leaves;
        const auto* l = expected->tree().probeConstLeaf(it->origin());
        REQUIRE(l);
        REQUIRE(l->getValueMask() == it->getValueMask());
        for (auto v = it->cbeginValueOn(); v; ++v) REQUIRE(l->getValue(v.pos()) == *v);
    }
    CHECK(leaves == expected->tree().leafCount());
    CHECK(legacy->activeVoxelCount() == plane->activeVoxelCount());
    auto pa = plane->getConstAccessor();
    const auto back = plane::unfoldGrid(*legacy);
    for (auto it = back->cbeginValueOn(); it; ++it) {
        REQUIRE(pa.isValueOn(it.getCoord()));
        REQUIRE(*it == pa.getValue(it.getCoord()));
    }
    CHECK(plane::foldGrid(*planeHits)->tree().hasSameTopology(legacyHits->tree()));
    // a grid already of this fold, or not folded, is left as it is
    const auto before = expected->activeVoxelCount();
    plane::upgradeLegacyFold(*expected);
    CHECK(plane::isFolded(*expected));
    CHECK(expected->activeVoxelCount() == before);
}

TEST_CASE("A checkpoint of the plane layout resumes on a folding build to the same frames", "[fast][fold][checkpoint]")
{
    // Fields restored from a checkpoint written before the fold (FROSTVDB_NO_PLANE_FOLD=1 stands
    // in for the older build) keep their layout: every reader and writer asks the grid.
    const std::string text = hybridScene("square", "euler");
    const std::string path = tempDir("fold_ckpt") + "/old.ckpt";
    Simulation straight = makeSim(text);
    for (int s = 0; s < 30; ++s) straight.step();
    int64_t k = 0;
    {
        ::setenv("FROSTVDB_NO_PLANE_FOLD", "1", 1);
        Simulation old = makeSim(text);
        for (int s = 0; s < 12; ++s) old.step();
        while (!old.atCheckpointBoundary()) old.step();
        k = old.stepsTaken();
        old.saveCheckpoint(path);
        ::unsetenv("FROSTVDB_NO_PLANE_FOLD");
    }
    REQUIRE(k < 30);
    Simulation resumed = makeSim(text);
    resumed.loadCheckpoint(path);
    for (int64_t s = k; s < 30; ++s) resumed.step();
    CHECK(plane::isFolded(*straight.world().fields.grid("growth_acc")));
    CHECK(!plane::isFolded(*resumed.world().fields.grid("growth_acc")));
    // p and T of the old layout are folded by the phase field's next step (a permutation that
    // keeps the standing region: the frames below are the same)
    for (const char* f : {"p", "T"}) {
        CHECK(plane::isFolded(*straight.world().fields.grid(f)));
        CHECK(plane::isFolded(*resumed.world().fields.grid(f)));
    }
    const Frame a = straight.currentFrame(1), b = resumed.currentFrame(1);
    REQUIRE(a.grids.size() == b.grids.size());
    for (size_t i = 0; i < a.grids.size(); ++i) {
        auto x = openvdb::gridPtrCast<openvdb::FloatGrid>(a.grids[i]);
        auto y = openvdb::gridPtrCast<openvdb::FloatGrid>(b.grids[i]);
        REQUIRE(x);
        REQUIRE(y);
        INFO(x->getName());
        CHECK(x->getName() == y->getName());
        CHECK(x->tree().hasSameTopology(y->tree()));
        CHECK(maxAbsDiff(*x, *y) == 0.0);
    }
}

TEST_CASE("A plane region's folded topology and a folded grid's plane topology are the fold's", "[fast][fold]")
{
    // a plane region of partly filled leaves, negative coordinates included
    auto region = openvdb::MaskGrid::create(false);
    auto g = openvdb::FloatGrid::create(0.f);
    for (int y = -20; y < 30; ++y)
        for (int x = -75; x < 90; ++x)
            if ((x * 7 + y * 3) % 5 != 0) {
                region->tree().setValueOn(openvdb::Coord(x, y, 0));
                g->tree().setValue(openvdb::Coord(x, y, 0), float(x - y));
            }
    auto folded = plane::foldTopology(*region);
    CHECK(plane::isFolded(*folded));
    CHECK(folded->activeVoxelCount() == region->activeVoxelCount());
    for (auto it = region->tree().cbeginValueOn(); it; ++it) REQUIRE(folded->tree().isValueOn(plane::fold(it.getCoord())));
    // every plane leaf has its folded leaf, even an empty one
    region->tree().touchLeaf(openvdb::Coord(400, 400, 0));
    CHECK(plane::foldTopology(*region)->tree().probeConstLeaf(plane::foldedLeafOrigin(openvdb::Coord(400, 400, 0))));
    auto back = plane::unfoldTopology(*plane::foldGrid(*g));
    CHECK(back->tree().hasSameTopology(openvdb::MaskTree(g->tree(), false, openvdb::TopologyCopy())));
}

namespace {
/// Leaf origins and value masks of @a tree, in tree order, and its node counts per level.
std::pair<std::vector<std::pair<openvdb::Coord, std::array<uint64_t, 8>>>, std::vector<openvdb::Index32>>
leavesAndNodes(const openvdb::MaskTree& tree)
{
    std::vector<std::pair<openvdb::Coord, std::array<uint64_t, 8>>> leaves;
    for (auto it = tree.cbeginLeaf(); it; ++it) {
        std::array<uint64_t, 8> words{};
        for (int w = 0; w < 8; ++w) words[size_t(w)] = it->getValueMask().template getWord<uint64_t>(openvdb::Index(w));
        leaves.emplace_back(it->origin(), words);
    }
    return {leaves, tree.nodeCount()};
}
} // namespace

TEST_CASE("The region of folded p and T is the region of the plane layout's, folded, for every reach", "[fast][fold][region]")
{
    // random sources on a domain with a negative origin off the leaf grid, some outside it;
    // steps 1..3: the leaf-level path reading folded chunks, 9: through the unfolded topology
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        const Lattice lat{kind, 3.0 / 64.0};
        const Domain dom = makePlaneDomain(lat, openvdb::Coord(203, 150, 1), 1e-4, openvdb::Coord(-77, -13, 0));
        auto p = openvdb::FloatGrid::create(0.f), T = openvdb::FloatGrid::create(0.f);
        for (uint64_t i = 0; i < 300; ++i) {
            const int x = -90 + int(toUnit(hashCounters(7, i, 0, 0)) * 240);
            const int y = -20 + int(toUnit(hashCounters(7, i, 1, 0)) * 180);
            (i % 3 ? T : p)->tree().setValue(openvdb::Coord(x, y, 0), 0.25f);
        }
        const auto pf = plane::foldGrid(*p), tf = plane::foldGrid(*T);
        RegionSettings rs;
        for (int steps : {1, 2, 3, 9}) {
            INFO("lattice " << int(kind) << ", steps " << steps);
            const auto want = buildActiveRegion({p.get(), T.get()}, rs, 2, dom, steps);
            const auto got = buildActiveRegionOfFolded({pf.get(), tf.get()}, rs, 2, dom, steps);
            CHECK(plane::isFolded(*got));
            CHECK(leavesAndNodes(got->tree()) == leavesAndNodes(plane::foldTopology(*want)->tree()));
            CHECK(got->activeVoxelCount() == want->activeVoxelCount());
            // unchanged fields: the last region comes back as it is
            CHECK(buildActiveRegionOfFolded({pf.get(), tf.get()}, rs, 2, dom, steps, got) == got);
        }
    }
}


TEST_CASE("A folded region edited in place equals the one built afresh", "[fast][fold][region]")
{
    // sources that move across the domain round by round, so leaves are gained and lost, the
    // support's edge clips some (a negative origin off the leaf grid), internal nodes empty out
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal})
        for (int steps : {1, 3}) {
            const Lattice lat{kind, 3.0 / 64.0};
            const Domain dom = makePlaneDomain(lat, openvdb::Coord(603, 350, 1), 1e-4, openvdb::Coord(-77, -13, 0));
            RegionSettings rs;
            openvdb::MaskGrid::Ptr standing;
            size_t removed = 0, added = 0;
            for (int round = 0; round < 12; ++round) {
                INFO("lattice " << int(kind) << ", steps " << steps << ", round " << round);
                auto p = openvdb::FloatGrid::create(0.f), T = openvdb::FloatGrid::create(0.f);
                const int shift = round == 6 ? 5 * 40 : round * 40; // round 6: the fields of round 5
                for (uint64_t i = 0; i < 120; ++i) {
                    const int x = -90 + shift + int(toUnit(hashCounters(9, i, 0, 0)) * 200);
                    const int y = -20 + int(toUnit(hashCounters(9, i, 1, uint64_t(round == 6 ? 5 : round))) * 380);
                    (i % 3 ? T : p)->tree().setValue(openvdb::Coord(x, y, 0), 0.25f);
                }
                const auto pf = plane::foldGrid(*p), tf = plane::foldGrid(*T);
                const auto fresh = buildActiveRegionOfFolded({pf.get(), tf.get()}, rs, 2, dom, steps);
                CHECK(leavesAndNodes(fresh->tree()) ==
                      leavesAndNodes(plane::foldTopology(*buildActiveRegion({p.get(), T.get()}, rs, 2, dom, steps))->tree()));
                if (!standing) {
                    standing = fresh->deepCopy();
                    continue;
                }
                RegionEdit edit;
                CHECK(buildActiveRegionOfFolded({pf.get(), tf.get()}, rs, 2, dom, steps, standing, &edit) == standing);
                CHECK(edit.empty() == (round == 6)); // unchanged fields: nothing edited
                removed += edit.removed.size();
                added += edit.added.size();
                CHECK(leavesAndNodes(standing->tree()) == leavesAndNodes(fresh->tree()));
                CHECK(standing->tree().hasSameTopology(fresh->tree()));
            }
            CHECK(removed > 100); // the history did lose and gain leaves
            CHECK(added > 100);
        }
}

TEST_CASE("A folded grid draws the displacement map of its plane layout byte for byte", "[fast][fold][export]")
{
    // columns across a 64-column tile, a 1024-column span and a band edge (x = 0), values in [0, 1]
    // and inactive ones off the background
    const Lattice hex{LatticeKind::Hexagonal, 3.0 / 64.0};
    const Domain dom = makePlaneDomain(hex, openvdb::Coord(300, 200, 1), 1e-4, openvdb::Coord(-140, -8, 0));
    auto g = openvdb::FloatGrid::create(0.f);
    g->setName("growth");
    g->setTransform(dom.transform()->copy());
    for (int i = 0; i < 9000; ++i) {
        const uint64_t h = hashCounters(31, uint64_t(i));
        const openvdb::Coord c(int(h % 300) - 140, int((h >> 20) % 200) - 8, 0);
        if (h >> 60 & 3) g->tree().setValueOn(c, float(h % 1000) * 0.001f);
        else g->tree().setValueOff(c, 0.5f);
    }
    const auto folded = plane::foldGrid(*g);
    const auto plane = plane::unfoldGrid(*folded); // what a frame held: the plane layout of the field
    const std::string dir = tempDir("fold_pngs");
    for (int tile : {64, 1 << 30}) {
        INFO("tile " << tile);
        const auto want = writeDisplacementMaps(*plane, dom, dir + "/plane", tile);
        const auto got = writeDisplacementMaps(*folded, dom, dir + "/folded", tile);
        REQUIRE(want.size() == got.size());
        CHECK(!want.empty());
        for (size_t i = 0; i < want.size(); ++i) CHECK(fileBytes(want[i]) == fileBytes(got[i]));
    }
}

namespace {
/// A hexagonal 300 x 200 plane away from the origin, for the export tests.
Domain exportTestDomain()
{
    const Lattice hex{LatticeKind::Hexagonal, 3.0 / 64.0};
    return makePlaneDomain(hex, openvdb::Coord(300, 200, 1), 1e-4, openvdb::Coord(-40, -8, 0));
}
/// Scattered values on @a dom: inactive values off the background, chunks of inactive values
/// only, a domain's edge.
openvdb::FloatGrid::Ptr scatteredPlaneField(const Domain& dom)
{
    auto g = openvdb::FloatGrid::create(0.25f);
    g->setName("g");
    g->setTransform(dom.transform()->copy());
    for (int i = 0; i < 6000; ++i) {
        const uint64_t h = hashCounters(11, uint64_t(i));
        const openvdb::Coord c(int(h % 300) - 40, int((h >> 20) % 200) - 8, 0);
        if (h >> 60 & 1) g->tree().setValueOn(c, float(h % 1000) * 0.001f);
        else g->tree().setValueOff(c, -float(h % 1000));
    }
    return g;
}
} // namespace

TEST_CASE("A folded field resampled in place exports the bits its unfolded copy exports", "[fast][fold][export]")
{
    const Domain dom = exportTestDomain();
    const auto folded = plane::foldGrid(*scatteredPlaneField(dom));
    auto dress = [](openvdb::FloatGrid& x) {
        x.setName("dressed");
        x.setGridClass(openvdb::GRID_UNKNOWN);
    };
    for (bool keep : {false, true}) {
        INFO("keep lattice " << keep);
        auto copy = plane::unfoldGrid(*folded);
        dress(*copy);
        const auto want = openvdb::gridPtrCast<openvdb::FloatGrid>(exportGrid(copy, dom, keep));
        const auto got = openvdb::gridPtrCast<openvdb::FloatGrid>(exportFolded(*folded, dom, keep, dress));
        REQUIRE(want);
        REQUIRE(got);
        CHECK(got->str() == want->str()); // name, class, metadata
        CHECK(got->transform() == want->transform());
        CHECK(got->tree().hasSameTopology(want->tree()));
        CHECK(got->activeVoxelCount() > 0);
        auto acc = got->getConstAccessor();
        size_t differ = 0;
        for (auto it = want->cbeginValueAll(); it; ++it)
            if (std::memcmp(&*it, &static_cast<const float&>(acc.getValue(it.getCoord())), sizeof(float)) != 0) ++differ;
        CHECK(differ == 0);
    }
}

TEST_CASE("A streamed folded export writes the file of exportFolded's grid", "[fast][fold][export]")
{
    const Domain dom = exportTestDomain();
    const openvdb::FloatGrid::ConstPtr folded = plane::foldGrid(*scatteredPlaneField(dom));
    auto dress = [](openvdb::FloatGrid& x) { x.setName("dressed"); };
    const auto eager = exportFolded(*folded, dom, false, dress);
    const auto streamed = exportFoldedStreamed(folded, dom, false, dress);
    REQUIRE(dynamic_cast<const StreamedFloatGrid*>(streamed.get()));
    CHECK(streamed->activeVoxelCount() == eager->activeVoxelCount());
    CHECK(streamed->memUsage() == eager->memUsage()); // written as file_mem_bytes
    const std::string dir = tempDir("streamed_export");
    for (bool half : {false, true}) {
        INFO("half " << half);
        writeVdbAtomic(dir + "/eager.vdb", {eager}, openvdb::MetaMap(), half);
        writeVdbAtomic(dir + "/streamed.vdb", {streamed}, openvdb::MetaMap(), half);
        // the same bytes but the header's random UUID (36 characters after 21 bytes)
        const std::string a = fileBytes(dir + "/eager.vdb"), b = fileBytes(dir + "/streamed.vdb");
        REQUIRE(a.size() == b.size());
        CHECK(a.substr(0, 21) == b.substr(0, 21));
        CHECK(a.substr(57) == b.substr(57));
    }
    // its values are read by nothing but the writer: the eager grid's are what the file holds
    const auto back = openvdb::gridPtrCast<openvdb::FloatGrid>(readVdb(dir + "/streamed.vdb")->front());
    REQUIRE(back);
    CHECK(back->tree().hasSameTopology(openvdb::gridPtrCast<openvdb::FloatGrid>(eager)->tree()));
}
