/// @file ShellPhaseFieldBackend.cpp
/// @brief [phase_field] on a shell (discretisations "surface" and "closest_point"): the fields
/// live in band order in shell::ShellPhaseField between steps and are written to World's grids
/// only when the driver reads them (publishFields). Also reads the keys only shells have:
/// frost_mesh, wind, wind_model.
#include <frostvdb/core/Error.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/ice/PhaseFieldBackend.h>
#include <frostvdb/io/Mesh.h>
#include <frostvdb/shell/ShellBudget.h>
#include <frostvdb/shell/ShellDomain.h>
#include <frostvdb/shell/ShellGrids.h>
#include <frostvdb/shell/ShellPhaseField.h>
#include <frostvdb/shell/ShellTexture.h>
#include <frostvdb/shell/ShellWind.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <thread>

namespace frostvdb::shell {
namespace {

/// The keys only a shell reads.
struct ShellOptions {
    std::string frostMesh = "none"; ///< none, obj or ply
    openvdb::Vec3d wind{0, 0, 0};   ///< prescribed wind advecting the heat
    bool potentialWind = false;     ///< wind_model = "potential" (shell/ShellWind.h)
};

class ShellPhaseFieldBackend final : public PhaseFieldBackend {
public:
    ShellPhaseFieldBackend(const PhaseFieldSetup& setup, const ShellOptions& options)
        : mSetup(setup), mOptions(options) {}

    void declare(FieldDeclaration& d) const override
    {
        d.use(kSurfaceFields, kInitialises).use(kSurfaceWind, kInitialises);
        d.output(out::kIceSdf);
    }

    bool seedsItself(const World& world) const override
    {
        const auto* tex = texturesOf(world.domain);
        return bandOf(world.domain)->colourUse() == BandSettings::ColourUse::Seed || (tex && tex->seed);
    }

    MemoryEstimate memoryEstimate(const World& world) const override
    {
        // the whole band (dense, or built whole by [dla] or the potential flow): the same estimate
        // as [dla]'s, so the driver counts the band once (issue 25, finding 2)
        const auto band = bandOf(world.domain);
        if (!world.region.dense && !band->whole() && !mOptions.potentialWind) return {};
        return wholeBandEstimate(world.domain);
    }

    void initialize(World& world) override
    {
        auto band = bandOf(world.domain);
        KobayashiParams solverParams = mSetup.params;
        solverParams.dt = mSetup.params.dt / mSetup.substeps;
        mShell = std::make_unique<ShellPhaseField>(band, solverParams, world.domain.lattice().spacing());
        if (mOptions.potentialWind) {
            // The potential flow is solved around the whole object (its solid is the whole band),
            // so the band is built whole first; the active region still steps only near the ice.
            band->materialiseAll();
        }
        // [region]: the band around the ice (tolerance) or the whole band (dense, the reference)
        mShell->setActiveRegion(!world.region.dense, world.region.tolerance);
        printEstimate(*band, world);
        if (mOptions.potentialWind) mShell->setWindField(potentialFlowWind(*band, mOptions.wind, 0));
        else mShell->setWind(mOptions.wind); // projected on each leaf's tangent planes as it is built
        // the tangential wind shared with [dla]'s walker drift (shell/ShellWind.h): [dla] on a
        // shell builds the band whole at creation, so this holds every voxel when it is used
        if (band->whole()) world.state<ShellWindState>().tangential = mShell->windField();
        // [dla] freezes into the band arrays directly (no grid round trip per step)
        world.state<SurfaceFields>().solver = mShell.get();
        gather(world);
        stampSeeds(world);
        mShell->extendAll(); // seeds were stamped in 3D: make them closest-point data
        scatter(world);
    }

    void step(World& world, int64_t step, double time) override
    {
        // another effect may have written p or T since we scattered them: read them back
        if (world.fields.get<openvdb::FloatGrid>(ice::kPhase) != mP ||
            world.fields.get<openvdb::FloatGrid>(ice::kTemperature) != mT)
            gather(world);
        const double subDt = mSetup.params.dt / mSetup.substeps;
        for (int s = 0; s < mSetup.substeps; ++s) // noise keyed by the substep's index, as on a plane
            mShell->step(time + (s + 1) * subDt, step * mSetup.substeps + s, world.seed, &mStats);
        // the band arrays are the state between steps: World's grids are written back only when
        // the driver reads them (publishFields: frames and checkpoints)
    }

    void publishFields(World& world) override { scatter(world); }

    void countKeptFields(std::map<std::string, uint64_t>& activeByField) const override
    {
        // toGrid's topology: the band's voxels off the background
        auto offBackground = [](const std::vector<float>& values, float background) {
            uint64_t n = 0;
            for (float v : values) n += v != background;
            return n;
        };
        activeByField[ice::kPhase.name] = offBackground(mShell->p(), 0.f);
        activeByField[ice::kTemperature.name] = offBackground(mShell->T(), float(mSetup.params.farTemperature));
        activeByField[ice::kGrowth.name] = offBackground(mShell->growthValues(), 0.f);
        activeByField[ice::kFreezeTime.name] = offBackground(mShell->freezeValues(), 0.f);
    }

    /// The frame's grids straight from the band arrays (World's grids are not published for a
    /// frame): `ice` now (the preview draws it), the rest deferred (Frame::addDeferred), each made
    /// as the writer reaches it, so a frame holds the fog and one other grid at a time.
    void addToFrame(World&, Frame& frame) override
    {
        const ShellBand& band = mShell->band();
        // `ice` is the frost layer grown outward along the normal (not p on the band).
        auto fog = frostFog(band, mShell->p(), mShell->growthValues());
        bool replaced = false;
        for (auto& g : frame.grids)
            if (g->getName() == out::kIce.name) g = fog, replaced = true;
        if (!replaced) { // else another effect wrote the ice outputs already
            frame.add(fog);
            addFieldOutputs(frame);
        }
        if (band.surfaceNodes())
            frame.addDeferred(out::kIceSdf, [this] {
                return frostLevelSetOnNodes(mShell->band(), mShell->p(), mShell->growthValues());
            });
        else frame.add(frostLevelSet(*fog));
    }

    bool writePreview(World&, const Frame& frame, const std::string& pngPath) override
    {
        if (mOptions.frostMesh == "none") return false;
        for (const auto& g : frame.grids) {
            if (g->getName() != out::kIce.name) continue;
            std::vector<openvdb::Vec3s> points;
            std::vector<openvdb::Vec3I> tris;
            std::vector<openvdb::Vec4I> quads;
            frostMesh(*openvdb::gridConstPtrCast<openvdb::FloatGrid>(g), points, tris, quads);
            const std::string base = pngPath.substr(0, pngPath.size() - 4);
            if (mOptions.frostMesh == "obj") writeObj(base + ".obj", points, tris, quads);
            else writePly(base + ".ply", points, tris, quads);
        }
        return false; // the driver still draws `ice`
    }

    // The band fields are World fields; lw_cn's history and the active region are ours.
    void saveState(const World&, StateWriter& out) const override
    {
        if (secondOrder()) {
            const ShellPhaseField& sh = *mShell;
            out.putInt("shell_history", sh.hasHistory() ? 1 : 0);
            out.putDouble("shell_last_step_dt", sh.lastStepDt());
            out.putGrid("shell_history_p", toGrid(sh.band(), sh.historyP(), 0.f, "shell_history_p"));
            out.putGrid("shell_history_T",
                        toGrid(sh.band(), sh.historyT(), float(mSetup.params.farTemperature), "shell_history_T"));
        }
        if (!mShell->activeRegion()) return;
        auto boxes = openvdb::Int32Grid::create(0);
        auto stepped = openvdb::MaskGrid::create();
        mShell->regionState(*boxes, *stepped);
        out.putGrid("shell_region_boxes", boxes);
        out.putGrid("shell_region_stepped", stepped);
    }

    void loadState(World& world, const StateReader& in) override
    {
        gather(world);
        if (in.has("shell_region_stepped"))
            mShell->restoreRegion(*in.getGrid<openvdb::Int32Grid>("shell_region_boxes"),
                                  *in.getGrid<openvdb::MaskGrid>("shell_region_stepped"));
        if (secondOrder()) {
            mShell->hasHistory() = in.getInt("shell_history") != 0;
            mShell->lastStepDt() = in.getDouble("shell_last_step_dt");
            fromGrid(mShell->band(), *in.getGrid<openvdb::FloatGrid>("shell_history_p"), mShell->historyP());
            fromGrid(mShell->band(), *in.getGrid<openvdb::FloatGrid>("shell_history_T"), mShell->historyT());
        }
    }

    std::vector<std::pair<std::string, double>> timings() const override
    {
        std::vector<std::pair<std::string, double>> t{{"kernel", mStats.kernelSeconds},
                                                      {"extend", mStats.extendSeconds}};
        if (secondOrder()) t.push_back({"solve", mStats.solveSeconds});
        return t;
    }

    std::vector<std::pair<std::string, double>> counters() const override
    {
        std::vector<std::pair<std::string, double>> t{{"region_rebuilds", 0.0},
                                                      {"voxel_updates", double(mStats.voxelUpdates)}};
        if (secondOrder()) {
            const double n = double(std::max<int64_t>(1, mStats.solves));
            t.push_back({"mean_iterations_p", double(mStats.iterationsP) / n});
            t.push_back({"mean_iterations_T", double(mStats.iterationsT) / n});
            t.push_back({"unconverged_solves", double(mStats.unconverged)});
            t.push_back({"clipped_voxels", double(mStats.clippedVoxels)});
        }
        return t;
    }

private:
    PhaseFieldSetup mSetup;
    ShellOptions mOptions;
    std::unique_ptr<ShellPhaseField> mShell;
    ShellStepStats mStats;
    /// The p and T grids scatter() last wrote (held, so a new grid never reuses the address).
    openvdb::FloatGrid::Ptr mP, mT;

    bool secondOrder() const { return mSetup.params.scheme == PhaseFieldScheme::SecondOrder; }

    /// World's grids into the band arrays.
    void gather(World& world)
    {
        const ShellBand& band = mShell->band();
        // (building the band's leaves wherever p or T is off its background: seeds)
        fromGrid(band, *world.fields.get<openvdb::FloatGrid>(ice::kPhase), mShell->p(), true);
        fromGrid(band, *world.fields.get<openvdb::FloatGrid>(ice::kTemperature), mShell->T(), true);
        std::vector<float> v;
        fromGrid(band, *world.fields.get<openvdb::FloatGrid>(ice::kGrowth), v);
        mShell->growthValues() = v;
        fromGrid(band, *world.fields.get<openvdb::FloatGrid>(ice::kFreezeTime), v);
        mShell->freezeValues() = v;
        // the melt field x the colour melt map x melt_texture (shell/ShellTexture.h): now for the
        // voxels built so far, and for each leaf the active region builds later
        openvdb::FloatGrid::ConstPtr melt = world.fields.get<openvdb::FloatGrid>(ice::kMelt);
        const auto* tex = texturesOf(world.domain);
        mShell->setMeltSource(meltSource(melt, band, tex), meltMap(band, melt.get(), tex));
        // the arrays now hold what these grids hold: read them again only when someone replaces them
        mP = world.fields.get<openvdb::FloatGrid>(ice::kPhase);
        mT = world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
    }

    /// `ice_temperature`, `growth` and `freeze_time` as ice::addIceFieldOutputs writes them from
    /// the published fields, made from the band arrays when the writer reaches them.
    void addFieldOutputs(Frame& frame) const
    {
        frame.addDeferred(out::kIceTemperature, [this] {
            auto T = toGrid(mShell->band(), mShell->T(), float(mSetup.params.farTemperature), out::kIceTemperature.name);
            T->setGridClass(openvdb::GRID_UNKNOWN); // dimensionless: not the gas's Kelvin
            return T;
        });
        frame.addDeferred(out::kGrowth, [this] {
            auto growth = toGrid(mShell->band(), mShell->growthValues(), 0.f, ice::kGrowth.name);
            ice::normaliseGrowth(*growth);
            return growth;
        });
        frame.addDeferred(out::kFreezeTime, [this] {
            return toGrid(mShell->band(), mShell->freezeValues(), 0.f, out::kFreezeTime.name);
        });
    }

    /// The band arrays into World's grids.
    void scatter(World& world)
    {
        const ShellBand& band = mShell->band();
        mP = toGrid(band, mShell->p(), 0.f, ice::kPhase.name);
        mT = toGrid(band, mShell->T(), float(mSetup.params.farTemperature), ice::kTemperature.name);
        world.fields.replace(ice::kPhase, mP);
        world.fields.replace(ice::kTemperature, mT);
        world.fields.replace(ice::kGrowth, toGrid(band, mShell->growthValues(), 0.f, ice::kGrowth.name));
        world.fields.replace(ice::kFreezeTime, toGrid(band, mShell->freezeValues(), 0.f, ice::kFreezeTime.name));
    }

    /// Ice where the vertex colours (vertex_colours = "seed") or seed_texture are bright.
    void stampSeeds(const World& world)
    {
        const ShellBand& band = mShell->band();
        const auto& lum = band.colourLuminance();
        if (band.colourUse() == BandSettings::ColourUse::Seed)
            for (size_t i = 0; i < lum.size(); ++i)
                if (lum[i] > 0.5f) mShell->p()[i] = 1.f;
        // (the domain built every leaf that can hold a texture seed)
        if (const auto* tex = texturesOf(world.domain); tex && tex->seed) {
            auto& p = mShell->p();
            band.forEachVoxel(nullptr, [&](size_t i) {
                if (tex->seedAt(band, i) > 0.5f) p[i] = 1.f;
            });
        }
    }

    /// One line before the run (stderr): the surface's cells, the memory they ask when the band
    /// is whole, and the steps per second once the whole surface is stepped, from the node update
    /// rate measured on the hero windshield (4.5 M nodes: 6.7 M updates per second per core; a
    /// band that fits the caches, the pane's 0.29 M nodes, reaches 9 M): an upper bound of the
    /// time, as the active region steps only the ice and its heat halo.
    static void printEstimate(const ShellBand& band, const World& world)
    {
        constexpr double kNodeUpdatesPerSecondPerCore = 6e6;
        const double cells = band.surfaceVoxels(), cores = double(std::max(1u, std::thread::hardware_concurrency()));
        const double rate = kNodeUpdatesPerSecondPerCore * cores / std::max(1.0, cells);
        const double steps = double(world.frames * world.stepsPerFrame);
        std::fprintf(stderr, "frostvdb: shell: %.2f M surface cells (%s), %zu built now; whole: about %s; about %.1f steps/s "
                             "when all are stepped (%d steps: at most %.0f s)\n",
                     cells * 1e-6, band.surfaceNodes() ? "surface nodes" : "closest-point band", band.size(),
                     formatBytes(cells * band.bytesPerSurfaceCell()).c_str(), rate, int(steps), steps / rate);
    }
};

/// The shell's keys, and the checks that need both them and the scheme.
PhaseFieldBackendFactory readShellKeys(ParamDict& d, PhaseFieldSetup& setup, const World& world, bool applies)
{
    ShellOptions o;
    const std::string notShell = "[domain] kind = \"" + world.domain.kind() + "\"";
    o.frostMesh = d.getString("frost_mesh", "none", {"none", "obj", "ply"},
        "shell domains: also write the frost layer (ice's 0.5 iso-surface, OpenVDB volume-to-mesh) as a polygon "
        "mesh beside each preview (<scene>.<frame>.obj/ply), for DCC tools that prefer geometry");
    d.onlyWhen(applies, "frost_mesh", notShell);
    const auto wind = d.getFloatArray("wind", {0, 0, 0}, {3}, -1e4, 1e4, "cells of h per unit ice time",
        "shell domains: a prescribed wind (world direction and speed) projected on each tangent plane, "
        "advecting the heat (first-order upwind; on a plane use [fluid])");
    o.wind = openvdb::Vec3d(wind[0], wind[1], wind[2]);
    d.onlyWhen(applies, "wind", notShell);
    o.potentialWind = d.getString("wind_model", "uniform", {"uniform", "potential"},
        "shell domains: uniform: `wind` projected on each tangent plane; potential: the potential flow around the "
        "closed mesh with free stream `wind` (OpenVDB tools::PotentialFlow), its surface velocity on the tangent "
        "planes (about 1.5x the free stream at a sphere's equator, 0 at its stagnation points)") == "potential";
    d.onlyWhen(applies, "wind_model", notShell);
    if (!applies) return {};

    KobayashiParams& k = setup.params;
    const bool euler = k.scheme == PhaseFieldScheme::Euler;
    // lw_cn and the potential flow run on the closest-point band (docs/shells.md "Discretisation")
    if (world.domain.discretisation() == "surface") {
        if (!euler)
            d.fail("scheme", "lw_cn on a shell runs on the closest-point band: set [domain] discretisation = "
                             "\"closest_point\" (allowed here: euler)");
        if (o.potentialWind)
            d.fail("wind_model", "the potential flow is solved on the closest-point band: set [domain] discretisation = "
                                 "\"closest_point\" (allowed here: uniform)");
    }
    // the potential flow goes around a closed object (its solid is the inside of the mesh)
    if (o.potentialWind && bandOf(world.domain)->borderEdgeCount() > 0)
        d.fail("wind_model", "potential needs a closed mesh (the flow goes around the object's inside); this mesh has "
                             "an open border (allowed here: uniform)");
    // lw_cn on a shell: the implicit closest-point system (shell/ShellImplicit.h) is not an
    // M-matrix (the extension's cubic weights are not all positive): BiCGSTAB only
    if (!euler) {
        if (d.has("solver") && !k.useBiCGSTAB)
            d.fail("solver", "shell domains solve lw_cn's closest-point band system with BiCGSTAB (allowed: bicgstab)");
        k.useBiCGSTAB = true;
    }
    // dt (6 / h^2 + |v|_1 / h) <= 1 (ShellPhaseField::windStabilityLimit, before projection)
    const double h = world.domain.lattice().spacing();
    // a potential flow is faster than its free stream over the object (1.5x on a sphere): allow 2x
    const double v1 = (o.potentialWind ? 2.0 : 1.0) * (std::fabs(wind[0]) + std::fabs(wind[1]) + std::fabs(wind[2]));
    // lw_cn: only the explicit half of the Crank-Nicolson average needs it (dt / 2)
    const double windLimit = (euler ? 1.0 : 2.0) / (6.0 / (h * h) + v1 / h);
    const double subDt = k.dt / setup.substeps;
    if (v1 > 0 && subDt > windLimit)
        d.fail("wind", "with dt " + std::to_string(subDt) + " the wind's upwind heat step needs dt <= " +
                           std::to_string(windLimit) + " (|v|_1 <= " +
                           std::to_string(((euler ? 1.0 : 2.0) / subDt - 6.0 / (h * h)) * h) + " at this dt)");
    return [&setup, o] { return std::make_unique<ShellPhaseFieldBackend>(setup, o); };
}

} // namespace

FROSTVDB_REGISTER_PHASE_FIELD_BACKEND(shell, (std::vector<std::string>{"surface", "closest_point"}), readShellKeys);

} // namespace frostvdb::shell
