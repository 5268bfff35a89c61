/// @file GG3DEffect.cpp
/// @brief Section [gravner_griffeath_3d]: presets (the paper's named cases), keys, guard rails,
/// memory estimate, batch flakes. The grids are built in GG3DOutput.cpp.
#include <frostvdb/automata/GG3DEffect.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/core/State.h>
#include <frostvdb/io/Preview.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <sstream>

namespace frostvdb {
namespace automata {

namespace {
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

using A7 = std::array<double, kGGConfigs>;
A7 all7(double v) { return {v, v, v, v, v, v, v}; }

GG3DPreset make(const std::string& name, const std::string& family, double rho, A7 beta, A7 kappa, A7 mu,
                double phi = 0.0, int seedHeight = 1)
{
    GG3DPreset p;
    p.name = name;
    p.family = family;
    p.p.rho = rho;
    p.p.beta = beta;
    p.p.kappa = kappa;
    p.p.mu = mu;
    p.p.phi = phi;
    p.seedHeight = seedHeight;
    return p;
}

std::string fmt(double v)
{
    std::ostringstream s;
    s << v;
    return s.str();
}
} // namespace

// Order of the 7-entry arrays: 01, 10, 20, 30, 11, 21, 31 (facts table columns beta01, beta10,
// beta20, beta11 and "beta30, beta21, beta31" rearranged).
const std::vector<GG3DPreset>& gg3dPresets()
{
    static const std::vector<GG3DPreset> presets = [] {
        std::vector<GG3DPreset> v;
        const A7 b4{2.5, 2.0, 2.0, 1.0, 2.0, 1.0, 1.0};
        const A7 b14{1.6, 1.5, 1.5, 1.0, 1.4, 1.0, 1.0};
        v.push_back(make("fig01_intro_plate", "plate", 0.12, {2.8, 2.2, 2.2, 1.0, 1.6, 1.6, 1.0}, all7(0.005),
                         {0.0001, 0.001, 0.001, 0.0001, 0.0001, 0.0001, 0.0001}, 0.01));
        v.push_back(make("fig03_failed", "failed plate", 0.1, {1.73, 1.34, 1.34, 1.0, 1.0, 1.0, 1.0}, all7(0.1),
                         all7(0.001)));
        v.push_back(make("fig04_plate_ridges", "plate with ridges", 0.1, b4, all7(0.1), all7(0.001)));
        v.push_back(make("fig06_double_plate", "double plate", 0.1, b4, all7(0.1), all7(0.001), 0.0, 3));
        v.push_back(make("fig07_plate", "plate", 0.15, b4, all7(0.1), all7(0.001)));
        v.push_back(make("fig08_sectored_plate", "sectored plate", 0.09, b4, all7(0.1), all7(0.001)));
        v.push_back(make("fig09_sectored_branches", "sectored branches", 0.05, b4, all7(0.1), all7(0.001)));
        v.push_back(make("fig10_sectored_branches", "sectored branches", 0.045, b4, all7(0.1), all7(0.001)));
        v.push_back(make("fig13_fern", "fern", 0.105, b14, all7(0.1), all7(0.008)));
        v.push_back(make("fig14_classic_dendrite", "classic dendrite", 0.1, b14, all7(0.1), all7(0.008)));
        v.push_back(make("fig16_simple_star", "simple star", 0.09, b14, all7(0.1), all7(0.008)));
        v.push_back(make("fig20_sandwich_plate", "sandwich plate", 0.08, {6.0, 2.5, 2.5, 1.0, 2.0, 1.0, 1.0},
                         {0.5, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1}, all7(0.0001)));
        v.push_back(make("fig24_fern", "fern", 0.14, {3.0, 1.4, 1.4, 1.0, 1.4, 1.0, 1.0}, all7(0.1),
                         {0.002, 0.005, 0.005, 0.001, 0.001, 0.001, 0.001}, 0.01, 3));
        v.push_back(make("fig28_simple_star", "simple star", 0.16, {3.1, 1.05, 1.03, 1.02, 1.04, 1.01, 1.0},
                         all7(0.01), {0.01, 0.03, 0.03, 0.01, 0.01, 0.01, 0.01}, 0.005));
        v.push_back(make("fig29_needle", "needle", 0.1, {2.0, 4.0, 4.0, 1.0, 4.0, 1.0, 1.0}, all7(0.1), all7(0.001)));
        v.push_back(make("fig30_hollow_column", "hollow column", 0.1, {1.0, 2.0, 2.0, 0.5, 0.5, 0.5, 1.0},
                         all7(0.1), all7(0.01)));
        v.push_back(make("fig31_column_hollow_facets", "column", 0.1, {1.5, 1.6, 1.6, 1.0, 1.0, 1.0, 1.0},
                         all7(0.1), all7(0.015)));
        // Fig. 32: only beta10's switch (2.25 -> 1.15 at t = 8,000) is in the facts; the rest is
        // completed here as a column set-up (beta01 = 1.2 so the column grows up before the
        // switch, the other thresholds 1, kappa 0.1 and mu 0.01 as Fig. 30), and beta20 follows
        // beta10 as in every other case of the table.
        {
            GG3DPreset c = make("fig32_capped_column", "capped column", 0.1, {1.2, 2.25, 2.25, 1.0, 1.0, 1.0, 1.0},
                                all7(0.1), all7(0.01));
            GG3DSwitch s;
            s.step = 8000;
            s.hasBeta = true;
            s.beta = {1.2, 1.15, 1.15, 1.0, 1.0, 1.0, 1.0};
            c.switches.push_back(s);
            v.push_back(c);
        }
        v.push_back(make("fig39_stellar_dendrite_needles", "stellar dendrite with needles", 0.1,
                         {1.58, 1.5, 1.5, 1.0, 1.5, 1.0, 1.0}, all7(0.1), all7(0.006)));
        v.push_back(make("fig40_star_with_needles", "star with needles", 0.06, all7(1.0),
                         {0.11, 0.1, 0.1, 0.05, 0.01, 0.01, 0.01}, all7(0.03)));
        v.push_back(make("fig43_sandwich_broad_branches", "sandwich plate, broad branches", 0.09,
                         {1.41, 1.2, 1.2, 1.0, 1.0, 1.0, 1.0}, all7(0.1), all7(0.025)));
        return v;
    }();
    return presets;
}

const GG3DPreset* findGG3DPreset(const std::string& name)
{
    for (const auto& p : gg3dPresets())
        if (p.name == name) return &p;
    return nullptr;
}

std::vector<std::string> gg3dGuardRails(const GG3DParams& p)
{
    std::vector<std::string> out;
    for (int k : {0, 1}) { // configurations 01 and 10
        const std::string ij = ggConfigName(k);
        const double inflow = (1.0 - p.kappa[size_t(k)]) * p.rho;
        if (!(inflow < p.beta[size_t(k)]))
            out.push_back("(1 - kappa_" + ij + ") rho = " + fmt(inflow) + " >= beta_" + ij + " = " +
                          fmt(p.beta[size_t(k)]) + ": runaway Packard-like growth");
        const double melt = p.mu[size_t(k)] * p.beta[size_t(k)];
        if (!(melt < inflow))
            out.push_back("mu_" + ij + " beta_" + ij + " = " + fmt(melt) + " >= (1 - kappa_" + ij + ") rho = " +
                          fmt(inflow) + ": growth stalls");
    }
    return out;
}

// ---------------------------------------------------------------------------------------------

GG3DEffect::GG3DEffect(GG3DConfig cfg, GG3DOutput out, std::string preset)
    : mCfg(std::move(cfg)), mOut(std::move(out)), mPreset(std::move(preset))
{
}

FieldDeclaration GG3DEffect::declaration() const
{
    FieldDeclaration d; // its own lattice and clock: no fields shared with other effects
    d.stage = Stage::Sources;
    d.output(out::kCells).output(out::kAutomatonIce).output(out::kFreezeStep);
    if (mOut.sdf) d.output(out::kIceSdf);
    return d;
}

GG3DConfig GG3DEffect::flakeConfig(const GG3DConfig& base, double vary, int k)
{
    if (k == 0) return base;
    GG3DConfig c = base;
    CounterRng rng(base.seed, 0x47473346ull, uint64_t(k)); // "GG3F"
    auto jitter = [&](double v) { return v * (1.0 + vary * (2.0 * rng.uniform() - 1.0)); };
    c.p.rho = jitter(c.p.rho);
    for (double& b : c.p.beta) b = std::max(0.05, jitter(b));
    for (double& m : c.p.mu) m = std::clamp(jitter(m), 0.0, 1.0);
    // The horizontal thresholds stay equal pairwise (beta10 = beta20 in every published case).
    c.p.beta[2] = c.p.beta[1];
    c.seedRadius = std::max(1, c.seedRadius + int(rng.uniform() * 3.0) - 1);
    return c;
}

namespace {

/// The rule's keys: rho, beta, kappa, mu, phi, noise, hole filling and one parameter switch.
void readGG3DRule(ParamDict& d, const GG3DPreset& base, GG3DConfig& cfg)
{
    GG3DParams& p = cfg.p;
    auto arr7 = [&](const std::string& key, const A7& def, double lo, double hi, const std::string& doc) {
        const auto v = d.getFloatArray(key, {def.begin(), def.end()}, {1, 7}, lo, hi, "",
                                       doc + " (one value, or 7 in the order 01, 10, 20, 30, 11, 21, 31)");
        A7 out;
        for (size_t k = 0; k < 7; ++k) out[k] = v.size() == 1 ? v[0] : v[k];
        return out;
    };
    p.rho = d.getFloat("rho", base.p.rho, 1e-6, 10.0, "", "initial vapour density rho (the background far away)");
    p.beta = arr7("beta", base.p.beta, 1e-6, 1000.0,
        "attachment threshold beta_ij, i = min(3, attached horizontal neighbours), j = min(1, vertical)");
    p.kappa = arr7("kappa", base.p.kappa, 0.0, 1.0, "fraction kappa_ij of a boundary site's vapour that stays vapour on freezing");
    p.mu = arr7("mu", base.p.mu, 0.0, 1.0, "fraction mu_ij of boundary mass that melts back to vapour each step");
    p.phi = d.getFloat("phi", base.p.phi, 0.0, 0.5, "", "drift: fraction of vapour moving one layer down per step (breaks up/down symmetry)");
    p.noise = d.getFloat("noise", 0.0, 0.0, 0.1, "",
        "the paper's noise eps: a random half of the cells keep eps of their vapour out of diffusion (0: deterministic)");
    p.holeFill = d.getBool("hole_fill", true, "attach any boundary site with >= 4 attached horizontal neighbours");
    p.holeFillNeedsVertical = d.getBool("hole_fill_vertical", false,
        "hole filling also needs >= 1 attached vertical neighbour (one transcription's reading)");

    // One parameter switch (the paper's time-varying cases); a preset's own switch is the default.
    const GG3DSwitch* ps = base.switches.empty() ? nullptr : &base.switches[0];
    const int64_t swStep = d.getInt("switch_step", ps ? ps->step : 0, 0, int64_t(1) << 40, "steps",
        "step at which the switch_* values replace beta / kappa / mu / phi; 0 = no switch");
    if (swStep > 0) {
        GG3DSwitch s;
        s.step = swStep;
        const A7 sb = ps && ps->hasBeta ? ps->beta : p.beta;
        s.beta = arr7("switch_beta", sb, 1e-6, 1000.0, "beta after switch_step");
        s.kappa = arr7("switch_kappa", p.kappa, 0.0, 1.0, "kappa after switch_step");
        s.mu = arr7("switch_mu", p.mu, 0.0, 1.0, "mu after switch_step");
        s.phi = d.getFloat("switch_phi", p.phi, 0.0, 0.5, "", "phi after switch_step");
        s.hasBeta = s.hasKappa = s.hasMu = true;
        cfg.switches.push_back(s);
    } else {
        for (const char* k : {"switch_beta", "switch_kappa", "switch_mu"})
            arr7(k, all7(1.0), 0.0, 1000.0, std::string(k).substr(7) + " after switch_step");
        d.getFloat("switch_phi", 0.0, 0.0, 0.5, "", "phi after switch_step");
    }

}

/// The lattice's keys: domain radius, layers, walls, seeds, wedge, sparse tolerance, stop radius.
void readGG3DLattice(ParamDict& d, const World& world, const GG3DPreset& base, GG3DConfig& cfg)
{
    const openvdb::Coord dim = world.domain.bbox().dim();
    const int fromDomain = std::max(4, (std::min(dim.x(), dim.y()) - 1) / 2);
    cfg.domainRadius = int(d.getInt("domain_radius", 0, 0, 100000, "cells",
        "hexagon radius of the domain; 0 = from [domain] size, (min(nx, ny) - 1) / 2"));
    if (cfg.domainRadius == 0) cfg.domainRadius = fromDomain;
    if (cfg.domainRadius < 8) d.fail("domain_radius", "must be at least 8 cells (got " + std::to_string(cfg.domainRadius) + ")");
    cfg.layers = int(d.getInt("layers", 0, 0, 100000, "prisms",
        "domain height in prism layers, centred on the seed; 0 = [domain] size z for a box, else 2/3 of the "
        "domain diameter (rounded to the seed's parity)"));
    if (cfg.layers == 0) cfg.layers = world.domain.flat() ? std::max(9, 2 * cfg.domainRadius / 3) : dim.z();
    cfg.walls = d.getString("walls", "reflecting", {"reflecting", "reservoir"},
        "domain boundary: reflecting (mass conserved; equals the paper's periodic domain for symmetric flakes) or a "
        "vapour reservoir at rho") == "reflecting" ? GG3DWalls::Reflecting : GG3DWalls::Reservoir;
    cfg.seedRadius = int(d.getInt("seed_radius", 2, 0, 1000, "cells", "radius of the hexagonal seed prism"));
    cfg.seedHeight = int(d.getInt("seed_height", base.seedHeight, 1, 1000, "prisms", "height of the seed prism"));
    cfg.seedRadius2 = int(d.getInt("seed_radius2", -1, -1, 1000, "cells",
        "two-radius seeds: radius of a second prism on the same axis; -1 = none"));
    cfg.seedHeight2 = int(d.getInt("seed_height2", 1, 1, 1000, "prisms",
        "height of the second seed prism (rounded to seed_height's parity)"));
    cfg.wedge = d.getBool("wedge", true,
        "compute the 1/24 fundamental domain (1/12 with drift); bit-identical to the whole domain");
    cfg.sparseTolerance = d.getFloat("sparse_tolerance", 0.0, 0.0, 1.0, "",
        "|d - rho| at the active box's edge that still counts as background (0: exact, box grows as the disturbance)");
    cfg.stopRadius = int(d.getInt("stop_radius", 0, 0, 100000, "cells",
        "stop growing when the crystal reaches this radius; 0 = 80 % of domain_radius"));
    if (cfg.seedRadius + 3 > cfg.domainRadius || std::max(cfg.seedRadius2, 0) + 3 > cfg.domainRadius)
        d.fail("seed_radius", "the seed (radius " + std::to_string(std::max(cfg.seedRadius, cfg.seedRadius2)) +
                                  ") does not fit domain_radius " + std::to_string(cfg.domainRadius) + " (needs radius + 3)");
    if (std::max(cfg.seedHeight, cfg.seedHeight2) + 4 > cfg.layers)
        d.fail("seed_height", "the seed does not fit layers = " + std::to_string(cfg.layers) + " (needs height + 4)");

}

/// The output keys (voxels per cell, prism height, level set, mesh, batch).
GG3DOutput readGG3DOutput(ParamDict& d, const World& world)
{
    GG3DOutput out;
    out.voxelsPerCell = int(d.getInt("voxels_per_cell", 3, 1, 16, "voxels",
        "`automaton_ice` / `ice_sdf` voxels (cubes) per cell spacing: the prisms resampled to a cubic grid"));
    out.prismHeight = d.getFloat("prism_height", 1.0, 0.05, 100.0, "cells", "prism height in cell spacings");
    {   // OpenVDB refuses near-singular maps ("ArithmeticError: Non-zero scale values required"):
        // check the `automaton_ice` voxel and the prism layer here and say which key to change.
        const double h = world.domain.voxelSize();
        try {
            openvdb::math::Transform::createLinearTransform(h / out.voxelsPerCell);
            openvdb::math::Transform::createLinearTransform(h * out.prismHeight);
        } catch (const std::exception&) {
            char msg[200];
            std::snprintf(msg, sizeof msg,
                          "`automaton_ice` voxels of [domain] voxel_size / voxels_per_cell = %.3g m (prism height %.3g m) are "
                          "below OpenVDB's limit (about 3e-5 m): lower voxels_per_cell or raise voxel_size",
                          h / out.voxelsPerCell, h * out.prismHeight);
            d.fail(d.has("prism_height") && h * out.prismHeight < h / out.voxelsPerCell ? "prism_height" : "voxels_per_cell", msg);
        }
    }
    out.sdf = d.getBool("sdf", true, "write `ice_sdf`, a narrow-band level set of the crystal");
    out.sdfSmoothing = int(d.getInt("sdf_smoothing", 1, 0, 10, "passes",
        "smoothing passes of `ice_sdf` (rounds the voxel staircase; facets stay flat)"));
    out.mesh = d.getString("mesh", "none", {"none", "obj", "ply"}, "also write the crystal's surface as a mesh file");
    out.meshPath = d.getString("mesh_file", "", {},
        "mesh file name (frame number added before the extension); \"\" = <scene name>_gg3d.<frame>.<obj|ply> in the "
        "current directory");
    out.meshAdaptivity = d.getFloat("mesh_adaptivity", 0.0, 0.0, 1.0, "", "VolumeToMesh adaptivity (0: all quads)");
    out.batch = int(d.getInt("batch", 1, 1, 4096, "flakes",
        "grow this many distinct flakes (parameters jittered by `vary`): grids cells_k, automaton_ice_k, ... plus all side by "
        "side in cells, automaton_ice, ..."));
    out.vary = d.getFloat("vary", 0.05, 0.0, 0.5, "", "batch: relative jitter of rho, beta and mu for flakes 1..K-1");
    return out;
}

/// Memory before allocation: every flake may grow its box to the whole domain.
void refuseOverBudget(ParamDict& d, const GG3DConfig& cfg, const GG3DOutput& out)
{
    const double budgetGB = d.getFloat("memory_budget", 6.0, 0.01, 1e6, "GB",
        "refuse the scene when the estimated solver memory of all flakes exceeds this");

    const double perFlake = double(gg3dMemoryEstimate(cfg)) * 1e-9;
    const double need = perFlake * out.batch;
    if (need > budgetGB) {
        char msg[256];
        std::snprintf(msg, sizeof msg,
                      "needs about %.3g GB (%d flakes x %.3g GB at domain_radius %d, layers %d), over memory_budget = %g GB",
                      need, out.batch, perFlake, cfg.domainRadius, cfg.layers, budgetGB);
        d.fail(out.batch > 1 ? "batch" : "domain_radius", msg);
    }

}

} // namespace

std::unique_ptr<Effect> GG3DEffect::create(ParamDict& d, const World& world)
{
    std::vector<std::string> names{"none"};
    for (const auto& p : gg3dPresets()) names.push_back(p.name);
    const std::string preset = d.getString("preset", "none", names,
        "a published case of Gravner & Griffeath (2009) (see docs/snowflakes3d.md); every other key overrides it");
    GG3DPreset base = *findGG3DPreset("fig04_plate_ridges");
    if (preset != "none") base = *findGG3DPreset(preset);

    GG3DConfig cfg;
    readGG3DRule(d, base, cfg);
    readGG3DLattice(d, world, base, cfg);
    const GG3DOutput out = readGG3DOutput(d, world);
    refuseOverBudget(d, cfg, out);

    // The paper's guard rails: warn, naming the preset and the inequality.
    for (const auto& w : gg3dGuardRails(cfg.p))
        std::cerr << "warning: [gravner_griffeath_3d] preset " << preset << ": " << w << "\n";
    return std::make_unique<GG3DEffect>(cfg, out, preset);
}

void GG3DEffect::initialize(World& world)
{
    mCellSize = world.domain.voxelSize();
    GG3DConfig base = mCfg;
    base.seed = hashCounters(world.seed, 0x47473344ull); // "GG3D"
    mFlakes.clear();
    for (int k = 0; k < mOut.batch; ++k) mFlakes.push_back(std::make_unique<GG3D>(flakeConfig(base, mOut.vary, k)));
}

void GG3DEffect::step(World&, const StepInfo&)
{
    const auto t0 = Clock::now();
    for (auto& f : mFlakes) f->step();
    mStepSeconds += since(t0);
}

void GG3DEffect::saveState(const World&, StateWriter& out) const
{
    out.putInt("flakes", int64_t(mFlakes.size()));
    for (size_t k = 0; k < mFlakes.size(); ++k) {
        StateWriter w = out.scope("flake" + std::to_string(k));
        GG3D& f = *mFlakes[k]; // visitArrays hands out references; nothing is changed here
        w.putArray("counters", f.stateScalars());
        f.visitArrays([&](const char* name, auto& v) { w.putArray(name, v); });
    }
}

void GG3DEffect::loadState(World&, const StateReader& in)
{
    if (in.getInt("flakes") != int64_t(mFlakes.size())) in.fail("flakes", "another number of flakes");
    for (size_t k = 0; k < mFlakes.size(); ++k) {
        const StateReader r = in.scope("flake" + std::to_string(k));
        GG3D& f = *mFlakes[k];
        std::vector<int64_t> counters;
        r.getArray("counters", counters);
        try {
            f.restoreScalars(counters);
        } catch (const std::exception& e) {
            r.fail("counters", e.what());
        }
        const size_t n = f.storageSize();
        f.visitArrays([&](const char* name, auto& v) {
            r.getArray(name, v);
            // the noise hold exists only with noise
            const size_t want = std::string(name) != "hold" || f.params().noise > 0.0 ? n : 0;
            if (v.size() != want)
                r.fail(name, "holds " + std::to_string(v.size()) + " cells, expected " + std::to_string(want));
        });
    }
}

namespace {
/// The nodes above the leaves of a float grid around the lattice's origin: the crystal is centred
/// there, so each grid's voxels straddle it on every axis and take 8 top-level nodes (32^3 and
/// 16^3 child tables, about 2.4 MB) however few they are.
double originTreeBytes()
{
    using Upper = openvdb::FloatTree::RootNodeType::ChildNodeType;
    using Lower = Upper::ChildNodeType;
    return 8.0 * double(sizeof(Upper) + sizeof(Lower));
}
/// Such trees alive at the output's peak: cells, freeze_step, automaton_ice and ice_sdf, and
/// the slab and mask trees they are made from (measured: a one-step run's output took 13.0 MiB,
/// 5.6 of them, with a 19-cell seed).
constexpr double kOutputTrees = 5.5;
/// Bytes of a frame's grids per voxel of an attached cell (voxels_per_cell^3 x prism_height of
/// them): automaton_ice, ice_sdf and the mask and filter trees topologyToLevelSet makes, at the
/// output's peak (measured: 132 MiB for the dendrite's 114,587 cells at voxels_per_cell 3, 44.7;
/// the per-frame check, GG3DOutput.cpp, charges 50).
constexpr double kGridBytesPerCellVoxel = 44.0;
} // namespace

MemoryEstimate GG3DEffect::memoryEstimate(const World& world) const
{
    // the box a run of this many steps grows (issue 25: a one-step run was charged the whole
    // domain, 5x its peak; then a 60-step run the box its steps could reach, twice: 1.53x), and
    // its largest moment, a growth's old and new arrays (gg3dSolverBytes); the frame's grids
    // come on top of the grown box (a one-step run's 13 MiB of grids were missed),
    // and they follow the crystal the run may grow (the shipped scenes were charged 0.15-0.40 of
    // their peaks): its attached cells from the growth model (gg3dCrystalCellsEstimate)
    const int64_t steps = world.frames * world.stepsPerFrame;
    const GG3DSolverBytes solver = gg3dSolverBytes(mCfg, steps);
    std::string cellsDetail;
    const double cells = gg3dCrystalCellsEstimate(mCfg, steps, &cellsDetail);
    const double perCell = kGridBytesPerCellVoxel * std::pow(double(mOut.voxelsPerCell), 3.0) * mOut.prismHeight;
    const double grids = kOutputTrees * originTreeBytes() + cells * perCell;
    const double flakes = double(mOut.batch) + (mOut.batch > 1 ? 1.0 : 0.0); // and the combined grids
    char what[600];
    std::snprintf(what, sizeof what,
                  "%d flakes x %.3g bytes of solver arrays (a box of radius %d, %d layers, of domain_radius %d, layers "
                  "%d; %.3g while it grows), and their frame grids: %s",
                  mOut.batch, solver.grown, solver.radius, solver.layers, mCfg.domainRadius, mCfg.layers, solver.peak,
                  cellsDetail.c_str());
    return {std::max(solver.peak * mOut.batch, solver.grown * mOut.batch + grids * flakes),
            std::string(name()) + (mOut.batch > 1 ? ".batch" : ".domain_radius"), what};
}

std::vector<std::pair<std::string, double>> GG3DEffect::counters() const
{
    double grown = 0, stopped = 0;
    for (const auto& f : mFlakes) {
        grown = std::max(grown, double(f->steps()));
        stopped += f->stopped() ? 1 : 0;
    }
    return {{"steps_grown", grown}, {"flakes_stopped", stopped}};
}

std::vector<std::pair<std::string, double>> GG3DEffect::timings() const
{
    return {{"gg3d step", mStepSeconds}, {"gg3d output", mOutputSeconds}};
}

bool GG3DEffect::writePreview(World&, const Frame& frame, const std::string& pngPath)
{
    for (const auto& g : frame.grids)
        if (g->getName() == (mOut.sdf ? out::kIceSdf.name : out::kAutomatonIce.name))
            if (auto fg = openvdb::gridConstPtrCast<openvdb::FloatGrid>(g)) {
                if (fg->activeVoxelCount() == 0) return false;
                if (mOut.sdf) renderGG3DPreview(*fg, pngPath);
                else frostvdb::writePreview(*fg, pngPath);
                return true;
            }
    return false;
}

} // namespace automata
} // namespace frostvdb
