// Scene-level tests of the automata effects: every rule runs from a scene and writes cells, ice
// and freeze_step; batch mode makes distinct flakes; the shipped scenes parse.
#include <frostvdb/BuildPaths.h>
#include <openvdb/tools/Count.h>
#include <catch2/catch.hpp>

#include <frostvdb/automata/AutomatonEffect.h>
#include <frostvdb/core/Scene.h>
#include <frostvdb/core/Simulation.h>

#include <filesystem>
#include <map>

using namespace frostvdb;

namespace {

std::map<std::string, openvdb::FloatGrid::Ptr> runScene(const std::string& text, Simulation** keep = nullptr)
{
    static std::unique_ptr<Simulation> sim;
    sim = std::make_unique<Simulation>(Scene::fromString(text, "<test>"));
    sim->initialize();
    const int64_t steps = sim->world().frames * sim->world().stepsPerFrame;
    for (int64_t s = 0; s < steps; ++s) sim->step();
    Frame f = sim->currentFrame(1);
    std::map<std::string, openvdb::FloatGrid::Ptr> grids;
    for (auto& g : f.grids) grids[g->getName()] = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
    if (keep) *keep = sim.get();
    return grids;
}

} // namespace

TEST_CASE("every automaton section writes cells, ice and freeze_step", "[automata][fast]")
{
    // [gravner_griffeath_3d] has its own tests (gg3d_test.cpp).
    const char* sections[] = {"packard", "coxe_reiter", "probabilistic_ca", "reiter", "gravner_griffeath"};
    for (const char* sec : sections) {
        const bool is3D = std::string(sec) == "gravner_griffeath_3d";
        std::string text = "[scene]\nframes = 1\nsteps_per_frame = " + std::string(is3D ? "40" : "60") +
                           "\n[domain]\nsize = [81, 81]\nvoxel_size = 0.001\n[" + sec + "]\n";
        if (is3D) text += "layers = 11\nradius = 20\n";
        if (std::string(sec) == "reiter") text += "beta = 0.8\ngamma = 0.002\n";
        INFO(sec);
        auto g = runScene(text);
        REQUIRE(g.count("cells"));
        REQUIRE(g.count("automaton_ice"));
        REQUIRE(g.count("freeze_step"));
        CHECK(g["cells"]->activeVoxelCount() > 0);
        CHECK(g["automaton_ice"]->activeVoxelCount() > 0);
        CHECK(g["freeze_step"]->activeVoxelCount() > 1);
        CHECK(g["automaton_ice"]->getGridClass() == openvdb::GRID_FOG_VOLUME);
        // `ice` is on cubes; `cells` uses the sheared hexagonal transform.
        const auto vs = g["automaton_ice"]->voxelSize();
        CHECK(vs.x() == Approx(vs.y()));
        CHECK(vs.x() == Approx(vs.z()));
        CHECK(g["automaton_ice"]->evalActiveVoxelBoundingBox().dim().z() > 1);
        const auto ice = openvdb::tools::minMax(g["automaton_ice"]->tree());
        CHECK(ice.max() <= 1.0f);
        CHECK(ice.min() >= 0.0f);
        // The seed cell is at index (0, 0, 0) and froze at step 0.
        CHECK(g["freeze_step"]->tree().getValue(openvdb::Coord(0)) == 0.0f);
        // World position of cell (1, 0) is one cell spacing along x.
        const auto p = g["cells"]->transform().indexToWorld(openvdb::Coord(1, 0, 0));
        CHECK(p.x() == Approx(0.001));
        CHECK(p.y() == Approx(0.0).margin(1e-12));
    }
}

TEST_CASE("batch mode grows K distinct flakes in one run", "[automata][fast]")
{
    const std::string text = "[scene]\nframes = 1\nsteps_per_frame = 40\nseed = 3\n"
                             "[domain]\nsize = [61, 61]\n[coxe_reiter]\nbackground = 0.2\nbatch = 3\n";
    Simulation* sim = nullptr;
    auto g = runScene(text, &sim);
    for (const char* name : {"automaton_ice", "automaton_ice_0", "automaton_ice_1", "automaton_ice_2", "cells_0", "cells_1", "cells_2", "freeze_step_2"}) {
        INFO(name);
        REQUIRE(g.count(name));
        CHECK(g[name]->activeVoxelCount() > 0);
    }
    CHECK(g["automaton_ice_1"]->activeVoxelCount() != g["automaton_ice_2"]->activeVoxelCount());
    auto* fx = dynamic_cast<automata::AutomatonEffect*>(sim->effect("coxe_reiter"));
    REQUIRE(fx);
    REQUIRE(fx->flakes().size() == 3);
    for (auto& f : fx->flakes()) {
        CHECK(f->usesWedge());
        CHECK(f->isD6Symmetric());
    }
    // The combined grid holds every flake side by side; each ice_k is centred on the origin.
    CHECK(g["automaton_ice"]->activeVoxelCount() ==
          g["automaton_ice_0"]->activeVoxelCount() + g["automaton_ice_1"]->activeVoxelCount() + g["automaton_ice_2"]->activeVoxelCount());
    const auto bb = g["automaton_ice_2"]->evalActiveVoxelBoundingBox();
    CHECK(bb.min().x() == -bb.max().x());
    // Flake 0 is exactly the unbatched flake.
    const uint64_t flake0 = g["automaton_ice_0"]->activeVoxelCount();
    auto single = runScene("[scene]\nframes = 1\nsteps_per_frame = 40\nseed = 3\n"
                           "[domain]\nsize = [61, 61]\n[coxe_reiter]\nbackground = 0.2\n");
    CHECK(single["automaton_ice"]->activeVoxelCount() == flake0);
}

TEST_CASE("unknown keys and other rules' keys are errors", "[automata][fast]")
{
    CHECK_THROWS(Simulation(Scene::fromString("[packard]\nbackground = 0.2\n", "<t>")));
    CHECK_THROWS(Simulation(Scene::fromString("[coxe_reiter]\nbackground = 0.7\n", "<t>")));
    CHECK_THROWS(Simulation(Scene::fromString("[probabilistic_ca]\np_freeze = [0.5]\n", "<t>")));
    CHECK_NOTHROW(Simulation(Scene::fromString("[reiter]\nbeta = 0.35\n", "<t>")));
}

TEST_CASE("shipped automata scenes load and validate", "[automata][fast]")
{
    namespace fs = std::filesystem;
    int n = 0;
    for (const auto& e : fs::directory_iterator(fs::path(FROSTVDB_SOURCE_DIR) / "scenes")) {
        const std::string name = e.path().filename().string();
        if (name.rfind("automata_", 0) != 0 || e.path().extension() != ".toml") continue;
        INFO(name);
        CHECK_NOTHROW(Simulation(Scene::load(e.path().string())));
        ++n;
    }
    CHECK(n >= 8);
}
