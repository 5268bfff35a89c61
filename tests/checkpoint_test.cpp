// Checkpoints: the state archive keeps exact bits, every effect with history resumes bit for bit,
// and the real binary killed with SIGKILL at several points resumes to frames identical to an
// uninterrupted run, never showing a partial file under a frame name.
#include "test_util.h"

#include <frostvdb/BuildPaths.h>
#include <frostvdb/core/Checkpoint.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/State.h>

#include <catch2/catch.hpp>

#include <openvdb/io/File.h>

#include <chrono>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <set>
#include <thread>

#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

using namespace frostvdb;
namespace fs = std::filesystem;

namespace {

/// Bit-exact comparison of two grids: type, name, metadata, transform, topology (tiles too) and
/// every stored value, active or not.
template <typename GridT>
bool sameTypedBits(const GridT& a, const GridT& b, std::string& why)
{
    if (a.transform() != b.transform()) return why = "transform", false;
    if (a.str() != b.str()) return why = "metadata", false;
    if (std::memcmp(&a.background(), &b.background(), sizeof(typename GridT::ValueType)) != 0)
        return why = "background", false;
    if (a.tree().leafCount() != b.tree().leafCount() || a.tree().activeTileCount() != b.tree().activeTileCount())
        return why = "node counts", false;
    if (!a.tree().hasSameTopology(b.tree())) return why = "topology", false;
    auto ib = b.tree().cbeginValueAll();
    for (auto ia = a.tree().cbeginValueAll(); ia; ++ia, ++ib) {
        if (!ib || ia.getCoord() != ib.getCoord() || ia.getDepth() != ib.getDepth() || ia.isValueOn() != ib.isValueOn())
            return why = "value layout", false;
        const auto va = *ia, vb = *ib;
        if (std::memcmp(&va, &vb, sizeof(va)) != 0) return why = "value bits", false;
    }
    return !ib || (why = "value count", false);
}

bool sameGridBits(const openvdb::GridBase::ConstPtr& a, const openvdb::GridBase::ConstPtr& b, std::string& why)
{
    if (!a || !b) return (!a && !b) || (why = "null grid", false);
    if (a->type() != b->type() || a->getName() != b->getName()) return why = "type or name", false;
    if (auto x = openvdb::gridConstPtrCast<openvdb::FloatGrid>(a))
        return sameTypedBits(*x, *openvdb::gridConstPtrCast<openvdb::FloatGrid>(b), why);
    if (auto x = openvdb::gridConstPtrCast<openvdb::Vec3SGrid>(a))
        return sameTypedBits(*x, *openvdb::gridConstPtrCast<openvdb::Vec3SGrid>(b), why);
    if (auto x = openvdb::gridConstPtrCast<openvdb::Int32Grid>(a))
        return sameTypedBits(*x, *openvdb::gridConstPtrCast<openvdb::Int32Grid>(b), why);
    if (auto x = openvdb::gridConstPtrCast<openvdb::DoubleGrid>(a))
        return sameTypedBits(*x, *openvdb::gridConstPtrCast<openvdb::DoubleGrid>(b), why);
    return why = "unsupported type " + a->type(), false;
}

/// Every World field and every grid of the current frame, bit for bit.
void requireSameState(Simulation& a, Simulation& b, const std::string& label)
{
    INFO(label);
    REQUIRE(a.stepsTaken() == b.stepsTaken());
    REQUIRE(a.world().fields.names().size() == b.world().fields.names().size());
    for (const auto& n : a.world().fields.names()) {
        std::string why;
        INFO("field " << n);
        CHECK(sameGridBits(a.world().fields.grid(n), b.world().fields.grid(n), why));
        INFO(why);
    }
    const Frame fa = a.currentFrame(1), fb = b.currentFrame(1);
    REQUIRE(fa.grids.size() == fb.grids.size());
    CHECK(fa.time == fb.time);
    for (size_t i = 0; i < fa.grids.size(); ++i) {
        std::string why;
        const bool same = sameGridBits(fa.grids[i], fb.grids[i], why);
        INFO("frame grid " << fa.grids[i]->getName() << ": " << why);
        CHECK(same);
    }
}

/// Runs @a total steps straight, and again as k steps + checkpoint + a fresh Simulation resumed
/// from it + the rest; the two end states must agree bit for bit.
void checkResume(const std::string& label, const std::string& text, int64_t k, int64_t total)
{
    const std::string dir = test::tempDir("ckpt_" + label);
    const std::string path = checkpointPath(dir, "resume");
    Simulation straight = test::makeSim(text);
    for (int64_t s = 0; s < total; ++s) straight.step();
    {
        Simulation first = test::makeSim(text);
        for (int64_t s = 0; s < k; ++s) first.step();
        while (!first.atCheckpointBoundary()) first.step(); // as the driver defers a due checkpoint
        k = first.stepsTaken();
        REQUIRE(k < total);
        first.saveCheckpoint(path);
    }
    Simulation resumed = test::makeSim(text);
    resumed.loadCheckpoint(path);
    REQUIRE(resumed.stepsTaken() == k);
    for (int64_t s = k; s < total; ++s) resumed.step();
    requireSameState(straight, resumed, label);
}

std::string scene(const std::string& body, const std::string& size = "[40, 40]")
{
    return "[scene]\nname = \"resume\"\nseed = 7\nframes = 2\nsteps_per_frame = 6\n[domain]\nsize = " + size +
           "\nvoxel_size = 0.0001\n" + body;
}

} // namespace

TEST_CASE("state archive keeps exact bits and refuses damaged files", "[checkpoint]")
{
    StateArchive a;
    StateWriter w(a);
    w.putInt("i", -(int64_t(1) << 60));
    w.putDouble("d", 0.1 + 0.2);
    w.putDouble("negzero", -0.0);
    w.putString("s", std::string("a\0b", 3));
    w.scope("fx").putArray("arr", std::vector<uint16_t>{1, 65535, 7});
    auto g = openvdb::FloatGrid::create(0.25f);
    g->setName("p");
    g->tree().setValue(openvdb::Coord(1, 2, 3), -0.0f);
    g->tree().setValueOff(openvdb::Coord(4, 2, 3), 0.3f);       // an inactive non-background value
    g->tree().setValueOff(openvdb::Coord(5, 2, 3), -0.25f);     // -background, folded by mask compression
    g->tree().fill(openvdb::CoordBBox(openvdb::Coord(64), openvdb::Coord(95)), 2.f, true); // a tile
    g->insertMeta("note", openvdb::StringMetadata("kept"));
    w.putGrid("g", g);
    w.putGrid("none", nullptr);

    const std::string dir = test::tempDir("ckpt_archive");
    const std::string path = dir + "/x.checkpoint";
    writeCheckpointFile(path, a);
    const StateArchive b = readCheckpointFile(path);
    StateReader r(b);
    CHECK(r.getInt("i") == -(int64_t(1) << 60));
    CHECK(r.getDouble("d") == 0.1 + 0.2);
    CHECK(std::signbit(r.getDouble("negzero")));
    CHECK(r.getString("s") == std::string("a\0b", 3));
    std::vector<uint16_t> arr;
    r.scope("fx").getArray("arr", arr);
    CHECK(arr == std::vector<uint16_t>{1, 65535, 7});
    std::vector<uint32_t> wrong;
    CHECK_THROWS_AS(r.scope("fx").getArray("arr", wrong), CheckpointError);
    auto back = r.getGrid<openvdb::FloatGrid>("g");
    std::string why;
    CHECK(sameTypedBits(*g, *back, why));
    INFO(why);
    CHECK(std::signbit(back->tree().getValue(openvdb::Coord(5, 2, 3))));
    CHECK(r.getGridBase("none") == nullptr);
    CHECK_THROWS_AS(r.getGrid<openvdb::Vec3SGrid>("g"), CheckpointError);
    CHECK_THROWS_AS(r.getInt("missing"), CheckpointError);
    // no temporary is left beside it
    int files = 0;
    for (auto& e : fs::directory_iterator(dir)) files += e.path().filename() == "x.checkpoint" ? 1 : 100;
    CHECK(files == 1);

    std::string bytes = test::readFile(path);
    std::string damaged = bytes;
    damaged[bytes.size() / 2] ^= 0x10;
    CHECK_THROWS_WITH(StateArchive::deserialise(damaged, "d"), Catch::Contains("checksum"));
    CHECK_THROWS_WITH(StateArchive::deserialise(bytes.substr(0, bytes.size() - 9), "t"), Catch::Contains("truncated"));
    CHECK_THROWS_WITH(StateArchive::deserialise("hello", "h"), Catch::Contains("not a frostvdb checkpoint"));
    CHECK_THROWS_WITH(readCheckpointFile(dir + "/absent.checkpoint"), Catch::Contains("no checkpoint"));
}

TEST_CASE("checkpoint policy: N steps or Nm minutes, anything else refused", "[checkpoint]")
{
    CHECK(CheckpointPolicy::parse("25").everySteps == 25);
    CHECK(CheckpointPolicy::parse("30m").everyMinutes == 30.0);
    CHECK(CheckpointPolicy::parse("0.5m").everyMinutes == 0.5);
    CHECK_FALSE(CheckpointPolicy::parse("").enabled());
    for (const char* bad : {"0", "-3", "2.5", "m", "0m", "-1m", "10s", "5x", "nanm", "1e999m"})
        CHECK_THROWS_WITH(CheckpointPolicy::parse(bad), Catch::Contains("--checkpoint-every"));
}

TEST_CASE("an effect with history but no state implementation refuses checkpoints", "[checkpoint]")
{
    struct Historic : Effect {
        std::string name() const override { return "historic"; }
        FieldDeclaration declaration() const override { return {}; }
        void initialize(World&) override {}
        void step(World&, const StepInfo&) override {}
        void addToFrame(World&, Frame&) override {}
    } fx;
    World world;
    StateArchive a;
    StateWriter w(a);
    CHECK_FALSE(fx.supportsCheckpoint());
    CHECK_THROWS_WITH(fx.saveState(world, w), Catch::Contains("[historic] keeps state"));
    CHECK_THROWS_AS(fx.loadState(world, StateReader(a)), CheckpointError);
}

TEST_CASE("every effect with history resumes bit for bit", "[checkpoint]")
{
    SECTION("phase field, forward Euler with noise")
    checkResume("euler", scene("[phase_field]\nnoise = 0.01\n"), 5, 11);
    SECTION("phase field, lw_cn (history grids)")
    checkResume("lwcn", scene("[phase_field]\nscheme = \"lw_cn\"\nprecision = \"rp\"\n"), 4, 9);
    SECTION("DLA with multiple hits and a melt map, on the phase field")
    checkResume("dla", scene("[[crystal.seed]]\nshape = \"point\"\nradius = 2\n[[crystal.melt]]\nshape = \"edge\"\n"
                             "edges = \"left\"\nvalue = 0.5\n[phase_field]\n[dla]\nhumidity = 40\nhits = 2\nbatch = 7\n"),
                5, 12);
    SECTION("fluid around the crystal (velocities and warm-started pressure)")
    checkResume("fluid", scene("[phase_field]\nanisotropy_mode = 4\n[fluid]\ninflow_speed = 3.5\ntolerance = 1e-3\n"),
                3, 7);
    SECTION("fluid, the sparse band solver (velocities and the pressure on its unknowns)")
    checkResume("fluid_sparse", scene("[phase_field]\nanisotropy_mode = 4\n[fluid]\ninflow_speed = 3.5\nsolver = \"sparse\"\nband_width = 6\n"),
                4, 9);
    SECTION("DLA humidity from steam (gas published into the fields)")
    checkResume("steam", scene("[steam]\ncenter = [0.002, 0.002, 0.001]\nradius = 0.002\nheight = 0.004\n"
                               "density_scale = 40.0\nthreshold = 0.01\n[dla]\nhumidity = 30\nsteam_humidity = 2.0\n"),
                6, 13);
    SECTION("Packard")
    checkResume("packard", scene("[packard]\n", "[41, 41]"), 4, 10);
    SECTION("Coxe-Reiter")
    checkResume("coxe", scene("[coxe_reiter]\n", "[41, 41]"), 4, 10);
    SECTION("probabilistic, a batch of flakes")
    checkResume("prob", scene("[probabilistic_ca]\nbatch = 3\n", "[41, 41]"), 4, 10);
    SECTION("Reiter")
    checkResume("reiter", scene("[reiter]\n", "[41, 41]"), 4, 10);
    SECTION("Gravner-Griffeath 2D with noise")
    checkResume("gg", scene("[gravner_griffeath]\nsigma = 0.01\n", "[41, 41]"), 4, 10);
    SECTION("Gravner-Griffeath 3D, 1/24 wedge: the active box regrows after the checkpoint")
    checkResume("gg3d_wedge", scene("[gravner_griffeath_3d]\npreset = \"fig07_plate\"\ndomain_radius = 14\nlayers = 9\n",
                                    "[31, 31]"), 9, 40);
    SECTION("Gravner-Griffeath 3D, whole domain, drift, noise, a switch after the checkpoint, 2 flakes")
    checkResume("gg3d_switch",
                scene("[gravner_griffeath_3d]\npreset = \"fig14_classic_dendrite\"\ndomain_radius = 12\nlayers = 11\n"
                      "wedge = false\nphi = 0.01\nnoise = 0.00001\nswitch_step = 14\nswitch_beta = [1.2]\nbatch = 2\n",
                      "[25, 25]"),
                8, 24);
    SECTION("Gravner-Griffeath 3D, a time-switched preset resumed after its switch")
    checkResume("gg3d_after", scene("[gravner_griffeath_3d]\npreset = \"fig32_capped_column\"\nswitch_step = 5\n"
                                    "domain_radius = 10\nlayers = 15\n", "[21, 21]"), 7, 18);
}

TEST_CASE("Gravner-Griffeath 3D checkpoint from another domain is refused by name", "[checkpoint][gg3d]")
{
    const std::string text = scene("[gravner_griffeath_3d]\ndomain_radius = 10\nlayers = 9\n", "[21, 21]");
    const std::string path = checkpointPath(test::tempDir("ckpt_gg3d_other"), "resume");
    {
        Simulation sim = test::makeSim(text);
        for (int s = 0; s < 3; ++s) sim.step();
        sim.saveCheckpoint(path);
    }
    // the scene check names the differing key before any array is touched
    Simulation other = test::makeSim(text, {"gravner_griffeath_3d.domain_radius=11"});
    CHECK_THROWS_WITH(other.loadCheckpoint(path), Catch::Contains("gravner_griffeath_3d.domain_radius"));
}

TEST_CASE("resume refuses another scene and names the first differing parameter", "[checkpoint]")
{
    const std::string text = scene("[phase_field]\n");
    const std::string dir = test::tempDir("ckpt_mismatch");
    const std::string path = checkpointPath(dir, "resume");
    {
        Simulation sim = test::makeSim(text);
        sim.step();
        sim.saveCheckpoint(path);
    }
    Simulation other = test::makeSim(text, {"phase_field.delta=0.05"});
    CHECK_THROWS_WITH(other.loadCheckpoint(path), Catch::Contains("phase_field.delta = 0.05"));
    // output settings and the frame count may change: extend a finished run, write other previews
    Simulation more = test::makeSim(text, {"scene.frames=5", "output.preview=every"});
    CHECK_NOTHROW(more.loadCheckpoint(path));
    CHECK(more.stepsTaken() == 1);
}

// ---------------------------------------------------------------------------------------------
// The real binary, killed with SIGKILL.

namespace {

pid_t spawn(const std::vector<std::string>& args)
{
    const pid_t pid = fork();
    if (pid == 0) {
        const int devnull = open("/dev/null", O_WRONLY);
        dup2(devnull, 1);
        dup2(devnull, 2);
        std::vector<char*> argv;
        argv.push_back(const_cast<char*>(FROSTVDB_BINARY));
        for (auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
        argv.push_back(nullptr);
        execv(FROSTVDB_BINARY, argv.data());
        _exit(127);
    }
    return pid;
}

int waitExit(pid_t pid)
{
    int st = 0;
    waitpid(pid, &st, 0);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -WTERMSIG(st);
}

/// Same bytes, except the 36-character UUID OpenVDB puts in every file header (bytes 21-56).
bool sameFrameFile(const std::string& a, const std::string& b)
{
    const bool vdb = a.size() > 4 && a.substr(a.size() - 4) == ".vdb";
    if (!vdb) return test::readFile(a) == test::readFile(b);
    // Every grid bit for bit and every file metadata item equal, except the recorded command
    // line: a resumed frame says truthfully that it was made by `run ... --resume DIR`.
    openvdb::io::File fa(a), fb(b);
    fa.open(false);
    fb.open(false);
    auto ma = fa.getMetadata(), mb = fb.getMetadata();
    ma->removeMeta("command_line");
    mb->removeMeta("command_line");
    if (ma->str() != mb->str()) return false;
    auto ga = fa.getGrids(), gb = fb.getGrids();
    if (ga->size() != gb->size()) return false;
    for (size_t i = 0; i < ga->size(); ++i) {
        std::string why;
        if (!sameGridBits((*ga)[i], (*gb)[i], why)) return false;
        if ((*ga)[i]->str() != (*gb)[i]->str()) return false; // grid metadata
    }
    return true;
}

/// Visible files (not starting with '.') other than the checkpoint and run.json.
std::set<std::string> frameFiles(const std::string& dir)
{
    std::set<std::string> out;
    for (auto& e : fs::directory_iterator(dir)) {
        const std::string n = e.path().filename().string();
        if (n[0] == '.' || n == "run.json" || n.find(".checkpoint") != std::string::npos) continue;
        out.insert(n);
    }
    return out;
}

} // namespace

TEST_CASE("kill -9 at several points, resume: every frame bit-identical, no partial file", "[checkpoint]")
{
    // A hybrid frost scene (phase field + DLA with hits), 8 frames of 5 steps, checkpoints every
    // 3 steps (so most fall inside a frame), a preview PNG and a displacement PNG per frame.
    const std::string scenePath = test::tempDir("ckpt_kill_scene") + "/kill.toml";
    std::ofstream(scenePath) << "[scene]\nname = \"kill\"\nseed = 3\nframes = 8\nsteps_per_frame = 5\n"
                                "[domain]\nsize = [72, 72]\nvoxel_size = 0.0001\n[output]\npreview = \"every\"\n"
                                "[phase_field]\n[dla]\nhumidity = 80\nhits = 2\njumps = false\n";
    const std::string ref = test::tempDir("ckpt_kill_ref"), dir = test::tempDir("ckpt_kill_run");
    REQUIRE(waitExit(spawn({"run", scenePath, "--out", ref, "-q", "--threads", "2"})) == 0);
    const std::set<std::string> expected = frameFiles(ref);
    REQUIRE(expected.size() == 8 * 3); // vdb, preview png, displacement png per frame

    auto checkVisible = [&](int attempt) {
        for (const auto& n : frameFiles(dir)) {
            INFO("attempt " << attempt << ": " << n);
            REQUIRE(expected.count(n) == 1);
            CHECK(sameFrameFile(ref + "/" + n, dir + "/" + n));
        }
    };
    // kill points: when frame k's file appears, plus a delay (ms), so that kills land inside
    // steps, frame writes (vdb, previews) and checkpoint writes of a running process
    const std::vector<std::pair<int, int>> killAt = {{1, 0}, {2, 3}, {3, 0}, {4, 7}, {5, 1}, {6, 12}, {7, 2}};
    int attempt = 0, kills = 0, resumes = 0;
    for (; attempt < 40; ++attempt) {
        const bool haveCheckpoint = fs::exists(checkpointPath(dir, "kill"));
        std::vector<std::string> args = {"run", scenePath, "-q", "--threads", "2", "--checkpoint-every", "3"};
        if (haveCheckpoint) args.insert(args.end(), {"--resume", dir});
        else args.insert(args.end(), {"--out", dir});
        resumes += haveCheckpoint;
        const pid_t pid = spawn(args);
        if (attempt < int(killAt.size())) {
            char frame[32];
            std::snprintf(frame, sizeof(frame), "/kill.%04d.vdb", killAt[size_t(attempt)].first);
            std::chrono::steady_clock::time_point seen{};
            bool triggered = false;
            while (true) {
                int st = 0;
                if (waitpid(pid, &st, WNOHANG) == pid) { // finished before the kill
                    REQUIRE(WIFEXITED(st));
                    REQUIRE(WEXITSTATUS(st) == 0);
                    goto finished;
                }
                const auto now = std::chrono::steady_clock::now();
                if (!triggered && fs::exists(dir + frame)) triggered = true, seen = now;
                if (triggered &&
                    std::chrono::duration<double, std::milli>(now - seen).count() >= killAt[size_t(attempt)].second)
                    break;
                std::this_thread::sleep_for(std::chrono::microseconds(100));
            }
            kill(pid, SIGKILL);
            REQUIRE(waitExit(pid) == -SIGKILL);
            ++kills;
            checkVisible(attempt);
            continue;
        }
        REQUIRE(waitExit(pid) == 0);
        goto finished;
    }
    FAIL("the run never finished");
finished:
    INFO("kills " << kills << ", resumes " << resumes);
    CHECK(kills >= 5);
    CHECK(resumes >= 4);
    CHECK(frameFiles(dir) == expected);
    checkVisible(attempt);
    CHECK(test::readFile(dir + "/run.json").find("\"resumed_from_step\": -1") == std::string::npos);
    // the last resume removed the temporaries the killed runs left behind
    for (auto& e : fs::directory_iterator(dir)) CHECK(e.path().filename().string().find(".tmp") == std::string::npos);
}

TEST_CASE("Gravner-Griffeath 3D: kill -9 mid-run, resume: every frame bit-identical", "[checkpoint][gg3d]")
{
    // 6 frames of a classic dendrite with a time switch, checkpoints every 7 steps (inside frames);
    // killed twice while running, then resumed to the end.
    const std::string scenePath = test::tempDir("ckpt_gg3d_kill_scene") + "/gg.toml";
    std::ofstream(scenePath) << "[scene]\nname = \"gg\"\nseed = 5\nframes = 6\nsteps_per_frame = 40\n"
                                "[domain]\nsize = [41, 41]\nvoxel_size = 0.0001\n[output]\npreview = \"none\"\n"
                                "[gravner_griffeath_3d]\npreset = \"fig14_classic_dendrite\"\ndomain_radius = 20\n"
                                "layers = 13\nnoise = 0.00001\nswitch_step = 100\nswitch_beta = [1.3]\n";
    const std::string ref = test::tempDir("ckpt_gg3d_kill_ref"), dir = test::tempDir("ckpt_gg3d_kill_run");
    REQUIRE(waitExit(spawn({"run", scenePath, "--out", ref, "-q", "--threads", "2"})) == 0);
    const std::set<std::string> expected = frameFiles(ref);
    REQUIRE(expected.size() == 6);

    int kills = 0, resumes = 0;
    for (int attempt = 0; attempt < 10; ++attempt) {
        const bool haveCheckpoint = fs::exists(checkpointPath(dir, "gg"));
        std::vector<std::string> args = {"run", scenePath, "-q", "--threads", "2", "--checkpoint-every", "7"};
        if (haveCheckpoint) args.insert(args.end(), {"--resume", dir});
        else args.insert(args.end(), {"--out", dir});
        resumes += haveCheckpoint;
        const pid_t pid = spawn(args);
        if (kills < 2) { // kill once frame 2 (then 4) is on disk, while the next frame is being grown
            const std::string frame = dir + (kills == 0 ? "/gg.0002.vdb" : "/gg.0004.vdb");
            int st = 0;
            bool exited = false;
            while (!fs::exists(frame)) {
                if (waitpid(pid, &st, WNOHANG) == pid) { exited = true; break; }
                std::this_thread::sleep_for(std::chrono::microseconds(100));
            }
            if (!exited) {
                std::this_thread::sleep_for(std::chrono::milliseconds(2));
                kill(pid, SIGKILL);
                REQUIRE(waitExit(pid) == -SIGKILL);
                ++kills;
                for (const auto& n : frameFiles(dir)) {
                    INFO("after kill " << kills << ": " << n);
                    CHECK(sameFrameFile(ref + "/" + n, dir + "/" + n));
                }
                continue;
            }
            REQUIRE(WIFEXITED(st));
            REQUIRE(WEXITSTATUS(st) == 0);
            break;
        }
        REQUIRE(waitExit(pid) == 0);
        break;
    }
    INFO("kills " << kills << ", resumes " << resumes);
    CHECK(kills >= 1);
    CHECK(resumes >= 1);
    REQUIRE(frameFiles(dir) == expected);
    for (const auto& n : expected) {
        INFO(n);
        CHECK(sameFrameFile(ref + "/" + n, dir + "/" + n));
    }
}
