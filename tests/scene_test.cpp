// Scene validation: each kind of bad input gives a message naming file, line and key.
#include <frostvdb/BuildPaths.h>
#include "test_util.h"

#include <frostvdb/core/Error.h>

#include <catch2/catch.hpp>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

const char* kGood = "[domain]\nsize = [32, 32]\n\n[phase_field]\ndt = 0.0002\n";

} // namespace

TEST_CASE("A valid scene builds only the effects it names", "[fast][scene]")
{
    auto sim = makeSim(kGood);
    REQUIRE(sim.effects().size() == 1);
    CHECK(sim.effects()[0]->name() == "phase_field");
    sim.initialize();
    // Only the fields the phase field asked for exist.
    std::vector<std::string> names = sim.world().fields.names();
    std::sort(names.begin(), names.end());
    CHECK(names == std::vector<std::string>{"T", "freeze_time", "growth_acc", "p"});
}

TEST_CASE("Bad scenes are refused with file, line and key", "[fast][scene]")
{
    SECTION("unknown section")
    {
        const auto msg = errorOf(std::string(kGood) + "\n[snowman]\nsize = 3\n");
        CHECK(msg.find("test.toml:7") != std::string::npos);
        CHECK(msg.find("[snowman]") != std::string::npos);
        CHECK(msg.find("unknown section") != std::string::npos);
    }
    SECTION("unknown key")
    {
        const auto msg = errorOf("[phase_field]\ndt = 0.0002\ndetla = 0.1\n");
        CHECK(msg.find("test.toml:3") != std::string::npos);
        CHECK(msg.find("phase_field.detla") != std::string::npos);
        CHECK(msg.find("unknown key") != std::string::npos);
        CHECK(msg.find("delta") != std::string::npos); // the known keys are listed
    }
    SECTION("wrong type")
    {
        const auto msg = errorOf("[phase_field]\n\ndt = \"fast\"\n");
        CHECK(msg.find("test.toml:3") != std::string::npos);
        CHECK(msg.find("phase_field.dt") != std::string::npos);
        CHECK(msg.find("expected a number") != std::string::npos);
    }
    SECTION("out of range")
    {
        const auto msg = errorOf("[phase_field]\ndelta = 0.9\n");
        CHECK(msg.find("test.toml:2") != std::string::npos);
        CHECK(msg.find("phase_field.delta") != std::string::npos);
        CHECK(msg.find("out of range [0, 0.5]") != std::string::npos);
    }
    SECTION("bad choice")
    {
        const auto msg = errorOf("[domain]\nlattice = \"triangular\"\n[phase_field]\n");
        CHECK(msg.find("domain.lattice") != std::string::npos);
        CHECK(msg.find("square | hexagonal") != std::string::npos);
    }
    SECTION("wrong array length")
    {
        const auto msg = errorOf("[domain]\nsize = [1, 2, 3, 4]\n[phase_field]\n");
        CHECK(msg.find("test.toml:2") != std::string::npos);
        CHECK(msg.find("domain.size") != std::string::npos);
    }
    SECTION("syntax error")
    {
        const auto msg = errorOf("[phase_field]\ndt = = 3\n");
        CHECK(msg.find("test.toml:2") != std::string::npos);
        CHECK(msg.find("syntax error") != std::string::npos);
    }
    SECTION("no effect at all")
    {
        CHECK(errorOf("[domain]\nsize = [8, 8]\n").find("names no effect") != std::string::npos);
    }
    SECTION("command-line override out of range names --set")
    {
        const auto msg = errorOf(kGood, {"phase_field.dt=5"});
        CHECK(msg.find("--set") != std::string::npos);
        CHECK(msg.find("phase_field.dt") != std::string::npos);
    }
    SECTION("malformed override")
    {
        const auto msg = errorOf(kGood, {"phase_field_dt=5"});
        CHECK(msg.find("section.key=value") != std::string::npos);
    }
}

TEST_CASE("Overrides replace scene values and bare words are strings", "[fast][scene]")
{
    auto sim = makeSim(kGood, {"domain.lattice=hexagonal", "domain.size=[48, 40]", "phase_field.dt=0.0001"});
    CHECK(sim.world().domain.lattice().kind() == LatticeKind::Hexagonal);
    CHECK(sim.world().domain.bbox().max() == openvdb::Coord(47, 39, 0));
}

TEST_CASE("Every registered key is documented with a default and range", "[fast][scene]")
{
    const std::string md = sceneReferenceMarkdown();
    CHECK(md.find("## [phase_field]") != std::string::npos);
    CHECK(md.find("`anisotropy_mode`") != std::string::npos);
    CHECK(md.find("| `tolerance` |") != std::string::npos);
}

TEST_CASE("docs/scene-reference.md is in step with the code", "[fast][scene][docs]")
{
    const std::string onDisk = readFile(std::string(FROSTVDB_SOURCE_DIR) + "/docs/scene-reference.md");
    INFO("regenerate with: build/bin/frostvdb keys > docs/scene-reference.md");
    CHECK(onDisk == sceneReferenceMarkdown());
}

TEST_CASE("A voxel size OpenVDB cannot represent is a scene error", "[fast][scene]")
{
    const auto msg = errorOf("[domain]\nlattice = \"hexagonal\"\nvoxel_size = 1e-8\n[phase_field]\n");
    CHECK(msg.find("test.toml:3") != std::string::npos);
    CHECK(msg.find("domain.voxel_size") != std::string::npos);
}
