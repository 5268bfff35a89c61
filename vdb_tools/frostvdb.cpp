/// frostvdb: grows ice, frost and snowflakes and makes procedural steam as OpenVDB volumes.
///   frostvdb run [SCENE] [--out DIR] [--set K=V]... [--threads N] [--seed S] [--frames A-B] [--keep-lattice]
///                [--overwrite] [--progress human|json|none] [--estimate[=SECONDS]]
///                [--checkpoint-every N|Nm] [--resume DIR] [--wait-lock]
///   frostvdb info FILE.vdb
///   frostvdb preview FILE.vdb -o FILE.png [--grid NAME]
///   frostvdb bench NAME [--threads N] [--quick]
///   frostvdb keys [--markdown]
#include <frostvdb/core/Bench.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Progress.h>
#include <frostvdb/core/Simulation.h>
#include <frostvdb/io/AtomicFile.h>
#include <frostvdb/io/Preview.h>
#include <frostvdb/io/VdbIO.h>

#include <boost/program_options.hpp>
#include <openvdb/openvdb.h>

#include <iostream>
#include <regex>
#include <set>
#include <sstream>

namespace po = boost::program_options;
using namespace frostvdb;

namespace {

const char* kUsage = R"(usage: frostvdb COMMAND [options]

commands:
  run [SCENE]      simulate a scene (the built-in dendrite when SCENE is omitted)
  info FILE.vdb    list the grids of a file: class, type, active voxels, bbox, voxel size, metadata
  preview FILE.vdb -o FILE.png [--grid NAME]
                   draw a grid: shaded top view for flat grids, ray-marched for volumes
  bench NAME       run a benchmark (frostvdb bench --help lists them)
  keys             list every scene section and key with default, unit and range

`frostvdb COMMAND --help` describes each command.
)";

/// Parses exactly "N" or "A-B" (decimal frame numbers from 1); anything else is an error.
/// The range is checked against the scene's frames by the run.
void parseFrames(const std::string& s, int64_t& first, int64_t& last)
{
    static const std::regex form(R"(^([0-9]{1,9})(-([0-9]{1,9}))?$)");
    std::smatch m;
    if (!std::regex_match(s, m, form))
        throw SceneError("--frames", 0, "", "expected N or A-B (frame numbers from 1), got '" + shortMessage(s, 40) + "'");
    first = std::stoll(m[1].str());
    last = m[3].matched ? std::stoll(m[3].str()) : first;
    if (first < 1 || last < first)
        throw SceneError("--frames", 0, "", "expected 1 <= A <= B, got '" + s + "'");
}

/// The command line as a shell would re-run it (arguments with spaces or quotes single-quoted).
std::string commandLineText(int argc, char** argv)
{
    std::string out;
    for (int i = 0; i < argc; ++i) {
        std::string a = argv[i];
        const bool plain = !a.empty() && a.find_first_not_of("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz"
                                                             "0123456789_-.,/=:+@[]") == std::string::npos;
        if (!plain) {
            std::string q = "'";
            for (char c : a) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
            a = q + "'";
        }
        out += (i ? " " : "") + a;
    }
    return out;
}

std::string gCommandLine;
bool gJsonErrors = false; ///< run --progress json: errors also as one JSON line on stderr

/// --checkpoint-every and --resume: the run options they set (--resume DIR also means --out DIR
/// unless --out is given).
void applyCheckpointOptions(const po::variables_map& vm, RunOptions& ro)
{
    if (vm.count("checkpoint-every")) ro.checkpoint = CheckpointPolicy::parse(vm["checkpoint-every"].as<std::string>());
    if (vm.count("resume")) {
        ro.resumeDir = vm["resume"].as<std::string>();
        if (ro.resumeDir.empty()) throw SceneError("--resume", 0, "", "needs the output folder of the interrupted run");
        if (ro.outDir.empty()) ro.outDir = ro.resumeDir;
    }
}

int cmdRun(const std::vector<std::string>& args)
{
    po::options_description opts("frostvdb run [SCENE] [options]");
    std::vector<std::string> sets;
    std::string out, frames;
    int threads = 0;
    int64_t seed = -1;
    opts.add_options()
        ("help,h", "show this help")
        ("scene", po::value<std::string>(), "scene file (TOML); omitted: the built-in dendrite scene")
        ("out,o", po::value<std::string>(&out), "output folder (default out/<scene name>)")
        ("set,s", po::value<std::vector<std::string>>(&sets)->composing(), "override a key: section.key=value (repeatable)")
        ("threads,t", po::value<int>(&threads)->default_value(0), "worker threads (0: all cores)")
        ("seed", po::value<int64_t>(&seed), "random seed >= 0 (overrides scene.seed)")
        ("frames", po::value<std::string>(&frames), "write only frame N or frames A-B, within the scene's frames "
                                                    "(procedural effects skip the rest)")
        ("overwrite", "the output folder may hold frames of another run: remove this scene's old frames first")
        ("checkpoint-every", po::value<std::string>(),
         "write the whole state to OUT/<scene>.checkpoint every N steps, or every N minutes with Nm "
         "(e.g. 500 or 30m), and after the last frame")
        ("resume", po::value<std::string>(),
         "continue from the checkpoint in this folder (same scene and --set values); frames after it "
         "come out bit-identical to an uninterrupted run")
        ("keep-lattice", "hexagonal domains: write grids on the sheared lattice transform instead of resampling "
                         "them to square voxels (output.keep_lattice = true)")
        ("wait-lock", "another run holds the output folder's lock on these frames: wait for it to end instead of "
                      "refusing (exit code 5)")
        ("quiet,q", "no progress output (same as --progress none)")
        ("progress", po::value<std::string>()->default_value("human"),
         "human: a bar on a terminal, a line every 10% in logs; json: one JSON object per line on stderr "
         "(event, phase, step, steps, frame, frames, elapsed, eta; then one per written frame with its files, "
         "\"done\" at the end, \"error\" with the message on failure) for front ends and farm wrappers; none")
        ("estimate", po::value<double>()->implicit_value(1.5, "1.5"),
         "print the estimated memory and time and exit without writing anything: the effects' memory estimates, "
         "and the time of the first steps for about this many seconds (--estimate=0.5) extrapolated to the run; "
         "with --progress json, one JSON object on stdout")
        ("print-default-scene", "print the built-in default scene and exit");
    po::positional_options_description pos;
    pos.add("scene", 1);
    po::variables_map vm;
    po::store(po::command_line_parser(args).options(opts).positional(pos).run(), vm);
    po::notify(vm);
    if (vm.count("help")) {
        std::cout << opts << "\nExamples:\n  frostvdb run\n  frostvdb run scenes/dendrite_square.toml --set "
                             "phase_field.dt=0.0001 --out out/test\n";
        return 0;
    }
    if (vm.count("print-default-scene")) {
        std::cout << Scene::builtinDefaultText();
        return 0;
    }
    if (threads < 0) throw SceneError("--threads", 0, "", "must be >= 0");
    ProgressStyle style;
    try {
        style = parseProgressStyle(vm["progress"].as<std::string>());
    } catch (const std::invalid_argument& e) {
        throw SceneError("--progress", 0, "", e.what());
    }
    if (vm.count("quiet")) style = ProgressStyle::None;
    gJsonErrors = style == ProgressStyle::Json;
    Scene scene = vm.count("scene") ? Scene::load(vm["scene"].as<std::string>()) : Scene::builtinDefault();
    for (const auto& s : sets) scene.applyOverride(s);
    if (vm.count("seed")) {
        if (seed < 0) throw SceneError("--seed", 0, "", "must be >= 0, got " + std::to_string(seed));
        scene.applyOverride("scene.seed=" + std::to_string(seed));
    }
    if (vm.count("keep-lattice")) scene.applyOverride("output.keep_lattice=true");
    RunOptions ro;
    ro.outDir = out;
    ro.threads = threads;
    ro.progress = style != ProgressStyle::None;
    ro.progressJson = style == ProgressStyle::Json;
    ro.overwrite = vm.count("overwrite") > 0;
    ro.waitLock = vm.count("wait-lock") > 0;
    ro.commandLine = gCommandLine;
    if (!frames.empty()) parseFrames(frames, ro.firstFrame, ro.lastFrame);
    applyCheckpointOptions(vm, ro);
    Simulation sim(std::move(scene)); // validates every section and key before anything runs
    if (vm.count("estimate")) {
        const double probe = vm["estimate"].as<double>();
        if (!(probe >= 0.0 && probe <= 3600.0)) throw SceneError("--estimate", 0, "", "probe seconds must be in [0, 3600]");
        const RunEstimate est = sim.estimate(ro, probe);
        std::cout << (style == ProgressStyle::Json ? est.toJson() + "\n" : est.toText());
        return 0;
    }
    const RunSummary sum = sim.run(ro);
    std::cout << sum.toText();
    const std::string dir = ro.outDir.empty() ? "out/" + sum.scene : ro.outDir;
    std::cout << "  wrote " << sum.files.size() << " files and " << sum.summaryFile << " to " << dir << "/\n";
    return 0;
}

std::string metaValue(const openvdb::Metadata& m)
{
    std::string s = m.str();
    for (auto& c : s)
        if (c == '\n') c = ' ';
    if (s.size() > 100) s = s.substr(0, 97) + "...";
    return s;
}

int cmdInfo(const std::vector<std::string>& args)
{
    po::options_description opts("frostvdb info FILE.vdb");
    opts.add_options()("help,h", "show this help")("file", po::value<std::string>(), "VDB file");
    po::positional_options_description pos;
    pos.add("file", 1);
    po::variables_map vm;
    po::store(po::command_line_parser(args).options(opts).positional(pos).run(), vm);
    if (vm.count("help") || !vm.count("file")) {
        std::cout << opts;
        return vm.count("help") ? 0 : 2;
    }
    const std::string path = vm["file"].as<std::string>();
    openvdb::MetaMap::Ptr meta;
    auto grids = readVdb(path, &meta, /*requireGrids=*/true);
    const VdbLayout layout = validateVdb(path, readWholeFile(path));
    // The file-wide summary: what `[output] precision` and `compression` asked for.
    bool anyHalf = false, anyFull = false;
    std::set<std::string> comps;
    for (const auto& span : layout.grids) {
        const bool floating = span.type.find("_float_") != std::string::npos || span.type.find("_vec3s_") != std::string::npos;
        if (span.half) anyHalf = true;
        else if (floating) anyFull = true;
        if (span.compression >= 0) comps.insert(compressionText(uint32_t(span.compression)));
    }
    std::string compText;
    for (const auto& c : comps) compText += (compText.empty() ? "" : ", ") + c;
    std::cout << path << ": " << grids->size() << " grid(s), precision "
              << (anyHalf && anyFull ? "mixed" : anyHalf ? "half" : "float") << ", compression "
              << (compText.empty() ? "not recorded" : compText) << "\n";
    for (auto& g : *grids) {
        const auto bbox = g->evalActiveVoxelBoundingBox();
        const auto vs = g->voxelSize();
        std::cout << "  " << g->getName() << "\n"
                  << "    class " << openvdb::GridBase::gridClassToString(g->getGridClass()) << ", type " << g->valueType()
                  << (g->isType<openvdb::Vec3SGrid>() ? std::string(", vector type ") +
                                                            openvdb::GridBase::vecTypeToString(g->getVectorType())
                                                      : std::string())
                  << "\n    active voxels " << g->activeVoxelCount() << ", bbox " << bbox.min() << " - " << bbox.max()
                  << "\n    voxel size " << vs[0] << " x " << vs[1] << " x " << vs[2] << " m, memory "
                  << g->memUsage() / 1024 << " KiB\n";        for (const auto& span : layout.grids)
            if (span.name == g->getName() && (g->isType<openvdb::FloatGrid>() || g->isType<openvdb::Vec3SGrid>() ||
                                              g->isType<openvdb::DoubleGrid>() || g->isType<openvdb::Vec3DGrid>()))
                std::cout << "    precision " << (span.half ? "half (16-bit)" : "float (32-bit)") << ", compression "
                          << (span.compression < 0 ? std::string("not recorded") : compressionText(uint32_t(span.compression)))
                          << "\n";
            else if (span.name == g->getName())
                std::cout << "    compression "
                          << (span.compression < 0 ? std::string("not recorded") : compressionText(uint32_t(span.compression)))
                          << "\n";
        for (auto it = g->beginMeta(); it != g->endMeta(); ++it) {
            const std::string& k = it->first;
            if (k == "name" || k == "class" || k == "file_bbox_min" || k == "file_bbox_max" || k == "file_mem_bytes" ||
                k == "file_voxel_count" || k == "is_local_space" || k == "vector_type" || k == "value_type" ||
                k == "file_compression") // OpenVDB's read-time guess; the line above reads the grid's own flags
                continue;
            std::cout << "    " << k << ": " << metaValue(*it->second) << "\n";
        }
    }
    std::cout << "  file metadata:\n";
    for (auto it = meta->beginMeta(); it != meta->endMeta(); ++it) {
        if (it->first == "scene") {
            const std::string s = it->second->str();
            std::cout << "    scene: (" << std::count(s.begin(), s.end(), '\n') << " lines of scene text)\n";
            continue;
        }
        std::cout << "    " << it->first << ": " << metaValue(*it->second) << "\n";
    }
    return 0;
}

int cmdPreview(const std::vector<std::string>& args)
{
    po::options_description opts("frostvdb preview FILE.vdb -o FILE.png [--grid NAME]");
    std::string out, gridName;
    int width = 512;
    opts.add_options()("help,h", "show this help")("file", po::value<std::string>(), "VDB file")(
        "output,o", po::value<std::string>(&out), "PNG to write")(
        "grid,g", po::value<std::string>(&gridName), "grid to draw (default: ice, density, cells or the first float grid)")(
        "width,w", po::value<int>(&width)->default_value(512), "image width in pixels");
    po::positional_options_description pos;
    pos.add("file", 1);
    po::variables_map vm;
    po::store(po::command_line_parser(args).options(opts).positional(pos).run(), vm);
    po::notify(vm);
    if (vm.count("help") || !vm.count("file") || out.empty()) {
        std::cout << opts;
        return vm.count("help") ? 0 : 2;
    }
    if (width < 16 || width > 8192) throw SceneError("--width", 0, "", "must be in [16, 8192]");
    auto grids = readVdb(vm["file"].as<std::string>());
    openvdb::GridBase::Ptr pick;
    std::vector<std::string> wanted = gridName.empty() ? std::vector<std::string>{out::kIce.name, out::kAutomatonIce.name, out::kAggregateIce.name,
                                                                                  out::kDensity.name, out::kCells.name}
                                                       : std::vector<std::string>{gridName};
    for (auto& w : wanted)
        for (auto& g : *grids)
            if (!pick && g->getName() == w) pick = g;
    if (!pick && gridName.empty())
        for (auto& g : *grids)
            if (!pick && g->isType<openvdb::FloatGrid>()) pick = g;
    if (!pick) {
        std::string names;
        for (auto& g : *grids) names += (names.empty() ? "" : ", ") + g->getName() + " (" + g->valueType() + ")";
        if (gridName.empty())
            throw SceneError(vm["file"].as<std::string>(), 0, "",
                             "no float grid to draw (grids: " + (names.empty() ? std::string("none") : names) + ")");
        throw SceneError(vm["file"].as<std::string>(), 0, "--grid",
                         "no grid named '" + gridName + "' (grids: " + (names.empty() ? std::string("none") : names) + ")");
    }
    PreviewOptions po;
    po.width = width;
    writePreview(*pick, out, po);
    std::cout << "wrote " << out << " (grid " << pick->getName() << ")\n";
    return 0;
}

int cmdBench(const std::vector<std::string>& args)
{
    BenchArgs ba;
    std::string name;
    bool help = false;
    for (size_t i = 0; i < args.size(); ++i) {
        const std::string& a = args[i];
        if (a == "--help" || a == "-h") help = true;
        else if (a == "--quick") ba.quick = true;
        else if (a == "--threads" && i + 1 < args.size()) ba.threads = std::stoi(args[++i]);
        else if (a == "--docs" && i + 1 < args.size()) ba.docsDir = args[++i];
        else if (name.empty() && a[0] != '-') name = a;
        else ba.args.push_back(a);
    }
    if (help || name.empty()) {
        std::cout << "usage: frostvdb bench NAME [--threads N] [--quick] [--docs DIR]\n\nbenchmarks:\n";
        for (auto* b : BenchRegistry::all()) std::cout << "  " << b->name << "  " << b->summary << "\n";
        return help ? 0 : 2;
    }
    const BenchInfo* b = BenchRegistry::find(name);
    if (!b) throw SceneError("bench", 0, "", "unknown benchmark '" + name + "' (frostvdb bench --help lists them)");
    return b->run(ba);
}

int cmdKeys(const std::vector<std::string>& args)
{
    std::cout << sceneReferenceMarkdown();
    return 0;
}

} // namespace

int main(int argc, char** argv)
{
    openvdb::initialize();
    if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h" || std::string(argv[1]) == "help") {
        std::cout << kUsage;
        return argc < 2 ? 2 : 0;
    }
    if (std::string(argv[1]) == "--version") {
        std::cout << "frostvdb " << FROSTVDB_VERSION << " (OpenVDB " << openvdb::getLibraryVersionString() << ")\n";
        return 0;
    }
    const std::string cmd = argv[1];
    gCommandLine = commandLineText(argc, argv);
    std::vector<std::string> args(argv + 2, argv + argc);
    // --progress json: a failure is also one JSON line, so a front end needs to parse one format.
    auto fail = [&](const std::string& line, int code) {
        std::cerr << line << "\n";
        if (gJsonErrors)
            std::cerr << "{\"event\":\"error\",\"phase\":\"error\",\"message\":" << jsonQuote(line)
                      << ",\"exit_code\":" << code << "}\n";
        return code;
    };
    try {
        if (cmd == "run") return cmdRun(args);
        if (cmd == "info") return cmdInfo(args);
        if (cmd == "preview") return cmdPreview(args);
        if (cmd == "bench") return cmdBench(args);
        if (cmd == "keys") return cmdKeys(args);
        std::cerr << "frostvdb: unknown command '" << cmd << "'\n" << kUsage;
        return 2;
    } catch (const po::error& e) {
        return fail(std::string() + "frostvdb: " + cmd + ": " + shortMessage(e.what()) + " (see frostvdb " + cmd + " --help)", 2);
    } catch (const std::exception& e) {
        // one line, and one exit code per failure class (exitCodeOf; README "Exit codes")
        const int code = exitCodeOf(e);
        if (dynamic_cast<const std::bad_alloc*>(&e))
            return fail("frostvdb: error: out of memory (an allocation failed; lower the scene's sizes or "
                        "run.memory_limit)", code);
        if (code == 2 && dynamic_cast<const CheckpointError*>(&e))
            return fail(std::string() + "frostvdb: checkpoint: " + shortMessage(e.what()), code);
        if (code == 3) return fail(std::string() + "frostvdb: simulation stopped: " + shortMessage(e.what()), code);
        if (code == 4) return fail(std::string() + "frostvdb: output failed: " + shortMessage(e.what()), code);
        if (code == 5) return fail(std::string() + "frostvdb: output folder busy: " + shortMessage(e.what()), code);
        return fail(std::string() + "frostvdb: error: " + shortMessage(e.what()), code);
    }
}
