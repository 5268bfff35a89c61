/// @file SnowflakeBench.cpp
/// @brief `frostvdb bench snowflake`: the ice paper's Figure 7 scene (scenes/snowflake.toml:
/// 1024^2 hexagonal, H = 60000 walkers per step, 200 steps, DLA + phase field) run end to end
/// with its frames written, timed per phase. The paper needed 2 hours on a 2.66 GHz Xeon; the
/// target here is issue 24's: at most 10 s wall on the 2-core machine (issue 10 asked 15 s),
/// output under 10 % of it.
#include <frostvdb/BuildPaths.h>
#include <frostvdb/core/Bench.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Simulation.h>
#include <frostvdb/core/Export.h>
#include <frostvdb/io/Preview.h>

#include <sys/resource.h>

#include <chrono>

#include <cstdio>
#include <filesystem>
#include <map>

namespace frostvdb {
namespace {

/// CPU seconds (all threads) beside the wall seconds of each phase: CPU / wall is how many
/// cores a phase kept busy (2 at best on the 2-core machine); a phase near 1 ran serially. On a
/// loaded machine the wall times grow and the CPU times hardly move.
void printParallelism(std::map<std::string, double>& eff, std::map<std::string, double>& effCpu,
                      std::map<std::string, double>& detail, const RunSummary& sum, double runCpu)
{
    auto part = [](const char* name, double cpu, double wall) {
        std::printf("%s %.1f s (%.2f)", name, cpu, wall > 0 ? cpu / wall : 0.0);
    };
    std::printf("CPU (all threads) and CPU / wall: ");
    part("walkers", effCpu["dla"], eff["dla"]);
    part(", of them walks", detail["dla.walkers_cpu"], detail["dla.walkers"]);
    part("; phase field with heat", effCpu["phase_field"], eff["phase_field"]);
    part("; output", sum.outputCpuSeconds, sum.outputSeconds);
    part("; whole run", runCpu, sum.totalSeconds);
    std::printf("\n");
}

int benchSnowflake(const BenchArgs& args)
{
    const std::string path = std::string(FROSTVDB_SOURCE_DIR) + "/scenes/snowflake.toml";
    Scene scene = Scene::load(path);
    if (args.quick) { // a 256^2 smoke version with the same walker density
        scene.applyOverride("domain.size=[256,256]");
        scene.applyOverride("dla.humidity=3750");
    }
    const auto out = std::filesystem::temp_directory_path() / "frostvdb_bench_snowflake";
    std::filesystem::remove_all(out);
    Simulation sim(std::move(scene));
    RunOptions ro;
    ro.outDir = out.string();
    ro.threads = args.threads;
    ro.progress = true;
    const double cpu0 = bench::cpuSeconds();
    const RunSummary sum = sim.run(ro);
    const double runCpu = bench::cpuSeconds() - cpu0;

    std::map<std::string, double> eff, effCpu, detail;
    for (auto& [k, v] : sum.effectSeconds) eff[k] = v;
    for (auto& [k, v] : sum.effectCpuSeconds) effCpu[k] = v;
    for (auto& [k, v] : sum.detailSeconds) detail[k] = v;
    for (auto& [k, v] : sum.detailCounts) detail[k] = v;
    const double heat = detail["phase_field.heat"];
    const double walkers = eff["dla"], phase = eff["phase_field"] - heat;
    std::printf("\nSnowflake (scenes/snowflake.toml%s): %lld steps, %lld frames written\n\n",
                args.quick ? ", --quick 256^2" : "", (long long)sum.steps, (long long)sum.framesWritten);
    std::printf("| phase | seconds | share |\n|---|---:|---:|\n");
    auto row = [&](const char* name, double s) { std::printf("| %s | %.1f | %.0f%% |\n", name, s, 100.0 * s / sum.totalSeconds); };
    row("walkers (DLA: release, walks, sticking, distance map)", walkers);
    row("phase field (region, explicit kernel, p solve, truncation)", phase);
    row("heat (latent heat and the T solve)", heat);
    row("output (resample to square, VDB, displacement PNG, preview)", sum.outputSeconds);
    row("total (wall)", sum.totalSeconds);
    std::printf("\nwalker detail: walks %.1f s, sticking %.1f s, distance map %.1f s (%.0f full rebuilds after a "
                "melt), jump tables %.1f s\n",
                detail["dla.walkers"], detail["dla.apply"], detail["dla.distance"], detail["dla.distance_rebuilds"],
                detail["dla.tables"]);
    std::printf("phase field detail: region %.1f s, kernel %.1f s (solves %.1f s), truncation %.1f s; "
                "mean iterations p %.2f, T %.2f; clipped voxels %.0f\n",
                detail["phase_field.region"], detail["phase_field.kernel"], detail["phase_field.solve"],
                detail["phase_field.truncate"], detail["phase_field.mean_iterations_p"],
                detail["phase_field.mean_iterations_T"], detail["phase_field.clipped_voxels"]);
    printParallelism(eff, effCpu, detail, sum, runCpu);
    std::printf("peak memory %.0f MiB; the paper: 2 hours (7200 s) on a 2.66 GHz Xeon; target (issue 24) <= 10 s with output < 10%%: %s\n",
                sum.peakRssBytes / 1048576.0,
                sum.totalSeconds <= 10.0 && sum.outputSeconds < 0.1 * sum.totalSeconds ? "met" : "MISSED");
    // the last frame's output once more, piece by piece
    using Clock = std::chrono::steady_clock;
    auto since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
    Frame frame = sim.currentFrame(sum.framesWritten);
    auto t0 = Clock::now();
    const auto grids = exportGrids(frame.grids, sim.world().domain, sim.output().keepLattice);
    const double tResample = since(t0);
    t0 = Clock::now();
    sim.writeFrame(frame, out.string()); // resamples again, then writes
    const double tVdb = since(t0) - tResample;
    t0 = Clock::now();
    sim.writeDisplacement(frame, out.string());
    const double tDisp = since(t0);
    double tPreview = 0;
    for (auto& g : frame.grids)
        if (g->getName() == out::kAutomatonIce.name) {
            t0 = Clock::now();
            writePreview(*g, (out / "preview_timing.png").string());
            tPreview = since(t0);
        }
    uint64_t voxels = 0;
    for (auto& g : grids) voxels += g->activeVoxelCount();
    std::printf("last frame output again: resample to square %.2f s (%zu grids, %llu active voxels), VDB write "
                "%.2f s, displacement map %.2f s, preview %.2f s\n",
                tResample, grids.size(), (unsigned long long)voxels, tVdb, tDisp, tPreview);
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    std::printf("process CPU time: user %.1f s, system %.1f s (wall figures above depend on the machine's load)\n",
                ru.ru_utime.tv_sec + ru.ru_utime.tv_usec * 1e-6, ru.ru_stime.tv_sec + ru.ru_stime.tv_usec * 1e-6);
    std::printf("frames in %s\n", out.string().c_str());
    return 0;
}

} // namespace

FROSTVDB_REGISTER_BENCH(snowflake, "snowflake",
                        "the ice paper's Figure 7 snowflake (1024^2 hex, H = 60000, 200 steps) timed per phase",
                        benchSnowflake);

} // namespace frostvdb
