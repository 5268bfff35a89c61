// Issue 24 (planes): whole frames of a square and a hexagonal hybrid scene (walkers + phase
// field, both schemes) compared bit for bit between the session's new paths and the ones they
// replace, switched by environment variables read at every step:
//  - FROSTVDB_FULL_DISTANCE_SYNC=1: the walkers' distance map reads all of p each step instead
//    of the cells where the phase field moved p across 1/2;
//  - FROSTVDB_NO_VECTOR_ROWS=1: the plain rows instead of the vector ones (the hexagonal
//    lattice's D6 rows are new);
//  - FROSTVDB_NO_FUSED_TRUNCATION=1: truncation as its own pass instead of in forward Euler's commit.
#include <catch2/catch.hpp>

#include "test_util.h"

#include <frostvdb/core/FieldEdits.h>
#include <frostvdb/core/FieldWriters.h>

#include <cstdlib>

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

const char* const kOldPaths[] = {"FROSTVDB_FULL_DISTANCE_SYNC", "FROSTVDB_NO_VECTOR_ROWS", "FROSTVDB_NO_FUSED_TRUNCATION"};

/// Runs @a text writing every frame; with @a old the replaced paths (all of them).
std::vector<std::string> runFrames(const std::string& text, bool old, const std::string& tag, int threads)
{
    for (const char* v : kOldPaths) {
        if (old) ::setenv(v, "1", 1);
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
    return {ro.outDir + "/hybrid.0001.vdb", ro.outDir + "/hybrid.0002.vdb"};
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
