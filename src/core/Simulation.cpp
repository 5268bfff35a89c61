#include <frostvdb/core/Simulation.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Progress.h>
#include <frostvdb/io/Export.h>
#include <frostvdb/io/Preview.h>
#include <frostvdb/io/VdbIO.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <set>
#include <sstream>
#include <sys/resource.h>

namespace frostvdb {

namespace {

const std::set<std::string> kCoreSections = {"scene", "domain", "region", "output"};

using Clock = std::chrono::steady_clock;
double seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

uint64_t peakRss()
{
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    return uint64_t(ru.ru_maxrss) * 1024ull;
}

std::string jsonEscape(const std::string& s)
{
    std::string o;
    for (char c : s) {
        switch (c) {
        case '"': o += "\\\""; break;
        case '\\': o += "\\\\"; break;
        case '\n': o += "\\n"; break;
        case '\t': o += "\\t"; break;
        default:
            if (static_cast<unsigned char>(c) < 0x20) { char b[8]; std::snprintf(b, 8, "\\u%04x", c); o += b; }
            else o += c;
        }
    }
    return o;
}

/// Reads the core sections that belong to the driver.
void readSceneSection(ParamDict& d, World& w, const std::string& fallbackName)
{
    w.sceneName = d.getString("name", fallbackName, {}, "scene name: output files are <name>.<frame>.vdb");
    d.getString("description", "", {}, "free text shown by `frostvdb info`; ignored by the solvers");
    w.seed = uint64_t(d.getInt("seed", 1, 0, int64_t(1) << 53, "", "random seed (same seed, same bits)"));
    w.frames = d.getInt("frames", 8, 1, 1000000, "frames", "number of output frames");
    w.stepsPerFrame = d.getInt("steps_per_frame", 100, 1, 100000000, "steps", "simulation steps between frames");
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
    d.onlyWhen(!r.dense, "tolerance", "dense = true");
    d.onlyWhen(!r.dense, "front_travel", "dense = true");
}

void readOutputSection(ParamDict& d, OutputSettings& o)
{
    o.vdb = d.getBool("vdb", true, "write <name>.<frame>.vdb files");
    const std::string p = d.getString("preview", "last", {"none", "last", "every"},
        "PNG previews: none, the last frame, or every frame");
    o.preview = p != "none";
    o.previewEvery = p == "every";
    o.previewGrid = d.getString("preview_grid", "", {}, "grid drawn in previews (default: ice, density or cells)");
    d.onlyWhen(o.preview, "preview_grid", "preview = \"none\"");
    o.halfFloat = d.getBool("half_float", false, "store float grids as 16-bit half floats");
    o.keepLattice = d.getBool("keep_lattice", false,
        "hexagonal domains: write grids on the sheared lattice transform instead of resampling them to square voxels "
        "(same as `frostvdb run --keep-lattice`)");
    o.displacementPng = d.getBool("displacement_png", true,
        "flat domains with ice: also write the displacement map (grid `growth`) as a 16-bit greyscale "
        "<name>.<frame>.displacement.png on the square export raster");
}

} // namespace

Simulation::Simulation(Scene scene) : mScene(std::move(scene))
{
    std::string fallback = std::filesystem::path(mScene.label()).stem().string();
    if (fallback.empty() || fallback[0] == '<') fallback = "scene";
    std::replace_if(fallback.begin(), fallback.end(),
                    [](char c) { return !(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-'); }, '_');
    readSceneSection(mScene.section("scene"), mWorld, fallback);
    mWorld.domain = Domain::fromParams(mScene.section("domain"));
    readRegionSection(mScene.section("region"), mWorld.region);
    readOutputSection(mScene.section("output"), mOutput);
    mWorld.sceneLabel = mScene.label();
    mWorld.sceneText = mScene.text();
    mWorld.fields = FieldSet(mWorld.domain.transform());
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
        mEffects.push_back(info->create(dict, mWorld));
        dict.checkAllRead();
    }
    if (mEffects.empty())
        throw SceneError(mScene.label(), 0, "", "the scene names no effect section, so there is nothing to simulate");
    std::vector<DeclaredEffect> declared;
    for (auto& e : mEffects) declared.push_back({e->name(), e->declaration()});
    mOrder = deriveEffectOrder(declared, mScene.label());
    for (const auto& d : declared)
        for (const auto& u : d.declaration.uses)
            if (u.key->role == FieldRole::Field && (u.access & kWrites) &&
                std::find(mWrittenFields.begin(), mWrittenFields.end(), u.key->name) == mWrittenFields.end())
                mWrittenFields.push_back(u.key->name);
    mEffectSeconds.assign(mEffects.size(), 0.0);
}

Simulation::~Simulation() = default;

Effect* Simulation::effect(const std::string& section) const
{
    for (auto& e : mEffects)
        if (e->name() == section) return e.get();
    return nullptr;
}

void Simulation::initialize()
{
    if (mInitialized) return;
    for (size_t i : mOrder.initialize) mEffects[i]->initialize(mWorld);
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
        mEffects[i]->step(mWorld, info);
        mEffectSeconds[i] += seconds(t0, Clock::now());
    }
    if (mWorld.domain.hasPostStep()) // e.g. a shell's closest-point re-extension
        for (const auto& name : mWrittenFields)
            if (auto g = mWorld.fields.base(name)) mWorld.domain.postStep(*g);
    ++mStep;
}

Frame Simulation::currentFrame(int64_t frameNumber)
{
    initialize();
    Frame frame;
    frame.frame = frameNumber;
    frame.step = mStep;
    for (auto& e : mEffects)
        if (e->time() > 0.0) { frame.time = e->time(); break; }
    for (auto& e : mEffects) e->addToFrame(mWorld, frame);
    return frame;
}

std::string Simulation::writeFrame(const Frame& frame, const std::string& dir)
{
    makeDirectories(dir);
    openvdb::MetaMap meta;
    meta.insertMeta("creator", openvdb::StringMetadata(std::string("frostvdb ") + FROSTVDB_VERSION));
    meta.insertMeta("frostvdb_version", openvdb::StringMetadata(FROSTVDB_VERSION));
    meta.insertMeta("scene", openvdb::StringMetadata(mWorld.sceneText));
    meta.insertMeta("scene_file", openvdb::StringMetadata(mWorld.sceneLabel));
    meta.insertMeta("seed", openvdb::Int64Metadata(int64_t(mWorld.seed)));
    meta.insertMeta("frame", openvdb::Int64Metadata(frame.frame));
    meta.insertMeta("step", openvdb::Int64Metadata(frame.step));
    meta.insertMeta("time", openvdb::DoubleMetadata(frame.time));
    meta.insertMeta("voxel_size_m", openvdb::DoubleMetadata(mWorld.domain.voxelSize()));
    openvdb::GridPtrVec grids = exportGrids(frame.grids, mWorld.domain, mOutput.keepLattice);
    for (auto& g : grids) {
        g->insertMeta("frostvdb_step", openvdb::Int64Metadata(frame.step));
        g->insertMeta("frostvdb_time", openvdb::DoubleMetadata(frame.time));
    }
    const std::string path = framePath(dir, mWorld.sceneName, frame.frame);
    writeVdbAtomic(path, grids, meta, mOutput.halfFloat);
    return path;
}

std::string Simulation::writeDisplacement(const Frame& frame, const std::string& dir)
{
    if (!mOutput.displacementPng || !mWorld.domain.flat()) return {};
    for (auto& g : frame.grids) {
        auto growth = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
        if (!growth || g->getName() != "growth") continue;
        makeDirectories(dir);
        const std::string path = framePath(dir, mWorld.sceneName, frame.frame, "displacement.png");
        writeDisplacementPng(*growth, mWorld.domain, path);
        return path;
    }
    return {};
}

RunSummary Simulation::run(const RunOptions& opt)
{
    std::unique_ptr<tbb::global_control> threads;
    if (opt.threads > 0)
        threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, opt.threads);

    const auto tStart = Clock::now();
    RunSummary sum;
    sum.scene = mWorld.sceneName;
    const std::string dir = opt.outDir.empty() ? "out/" + mWorld.sceneName : opt.outDir;
    const int64_t first = opt.firstFrame > 0 ? opt.firstFrame : 1;
    const int64_t last = opt.lastFrame > 0 ? std::min(opt.lastFrame, mWorld.frames) : mWorld.frames;
    if (first > last)
        throw SceneError("--frames", 0, "", "frame range " + std::to_string(first) + "-" + std::to_string(last) +
                                                " is empty (the scene has " + std::to_string(mWorld.frames) + " frames)");
    bool stateless = true;
    for (auto& e : mEffects) stateless = stateless && !e->needsHistory();

    initialize();
    const int64_t stepsToRun = (stateless ? (last - first + 1) : last) * mWorld.stepsPerFrame;
    Progress progress(mWorld.sceneName, stepsToRun, "steps", opt.progress);
    int64_t done = 0;
    double outputSeconds = 0;
    std::string lastPreviewPath;
    Frame lastFrame;
    for (int64_t f = stateless ? first : 1; f <= last; ++f) {
        if (stateless) mStep = (f - 1) * mWorld.stepsPerFrame;
        for (int64_t s = 0; s < mWorld.stepsPerFrame; ++s) {
            step();
            progress.update(++done);
        }
        sum.activeVoxels.emplace_back(mStep, mWorld.fields.activeVoxels());
        if (f < first || !opt.writeFiles) continue;
        const auto t0 = Clock::now();
        Frame frame = currentFrame(f);
        if (mOutput.vdb) sum.files.push_back(writeFrame(frame, dir));
        if (auto png = writeDisplacement(frame, dir); !png.empty()) sum.files.push_back(png);
        ++sum.framesWritten;
        if (mOutput.preview && (mOutput.previewEvery || f == last)) {
            makeDirectories(dir);
            const std::string png = framePath(dir, mWorld.sceneName, f, "png");
            bool drawn = false;
            for (auto& e : mEffects)
                if (!drawn && e->writePreview(mWorld, frame, png)) drawn = true;
            if (!drawn) {
                openvdb::GridBase::Ptr pick;
                for (const std::string want : {mOutput.previewGrid, std::string("ice"), std::string("density"),
                                               std::string("cells")}) {
                    if (want.empty() || pick) continue;
                    for (auto& g : frame.grids)
                        if (g->getName() == want && g->isType<openvdb::FloatGrid>()) pick = g;
                }
                if (!pick && !mOutput.previewGrid.empty())
                    throw SceneError(mWorld.sceneLabel, 0, "output.preview_grid",
                                     "no float grid named '" + mOutput.previewGrid + "' in the frame");
                if (pick) { writePreview(*pick, png); drawn = true; }
            }
            if (drawn) sum.files.push_back(png);
        }
        outputSeconds += seconds(t0, Clock::now());
    }
    progress.finish();

    sum.steps = mStep;
    for (size_t i = 0; i < mEffects.size(); ++i) {
        sum.effects.push_back(mEffects[i]->name());
        sum.effectSeconds.emplace_back(mEffects[i]->name(), mEffectSeconds[i]);
        for (auto& [k, v] : mEffects[i]->timings()) sum.detailSeconds.emplace_back(mEffects[i]->name() + "." + k, v);
    }
    sum.fields = mWorld.fields.names();
    sum.outputSeconds = outputSeconds;
    sum.totalSeconds = seconds(tStart, Clock::now());
    sum.peakRssBytes = peakRss();
    if (opt.writeFiles) {
        makeDirectories(dir);
        const std::string jsonPath = dir + "/run.json";
        const std::string tmp = temporaryPathFor(jsonPath);
        { std::ofstream(tmp) << sum.toJson(); }
        commitTemporary(tmp, jsonPath);
    }
    return sum;
}

std::string RunSummary::toJson() const
{
    std::ostringstream os;
    os.precision(6);
    os << "{\n  \"scene\": \"" << jsonEscape(scene) << "\",\n  \"version\": \"" << FROSTVDB_VERSION << "\",\n";
    os << "  \"effects\": [";
    for (size_t i = 0; i < effects.size(); ++i) os << (i ? ", " : "") << "\"" << jsonEscape(effects[i]) << "\"";
    os << "],\n  \"fields\": [";
    for (size_t i = 0; i < fields.size(); ++i) os << (i ? ", " : "") << "\"" << jsonEscape(fields[i]) << "\"";
    os << "],\n  \"steps\": " << steps << ",\n  \"frames_written\": " << framesWritten << ",\n";
    os << "  \"seconds\": {\"total\": " << totalSeconds << ", \"output\": " << outputSeconds;
    for (auto& [k, v] : effectSeconds) os << ", \"" << jsonEscape(k) << "\": " << v;
    os << "},\n  \"detail_seconds\": {";
    for (size_t i = 0; i < detailSeconds.size(); ++i)
        os << (i ? ", " : "") << "\"" << jsonEscape(detailSeconds[i].first) << "\": " << detailSeconds[i].second;
    os << "},\n  \"active_voxels\": [";
    for (size_t i = 0; i < activeVoxels.size(); ++i)
        os << (i ? ", " : "") << "[" << activeVoxels[i].first << ", " << activeVoxels[i].second << "]";
    os << "],\n  \"peak_memory_bytes\": " << peakRssBytes << ",\n  \"files\": [";
    for (size_t i = 0; i < files.size(); ++i) os << (i ? ",\n    " : "\n    ") << "\"" << jsonEscape(files[i]) << "\"";
    os << "\n  ]\n}\n";
    return os.str();
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
    os << "  output: " << outputSeconds << " s\n";
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
    ParamDict scene("scene"), domain("domain"), region("region"), output("output");
    readSceneSection(scene, w, "<scene file name>");
    w.domain = Domain::fromParams(domain);
    readRegionSection(region, w.region);
    OutputSettings o;
    readOutputSection(output, o);
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
    for (auto* info : EffectRegistry::all()) {
        ParamDict d(info->section);
        info->create(d, w);
        table(info->section, info->summary, d);
    }
    return os.str();
}

} // namespace frostvdb
