#include <frostvdb/core/Simulation.h>
#include <frostvdb/core/FoldedReader.h>
#include <frostvdb/core/PlaneFold.h>

#include <nlohmann/json.hpp>
#include <frostvdb/core/FieldWriters.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Progress.h>
#include <frostvdb/core/Stopwatch.h>
#include <frostvdb/io/AtomicFile.h>
#include <frostvdb/core/Export.h>
#include <frostvdb/io/InputFiles.h>
#include <frostvdb/io/OutputLock.h>
#include <frostvdb/io/Preview.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/Count.h>
#include <frostvdb/io/VdbIO.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <iomanip>
#include <iostream>
#include <regex>
#include <set>
#include <sstream>
#include <csignal>
#include <sys/resource.h>

namespace frostvdb {

namespace {

const std::set<std::string> kCoreSections = {"scene", "domain", "region", "output", "run"};
/// Frames of at least this many active voxels report progress while they are written (about a
/// second of compression and writing on one core).
constexpr double kProgressFrameVoxels = 1e7;

using Clock = std::chrono::steady_clock;
double seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

uint64_t peakRss()
{
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    return uint64_t(ru.ru_maxrss) * 1024ull;
}

/// FROSTVDB_MEMORY_TRACE=1: resident and peak memory (MiB) on stderr after each effect's
/// initialisation, step (first steps, then every 100) and output, after a frame's PNGs and as
/// each of its grids is made for the VDB, to see where a peak comes from
/// (docs/performance.md "Where a shell's memory goes"), with the seconds since the first line
/// (what each grid of a frame costs to make and write).
void traceMemory(const char* what, const std::string& effect, int64_t step)
{
    static const bool on = [] { const char* e = std::getenv("FROSTVDB_MEMORY_TRACE"); return e && *e && *e != '0'; }();
    if (!on) return;
    static const auto start = std::chrono::steady_clock::now();
    long rssKb = 0, hwmKb = 0;
    if (FILE* f = std::fopen("/proc/self/status", "r")) {
        char line[256];
        while (std::fgets(line, sizeof line, f)) {
            std::sscanf(line, "VmRSS: %ld", &rssKb);
            std::sscanf(line, "VmHWM: %ld", &hwmKb);
        }
        std::fclose(f);
    }
    const double at = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(stderr, "memory: %-14s %-12s step %6lld  resident %8.1f MiB  peak %8.1f MiB  at %8.3f s\n", what,
                 effect.c_str(), (long long)step, rssKb / 1024.0, hwmKb / 1024.0, at);
}

/// Reads the core sections that belong to the driver.
void readSceneSection(ParamDict& d, World& w, const std::string& fallbackName)
{
    w.sceneName = d.getString("name", fallbackName, {}, "scene name: output files are <name>.<frame>.vdb");
    d.getString("description", "", {}, "free text shown by `frostvdb info`; ignored by the solvers");
    w.seed = uint64_t(d.getInt("seed", 1, 0, int64_t(1) << 53, "", "random seed (same seed, same bits)"));
    w.frames = d.getInt("frames", 8, 1, 1000000, "frames", "number of output frames");
    w.stepsPerFrame = d.getInt("steps_per_frame", 100, 1, 100000000, "steps", "simulation steps between frames");
    if (d.has("name") && w.sceneName.empty()) d.fail("name", "must not be empty (it names the output files)");
    if (w.sceneName.size() > 100)
        d.fail("name", "at most 100 characters (it names files such as <name>.0001.displacement.png)");
    for (char c : d.has("name") ? w.sceneName : std::string())
        if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-'))
            d.fail("name", "use letters, digits, '_' and '-' only (it names files)");
}

void readRegionSection(ParamDict& d, RegionSettings& r)
{
    r.tolerance = d.getFloat("tolerance", 1e-6, 0.0, 1.0, "",
        "a voxel stays active while |value - far field| exceeds this; 0 reproduces the dense answer");
    r.dense = d.getBool("dense", false, "reference mode: every domain voxel is active every step");
    r.frontTravel = int(d.getInt("front_travel", 1, 0, 16, "cells",
        "extra dilation of the active region for the distance the front moves in one step"));
    r.rebuildEvery = int(d.getInt("rebuild_every", 0, 0, 64, "steps",
        "rebuild the active region (and truncate) every k steps, the dilation widened to k steps of travel; "
        "0: automatic (k = 8 cells / (stencil reach + front_travel), 16 once the region fills the domain; "
        "1 while another effect writes the fields)"));
    d.onlyWhen(!r.dense, "tolerance", "dense = true");
    d.onlyWhen(!r.dense, "front_travel", "dense = true");
}

/// [output] world_scale lives in World::shared (key below) so effects writing their own files see it.

void readOutputSection(ParamDict& d, OutputSettings& o, double* worldScale = nullptr)
{
    o.vdb = d.getBool("vdb", true, "write <name>.<frame>.vdb files");
    const std::string p = d.getString("preview", "last", {"none", "last", "every"},
        "PNG previews: none, the last frame, or every frame");
    o.preview = p != "none";
    o.previewEvery = p == "every";
    o.previewGrid = d.getString("preview_grid", "", {}, "grid drawn in previews (default: ice, density or cells)");
    d.onlyWhen(o.preview, "preview_grid", "preview = \"none\"");
    const std::string precision = d.getString("precision", "float", {"float", "half"},
        "storage of float grids: float (32-bit) or half (16-bit, OpenVDB setSaveFloatAsHalf, as Houdini's "
        "\"Write 16-Bit\"): smaller files, values within 2^-11 relative (about 3 decimal digits); grids are "
        "read back as float");
    const bool legacyHalf = d.getBool("half_float", false, "older spelling of precision = \"half\"");
    if (legacyHalf && d.has("precision") && precision == "float")
        d.onlyWhen(false, "half_float", "precision = \"float\"");
    o.halfFloat = precision == "half" || legacyHalf;
    o.compression = compressionFlags(d.getString("compression", "blosc", {"blosc", "zip", "none"},
        "data compression of the .vdb files: blosc (fast, the default), zip (smaller for some grids, slower; "
        "OpenVDB applies zip only to grids that are neither fog volumes nor level sets, so ice, ice_sdf and "
        "density keep only the active-mask compression), or none (the fastest to write and read; largest)"));
    o.keepLattice = d.getBool("keep_lattice", false,
        "hexagonal domains: write grids on the sheared lattice transform instead of resampling them to square voxels "
        "(same as `frostvdb run --keep-lattice`)");
    o.displacementPng = d.getBool("displacement_png", true,
        "flat domains with ice: also write the displacement map (grid `growth`) as a 16-bit greyscale "
        "<name>.<frame>.displacement.png on the square export raster (one pixel per lattice spacing); rasters "
        "larger than displacement_tile are cut into UDIM tiles <name>.<frame>.displacement.<1001+>.png and only "
        "tiles holding ice are written");
    o.displacementTile = int(d.getInt("displacement_tile", 4096, 64, 65536, "pixels",
        "side of a displacement UDIM tile: a raster up to this size is one PNG, a larger one is tiled "
        "(tile 1001 at the raster's bottom-left, u along +x, v along +y, at most 10 across)"));
    const double scale = d.getFloat("world_scale", 1.0, 1e-6, 1e9, "",
        "multiplies the world size of everything written (grid transforms, meshes); e.g. 100 for a 1 cm flake "
        "in a renderer that loses sub-millimetre voxels (docs/snowflakes3d.md)");
    if (worldScale) *worldScale = scale;
}

/// [run]: resources of the whole run. Returns the limit in bytes (0: unlimited).
double readRunSettings(ParamDict& d)
{
    const double gib = d.getFloat("memory_limit", 0.0, -1.0, 1048576.0, "GiB",
        "memory the run may use; effects estimate their allocations from the scene and refuse what exceeds it. "
        "0: the memory available on the machine when the run starts (MemAvailable); -1: no limit");
    if (gib < 0) return 0.0;
    if (gib > 0) return gib * 1024.0 * 1024.0 * 1024.0;
    const uint64_t avail = availableMemoryBytes();
    return avail > 0 ? double(avail) : 0.0;
}

std::string fnv1aHex(const std::string& s)
{
    uint64_t h = 1469598103934665603ull;
    for (unsigned char c : s) {
        h ^= c;
        h *= 1099511628211ull;
    }
    std::ostringstream os;
    os << std::hex << std::setw(16) << std::setfill('0') << h;
    return os.str();
}

/// The string value of the top-level "key" of a run.json, or "" (no file, not JSON, no such
/// string).
std::string runJsonString(const std::string& path, const std::string& key)
{
    std::ifstream in(path);
    if (!in) return {};
    const nlohmann::json j = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
    if (!j.is_object()) return {};
    const auto it = j.find(key);
    return it != j.end() && it->is_string() ? it->get<std::string>() : std::string();
}

/// The names in @a dir matching @a pattern whose first group (if any) is @a group (any if empty), sorted.
std::vector<std::string> namesIn(const std::string& dir, const std::regex& pattern, const std::string& group = {})
{
    std::vector<std::string> out;
    std::error_code ec;
    for (auto it = std::filesystem::directory_iterator(dir, ec); !ec && it != std::filesystem::directory_iterator();
         it.increment(ec)) {
        const std::string name = it->path().filename().string();
        std::smatch m;
        if (!std::regex_match(name, m, pattern)) continue;
        if (!group.empty() && m[1].str() != group) continue;
        out.push_back(name);
    }
    std::sort(out.begin(), out.end());
    return out;
}

/// The run summaries in @a dir: run.json (a run of the whole frame range) and
/// run.frames-A-B.json (a chunk of it).
std::vector<std::string> runSummariesIn(const std::string& dir)
{
    static const std::regex summaryName(R"(^run(\.frames-[0-9]+-[0-9]+)?\.json$)");
    return namesIn(dir, summaryName);
}

std::string joinLines(const std::vector<std::string>& v)
{
    std::string o;
    for (auto& x : v) o += (o.empty() ? "" : "\n") + x;
    return o;
}

} // namespace

std::vector<std::string> frameFilesIn(const std::string& dir, const std::string& sceneName)
{
    static const std::regex frameName(R"(^([A-Za-z0-9_-]+)\.[0-9]{4,}\.(vdb|png|displacement\.png)$)");
    return namesIn(dir, frameName, sceneName);
}

Simulation::Simulation(Scene scene) : mScene(std::move(scene))
{
    std::string fallback = std::filesystem::path(mScene.label()).stem().string();
    if (fallback.empty() || fallback[0] == '<') fallback = "scene";
    std::replace_if(fallback.begin(), fallback.end(),
                    [](char c) { return !(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-'); }, '_');
    readSceneSection(mScene.section("scene"), mWorld, fallback);
    // The budget first: input images (a domain's textures, maps) are held to it as they are read.
    mWorld.memoryLimitBytes = readRunSettings(mScene.section("run"));
    InputFileLog& inputs = mWorld.state<InputFileLog>();
    inputs.memoryLimitBytes = mWorld.memoryLimitBytes;
    InputFileScope inputScope(&inputs); // every mesh, texture and map read from here is recorded
    try {
        mWorld.domain = Domain::fromParams(mScene.section("domain"));
    } catch (const openvdb::Exception& e) {
        throw SceneError(mScene.label(), mScene.sectionLine("domain"), "domain.voxel_size",
                         "OpenVDB cannot build the domain's transform (" + shortMessage(e.what(), 120) + ")");
    }
    readRegionSection(mScene.section("region"), mWorld.region);
    readOutputSection(mScene.section("output"), mOutput, &mWorld.worldScale);
    mWorld.sceneLabel = mScene.label();
    mWorld.sceneText = mScene.text();
    try {
        mWorld.fields = FieldSet(mWorld.domain.transform());
    } catch (const openvdb::Exception& e) {
        // e.g. voxels below OpenVDB's smallest scale (its transform determinant must exceed 3e-15)
        throw SceneError(mScene.label(), mScene.sectionLine("domain"), "domain.voxel_size",
                         "OpenVDB cannot build the domain's transform (" + shortMessage(e.what(), 120) + ")");
    }
    for (const auto& name : kCoreSections) mScene.section(name).checkAllRead();

    for (const auto& name : mScene.sectionNames()) {
        if (kCoreSections.count(name)) continue;
        const EffectInfo* info = EffectRegistry::find(name);
        if (!info) {
            std::string known;
            for (auto* e : EffectRegistry::all()) known += (known.empty() ? "" : ", ") + e->section;
            throw SceneError(mScene.label(), mScene.sectionLine(name), "[" + name + "]",
                             "unknown section (effects: " + known + "; core: scene, domain, region, output)");
        }
        ParamDict& dict = mScene.section(name);
        atSection(name, "set-up", [&] { mEffects.push_back(info->create(dict, mWorld)); });
        dict.checkAllRead();
    }
    if (mEffects.empty())
        throw SceneError(mScene.label(), 0, "", "the scene names no effect section, so there is nothing to simulate");
    std::vector<DeclaredEffect> declared;
    for (auto& e : mEffects) declared.push_back({e->name(), e->declaration()});
    mOrder = deriveEffectOrder(declared, mScene.label());
    refuseOutputClashes(declared);
    FieldWriters& writers = mWorld.state<FieldWriters>();
    writers.count.clear();
    for (const auto& d : declared)
        for (const auto& u : d.declaration.uses)
            if (u.key->role == FieldRole::Field && (u.access & kWrites)) writers.count[u.key->name] += 1;
    mEffectSeconds.assign(mEffects.size(), 0.0);
    mEffectCpuSeconds.assign(mEffects.size(), 0.0);
    checkMemoryBudget();
    refuseDisplacementTiling(); // after the budget: a domain too large to hold is named as such
}

/// A flat domain's displacement raster must fit 10 UDIM tiles across (tile numbers 1001 + u + 10 v):
/// refused here, before anything runs, where the first frame with ice would have failed.
void Simulation::refuseDisplacementTiling() const
{
    if (!mOutput.displacementPng || !mWorld.domain.flat()) return;
    const int width = squareRaster(mWorld.domain).width(), tile = mOutput.displacementTile;
    const int across = udimTilesAcross(width, tile);
    if (across <= kUdimTilesAcross) return;
    throw SceneError(mScene.label(), mScene.sectionLine("output"), "output.displacement_tile",
                     "the displacement map is " + std::to_string(width) + " pixels wide: " + std::to_string(across) +
                         " UDIM tiles of " + std::to_string(tile) + " across, at most " +
                         std::to_string(kUdimTilesAcross) + " fit; set it to at least " +
                         std::to_string(udimTilesAcross(width, kUdimTilesAcross)) +
                         " (allowed 64-65536), or output.displacement_png = false");
}

/// Two effects that both put a grid of one name into every frame cannot be written (a frame file
/// holds one grid of a name): refused here, before anything runs, naming both sections. Output
/// grids the ice effects share (they are added once, by ice::addIceOutputs) and the summed gas
/// grids are not clashes; the grids an effect builds on its own lattice are.
void Simulation::refuseOutputClashes(const std::vector<DeclaredEffect>& declared) const
{
    static const std::vector<const FieldKey*> ownGrids = {&out::kCells, &out::kAutomatonIce, &out::kFreezeStep,
                                                          &out::kVapour, &out::kPoints,     &out::kAggregateIce};
    auto usesIceClock = [](const FieldDeclaration& d) {
        for (const auto& u : d.uses)
            if (u.key == &ice::kClock) return true;
        return false;
    };
    for (size_t b = 0; b < declared.size(); ++b)
        for (size_t a = 0; a < b; ++a)
            for (const FieldKey* kb : declared[b].declaration.outputs)
                for (const FieldKey* ka : declared[a].declaration.outputs) {
                    if (std::string(ka->name) != kb->name) continue;
                    bool shared = ka == kb && std::find(ownGrids.begin(), ownGrids.end(), ka) == ownGrids.end();
                    if (ka == &out::kIceSdf && kb == &out::kIceSdf) // the ice effects add one frost level set
                        shared = usesIceClock(declared[a].declaration) && usesIceClock(declared[b].declaration);
                    if (shared) continue;
                    throw SceneError(mScene.label(), mScene.sectionLine(declared[b].section),
                                     "[" + declared[a].section + "] and [" + declared[b].section + "]",
                                     std::string("both write a grid named '") + kb->name +
                                         "' to every frame, and a frame file holds one grid of a name (run them "
                                         "as two scenes, or drop one of the sections)");
                }
}

namespace {
/// True when @a m is an allocation already in @a counted (two effects that use one structure,
/// e.g. a shell's whole band for [phase_field] and [dla], report the same estimate); else adds it.
bool sharedEstimate(std::vector<MemoryEstimate>& counted, const MemoryEstimate& m)
{
    for (const auto& c : counted)
        if (m.bytes > 0 && c.key == m.key && c.detail == m.detail && c.bytes == m.bytes) return true;
    counted.push_back(m);
    return false;
}
} // namespace

void Simulation::checkMemoryBudget() const
{
    // The displacement PNG is one raster over the whole plane (core/Export.h): 4-byte floats and
    // 2-byte samples per cell, whatever the sparse fields hold.
    if (mOutput.displacementPng && mWorld.domain.flat())
        checkMemoryEstimate(perVoxelEstimate(double(mWorld.domain.bbox().volume()), 8.0, "domain.size",
                                             "the displacement PNG raster (output.displacement_png)"),
                            mWorld.memoryLimitBytes, mWorld.sceneLabel);
    MemoryEstimate total;
    std::vector<MemoryEstimate> counted;
    for (auto& e : mEffects) {
        MemoryEstimate m;
        atSection(e->name(), "memory estimate", [&] { m = e->memoryEstimate(mWorld); });
        if (m.key.empty()) m.key = e->name();
        checkMemoryEstimate(m, mWorld.memoryLimitBytes, mWorld.sceneLabel);
        if (sharedEstimate(counted, m)) continue; // one allocation two effects use (a shell's whole band)
        if (m.bytes > total.bytes) total.key = m.key;
        total.bytes += m.bytes;
    }
    total.detail = "all effects together";
    if (mEffects.size() > 1) checkMemoryEstimate(total, mWorld.memoryLimitBytes, mWorld.sceneLabel);
}

Simulation::~Simulation() = default;

/// Runs one call of section @a section's effect (its creation, estimate, initialisation, steps,
/// output); an exception from a library (OpenVDB, toml++, libpng, the allocator) becomes one
/// line naming the section, so the user knows which part of the scene to change. Errors
/// frostvdb raises itself already name their key and pass unchanged.
template <typename F>
void Simulation::atSection(const std::string& section, const char* phase, F&& call) const
{
    try {
        call();
    } catch (const SceneError&) {
        throw;
    } catch (const SimulationError&) {
        throw;
    } catch (const WriteError&) {
        throw;
    } catch (const OutputBusyError&) {
        throw;
    } catch (const std::bad_alloc&) {
        throw OutOfMemoryError(mWorld.sceneLabel, mScene.sectionLine(section), "[" + section + "]",
                               std::string("out of memory during ") + phase +
                                   " (no estimate foresaw it; lower this section's sizes)");
    } catch (const openvdb::Exception& x) {
        throw SceneError(mWorld.sceneLabel, mScene.sectionLine(section), "[" + section + "]",
                         std::string("OpenVDB refused the ") + phase + ": " + shortMessage(x.what(), 200));
    } catch (const std::exception& x) {
        throw SceneError(mWorld.sceneLabel, mScene.sectionLine(section), "[" + section + "]",
                         std::string(phase) + " failed: " + shortMessage(x.what(), 200));
    }
}

template <typename F>
void Simulation::atEffect(const Effect& e, const char* phase, F&& call)
{
    atSection(e.name(), phase, std::forward<F>(call));
}

Effect* Simulation::effect(const std::string& section) const
{
    for (auto& e : mEffects)
        if (e->name() == section) return e.get();
    return nullptr;
}

void Simulation::initialize()
{
    if (mInitialized) return;
    InputFileScope inputScope(&mWorld.state<InputFileLog>()); // maps and meshes effects read now
    for (size_t i : mOrder.initialize) {
        Effect* e = mEffects[i].get();
        atEffect(*e, "initialisation", [&] { e->initialize(mWorld); });
        traceMemory("initialised", e->name(), mStep);
    }
    mInitialized = true;
}

void Simulation::step()
{
    initialize();
    StepInfo info;
    info.step = mStep;
    info.frame = mStep / mWorld.stepsPerFrame + 1;
    for (size_t i : mOrder.step) {
        const auto t0 = Clock::now();
        const double c0 = processCpuSeconds();
        atEffect(*mEffects[i], "step", [&] { mEffects[i]->step(mWorld, info); });
        mEffectSeconds[i] += seconds(t0, Clock::now());
        mEffectCpuSeconds[i] += processCpuSeconds() - c0;
        if (mStep < 2 || mStep % 100 == 0) traceMemory("stepped", mEffects[i]->name(), mStep);
    }
    ++mStep;
}

void Simulation::publishFields()
{
    if (!mInitialized) return;
    for (auto& e : mEffects) e->publishFields(mWorld);
}

Frame Simulation::buildFrame(int64_t frameNumber)
{
    initialize();
    Frame frame;
    frame.frame = frameNumber;
    frame.step = mStep;
    for (auto& e : mEffects)
        if (e->time() > 0.0) { frame.time = e->time(); break; }
    // No publishFields: an effect that keeps its fields elsewhere makes its grids from them.
    for (auto& e : mEffects) {
        atEffect(*e, "output", [&] { e->addToFrame(mWorld, frame); });
        traceMemory("output", e->name(), mStep);
    }
    return frame;
}

Frame Simulation::currentFrame(int64_t frameNumber)
{
    Frame frame = buildFrame(frameNumber);
    // Copies made folded for the PNGs to read in place (ice/IceState.cpp) are made again in the
    // plane layout: a frame handed out holds the plane layout only.
    bool folded = false;
    for (const auto& g : frame.grids) folded = folded || (g && plane::isFolded(*g));
    if (folded) frame.dropCopies();
    frame.makeDeferred();
    for (size_t i = 0; i < frame.grids.size(); ++i) frame.grid(i);
    return frame;
}

uint64_t Simulation::fieldActiveVoxels() const
{
    std::map<std::string, uint64_t> perField;
    for (const auto& name : mWorld.fields.names()) perField[name] = mWorld.fields.grid(name)->activeVoxelCount();
    if (mInitialized)
        for (const auto& e : mEffects) e->countKeptFields(perField);
    uint64_t n = 0;
    for (const auto& [name, count] : perField) n += count;
    return n;
}

std::string Simulation::writeFrame(const Frame& frame, const std::string& dir)
{
    Frame copy = frame; // shares the grids
    return writeFrame(std::move(copy), dir);
}

std::string Simulation::writeFrame(Frame&& frame, const std::string& dir)
{
    makeDirectories(dir);
    openvdb::MetaMap meta;
    meta.insertMeta("creator", openvdb::StringMetadata(std::string("frostvdb ") + FROSTVDB_VERSION));
    meta.insertMeta("frostvdb_version", openvdb::StringMetadata(FROSTVDB_VERSION));
    meta.insertMeta("scene", openvdb::StringMetadata(mWorld.sceneText));
    meta.insertMeta("scene_file", openvdb::StringMetadata(mWorld.sceneLabel));
    meta.insertMeta("scene_effective", openvdb::StringMetadata(mScene.effectiveText()));
    meta.insertMeta("overrides", openvdb::StringMetadata(joinLines(mScene.overrides())));
    meta.insertMeta("command_line", openvdb::StringMetadata(mCommandLine));
    meta.insertMeta("seed", openvdb::Int64Metadata(int64_t(mWorld.seed)));
    meta.insertMeta("frame", openvdb::Int64Metadata(frame.frame));
    meta.insertMeta("step", openvdb::Int64Metadata(frame.step));
    meta.insertMeta("time", openvdb::DoubleMetadata(frame.time));
    meta.insertMeta("voxel_size_m", openvdb::DoubleMetadata(mWorld.domain.voxelSize()));
    const double worldScale = mWorld.worldScale;
    if (worldScale != 1.0) meta.insertMeta("world_scale", openvdb::DoubleMetadata(worldScale));
    // One grid at a time: each is exported (resampled from a hexagonal lattice), written and
    // dropped, and its source with it, so a large frame never holds all its output grids.
    const std::string path = framePath(dir, mWorld.sceneName, frame.frame);
    // A frame of tens of millions of voxels takes seconds to compress and write (a dense fog box:
    // issue 25's probe re-run found one silent for over 20 s after the steps): say how far it is.
    // (Copies of fields dropped until their turn count as the fields they copy.)
    double voxels = double(mWorld.fields.activeVoxels());
    for (const auto& g : frame.grids)
        if (g) voxels += double(g->activeVoxelCount());
    std::unique_ptr<Progress> progress;
    if (mWorld.progress && voxels >= kProgressFrameVoxels)
        progress = std::make_unique<Progress>("frame " + std::to_string(frame.frame) + " write",
                                              int64_t(frame.grids.size()), "grids");
    // grids the frame makes again now may be made exported already (folded plane fields, in place)
    const ExportScope exporting(mWorld.domain, mOutput.keepLattice);
    writeVdbStreamed(path, frame.grids.size(), [&](size_t i) {
        if (progress) progress->update(int64_t(i)); // the grids before this one are written
        openvdb::GridBase::Ptr g = exportGrid(frame.grid(i), mWorld.domain, mOutput.keepLattice);
        frame.grids[i].reset();
        traceMemory("made", g->getName(), mStep);
        if (worldScale != 1.0) { // a shallow copy: the frame's own grid keeps its transform
            auto x = g->transform().copy();
            x->postScale(worldScale);
            g = g->copyGrid();
            g->setTransform(x);
        }
        g->insertMeta("frostvdb_step", openvdb::Int64Metadata(frame.step));
        g->insertMeta("frostvdb_time", openvdb::DoubleMetadata(frame.time));
        return g;
    }, meta, mOutput.halfFloat, mOutput.compression);
    if (progress) progress->finish();
    return path;
}

std::vector<std::string> Simulation::writeDisplacement(const Frame& frame, const std::string& dir)
{
    if (!mOutput.displacementPng || !mWorld.domain.flat()) return {};
    for (auto& g : frame.grids) {
        auto growth = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
        if (!growth || g->getName() != out::kGrowth.name) continue;
        makeDirectories(dir);
        const std::string path = framePath(dir, mWorld.sceneName, frame.frame, "displacement.png");
        return writeDisplacementMaps(*growth, mWorld.domain, path.substr(0, path.size() - 4), mOutput.displacementTile);
    }
    return {};
}

// ---------------------------------------------------------------------------------------------
// Checkpoints: the fields and step counter here, each effect's own state through Effect::saveState.

struct Simulation::CheckpointClock {
    int64_t lastStep = -1;
    bool pending = false; ///< due, but deferred to the next step where every effect is at a boundary
    Clock::time_point last = Clock::now();
};

std::string Simulation::checkpointParameters()
{
    std::string text;
    for (const auto& name : mScene.sectionNames()) {
        if (name == "output") continue; // what is written, not what is simulated
        text += "[" + name + "]\n";
        text += mScene.section(name).canonicalText(name == "scene" ? std::vector<std::string>{"frames", "description"}
                                                                   : std::vector<std::string>{});
    }
    return text;
}

void Simulation::refuseUncheckpointable(const char* what) const
{
    std::string names;
    for (auto& e : mEffects)
        if (!e->supportsCheckpoint()) names += (names.empty() ? "[" : ", [") + e->name() + "]";
    if (!names.empty())
        throw CheckpointError("this scene cannot be " + std::string(what) + ": " + names +
                              " keep state from step to step that they cannot save yet");
}

bool Simulation::atCheckpointBoundary() const
{
    for (auto& e : mEffects)
        if (!e->atCheckpointBoundary()) return false;
    return true;
}

void Simulation::saveCheckpoint(const std::string& path)
{
    initialize();
    refuseUncheckpointable("checkpointed");
    StateArchive archive;
    StateWriter w(archive);
    w.putString("sim/version", FROSTVDB_VERSION);
    w.putString("sim/parameters", checkpointParameters());
    w.putString("sim/scene_text", mWorld.sceneText);
    w.putString("sim/inputs", mWorld.state<InputFileLog>().text()); // digests of meshes, textures, maps
    w.putInt("sim/step", mStep);
    publishFields();
    std::string names;
    for (const auto& n : mWorld.fields.names()) {
        names += n + "\n";
        w.putGrid("field/" + n, mWorld.fields.grid(n));
    }
    w.putString("sim/fields", names);
    StateWriter effects = w.scope("effect");
    for (auto& e : mEffects) {
        StateWriter scoped = effects.scope(e->name());
        e->saveState(mWorld, scoped);
    }
    writeCheckpointFile(path, archive);
}

void Simulation::loadCheckpoint(const std::string& path)
{
    const StateArchive archive = readCheckpointFile(path);
    const StateReader r(archive, "", path);
    const std::string theirs = r.getString("sim/parameters"), mine = checkpointParameters();
    if (theirs != mine) {
        // name the first line that differs
        std::istringstream a(theirs), b(mine);
        std::string la, lb;
        while (true) {
            const bool ga = bool(std::getline(a, la)), gb = bool(std::getline(b, lb));
            if (!ga) la = "(nothing)";
            if (!gb) lb = "(nothing)";
            if (la != lb || (!ga && !gb)) break;
        }
        throw CheckpointError(path + ": written by another scene or with other parameters (checkpoint: '" + la +
                              "', this run: '" + lb + "'); resume with the scene and --set values of the first run");
    }
    initialize();
    refuseUncheckpointable("resumed");
    refuseChangedInputs(r.has("sim/inputs") ? r.getString("sim/inputs") : std::string(), path);
    std::istringstream names(r.getString("sim/fields"));
    for (std::string n; std::getline(names, n);) {
        auto g = r.getGridBase("field/" + n);
        if (!g) r.fail("field/" + n, "missing grid");
        mWorld.fields.replace(n, g);
    }
    const StateReader effects = r.scope("effect");
    for (auto& e : mEffects) e->loadState(mWorld, effects.scope(e->name()));
    mStep = r.getInt("sim/step");
}

/// The checkpoint's run and this one must have read the same bytes from every input file (the
/// scene text alone does not say that a mesh or a map was edited in between).
void Simulation::refuseChangedInputs(const std::string& saved, const std::string& checkpoint)
{
    const auto theirs = InputFileLog::parse(saved);
    const auto& mine = mWorld.state<InputFileLog>().files;
    for (size_t i = 0; i < std::max(theirs.size(), mine.size()); ++i) {
        if (i >= theirs.size())
            throw CheckpointError(checkpoint + ": this run reads " + mine[i].path +
                                  ", which the checkpoint's run did not read; resume with the inputs of the first run");
        if (i >= mine.size())
            throw CheckpointError(checkpoint + ": the checkpoint's run read " + theirs[i].path +
                                  ", which this run does not; resume with the inputs of the first run");
        if (theirs[i].digest != mine[i].digest || theirs[i].bytes != mine[i].bytes)
            throw CheckpointError(mine[i].path + ": changed since the checkpoint was written (" +
                                  std::to_string(theirs[i].bytes) + " bytes, digest " + theirs[i].digest + "; now " +
                                  std::to_string(mine[i].bytes) + " bytes, digest " + mine[i].digest +
                                  "); restore it, or start the run again without --resume");
    }
}

int64_t Simulation::resumeForRun(const RunOptions& opt, const std::string& dir, int64_t first, int64_t last)
{
    if (opt.checkpoint.enabled()) refuseUncheckpointable("checkpointed");
    if (opt.resumeDir.empty()) return -1;
    loadCheckpoint(checkpointPath(opt.resumeDir, mWorld.sceneName));
    removeStaleTemporaries(opt.resumeDir);
    if (dir != opt.resumeDir) removeStaleTemporaries(dir);
    // frames the checkpoint has passed are not written again: they must be there already
    const int64_t passed = std::min(last, mStep / mWorld.stepsPerFrame);
    std::string missing;
    if (opt.writeFiles && mOutput.vdb)
        for (int64_t f = first; f <= passed; ++f)
            if (!std::filesystem::exists(framePath(dir, mWorld.sceneName, f)))
                missing += (missing.empty() ? "" : ", ") + std::to_string(f);
    if (!missing.empty())
        throw CheckpointError("the checkpoint is at step " + std::to_string(mStep) + " (after frame " +
                              std::to_string(mStep / mWorld.stepsPerFrame) + "), but frame(s) " + missing +
                              " are not in " + dir + "; run them without --resume");
    return mStep;
}

void Simulation::checkpointIfDue(const RunOptions& opt, const std::string& dir, CheckpointClock& clock, bool final,
                                 RunSummary& sum)
{
    if (!opt.checkpoint.enabled() || !opt.writeFiles || mStep == clock.lastStep || mStep == 0) return;
    bool stateless = true;
    for (auto& e : mEffects) stateless = stateless && !e->needsHistory();
    if (stateless) return; // frames are independent: chunk them with --frames instead
    const auto now = Clock::now();
    const bool due = final || clock.pending || (opt.checkpoint.everySteps > 0 && mStep % opt.checkpoint.everySteps == 0) ||
                     (opt.checkpoint.everyMinutes > 0 && seconds(clock.last, now) >= 60.0 * opt.checkpoint.everyMinutes);
    if (!due) return;
    if (!atCheckpointBoundary()) {
        // a final checkpoint off a boundary is skipped: the chain resumes from the last one,
        // whose later frames are on disk and come out the same again
        clock.pending = !final;
        return;
    }
    clock.pending = false;
    saveCheckpoint(checkpointPath(dir, mWorld.sceneName));
    clock.lastStep = mStep;
    clock.last = Clock::now();
    ++sum.checkpoints;
    updateSignalRecord(dir, sum);
}

void Simulation::checkFrameRange(int64_t first, int64_t last) const
{
    const std::string range = std::to_string(first) + "-" + std::to_string(last);
    if (first < 1 || last < first || last > mWorld.frames)
        throw SceneError("--frames", 0, "", "frame range " + range + " is not within the scene's frames 1-" +
                                                std::to_string(mWorld.frames));
}

RunSummary Simulation::startSummary(const RunOptions& opt, int64_t first, int64_t last) const
{
    RunSummary sum;
    sum.scene = mWorld.sceneName;
    sum.status = "running";
    sum.commandLine = opt.commandLine;
    sum.overrides = mScene.overrides();
    sum.effectiveScene = mScene.effectiveText();
    sum.sceneHash = fnv1aHex(sum.effectiveScene);
    sum.firstFrame = first;
    sum.lastFrame = last;
    sum.summaryFile = runSummaryName(sum);
    for (auto& e : mEffects) sum.effects.push_back(e->name());
    return sum;
}

/// Makes the folder trustworthy before the first frame: temporaries of killed runs removed, and
/// frames named like ours but made by another run (other keys or overrides, per run.json's
/// scene_hash) refused unless --overwrite, which removes them first. A run.json with status "running" then marks the folder as
/// this run's, so a concurrent chunk of the same scene (another --frames range) is accepted.
void Simulation::prepareOutputFolder(const std::string& dir, const RunOptions& opt, RunSummary& sum) const
{
    makeDirectories(dir);
    installTempCleanupHandlers();
    for (const auto& t : removeStaleTemporaries(dir))
        std::cerr << "frostvdb: removed " << dir << "/" << t << " (temporary file of a run that was killed)\n";
    // Any summary of this scene's run (the whole range or a parallel chunk) makes the folder ours.
    const auto summaries = runSummariesIn(dir);
    bool sameRun = false;
    for (const auto& s : summaries) sameRun = sameRun || runJsonString(dir + "/" + s, "scene_hash") == sum.sceneHash;
    const auto frames = frameFilesIn(dir, mWorld.sceneName);
    if (!frames.empty() && !sameRun) {
        if (!opt.overwrite) {
            const std::string was = !summaries.empty()
                                        ? summaries.front() + " records scene '" +
                                              runJsonString(dir + "/" + summaries.front(), "scene") +
                                              "' with other keys or overrides"
                                        : "no run.json";
            throw SceneError(dir, 0, "--out", "holds " + std::to_string(frames.size()) + " frame files of another run of '" +
                                                  mWorld.sceneName + "' (" + frames.front() + ", ...; " + was +
                                                  "); use --overwrite to remove them first, or choose another folder");
        }
        for (const auto& f : frames) {
            std::error_code ec;
            if (!std::filesystem::remove(dir + "/" + f, ec) || ec)
                throw WriteError(dir + "/" + f, "cannot remove the old frame: " + ec.message());
        }
        for (const auto& f : summaries) // the old run's summaries would list frames that are gone
            std::filesystem::remove(dir + "/" + f);
        std::cerr << "frostvdb: --overwrite: removed " << frames.size() << " frame files of the previous run of '"
                  << mWorld.sceneName << "' in " << dir << "\n";
    }
    writeRunJson(dir, sum);
    updateSignalRecord(dir, sum);
}

void Simulation::updateSignalRecord(const std::string& dir, const RunSummary& sum) const
{
    std::string text[3];
    const int sigs[3] = {SIGINT, SIGTERM, SIGHUP};
    const char* names[3] = {"SIGINT", "SIGTERM", "SIGHUP"};
    for (int i = 0; i < 3; ++i) {
        RunSummary s = sum;
        s.status = "interrupted";
        s.signal = names[i];
        s.exitCode = 128 + sigs[i];
        s.error = std::string("stopped by ") + names[i];
        s.steps = mStep;
        s.peakRssBytes = peakRss();
        text[i] = s.toJson();
    }
    setSignalRecord(dir + "/" + sum.summaryFile, text[0], text[1], text[2]);
}

namespace {
/// What writePreview reads of plane::unfoldGrid(@a g), read from the folded grid in place: its
/// plane layout's active box (from the chunks), its largest active value (the same values) and
/// FoldedReader for the samples.
FlatPreviewSource foldedPreviewSource(const openvdb::FloatGrid::ConstPtr& g)
{
    FlatPreviewSource src;
    for (auto leaf = g->tree().cbeginLeaf(); leaf; ++leaf) {
        plane::PlaneChunk chunks[8];
        const int n = plane::chunksOf(*leaf, chunks);
        for (int i = 0; i < n; ++i) {
            const plane::PlaneChunk& c = chunks[i];
            src.bbox.expand(openvdb::CoordBBox(c.origin.offsetBy(__builtin_ctz(c.columns), c.y0, 0),
                                               c.origin.offsetBy(31 - __builtin_clz(c.columns), c.y1, 0)));
        }
    }
    src.valueMax = openvdb::tools::minMax(g->tree()).max();
    src.transform = g->transformPtr();
    src.makeSampler = [g] {
        return std::function<float(const openvdb::Vec3d&)>([reader = plane::FoldedReader(*g)](const openvdb::Vec3d& p) {
            float v = 0.f;
            openvdb::tools::BoxSampler::sample(reader, p, v);
            return v;
        });
    };
    return src;
}
} // namespace

std::string Simulation::writeFramePreview(const Frame& frame, int64_t f, const std::string& dir)
{
    const std::string png = framePath(dir, mWorld.sceneName, f, "png");
    for (auto& e : mEffects)
        if (e->writePreview(mWorld, frame, png)) return png;
    openvdb::GridBase::Ptr pick;
    for (const std::string& want : {mOutput.previewGrid, std::string(out::kIce.name), std::string(out::kAutomatonIce.name),
                                   std::string(out::kAggregateIce.name), std::string(out::kDensity.name),
                                   std::string(out::kCells.name)}) {
        if (want.empty() || pick) continue;
        for (auto& g : frame.grids)
            if (g->getName() == want && g->isType<openvdb::FloatGrid>()) pick = g;
    }
    if (!pick && !mOutput.previewGrid.empty())
        throw SceneError(mWorld.sceneLabel, 0, "output.preview_grid",
                         "no float grid named '" + mOutput.previewGrid + "' in the frame");
    if (!pick) return {};
    // a frame's copy made folded for the PNGs (ice/IceState.cpp): drawn in place, through the
    // plane layout's view of it (io/ knows no fold), not through that layout's copy (36 bytes a
    // voxel: the frame's peak at 16384^2 once the VDB writer streamed its grids)
    if (auto g = openvdb::gridPtrCast<openvdb::FloatGrid>(pick); g && plane::isFolded(*g))
        writeFlatPreview(foldedPreviewSource(g), png);
    else
        writePreview(*pick, png);
    return png;
}

/// Hands the heap's free pages back to the system. Region rebuilds free small mask leaves
/// between the fields' 2 KiB leaf buffers, and glibc keeps such pages: at 16384^2 about 8 % of
/// the resident memory before a frame is written (measured with mallinfo2 and malloc_trim).
void Simulation::returnFreePages()
{
#ifdef __GLIBC__
    malloc_trim(0);
#endif
}

/// Writes frame @a f's files; each is listed in the summary only once it is complete.
void Simulation::writeFrameOutputs(int64_t f, int64_t last, const std::string& dir, RunSummary& sum)
{
    Frame frame = buildFrame(f);
    sum.activeVoxels.emplace_back(mStep, fieldActiveVoxels());
    // The PNGs first and the VDB last, so that it can consume the frame (one resampled grid at
    // a time); the summary lists them in the usual order. The grids the PNGs read are made now
    // if an effect deferred them.
    if (mOutput.displacementPng && mWorld.domain.flat()) frame.makeNamed(out::kGrowth.name);
    if (mOutput.preview && !mOutput.previewGrid.empty()) frame.makeNamed(mOutput.previewGrid);
    const std::vector<std::string> displacement = writeDisplacement(frame, dir);
    std::string preview;
    if (mOutput.preview && (mOutput.previewEvery || f == last)) preview = writeFramePreview(frame, f, dir);
    traceMemory("previewed", "", mStep);
    frame.dropCopies(); // made again one at a time as the VDB is written
    if (mOutput.vdb) sum.files.push_back(writeFrame(std::move(frame), dir));
    for (const auto& png : displacement) sum.files.push_back(png);
    ++sum.framesWritten;
    if (!preview.empty()) sum.files.push_back(preview);
    updateSignalRecord(dir, sum);
}

void Simulation::simulateFrames(int64_t first, int64_t last, const RunOptions& opt, const std::string& dir,
                                RunSummary& sum)
{
    bool stateless = true;
    for (auto& e : mEffects) stateless = stateless && !e->needsHistory();
    initialize();
    sum.resumedFromStep = resumeForRun(opt, dir, first, last);
    CheckpointClock checkpointClock;
    checkpointClock.lastStep = mStep;
    const int64_t startFrame = std::max(stateless ? first : int64_t(1), mStep / mWorld.stepsPerFrame + 1);
    const int64_t stepsToRun = stateless ? std::max<int64_t>(0, last - startFrame + 1) * mWorld.stepsPerFrame
                                         : std::max<int64_t>(0, last * mWorld.stepsPerFrame - mStep);
    const ProgressStyle style = !opt.progress ? ProgressStyle::None
                              : opt.progressJson ? ProgressStyle::Json : ProgressStyle::Human;
    mWorld.progress = style == ProgressStyle::Human; // effects' own bars only on the human style
    Progress progress(mWorld.sceneName, stepsToRun, "steps", style);
    int64_t done = 0;
    for (int64_t f = startFrame; f <= last; ++f) {
        if (stateless) mStep = (f - 1) * mWorld.stepsPerFrame;
        while (mStep < f * mWorld.stepsPerFrame) {
            checkpointIfDue(opt, dir, checkpointClock, false, sum); // mid-frame, or after the last frame's output
            step();
            progress.update(++done, f, last);
        }
        if (f < first || !opt.writeFiles) {
            sum.activeVoxels.emplace_back(mStep, fieldActiveVoxels());
            continue;
        }
        const auto t0 = Clock::now();
        const double c0 = processCpuSeconds();
        traceMemory("frame", "", mStep);
        returnFreePages(); // the output's copies then start from what the fields hold
        traceMemory("trimmed", "", mStep);
        const size_t before = sum.files.size();
        writeFrameOutputs(f, last, dir, sum);
        traceMemory("written", "", mStep);
        returnFreePages();
        traceMemory("trimmed", "", mStep);
        sum.outputSeconds += seconds(t0, Clock::now());
        sum.outputCpuSeconds += processCpuSeconds() - c0;
        if (progress.json()) {
            std::string files;
            for (size_t i = before; i < sum.files.size(); ++i) files += (files.empty() ? "" : ",") + jsonQuote(sum.files[i]);
            progress.event("frame", "write", f, last, ",\"files\":[" + files + "]");
        }
    }
    checkpointIfDue(opt, dir, checkpointClock, true, sum); // the next chained task starts here
    progress.finish();
    progress.event("done", "done", last, last, ",\"frames_written\":" + std::to_string(sum.framesWritten));
}

// ---------------------------------------------------------------------------------------------
// --estimate

RunEstimate Simulation::estimate(const RunOptions& opt, double probeSeconds)
{
    std::unique_ptr<tbb::global_control> threads;
    if (opt.threads > 0)
        threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, opt.threads);
    RunEstimate est;
    const int64_t first = opt.firstFrame > 0 ? opt.firstFrame : 1;
    const int64_t last = opt.lastFrame > 0 ? opt.lastFrame : mWorld.frames;
    checkFrameRange(first, last);
    bool stateless = true;
    for (auto& e : mEffects) stateless = stateless && !e->needsHistory();
    est.frames = last - first + 1;
    est.steps = (stateless ? est.frames : last) * mWorld.stepsPerFrame;
    est.memoryLimitBytes = mWorld.memoryLimitBytes;
    std::vector<MemoryEstimate> counted;
    if (mOutput.displacementPng && mWorld.domain.flat()) {
        est.memory.push_back(perVoxelEstimate(double(mWorld.domain.bbox().volume()), 8.0, "domain.size",
                                              "the displacement PNG raster (output.displacement_png)"));
        est.memoryBytes += est.memory.back().bytes;
    }
    for (auto& e : mEffects) {
        MemoryEstimate m;
        atSection(e->name(), "memory estimate", [&] { m = e->memoryEstimate(mWorld); });
        if (m.key.empty()) m.key = e->name();
        if (!sharedEstimate(counted, m)) est.memoryBytes += m.bytes;
        est.memory.push_back(m);
    }
    mWorld.progress = false;
    auto t0 = Clock::now();
    initialize();
    est.initSeconds = seconds(t0, Clock::now());
    t0 = Clock::now();
    // The probe: whole steps until the time is up (at least one, at most the run's).
    while (est.probeSteps < est.steps && (est.probeSteps == 0 || seconds(t0, Clock::now()) < probeSeconds)) {
        step();
        ++est.probeSteps;
    }
    est.probeSeconds = seconds(t0, Clock::now());
    if (mOutput.vdb) {
        t0 = Clock::now();
        Frame frame = currentFrame(std::max<int64_t>(1, mStep / mWorld.stepsPerFrame));
        for (size_t i = 0; i < frame.grids.size(); ++i) exportGrid(frame.grid(i), mWorld.domain, mOutput.keepLattice);
        est.frameSeconds = seconds(t0, Clock::now());
    }
    const double perStep = est.probeSteps > 0 ? est.probeSeconds / double(est.probeSteps) : 0.0;
    est.seconds = est.initSeconds + perStep * double(est.steps) + est.frameSeconds * double(est.frames);
    est.peakRssBytes = peakRss();
    return est;
}

namespace {
std::string fixed(double v, int digits)
{
    std::ostringstream os;
    os << std::fixed << std::setprecision(digits) << v;
    return os.str();
}
} // namespace

std::string RunEstimate::toText() const
{
    std::ostringstream os;
    os << "estimate (nothing written):\n";
    os << "  memory: about " << formatBytes(memoryBytes) << " by the effects' estimates";
    if (memoryLimitBytes > 0) os << " (limit " << formatBytes(memoryLimitBytes) << ")";
    os << "\n";
    for (const auto& m : memory)
        os << "    " << m.key << ": " << formatBytes(m.bytes) << (m.detail.empty() ? "" : " (" + m.detail + ")") << "\n";
    os << "  measured: peak " << formatBytes(double(peakRssBytes)) << " resident after " << probeSteps
       << " probe step(s)\n";
    os << "  time: about " << fixed(seconds, 1) << " s for " << steps << " steps and " << frames << " frame(s): setup "
       << fixed(initSeconds, 2) << " s, " << probeSteps << " probe step(s) in " << fixed(probeSeconds, 2)
       << " s, one frame's grids " << fixed(frameSeconds, 2) << " s\n";
    os << "  (linear in the steps: growing ice makes later steps slower, so take it as a lower bound)\n";
    return os.str();
}

std::string RunEstimate::toJson() const
{
    std::ostringstream os;
    os << "{\"event\":\"estimate\",\"memory_bytes\":" << fixed(memoryBytes, 0)
       << ",\"memory_limit_bytes\":" << fixed(memoryLimitBytes, 0) << ",\"memory\":[";
    for (size_t i = 0; i < memory.size(); ++i)
        os << (i ? "," : "") << "{\"key\":" << jsonQuote(memory[i].key) << ",\"bytes\":" << fixed(memory[i].bytes, 0)
           << ",\"detail\":" << jsonQuote(memory[i].detail) << "}";
    os << "],\"peak_rss_bytes\":" << peakRssBytes << ",\"steps\":" << steps << ",\"frames\":" << frames
       << ",\"probe_steps\":" << probeSteps << ",\"probe_seconds\":" << fixed(probeSeconds, 3)
       << ",\"init_seconds\":" << fixed(initSeconds, 3) << ",\"frame_seconds\":" << fixed(frameSeconds, 3)
       << ",\"seconds\":" << fixed(seconds, 3) << "}";
    return os.str();
}

void Simulation::finishSummary(RunSummary& sum) const
{
    sum.steps = mStep;
    sum.effectSeconds.clear();
    sum.effectCpuSeconds.clear();
    sum.detailSeconds.clear();
    sum.detailCounts.clear();
    for (size_t i = 0; i < mEffects.size(); ++i) {
        sum.effectSeconds.emplace_back(mEffects[i]->name(), mEffectSeconds[i]);
        sum.effectCpuSeconds.emplace_back(mEffects[i]->name(), mEffectCpuSeconds[i]);
        for (auto& [k, v] : mEffects[i]->timings()) sum.detailSeconds.emplace_back(mEffects[i]->name() + "." + k, v);
        for (auto& [k, v] : mEffects[i]->counters()) sum.detailCounts.emplace_back(mEffects[i]->name() + "." + k, v);
    }
    sum.fields = mWorld.fields.names();
    sum.peakRssBytes = peakRss();
}

/// run.json for a run of the scene's whole frame range; a chunk (--frames A-B, as farm tasks run
/// in parallel into one folder) writes run.frames-A-B.json, so chunks never replace each other's.
std::string Simulation::runSummaryName(const RunSummary& sum) const
{
    if (sum.firstFrame == 1 && sum.lastFrame == mWorld.frames) return "run.json";
    char buf[64];
    std::snprintf(buf, sizeof buf, "run.frames-%04lld-%04lld.json", static_cast<long long>(sum.firstFrame),
                  static_cast<long long>(sum.lastFrame));
    return buf;
}

void Simulation::writeRunJson(const std::string& dir, const RunSummary& sum) const
{
    writeFileAtomic(dir + "/" + sum.summaryFile, sum.toJson());
}

RunSummary Simulation::run(const RunOptions& opt)
{
    std::unique_ptr<tbb::global_control> threads;
    if (opt.threads > 0)
        threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, opt.threads);
    const auto tStart = Clock::now();
    const std::string dir = opt.outDir.empty() ? "out/" + mWorld.sceneName : opt.outDir;
    const int64_t first = opt.firstFrame > 0 ? opt.firstFrame : 1;
    const int64_t last = opt.lastFrame > 0 ? opt.lastFrame : mWorld.frames;
    checkFrameRange(first, last);
    mCommandLine = opt.commandLine;
    RunSummary sum = startSummary(opt, first, last);
    // The folder's lock on these frames, held until this run returns (the kernel drops it on any
    // exit): a second run into the same frames is refused, or waits with --wait-lock.
    std::unique_ptr<OutputFolderLock> lock;
    struct ClearSignalRecord {
        ~ClearSignalRecord() { setSignalRecord({}, {}, {}, {}); }
    } clearSignalRecord;
    if (opt.writeFiles) {
        makeDirectories(dir);
        lock = std::make_unique<OutputFolderLock>(dir, first, last, opt.waitLock, [&](const std::string& line) {
            std::cerr << "frostvdb: " << line << std::endl;
        });
        prepareOutputFolder(dir, opt, sum);
    }
    try {
        simulateFrames(first, last, opt, dir, sum);
    } catch (const std::exception& e) {
        // Record what is complete and why the run stopped; if even that cannot be written (a full
        // disk), the run.json written at the start still says "running", never "complete".
        if (opt.writeFiles) {
            setSignalRecord({}, {}, {}, {});
            sum.status = "failed";
            sum.error = shortMessage(e.what());
            sum.exitCode = exitCodeOf(e);
            finishSummary(sum);
            sum.totalSeconds = seconds(tStart, Clock::now());
            try { writeRunJson(dir, sum); } catch (const std::exception&) {}
        }
        throw;
    }
    setSignalRecord({}, {}, {}, {}); // from here run.json says "complete"
    sum.status = "complete";
    finishSummary(sum);
    sum.totalSeconds = seconds(tStart, Clock::now());
    if (opt.writeFiles) writeRunJson(dir, sum);
    return sum;
}

int exitCodeOf(const std::exception& e)
{
    if (dynamic_cast<const OutOfMemoryError*>(&e) || dynamic_cast<const std::bad_alloc*>(&e)) return 6;
    if (dynamic_cast<const SceneError*>(&e) || dynamic_cast<const CheckpointError*>(&e) ||
        dynamic_cast<const VdbFileError*>(&e))
        return 2;
    if (dynamic_cast<const SimulationError*>(&e)) return 3;
    if (dynamic_cast<const WriteError*>(&e)) return 4;
    if (dynamic_cast<const OutputBusyError*>(&e)) return 5;
    return 1;
}

std::string RunSummary::toJson() const
{
    using Json = nlohmann::ordered_json; // keys in the order written
    auto pairs = [](const std::vector<std::pair<std::string, double>>& v, Json o = Json::object()) {
        for (const auto& [k, x] : v) o[k] = x;
        return o;
    };
    Json j;
    j["scene"] = scene;
    j["version"] = FROSTVDB_VERSION;
    j["status"] = status;
    if (!error.empty()) j["error"] = error;
    if (!signal.empty()) j["signal"] = signal;
    if (exitCode >= 0) j["exit_code"] = exitCode;
    j["scene_hash"] = sceneHash;
    j["command_line"] = commandLine;
    j["overrides"] = overrides;
    j["frames"] = Json::array({firstFrame, lastFrame});
    j["effective_scene"] = effectiveScene;
    j["effects"] = effects;
    j["fields"] = fields;
    j["steps"] = steps;
    j["frames_written"] = framesWritten;
    j["seconds"] = pairs(effectSeconds, Json{{"total", totalSeconds}, {"output", outputSeconds}});
    j["detail_seconds"] = pairs(detailSeconds);
    j["detail_counts"] = pairs(detailCounts);
    j["active_voxels"] = Json::array();
    for (const auto& [step, voxels] : activeVoxels) j["active_voxels"].push_back(Json::array({step, voxels}));
    j["resumed_from_step"] = resumedFromStep;
    j["checkpoints"] = checkpoints;
    j["peak_memory_bytes"] = peakRssBytes;
    j["files"] = files;
    // Paths and messages may hold bytes that are not UTF-8: replaced, never an exception.
    return j.dump(2, ' ', false, Json::error_handler_t::replace) + "\n";
}

/// A counter as a person reads it: whole numbers as integers (600, 2537447480), others with six
/// significant digits (0.000417, 12.5).
static std::string countText(double v)
{
    char buf[64];
    if (std::isfinite(v) && v == std::floor(v) && std::fabs(v) < 9.0e15)
        std::snprintf(buf, sizeof buf, "%lld", static_cast<long long>(v));
    else
        std::snprintf(buf, sizeof buf, "%.6g", v);
    return buf;
}

std::string RunSummary::toText() const
{
    std::ostringstream os;
    os.setf(std::ios::fixed);
    os.precision(2);
    os << "scene " << scene << ": " << steps << " steps, " << framesWritten << " frames in " << totalSeconds << " s\n";
    os << "  effects run:";
    for (auto& e : effects) os << " " << e;
    os << "\n  fields allocated:";
    for (auto& f : fields) os << " " << f;
    os << "\n";
    for (auto& [k, v] : effectSeconds) os << "  " << k << ": " << v << " s\n";
    for (auto& [k, v] : detailSeconds) os << "    " << k << ": " << v << " s\n";
    for (auto& [k, v] : detailCounts) os << "    " << k << ": " << countText(v) << "\n";
    os << "  output: " << outputSeconds << " s\n";
    if (resumedFromStep >= 0) os << "  resumed from the checkpoint at step " << resumedFromStep << "\n";
    if (checkpoints > 0) os << "  checkpoints written: " << checkpoints << "\n";
    if (!activeVoxels.empty())
        os << "  active voxels (all fields): " << activeVoxels.front().second << " at step " << activeVoxels.front().first
           << " -> " << activeVoxels.back().second << " at step " << activeVoxels.back().first << "\n";
    os << "  peak memory: " << double(peakRssBytes) / (1024.0 * 1024.0) << " MiB\n";
    return os.str();
}

std::string sceneReferenceMarkdown()
{
    std::ostringstream os;
    os << "# Scene reference\n\nGenerated by `frostvdb keys --markdown` from the code that reads the keys, so it is "
          "always in step with the program. Every key can be overridden on the command line with "
          "`--set section.key=value`. Unknown sections and keys, wrong types and out-of-range values are errors "
          "that name the file, line and key.\n\n";
    auto table = [&](const std::string& section, const std::string& summary, const ParamDict& d,
                     const std::vector<ParamSpec>& more = {}) {
        os << "## [" << section << "]\n\n" << summary << "\n\n| key | type | default | range | unit | meaning |\n"
           << "|---|---|---|---|---|---|\n";
        std::vector<ParamSpec> specs = d.specs();
        specs.insert(specs.end(), more.begin(), more.end());
        for (auto& s : specs)
            os << "| `" << s.key << "` | " << s.type << " | `" << s.defaultText << "` | " << s.range << " | "
               << (s.unit.empty() ? "-" : s.unit) << " | " << s.doc << " |\n";
        os << "\n";
    };
    World w;
    ParamDict scene("scene"), domain("domain"), region("region"), output("output"), runSection("run");
    readSceneSection(scene, w, "<scene file name>");
    w.domain = Domain::fromParams(domain);
    readRegionSection(region, w.region);
    OutputSettings o;
    readOutputSection(output, o);
    readRunSettings(runSection);
    table("scene", "Run-wide settings.", scene);
    std::vector<ParamSpec> kindKeys; // keys of the other domain kinds (src/core/domains/)
    for (const auto* k : DomainRegistry::all()) {
        ParamDict other("domain");
        other.set("kind", k->kind, {"", 0});
        try { Domain::fromParams(other); } catch (const std::exception&) {} // specs are recorded before any refusal
        for (const auto& s : other.specs()) {
            bool known = false;
            for (const auto& t : domain.specs()) known = known || t.key == s.key;
            for (const auto& t : kindKeys) known = known || t.key == s.key;
            if (!known) kindKeys.push_back(s);
        }
    }
    table("domain", "Where effects live: a plane one voxel thick or a 3D box, on a square or hexagonal lattice.", domain,
          kindKeys);
    table("region", "The sparse active region of the PDE effects.", region);
    table("output", "What is written.", output);
    table("run", "Resources of the whole run (see docs/guide.md, \"Failures and what frostvdb does\").", runSection);
    for (auto* info : EffectRegistry::all()) {
        ParamDict d(info->section);
        info->create(d, w);
        table(info->section, info->summary, d);
    }
    return os.str();
}

} // namespace frostvdb
