// The driver's order comes from the effects' declarations: initialisers before readers, steps in
// the ice paper's stage order whatever the section order, and scenes that give one name two
// meanings, or keys that do not apply to the chosen options, are refused.
#include "test_util.h"

#include <frostvdb/core/Error.h>
#include <frostvdb/core/StepOrder.h>

#include <catch2/catch.hpp>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

std::vector<std::string> names(const Simulation& sim, const std::vector<size_t>& order)
{
    std::vector<std::string> n;
    for (size_t i : order) n.push_back(sim.effects()[i]->name());
    return n;
}

const FieldKey kOther{"ice", FieldType::Float, FieldRole::Output, "kg/m3", "0", "a test's different ice"};
const FieldKey kA{"a", FieldType::Float, FieldRole::Field, "", "0", "test field a"};
const FieldKey kB{"b", FieldType::Float, FieldRole::Field, "", "0", "test field b"};

} // namespace

TEST_CASE("Step and initialisation order follow the declarations, not the section order", "[fast][order]")
{
    // sections deliberately out of the paper's order
    auto sim = makeSim("[domain]\nsize = [48, 48]\n[fluid]\n[phase_field]\n[dla]\nhumidity = 10\n"
                       "[crystal]\n[[crystal.seed]]\nposition = [0.3, 0.5]\n");
    CHECK(names(sim, sim.order().step) == std::vector<std::string>{"crystal", "dla", "phase_field", "fluid"});
    const auto init = names(sim, sim.order().initialize);
    auto at = [&](const std::string& s) { return std::find(init.begin(), init.end(), s) - init.begin(); };
    CHECK(at("crystal") < at("phase_field")); // crystal initialises p, the phase field reads it
    CHECK(at("phase_field") < at("dla"));     // the phase field owns the ice clock the walkers read
    CHECK(at("phase_field") < at("fluid"));

    // the same scene in the paper's order runs the same steps, bit for bit
    auto ordered = makeSim("[domain]\nsize = [48, 48]\n[crystal]\n[[crystal.seed]]\nposition = [0.3, 0.5]\n"
                           "[dla]\nhumidity = 10\n[phase_field]\n[fluid]\n");
    for (int i = 0; i < 5; ++i) {
        sim.step();
        ordered.step();
    }
    for (const char* f : {"p", "T", "growth_acc"})
        CHECK(maxAbsDiff(*sim.world().fields.get<openvdb::FloatGrid>(f),
                         *ordered.world().fields.get<openvdb::FloatGrid>(f)) == 0.0);

    // gases publish density before the walkers read it
    auto steam = makeSim("[domain]\nsize = [32, 32]\nvoxel_size = 0.001\n[dla]\nhumidity = 5\n[steam]\n");
    CHECK(names(steam, steam.order().step) == std::vector<std::string>{"steam", "dla"});
}

TEST_CASE("deriveEffectOrder: writers before readers in a stage, cycles and two meanings refused", "[fast][order]")
{
    FieldDeclaration reader, writer;
    reader.stage = writer.stage = Stage::Sources;
    reader.use(kA, kReads);
    writer.use(kA, kWrites);
    auto o = deriveEffectOrder({{"r", reader}, {"w", writer}}, "t.toml");
    CHECK(o.step == std::vector<size_t>{1, 0});

    FieldDeclaration x, y;
    x.use(kA, kInitialises).use(kB, kReadsAtInit);
    y.use(kB, kInitialises).use(kA, kReadsAtInit);
    std::string msg;
    try { deriveEffectOrder({{"x", x}, {"y", y}}, "t.toml"); } catch (const SceneError& e) { msg = e.what(); }
    CHECK(msg.find("[x]") != std::string::npos);
    CHECK(msg.find("[y]") != std::string::npos);
    CHECK(msg.find("circular") != std::string::npos);

    FieldDeclaration ice, other;
    ice.output(out::kIce);
    other.output(kOther);
    msg.clear();
    try { deriveEffectOrder({{"phase_field", ice}, {"mine", other}}, "t.toml"); } catch (const SceneError& e) { msg = e.what(); }
    CHECK(msg.find("'ice'") != std::string::npos);
    CHECK(msg.find("different meanings") != std::string::npos);
    CHECK(msg.find("kg/m3") != std::string::npos);
}

TEST_CASE("A scene whose effects write one grid name with two meanings is refused", "[fast][order]")
{
    // two automata each put their own `cells` (on their own lattice) into every frame
    const auto msg = errorOf("[domain]\nsize = [32, 32]\n[packard]\n[reiter]\n");
    CHECK(msg.find("[packard] and [reiter]") != std::string::npos);
    CHECK(msg.find("'cells'") != std::string::npos);
    // the automaton's ice has a name of its own (automaton_ice): it no longer clashes with the
    // hybrid ice's `ice`
    CHECK(errorOf("[domain]\nsize = [32, 32]\n[phase_field]\n[packard]\n").find("'ice'") == std::string::npos);
    // steam and fire share `density` and `vel` with one meaning each: accepted
    // (at 1 cm voxels: the default 0.1 mm would exceed the memory budget for the default gas bounds)
    CHECK(errorOf("[domain]\nsize = [32, 32]\nvoxel_size = 0.01\n[steam]\n[fire]\n").empty());
}

TEST_CASE("Keys that do not apply to the chosen options are errors naming the option", "[fast][order][scene]")
{
    auto msg = errorOf("[domain]\nsize = [32, 32]\n[phase_field]\nscheme = \"euler\"\nsolver = \"bicgstab\"\n");
    CHECK(msg.find("phase_field.solver") != std::string::npos);
    CHECK(msg.find("scheme = \"euler\"") != std::string::npos);
    CHECK(msg.find("test.toml:5") != std::string::npos);
    msg = errorOf("[domain]\nsize = [32, 32]\n[phase_field]\nscheme = \"lw_cn\"\nsolver_tolerance = 1e-4\n");
    CHECK(msg.find("phase_field.solver_tolerance") != std::string::npos);
    CHECK(msg.find("precision = \"wp\"") != std::string::npos);
    CHECK(errorOf("[domain]\nsize = [32, 32]\n[phase_field]\nscheme = \"lw_cn\"\nprecision = \"custom\"\n"
                  "solver_tolerance = 1e-4\nsolver = \"bicgstab\"\n").empty());
    msg = errorOf("[domain]\nsize = [32, 32]\n[dla]\njumps = false\njump_max_radius = 40\n");
    CHECK(msg.find("dla.jump_max_radius") != std::string::npos);
    CHECK(msg.find("jumps = false") != std::string::npos);
    msg = errorOf("[domain]\nsize = [32, 32]\n[region]\ndense = true\ntolerance = 1e-3\n[phase_field]\n");
    CHECK(msg.find("region.tolerance") != std::string::npos);
    CHECK(msg.find("dense = true") != std::string::npos);
}
