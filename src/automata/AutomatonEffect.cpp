/// @file AutomatonEffect.cpp
/// @brief Scene sections for the hexagonal automata, and the one place where their plain arrays
/// become OpenVDB grids (`cells`, `automaton_ice`, `freeze_step`) and hexagon PNG previews.
#include <frostvdb/automata/AutomatonEffect.h>

#include <cstdio>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Lattice.h>
#include <frostvdb/geometry/HexTransform.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/io/Png.h>
#include <frostvdb/io/Preview.h>

#include <openvdb/openvdb.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace frostvdb {
namespace automata {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }



/// Plate weight in [0, 1] of a frozen cell (thickness mode "value").
double valueWeight(const HexAutomaton& a, size_t i)
{
    const double v = a.value(i);
    switch (a.config().rule) {
    case Rule::CoxeReiter: return std::clamp((v - 0.5) / 0.5, 0.0, 1.0);
    case Rule::Reiter: return std::clamp(v - 1.0, 0.0, 1.0);
    case Rule::GravnerGriffeath:
    case Rule::GravnerGriffeath3D: return std::clamp((v - 1.0) / 1.5, 0.0, 1.0);
    default: return 1.0;
    }
}

/// The preview colour of cell @a i (Coxe-Reiter scheme: value, then age of thick ice).
std::array<float, 3> cellColour(const HexAutomaton& a, size_t i)
{
    const double steps = std::max<double>(1.0, double(a.steps()));
    const bool thick = a.thickStep(i) >= 0;
    const double age = thick ? (steps - a.thickStep(i)) / steps : 0.0;
    double v = 0.0;
    switch (a.config().rule) {
    case Rule::CoxeReiter: v = a.value(i); break;
    case Rule::Reiter: v = 0.5 * std::min(0.999, a.value(i)); break;
    case Rule::GravnerGriffeath:
    case Rule::GravnerGriffeath3D:
        v = 0.45 * std::min(1.0, a.vapour(i) / std::max(1e-9, a.config().gg.rho));
        break;
    default: v = a.frozen(i) ? 1.0 : 0.0; break;
    }
    return coxeReiterColour(v, thick, age);
}

} // namespace

// ---------------------------------------------------------------------------------------------

AutomatonEffect::AutomatonEffect(std::string section, AutomatonConfig cfg, OutputOptions out)
    : mSection(std::move(section)), mCfg(std::move(cfg)), mOut(std::move(out))
{
}

FieldDeclaration AutomatonEffect::declaration() const
{
    FieldDeclaration d; // its own lattice and clock: no fields shared with other effects
    d.stage = Stage::Sources;
    d.output(out::kCells).output(out::kAutomatonIce).output(out::kFreezeStep);
    if (mOut.writeVapour) d.output(out::kVapour);
    return d;
}

AutomatonConfig AutomatonEffect::flakeConfig(const AutomatonConfig& base, const OutputOptions& out, int k)
{
    if (!out.sweepBackground.empty() || !out.sweepBackground2.empty() || !out.sweepSeedCells.empty()) {
        AutomatonConfig c = base;
        auto pick = [k](const std::vector<double>& v) { return v[size_t(k) % v.size()]; };
        if (!out.sweepBackground.empty()) c.cr.background = pick(out.sweepBackground);
        if (!out.sweepBackground2.empty()) c.cr.background2 = pick(out.sweepBackground2);
        if (!out.sweepSeedCells.empty()) c.seedCells = int(pick(out.sweepSeedCells));
        return c;
    }
    if (k == 0) return base;
    AutomatonConfig c = base;
    CounterRng rng(base.seed, 0x464c414bull, uint64_t(k)); // "FLAK"
    c.seed = hashCounters(base.seed, uint64_t(k), 0x53454544ull);
    auto jitter = [&](double v) { return v * (1.0 + out.vary * (2.0 * rng.uniform() - 1.0)); };
    switch (c.rule) {
    case Rule::CoxeReiter:
        c.cr.background = std::clamp(jitter(c.cr.background), 0.0, 0.49);
        if (c.cr.background2 >= 0) c.cr.background2 = std::clamp(jitter(c.cr.background2), 0.0, 0.49);
        break;
    case Rule::Probabilistic:
        for (auto& p : c.prob.pFreeze) p = std::clamp(p + out.vary * (2.0 * rng.uniform() - 1.0), 0.0, 1.0);
        for (auto& p : c.prob.pMelt) p = std::clamp(p + out.vary * (2.0 * rng.uniform() - 1.0), 0.0, 1.0);
        break;
    case Rule::Reiter:
        c.reiter.beta = std::clamp(jitter(c.reiter.beta), 0.0, 0.999);
        c.reiter.gamma = std::max(0.0, jitter(c.reiter.gamma));
        break;
    case Rule::GravnerGriffeath:
    case Rule::GravnerGriffeath3D:
        c.gg.rho = jitter(c.gg.rho);
        for (auto& row : c.gg.beta)
            for (double& b : row) b = std::max(1.0, jitter(b));
        c.gg.kappa[1][0] = c.gg.kappa[2][0] = jitter(c.gg.kappa[1][0]);
        break;
    default: break;
    }
    // A random D6-symmetric cluster of extra ice near the centre: distinct flakes even for
    // the parameter-free Packard rule, and the wedge computation still applies.
    for (int r = 0; 2 * r <= out.seedRadius; ++r)
        for (int q = std::max(r, 1); q + r <= out.seedRadius; ++q)
            if (rng.uniform() < 0.35)
                for (const Axial& o : d6Orbit(q, r)) c.extraSeeds.push_back(o);
    return c;
}

void AutomatonEffect::initialize(World& world)
{
    mCellSize = world.domain.voxelSize();
    AutomatonConfig base = mCfg;
    const openvdb::Coord dim = world.domain.bbox().dim();
    if (base.radius <= 0) base.radius = std::max(2, (std::min(dim.x(), dim.y()) - 1) / 2);
    if (base.rule == Rule::GravnerGriffeath3D && base.layers <= 0)
        base.layers = world.domain.flat() ? 31 : dim.z();
    base.seed = hashCounters(world.seed, 0x4155544full); // "AUTO"
    mFlakes.clear();
    for (int k = 0; k < mOut.batch; ++k)
        mFlakes.push_back(std::make_unique<HexAutomaton>(flakeConfig(base, mOut, k)));
}

MemoryEstimate AutomatonEffect::memoryEstimate(const World& world) const
{
    const openvdb::Coord dim = world.domain.bbox().dim();
    const double R = mCfg.radius > 0 ? mCfg.radius : std::max(2, (std::min(dim.x(), dim.y()) - 1) / 2);
    const bool is3D = mCfg.rule == Rule::GravnerGriffeath3D;
    const double layers = is3D ? (mCfg.layers > 0 ? mCfg.layers : (world.domain.flat() ? 31 : dim.z())) : 1.0;
    const double cells = (3.0 * R * R + 3.0 * R + 1.0) * layers;
    // The output grids hold the cells that differ from the background: within the ice and the
    // ring its rules have disturbed, which grows by at most the neighbourhood's reach (2 cells,
    // the two-level neighbourhood; 1 for the others) per step from the seeds. A run of few steps
    // on a large lattice writes a small flake, so its grids are bounded by the run's steps, not
    // only by the hexagon (issue 25: a one-step run on a 600-cell hexagon was charged 3.7x its peak).
    const double steps = double(world.frames) * double(world.stepsPerFrame);
    const double seedReach = 2.0 + (mOut.batch > 1 ? double(mOut.seedRadius) : 0.0);
    const double grown = std::min(R, seedReach + 2.0 * steps);
    const double X = (grown + 1.0) * mOut.voxelsPerCell + 1.0; // `automaton_ice` half-width in voxels (writeFlake)
    const double Z = is3D ? (layers * 0.5 + 1.0) * mOut.prismHeight * mOut.voxelsPerCell
                          : 0.5 * mOut.plateThickness * mOut.voxelsPerCell + 1.0;
    const double iceVoxels = (2 * X + 1) * (2 * X + 1) * (2 * Z + 1);
    const double slabs = std::ceil((2 * X + 1) / 32.0);
    // A non-empty OpenVDB float tree holds at least its top internal node (~300 KB); the 600 KB
    // per grid is calibrated on [packard] batch = 512 at 64x64 (measured peak 3.3 GB).
    // The automaton's arrays (automata/Automata.cpp, initialise()) cover the hexagon's square
    // layout with a 2-cell border, (2 (R + 2) + 1)^2 slots per layer (+ a wall layer above and
    // below in 3D): two values (8 + 8), the wall flag, freeze step and thickness (1 + 4 + 4),
    // two attached flags (1 + 1); Gravner-Griffeath adds boundary and crystal mass (8 + 8); per
    // slot of the first layer the D6 images (8) and canonical index (4).
    const bool gg = mCfg.rule == Rule::GravnerGriffeath || is3D;
    const double square = (2.0 * (R + 2.0) + 1.0) * (2.0 * (R + 2.0) + 1.0);
    const double slots = square * (is3D ? layers + 2.0 : 1.0);
    const double arrays = slots * (27.0 + (gg ? 16.0 : 0.0)) + square * 12.0;
    const double perFlake = arrays + 2.0 * iceVoxels * 4.5 + (4.0 + slabs) * 600e3;
    char what[160];
    std::snprintf(what, sizeof what, "%d flakes x %.3g bytes (%.3g cells, %.3g ice voxels each within %.0f cells of "
                  "the centre)", mOut.batch, perFlake, cells, iceVoxels, grown);
    const bool vpcDrives = iceVoxels * 9.0 > arrays;
    return {perFlake * mOut.batch,
            mSection + (mOut.batch > 1 ? ".batch" : vpcDrives ? ".voxels_per_cell" : ".radius"), what};
}

void AutomatonEffect::step(World&, const StepInfo&)
{
    const auto t0 = Clock::now();
    for (auto& f : mFlakes) f->step();
    mStepSeconds += since(t0);
}

void AutomatonEffect::saveState(const World&, StateWriter& out) const
{
    out.putInt("flakes", int64_t(mFlakes.size()));
    for (size_t k = 0; k < mFlakes.size(); ++k) {
        StateWriter w = out.scope("flake" + std::to_string(k));
        mFlakes[k]->visitState([&](const char* name, auto& member) {
            using M = std::decay_t<decltype(member)>;
            if constexpr (std::is_same_v<M, int64_t>) w.putInt(name, member);
            else w.putArray(name, member);
        });
    }
}

void AutomatonEffect::loadState(World&, const StateReader& in)
{
    if (in.getInt("flakes") != int64_t(mFlakes.size())) in.fail("flakes", "another number of flakes");
    for (size_t k = 0; k < mFlakes.size(); ++k) {
        const StateReader r = in.scope("flake" + std::to_string(k));
        mFlakes[k]->visitState([&](const char* name, auto& member) {
            using M = std::decay_t<decltype(member)>;
            if constexpr (std::is_same_v<M, int64_t>) {
                member = r.getInt(name);
            } else {
                const size_t n = member.size();
                r.getArray(name, member);
                if (member.size() != n) r.fail(name, "another lattice size");
            }
        });
    }
}

std::vector<std::pair<std::string, double>> AutomatonEffect::counters() const
{
    double frozen = 0;
    for (const auto& f : mFlakes) frozen += double(f->frozenCount());
    return {{"frozen_cells", frozen}};
}

std::vector<std::pair<std::string, double>> AutomatonEffect::timings() const
{
    return {{"automaton step", mStepSeconds}, {"automaton output", mOutputSeconds}};
}

namespace {

/// Writes one flake into the three grids, shifted by @a shift cells along the lattice q axis
/// (world x) and @a iceShift voxels along x in the ice grid.
void writeFlake(const HexAutomaton& a, const OutputOptions& out, double h, int shift, int iceShift,
                openvdb::FloatGrid& cells, openvdb::FloatGrid& ice, openvdb::FloatGrid& freeze,
                openvdb::FloatGrid* vapour)
{
    const HexLayout& L = a.layout();
    const int layers = a.layers();
    const int lc = (layers - 1) / 2;
    const bool is3D = a.config().rule == Rule::GravnerGriffeath3D;
    const float cellsBg = cells.background();
    auto cacc = cells.getAccessor();
    auto facc = freeze.getAccessor();
    for (int l = 0; l < layers; ++l)
        for (const Row& row : L.fullRows(l))
            for (int q = row.q0; q <= row.q1; ++q) {
                const size_t i = a.cellIndex(q, row.r, l);
                const openvdb::Coord ijk(q + shift, row.r, is3D ? l - lc : 0);
                const float v = float(a.value(i));
                if (v != cellsBg) cacc.setValue(ijk, v);
                if (a.frozen(i)) facc.setValue(ijk, float(a.freezeStep(i)));
                if (vapour && !a.frozen(i)) vapour->tree().setValue(ijk, float(a.vapour(i)));
            }

    // `automaton_ice` on a cubic voxel grid: each voxel column / voxel looks up its hexagonal cell.
    const int rad = a.frozenRadius();
    if (rad < 0) return;
    const double vs = h / out.voxelsPerCell;
    const int X = int(std::ceil((rad + 1.0) * h / vs)) + 1;
    const double steps = std::max<double>(1.0, double(a.steps()));
    const double ageSteps = out.ageSteps > 0 ? out.ageSteps : steps;
    const double layerH = out.prismHeight * h;
    const int Z = is3D ? int(std::ceil((layers * 0.5 + 1) * layerH / vs))
                       : int(std::ceil(0.5 * out.plateThickness * h / vs)) + 1;

    // Slabs of 32 voxel rows in parallel, each into its own tree (a tree's internal nodes are
    // large, so not one per row); merged in slab order (deterministic).
    const int nRows = 2 * X + 1;
    const int slab = 32;
    const int nSlabs = (nRows + slab - 1) / slab;
    std::vector<openvdb::FloatTree::Ptr> trees;
    trees.resize(static_cast<size_t>(nSlabs));
    tbb::parallel_for(0, nSlabs, [&](int si) {
        auto tree = std::make_shared<openvdb::FloatTree>(0.0f);
        openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(*tree);
        for (int yi = si * slab; yi < std::min(nRows, (si + 1) * slab); ++yi) {
        const int y = yi - X;
        for (int x = -X; x <= X; ++x) {
            const Axial c = cellAt(x * vs / h, y * vs / h);
            if (!L.inside(c.q, c.r)) continue;
            if (!is3D) {
                const size_t i = a.cellIndex(c.q, c.r);
                if (!a.frozen(i)) continue;
                double w = 1.0;
                if (out.thickness == "age")
                    w = std::min(1.0, (steps - a.freezeStep(i)) / ageSteps);
                else if (out.thickness == "value")
                    w = valueWeight(a, i);
                const double t = out.plateThickness * h * (out.plateMin + (1.0 - out.plateMin) * w);
                for (int z = -Z; z <= Z; ++z) {
                    const double d = std::clamp((0.5 * t - std::abs(z * vs)) / vs + 0.5, 0.0, 1.0);
                    if (d > 0.0) acc.setValue(openvdb::Coord(x + iceShift, y, z), float(d));
                }
            } else {
                for (int z = -Z; z <= Z; ++z) {
                    const int l = int(std::lround(z * vs / layerH)) + lc;
                    if (l < 0 || l >= layers) continue;
                    if (a.frozen(a.cellIndex(c.q, c.r, l)))
                        acc.setValue(openvdb::Coord(x + iceShift, y, z), 1.0f);
                }
            }
        }
        }
        trees[size_t(si)] = tree;
    });
    for (auto& t : trees) ice.tree().merge(*t, openvdb::MERGE_ACTIVE_STATES_AND_NODES);
}

} // namespace

void AutomatonEffect::addToFrame(World& world, Frame& frame)
{
    const auto t0 = Clock::now();
    const double h = mCellSize;
    const bool is3D = mCfg.rule == Rule::GravnerGriffeath3D;
    const double vs = h / mOut.voxelsPerCell;
    float cellsBg = 0.0f;
    if (mCfg.rule == Rule::CoxeReiter) cellsBg = float(mCfg.cr.background);
    if (mCfg.rule == Rule::Reiter) cellsBg = float(mCfg.reiter.beta);
    auto cellXform = is3D ? hex::prismTransform(h, mOut.prismHeight * h) : Lattice(LatticeKind::Hexagonal).transform(h);
    auto iceXform = openvdb::math::Transform::createLinearTransform(vs);

    // cells, automaton_ice, freeze_step (a step count, not the ice clock's freeze_time): named by
    // their keys when added to the frame
    const std::array<const FieldKey*, 3> keys{&out::kCells, &out::kAutomatonIce, &out::kFreezeStep};
    auto makeGrids = [&]() {
        auto cells = openvdb::FloatGrid::create(cellsBg);
        cells->setTransform(cellXform->copy());
        auto ice = openvdb::FloatGrid::create(0.0f);
        ice->setGridClass(openvdb::GRID_FOG_VOLUME);
        ice->setTransform(iceXform->copy());
        auto freeze = openvdb::FloatGrid::create(-1.0f);
        freeze->setTransform(cellXform->copy());
        freeze->insertMeta("unit", openvdb::StringMetadata("steps"));
        cells->insertMeta("rule", openvdb::StringMetadata(ruleName(mCfg.rule)));
        cells->insertMeta("lattice", openvdb::StringMetadata(
            is3D ? "hexagonal prisms, index (q, r, layer), centred on the flake"
                 : "hexagonal axial (q, r), world = h*(q + r/2, r*sqrt(3)/2), centred on the flake"));
        return std::array<openvdb::FloatGrid::Ptr, 3>{cells, ice, freeze};
    };

    const int K = int(mFlakes.size());
    for (auto& f : mFlakes) f->expand();
    auto all = makeGrids();
    openvdb::FloatGrid::Ptr vapour;
    if (mOut.writeVapour) {
        vapour = openvdb::FloatGrid::create(float(mCfg.gg.rho));
        vapour->setTransform(cellXform->copy());
    }
    for (int k = 0; k < K; ++k) {
        const HexAutomaton& a = *mFlakes[size_t(k)];
        const int R = a.layout().radius();
        // Flakes side by side along x in the combined grids, 2R + 4 cells apart.
        const int shift = k * (2 * R + 4);
        const int iceShift = int(std::lround(shift * h / vs));
        writeFlake(a, mOut, h, shift, iceShift, *all[0], *all[1], *all[2], k == 0 ? vapour.get() : nullptr);
        if (K > 1) {
            auto one = makeGrids();
            writeFlake(a, mOut, h, 0, 0, *one[0], *one[1], *one[2], nullptr);
            for (size_t i = 0; i < one.size(); ++i) {
                one[i]->pruneGrid();
                frame.add(*keys[i], one[i], "_" + std::to_string(k));
            }
        }
    }
    for (size_t i = 0; i < all.size(); ++i) {
        all[i]->pruneGrid();
        frame.add(*keys[i], all[i]);
    }
    if (vapour) frame.add(out::kVapour, vapour);
    mOutputSeconds += since(t0);
    (void)world;
}

bool AutomatonEffect::writePreview(World& world, const Frame& frame, const std::string& pngPath)
{
    if (mFlakes.empty()) return false;
    if (mCfg.rule == Rule::GravnerGriffeath3D) {
        // The true 3D crystal: ray-marched by the shared preview.
        for (const auto& g : frame.grids)
            if (g->getName() == out::kAutomatonIce.name) {
                if (auto fg = openvdb::gridConstPtrCast<openvdb::FloatGrid>(g)) {
                    if (fg->activeVoxelCount() == 0) return false;
                    frostvdb::writePreview(*fg, pngPath);
                    return true;
                }
            }
        return false;
    }
    // Hexagons in the Coxe-Reiter colours, one tile per flake.
    const int K = int(mFlakes.size());
    const int cols = K <= 4 ? K : int(std::ceil(std::sqrt(double(K))));
    const int rowsN = (K + cols - 1) / cols;
    const int tile = K == 1 ? 768 : std::max(160, 640 / cols);
    ImageRGB img(tile * cols, tile * rowsN);
    for (int k = 0; k < K; ++k) {
        const HexAutomaton& a = *mFlakes[size_t(k)];
        const HexLayout& L = a.layout();
        const int rad = std::max(8, a.frozenRadius() + 4);
        const double extent = std::min(double(L.radius()) + 1.0, rad * 1.15);
        const double scale = 2.0 * extent / tile; // cell spacings per pixel
        const int ox = (k % cols) * tile, oy = (k / cols) * tile;
        tbb::parallel_for(0, tile, [&](int py) {
            for (int px = 0; px < tile; ++px) {
                const double x = (px - 0.5 * tile + 0.5) * scale;
                const double y = -(py - 0.5 * tile + 0.5) * scale;
                const Axial c = cellAt(x, y);
                std::array<float, 3> col{0.f, 0.f, 0.f};
                if (L.inside(c.q, c.r)) col = cellColour(a, a.cellIndex(c.q, c.r));
                img.set(ox + px, oy + py, col[0], col[1], col[2]);
            }
        });
    }
    writePngRGB(pngPath, img);
    (void)world;
    return true;
}

// ---------------------------------------------------------------------------------------------
// Scene sections.

namespace {

OutputOptions readOutput(ParamDict& d, Rule rule, AutomatonConfig& cfg)
{
    OutputOptions o;
    const bool is3D = rule == Rule::GravnerGriffeath3D;
    cfg.radius = int(d.getInt("radius", 0, 0, 100000, "cells",
        "hexagon radius of the lattice; 0 = from [domain] size, (min(nx, ny) - 1) / 2"));
    cfg.seedCells = int(d.getInt("seed_cells", 1, 1, 4, "cells",
        "initial ice: 1 cell (six-fold), 2 (two-fold), 3 (three-fold) or 4 neighbouring cells (two-fold)"));
    cfg.wedge = d.getBool("wedge", true,
        "compute 1/12 of the lattice and mirror it (bit-identical; used only for symmetric set-ups)");
    o.batch = int(d.getInt("batch", 1, 1, 1024, "flakes",
        "grow this many distinct flakes at once: grids cells_k, automaton_ice_k, freeze_step_k (k = 0..K-1) "
        "centred on the origin, plus all flakes side by side in cells, automaton_ice, freeze_step"));
    o.vary = d.getFloat("vary", 0.05, 0.0, 0.5, "",
        "batch: relative random jitter of the rule's parameters for flakes 1..K-1 (flake 0 is exact)");
    o.seedRadius = int(d.getInt("seed_radius", 3, 0, 50, "cells",
        "batch: radius of the random six-fold cluster of seed ice of flakes 1..K-1 (0: single cell)"));
    const std::string defThick = (rule == Rule::CoxeReiter || rule == Rule::Reiter) ? "value" : "age";
    if (!is3D) {
        o.thickness = d.getString("thickness", defThick, {"age", "value", "uniform"},
            "`automaton_ice` plate thickness from the cell's age (old ice is thick), its value, or uniform");
        o.plateThickness = d.getFloat("plate_thickness", 1.5, 0.01, 1000.0, "cells",
            "thickest plate of `automaton_ice`, in cell spacings");
        o.plateMin = d.getFloat("plate_min", 0.25, 0.0, 1.0, "",
            "thinnest plate as a fraction of plate_thickness");
        o.ageSteps = d.getFloat("age_steps", 0.0, 0.0, 1e9, "steps",
            "age at which a plate reaches full thickness; 0 = the number of steps run");
    } else {
        cfg.layers = int(d.getInt("layers", 0, 0, 100000, "prisms",
            "prism layers; 0 = [domain] size z for a box, 31 for a plane"));
        o.prismHeight = d.getFloat("prism_height", 1.0, 0.05, 100.0, "cells",
            "prism height in cell spacings (the model's prisms are one spacing high)");
    }
    o.voxelsPerCell = int(d.getInt("voxels_per_cell", is3D ? 3 : 2, 1, 16, "voxels",
        "`automaton_ice` voxels (cubes) per cell spacing: the hexagonal lattice is resampled to a cubic grid"));
    return o;
}

std::vector<double> flattenWeights(const CoxeReiterParams& p)
{
    std::vector<double> out;
    for (const auto& row : p.weights) out.insert(out.end(), row.begin(), row.end());
    return out;
}

void readGG(ParamDict& d, GravnerGriffeathParams& g, bool is3D)
{
    g.rho = d.getFloat("rho", is3D ? 0.5 : 0.635, 0.0, 10.0, "", "initial vapour density rho");
    if (!is3D) {
        const double beta = d.getFloat("beta", 1.6, 0.0, 100.0, "",
            "boundary mass a tip or flat site (1-2 attached neighbours) needs to attach");
        g.beta[1][0] = g.beta[2][0] = beta;
        g.beta[3][0] = 1.0;
    } else {
        const auto b = d.getFloatArray("beta", {2.8, 1.6, 1.6, 1.0, 1.4, 1.1, 1.0}, {7}, 0.0, 100.0, "",
            "attachment thresholds beta_ij for (i horizontal, j vertical) attached neighbours in the "
            "order 01, 10, 20, 30, 11, 21, 31 (i = min(3, n_h), j = min(1, n_v))");
        g.beta[0][1] = b[0];
        g.beta[1][0] = b[1];
        g.beta[2][0] = b[2];
        g.beta[3][0] = b[3];
        g.beta[1][1] = b[4];
        g.beta[2][1] = b[5];
        g.beta[3][1] = b[6];
    }
    g.alpha = d.getFloat("alpha", is3D ? 0.1 : 0.4, 0.0, 100.0, "",
        "boundary mass enough for a 3-neighbour site in a vapour-poor neighbourhood (with theta)");
    g.theta = d.getFloat("theta", is3D ? 0.005 : 0.025, 0.0, 100.0, "",
        "neighbourhood vapour below which alpha applies");
    const std::string shape = is3D ? "{1, 7}: one value, or 7 in the beta order" : "";
    auto perClass = [&](const std::string& key, double def, const std::string& doc, double (&arr)[4][2]) {
        if (!is3D) {
            const double v = d.getFloat(key, def, 0.0, 1.0, "", doc);
            for (auto& row : arr) row[0] = row[1] = v;
            return;
        }
        const auto a = d.getFloatArray(key, {def}, {1, 7}, 0.0, 1.0, "", doc + " (" + shape + ")");
        static const int idx[7][2] = {{0, 1}, {1, 0}, {2, 0}, {3, 0}, {1, 1}, {2, 1}, {3, 1}};
        for (int k = 0; k < 7; ++k) arr[idx[k][0]][idx[k][1]] = a.size() == 1 ? a[0] : a[size_t(k)];
    };
    perClass("kappa", 0.005, "fraction of a boundary site's vapour that freezes straight into crystal", g.kappa);
    perClass("mu", 0.015, "fraction of boundary mass that melts back to vapour each step", g.mu);
    g.gamma = d.getFloat("gamma", 0.0005, 0.0, 1.0, "", "fraction of a boundary site's crystal mass that melts");
    g.sigma = d.getFloat("sigma", 0.0, 0.0, 0.5, "",
        "vapour noise: d *= 1 +- sigma (signs keyed by the canonical cell, so the flake stays symmetric)");
    if (is3D)
        g.phi = d.getFloat("phi", 3.0 / 14.0, 0.0, 0.5, "",
            "vertical diffusion weight per vertical neighbour (3/14: isotropic for unit prisms)");
    g.closed = d.getString("edge", "reservoir", {"reservoir", "closed"},
        "outer edge: a vapour reservoir at rho, or a closed reflecting wall (mass conserved)") == "closed";
}

template <Rule R>
class RuleEffect : public AutomatonEffect {
public:
    using AutomatonEffect::AutomatonEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World& world);
};

template <Rule R>
std::unique_ptr<Effect> RuleEffect<R>::create(ParamDict& d, const World& world)
{
    AutomatonConfig cfg;
    cfg.rule = R;
    OutputOptions out = readOutput(d, R, cfg);
    // `automaton_ice` voxels are h / voxels_per_cell: OpenVDB refuses transforms below ~1.44e-5 m (its
    // scale determinant must exceed 3e-15), so name the key here instead of failing at output.
    const double iceVoxel = world.domain.voxelSize() / out.voxelsPerCell;
    if (iceVoxel * iceVoxel * iceVoxel < 4e-15) {
        const int most = int(std::floor(world.domain.voxelSize() / std::cbrt(4e-15)));
        d.fail("voxels_per_cell", "ice voxels of domain.voxel_size / voxels_per_cell = " + std::to_string(iceVoxel) +
                                      " m are smaller than OpenVDB can represent (about 1.6e-5 m); use at most " +
                                      std::to_string(std::max(most, 0)) + " or a larger domain.voxel_size");
    }
    switch (R) {
    case Rule::CoxeReiter: {
        auto& p = cfg.cr;
        p.background = d.getFloat("background", 0.17, 0.0, 0.5, "",
            "fuzzy background level (Coxe-Reiter test values 0.156 .. 0.3)");
        p.background2 = d.getFloat("background2", -1.0, -1.0, 0.5, "",
            "second background level: alternates with `background` every `band` rings; -1 = constant");
        p.band = int(d.getInt("band", 16, 1, 100000, "rings", "rings per background band"));
        const auto w = d.getFloatArray("weights", flattenWeights(p), {44}, -100.0, 100.0, "",
            "11 x (alpha, beta, gamma, delta) in case order (C,N,P): (1,0,-) (0,0,0) (1,>=1,-) "
            "(0,1,1) (0,1,0) (0,2,0) (0,2,1) (0,2,2) (0,>=3,0) (0,>=3,1) (0,>=3,>=2); default Table 1");
        for (int c = 0; c < kCoxeReiterCases; ++c)
            for (int k = 0; k < 4; ++k) p.weights[size_t(c)][size_t(k)] = w[size_t(4 * c + k)];
        out.sweepBackground = d.getFloatArray("sweep_background", {}, {}, 0.0, 0.5, "",
            "one flake per entry with exactly this background (a sweep, e.g. Figures 5-6); sets batch");
        out.sweepBackground2 = d.getFloatArray("sweep_background2", {}, {}, -1.0, 0.5, "",
            "per-flake second background (oscillating bands, Figure 7); -1 = constant");
        out.sweepSeedCells = d.getFloatArray("sweep_seed_cells", {}, {}, 1.0, 4.0, "cells",
            "per-flake number of seed cells 1..4 (Figure 8)");
        size_t n = 0;
        for (const auto* v : {&out.sweepBackground, &out.sweepBackground2, &out.sweepSeedCells}) {
            if (v->empty()) continue;
            if (n != 0 && v->size() != n) d.fail("sweep_background", "sweep arrays must have the same length");
            n = v->size();
        }
        for (double sc : out.sweepSeedCells)
            if (sc != double(int(sc))) d.fail("sweep_seed_cells", "seed cells must be whole numbers 1..4");
        if (n > 0) {
            if (d.has("batch") && out.batch != int(n)) d.fail("batch", "batch must match the sweep length");
            out.batch = int(n);
        }
        break;
    }
    case Rule::Probabilistic: {
        const auto pf0 = defaultPFreeze(), pm0 = defaultPMelt();
        const auto pf = d.getFloatArray("p_freeze", {pf0.begin(), pf0.end()}, {12}, 0.0, 1.0, "",
            "probability that an empty cell freezes, per neighbourhood class 1..12 (see docs)");
        const auto pm = d.getFloatArray("p_melt", {pm0.begin(), pm0.end()}, {12}, 0.0, 1.0, "",
            "probability that an ice cell melts, per neighbourhood class 1..12");
        std::copy(pf.begin(), pf.end(), cfg.prob.pFreeze.begin());
        std::copy(pm.begin(), pm.end(), cfg.prob.pMelt.begin());
        break;
    }
    case Rule::Reiter:
        cfg.reiter.alpha = d.getFloat("alpha", 1.0, 0.0, 6.0, "", "diffusion weight alpha (usually 1)");
        cfg.reiter.beta = d.getFloat("beta", 0.4, 0.0, 0.9999, "", "background water level beta");
        cfg.reiter.gamma = d.getFloat("gamma", 0.001, 0.0, 1.0, "", "water added to receptive cells per step");
        break;
    case Rule::GravnerGriffeath: readGG(d, cfg.gg, false); out.writeVapour = d.getBool("write_vapour", false, "also write the vapour grid `vapour`"); break;
    case Rule::GravnerGriffeath3D: readGG(d, cfg.gg, true); break;
    default: break;
    }
    return std::make_unique<RuleEffect<R>>(ruleName(R), cfg, out);
}

using PackardEffect = RuleEffect<Rule::Packard>;
using CoxeReiterEffect = RuleEffect<Rule::CoxeReiter>;
using ProbabilisticEffect = RuleEffect<Rule::Probabilistic>;
using ReiterEffect = RuleEffect<Rule::Reiter>;
using GravnerGriffeathEffect = RuleEffect<Rule::GravnerGriffeath>;

} // namespace

FROSTVDB_REGISTER_EFFECT(PackardEffect, "packard",
    "Packard-Wolfram hexagonal snowflake: an empty cell with exactly one ice neighbour freezes");
FROSTVDB_REGISTER_EFFECT(CoxeReiterEffect, "coxe_reiter",
    "Coxe-Reiter fuzzy hexagonal automaton (two-level neighbourhood, 11 cases)");
FROSTVDB_REGISTER_EFFECT(ProbabilisticEffect, "probabilistic_ca",
    "probabilistic snowflake automaton: pFreeze/pMelt per 12 neighbourhood classes");
FROSTVDB_REGISTER_EFFECT(ReiterEffect, "reiter", "Reiter (2005) local model of snow crystal growth");
FROSTVDB_REGISTER_EFFECT(GravnerGriffeathEffect, "gravner_griffeath",
    "Gravner-Griffeath 2D mesoscopic snowflake (diffusion, freezing, attachment, melting)");
// [gravner_griffeath_3d] is the model as published: GG3DEffect.cpp (HexAutomaton's prism rule
// stays for the rule-level tests and the bench).

} // namespace automata
} // namespace frostvdb
