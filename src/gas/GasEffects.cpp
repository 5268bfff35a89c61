/// @file GasEffects.cpp
/// @brief The gas scene sections: [steam], [fog], [fire], [gas] (procedural gases) and the flow
/// sections [attractor], [repulsor], [linear_attractor], [vortex], [vector_field] that move every
/// gas of the scene.
///
/// The gases are procedural: frame N is a pure function of N (needsHistory() is false), so any
/// frame range renders alone. Each written frame gets `density` (fog volume, only voxels above
/// the threshold active), `vel` (m/s, contravariant-relative) and, for fire, `flame`,
/// `temperature` (K) and `Cd`. The density of the frame is also published as the field
/// `density` in world.fields (refreshed at the first step of each frame and at output), so
/// other effects (e.g. DLA walkers raising humidity near steam) can read it.
#include <frostvdb/gas/GasGrid.h>
#include <frostvdb/gas/GasModels.h>

#include <frostvdb/core/Effect.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Progress.h>

#include <openvdb/tools/Composite.h>
#include <openvdb/tools/GridTransformer.h>
#include <openvdb/tools/Interpolation.h>

#include <chrono>
#include <cstdio>
#include <map>
#include <mutex>

namespace frostvdb::gas {

namespace {

// ---------------------------------------------------------------------------------------------
// Flows: each flow section puts its function into the world's typed state (key gas::kFlows) at
// initialisation; gases read them at each frame. Applied in a fixed order whatever the section order.

enum FlowOrder { kAttractor = 0, kRepulsor = 1, kLinear = 2, kVortex = 3, kTable = 4 };

struct FlowState {
    std::map<int, std::shared_ptr<const FlowFunction>> flows;
    FlowList list() const
    {
        FlowList out;
        for (auto& [k, f] : flows) out.push_back(f);
        return out;
    }
};

class FlowEffect : public Effect {
public:
    FlowEffect(std::string section, int order, std::shared_ptr<const FlowFunction> f)
        : mSection(std::move(section)), mOrder(order), mFlow(std::move(f)) {}
    std::string name() const override { return mSection; }
    FieldDeclaration declaration() const override
    {
        FieldDeclaration d;
        d.stage = Stage::Sources;
        d.use(kFlows, kInitialises);
        return d;
    }
    void initialize(World& world) override
    {
        if (!mFlow) mFlow = load(world);
        world.state<FlowState>().flows[mOrder] = mFlow;
    }
    void step(World&, const StepInfo&) override {}
    void addToFrame(World&, Frame&) override {}
    bool needsHistory() const override { return false; }

protected:
    virtual std::shared_ptr<const FlowFunction> load(World&) { return mFlow; }

private:
    std::string mSection;
    int mOrder;

protected:
    std::shared_ptr<const FlowFunction> mFlow;
};

class AttractorEffect : public FlowEffect {
public:
    using FlowEffect::FlowEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        return std::make_unique<AttractorEffect>("attractor", kAttractor, readSphericalAttractor(d, false));
    }
};

class RepulsorEffect : public FlowEffect {
public:
    using FlowEffect::FlowEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        return std::make_unique<RepulsorEffect>("repulsor", kRepulsor, readSphericalAttractor(d, true));
    }
};

class LinearAttractorEffect : public FlowEffect {
public:
    using FlowEffect::FlowEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        return std::make_unique<LinearAttractorEffect>("linear_attractor", kLinear, readLinearAttractor(d));
    }
};

class VortexEffect : public FlowEffect {
public:
    using FlowEffect::FlowEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        return std::make_unique<VortexEffect>("vortex", kVortex, readVortex(d));
    }
};

class VectorFieldEffect : public FlowEffect {
public:
    VectorFieldEffect(VectorFieldSettings s) : FlowEffect("vector_field", kTable, nullptr), mSettings(std::move(s)) {}
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        // `frostvdb keys` builds every effect with empty parameters, so a missing file is
        // reported at initialisation, not here.
        auto s = readVectorField(d);
        return std::make_unique<VectorFieldEffect>(std::move(s));
    }

protected:
    std::shared_ptr<const FlowFunction> load(World& world) override
    {
        if (mSettings.file.empty())
            throw SceneError(world.sceneLabel, 0, "vector_field.file", "a .vdb file with a vector grid is required");
        auto t = VectorFieldTable::load(mSettings.file, mSettings.grid);
        mSettings.applyTo(*t);
        // the gas's `vel` is about scale x the table's speed: keep it well inside a float
        if (!(t->maxSpeed() * std::fabs(t->scale) <= 1e30))
            throw SceneError(world.sceneLabel, 0, "vector_field.scale",
                             "scale " + std::to_string(t->scale) + " x the table's largest speed " +
                                 std::to_string(t->maxSpeed()) + " m/s exceeds 1e30 m/s (a float `vel` overflows)");
        return t;
    }

private:
    VectorFieldSettings mSettings;
};

// ---------------------------------------------------------------------------------------------
// Gas effects

using Clock = std::chrono::steady_clock;

class GasEffect : public Effect {
public:
    GasEffect(std::string section, std::unique_ptr<GasModel> model, GasBuildOptions build)
        : mSection(std::move(section)), mModel(std::move(model)), mBuild(build)
    {
        mBuild.velocity = mModel->common().velocity;
        mBuild.fire = mModel->isFire();
    }
    std::string name() const override { return mSection; }
    FieldDeclaration declaration() const override
    {
        FieldDeclaration d;
        d.stage = Stage::Sources;
        d.use(kFlows, kReads);
        if (mPublish) d.use(kDensity, kWrites);
        d.output(out::kDensity);
        if (mBuild.velocity) d.output(out::kVel);
        if (mBuild.fire) {
            d.output(out::kFlame).output(out::kTemperature);
            if (mBuild.colour) d.output(out::kColour);
        }
        return d;
    }
    void initialize(World& world) override
    {
        mXform = gasTransform(world);
        mWorld = &world;
        // The flows are known now (their sections initialise first): check the first and the
        // last frame before any other effect spends time on the run.
        mFlows = world.state<FlowState>().list();
        for (int64_t f : {int64_t(1), world.frames}) {
            const GasContext ctx = GasContext::at(double(f), mModel->common().fps, &mFlows);
            checkBudgets(world, ctx);
        }
    }
    void step(World& world, const StepInfo& info) override
    {
        // publish the density of the frame this step leads to, once per frame
        if (!mPublish || info.frame == mFrameBuilt) return;
        build(world, info.frame);
    }
    void addToFrame(World& world, Frame& frame) override
    {
        if (frame.frame != mFrameBuilt || !mGrids.density) build(world, frame.frame);
        mergeInto(frame, mGrids.density, out::kDensity, true);
        if (mGrids.vel) mergeVec(frame, mGrids.vel, out::kVel);
        if (mGrids.flame) mergeInto(frame, mGrids.flame, out::kFlame, false);
        if (mGrids.temperature) mergeInto(frame, mGrids.temperature, out::kTemperature, false);
        if (mGrids.colour) mergeVec(frame, mGrids.colour, out::kColour);
        if (mPublish)
            for (auto& g : frame.grids)
                if (g->getName() == out::kDensity.name) publish(world, g); // the frame's (merged) density
    }
    bool needsHistory() const override { return false; }
    double time() const override { return double(mFrameBuilt) / mModel->common().fps; }
    bool writePreview(World& world, const Frame& frame, const std::string& pngPath) override
    {
        writeGasPreview(frame.grids, mModel->common().up, pngPath);
        return true;
    }
    std::vector<std::pair<std::string, double>> timings() const override
    {
        return {{"build", mBuildSeconds}};
    }
    std::vector<std::pair<std::string, double>> counters() const override
    {
        return {{"voxels_evaluated", double(mVoxelsEvaluated)}, {"frames_built", double(mFramesBuilt)}};
    }
    /// The largest frame without flows (they are known only at initialisation); build() checks
    /// again with the flows before each frame. A build keeps the leaves that hold gas, not its
    /// whole bounding box: a round column or a cone leaves the box's corners empty (issue 25: a
    /// teacup's steam was charged 4x its peak), and the turbulence leaves more of the candidates
    /// (candidateLeafOrigins) empty (the teacup's plume fills 41 % of them: 2.1x). Both are
    /// counted when the box is within max_voxels: the candidates by one test per leaf, their
    /// share that holds gas from every voxel of a sample of kShareSampleLeaves of them. A larger
    /// box is refused at initialisation anyway, and its box is the estimate.
    MemoryEstimate memoryEstimate(const World& world) const override
    {
        MemoryEstimate out;
        const auto xf = gasTransform(world);
        for (int64_t f : {int64_t(1), world.frames}) {
            const GasContext ctx = GasContext::at(double(f), mModel->common().fps, nullptr);
            const auto e = estimateGasBuild(*mModel, ctx, *xf, mBuild, world.sceneLabel, extentKey());
            MemoryEstimate m = describe(e, world, extentKey());
            if (e.boxLeaves > 0 && e.boxLeaves * 512.0 <= mMaxVoxels) {
                const double candidates = double(countCandidateLeaves(*mModel, ctx, *xf));
                const double share = sampledGasLeafShare(*mModel, ctx, *xf, kShareSampleLeaves);
                m.bytes = e.bytes * std::min(1.0, candidates / e.boxLeaves) * share;
                char buf[120];
                std::snprintf(buf, sizeof buf, ", %.3g in leaves that may hold gas, about %.0f %% of them holding it",
                              candidates * 512.0, 100.0 * share);
                m.detail += buf;
            }
            if (m.bytes > out.bytes) out = m;
        }
        return out;
    }
    const GasModel& model() const { return *mModel; }
    void setPublish(bool p) { mPublish = p; }
    void setMaxVoxels(double v) { mMaxVoxels = v; }

private:
    void build(World& world, int64_t frameNumber)
    {
        const auto t0 = Clock::now();
        mFlows = world.state<FlowState>().list();
        const GasContext ctx = GasContext::at(double(frameNumber), mModel->common().fps, &mFlows);
        const auto xf = mXform ? mXform : gasTransform(world);
        const double candidates = checkBudgets(world, ctx);
        GasBuildOptions opt = mBuild;
        std::unique_ptr<Progress> progress;
        if (world.progress && candidates * 512.0 > kProgressVoxels) {
            // a frame of many voxels is one long step: say how far it is
            progress = std::make_unique<Progress>(mSection + " frame " + std::to_string(frameNumber),
                                                  int64_t(candidates), "leaves");
            opt.progress = [&](uint64_t done, uint64_t) { progress->update(int64_t(done)); };
        }
        mGrids = buildGasGrids(*mModel, ctx, xf, opt);
        if (progress) progress->finish();
        mFrameBuilt = frameNumber;
        ++mFramesBuilt;
        mVoxelsEvaluated += mGrids.evaluatedVoxels;
        mGrids.density->insertMeta("frostvdb_gas", openvdb::StringMetadata(mSection));
        if (mPublish) publish(world, mGrids.density);
        mBuildSeconds += std::chrono::duration<double>(Clock::now() - t0).count();
    }
    /// Refuses a frame whose build would not fit run.memory_limit (every leaf of the bounds'
    /// index box kept) or would evaluate more than max_voxels (the leaves that may hold gas):
    /// both before a voxel is evaluated, naming the key that sets the extent. Returns the
    /// candidate leaves, or the leaves of the whole box (an upper bound, not counted further)
    /// when the box is within the budget and too small to report progress.
    double checkBudgets(const World& world, const GasContext& ctx) const
    {
        const auto xf = mXform ? mXform : gasTransform(world);
        const std::string key = flowKey().empty() ? extentKey() : flowKey();
        const auto e = estimateGasBuild(*mModel, ctx, *xf, mBuild, world.sceneLabel, key);
        checkMemoryEstimate(describe(e, world, key), world.memoryLimitBytes, world.sceneLabel);
        if (e.boxLeaves * 512.0 <= std::min(mMaxVoxels, kProgressVoxels)) return e.boxLeaves;
        const double candidates = double(countCandidateLeaves(*mModel, ctx, *xf));
        if (candidates * 512.0 > mMaxVoxels) {
            char buf[400];
            std::snprintf(buf, sizeof buf,
                          "frame %g evaluates about %.3g voxels (gas bounds %.3g x %.3g x %.3g m at domain.voxel_size "
                          "%.3g m), more than %s.max_voxels = %.3g allows: shrink the gas, raise domain.voxel_size "
                          "or raise %s.max_voxels",
                          ctx.time.frame, candidates * 512.0, e.hi.x - e.lo.x, e.hi.y - e.lo.y, e.hi.z - e.lo.z,
                          xf->voxelSize()[0], mSection.c_str(), mMaxVoxels, mSection.c_str());
            throw SceneError(world.sceneLabel, 0, key, buf);
        }
        return candidates;
    }
    /// The key that sets the gas's extent (what to change when it is too large): the larger of
    /// the radius and the height for steam and fire, the box otherwise.
    std::string extentKey() const
    {
        double radius = 0, height = 0;
        if (auto s = dynamic_cast<const SteamModel*>(mModel.get())) radius = s->radius, height = s->height;
        else if (auto f = dynamic_cast<const FireModel*>(mModel.get())) radius = f->radius, height = f->height;
        else return mSection + ".box_max";
        return mSection + (2.0 * radius > height ? ".radius" : ".height");
    }
    /// A flow that widens the gas (an envelope shift), if any: it then drives the extent.
    std::string flowKey() const
    {
        for (const auto& f : mFlows)
            if (auto a = dynamic_cast<const SphericalAttractor*>(f.get()); a && a->maxEnvelopeShift() > 0)
                return std::string(a->repulsor ? "repulsor" : "attractor") + ".envelope_shift";
        return {};
    }
    static MemoryEstimate describe(const GasBuildEstimate& e, const World& world, const std::string& key)
    {
        char buf[256];
        std::snprintf(buf, sizeof buf, "gas bounds %.3g x %.3g x %.3g m at domain.voxel_size %.3g m: up to %.3g voxels",
                      e.hi.x - e.lo.x, e.hi.y - e.lo.y, e.hi.z - e.lo.z, world.domain.voxelSize(), e.boxLeaves * 512.0);
        return {e.bytes, key, buf};
    }
    /// The field shares the grid's tree when the transforms agree. Otherwise (a sheared hexagonal
    /// lattice, whose transform cannot hold the gas itself) the density is resampled trilinearly
    /// onto the domain's transform: the fields keep one transform (FieldSet::replace imposes it)
    /// and consumers sampling in world space (the DLA steam humidity) see the same gas.
    void publish(World& world, const openvdb::GridBase::Ptr& g)
    {
        const auto xf = world.fields.transform();
        if (*g->transformPtr() == *xf) {
            world.fields.replace(kDensity, g->copyGrid());
            return;
        }
        auto src = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
        if (!src) return;
        auto dst = openvdb::FloatGrid::create(0.f);
        dst->setTransform(xf->copy());
        dst->setGridClass(openvdb::GRID_FOG_VOLUME);
        openvdb::tools::resampleToMatch<openvdb::tools::BoxSampler>(*src, *dst);
        world.fields.replace(kDensity, dst);
    }
    /// Adds @a g to the frame, or merges it into a grid of the same name another gas added
    /// (density sums, others keep the maximum). Merging builds a new grid: cached grids of the
    /// effects are never modified.
    static void mergeInto(Frame& frame, const openvdb::FloatGrid::Ptr& g, const FieldKey& key, bool sum)
    {
        for (auto& e : frame.grids)
            if (e->getName() == key.name)
                if (auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(e)) {
                    auto merged = f->deepCopy();
                    auto copy = g->deepCopy();
                    if (sum) openvdb::tools::compSum(*merged, *copy);
                    else openvdb::tools::compMax(*merged, *copy);
                    e = merged;
                    return;
                }
        frame.add(key, g);
    }
    static void mergeVec(Frame& frame, const openvdb::Vec3SGrid::Ptr& g, const FieldKey& key)
    {
        for (auto& e : frame.grids)
            if (e->getName() == key.name)
                if (auto f = openvdb::gridPtrCast<openvdb::Vec3SGrid>(e)) {
                    // the first gas wins where both are active
                    auto merged = f->deepCopy();
                    auto acc = merged->getAccessor();
                    for (auto it = g->cbeginValueOn(); it; ++it)
                        if (!acc.isValueOn(it.getCoord())) acc.setValue(it.getCoord(), *it);
                    e = merged;
                    return;
                }
        frame.add(key, g);
    }

    std::string mSection;
    std::unique_ptr<GasModel> mModel;
    GasBuildOptions mBuild;
    openvdb::math::Transform::Ptr mXform;
    World* mWorld = nullptr;
    FlowList mFlows;
    GasGrids mGrids;
    int64_t mFrameBuilt = -1;
    bool mPublish = true;
    double mBuildSeconds = 0;
    uint64_t mVoxelsEvaluated = 0;
    uint64_t mFramesBuilt = 0;
    double mMaxVoxels = 2e8;
    /// Frames evaluating more voxels than this report progress (a second or more of work).
    static constexpr double kProgressVoxels = 4e6;
    /// Candidate leaves evaluated to tell the share that holds gas: 1/4 of a second of one core
    /// at most (a leaf holding gas stops at its first voxel above the threshold); two standard
    /// errors at 128 are at most 9 % of the candidates.
    static constexpr size_t kShareSampleLeaves = 128;
};

/// The time budget of one gas frame, in voxels evaluated (the cost follows them: each is a
/// turbulence sum and, with `vel`, three displacements).
double readMaxVoxels(ParamDict& d)
{
    return d.getFloat("max_voxels", 2e8, 1e3, 1e15, "voxels",
                      "refuse a frame that would evaluate more voxels than this (the leaves that may hold gas, at "
                      "domain.voxel_size); one core evaluates about 4e6 fire voxels with vel per second");
}

bool readPublish(ParamDict& d)
{
    return d.getBool("publish_density", true,
                     "publish the frame's density as the world field `density` at the first step of each frame "
                     "(read by other effects, e.g. humidity of DLA walkers near steam)");
}

class SteamEffect : public GasEffect {
public:
    using GasEffect::GasEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        auto m = readSteam(d);
        auto e = std::make_unique<SteamEffect>("steam", std::move(m), GasBuildOptions());
        e->setPublish(readPublish(d));
        e->setMaxVoxels(readMaxVoxels(d));
        return e;
    }
};

class FogEffect : public GasEffect {
public:
    using GasEffect::GasEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        auto e = std::make_unique<FogEffect>("fog", readFog(d), GasBuildOptions());
        e->setPublish(readPublish(d));
        e->setMaxVoxels(readMaxVoxels(d));
        return e;
    }
};

class BasicGasEffect : public GasEffect {
public:
    using GasEffect::GasEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        auto e = std::make_unique<BasicGasEffect>("gas", readBasicGas(d), GasBuildOptions());
        e->setPublish(readPublish(d));
        e->setMaxVoxels(readMaxVoxels(d));
        return e;
    }
};

class FireEffect : public GasEffect {
public:
    using GasEffect::GasEffect;
    static std::unique_ptr<Effect> create(ParamDict& d, const World&)
    {
        auto m = readFire(d);
        GasBuildOptions o;
        o.colour = d.getBool("colour", true, "write the `Cd` colour grid (dense red to thin yellow)");
        o.ambientTemperature = d.getFloat("ambient_temperature", 293.15, 0.0, 1e5, "K",
                                          "temperature background (outside the flames)");
        o.peakTemperature = d.getFloat("peak_temperature", 1700.0, 0.0, 1e5, "K",
                                       "temperature where flame = 1 (temperature = ambient + flame (peak - ambient))");
        auto e = std::make_unique<FireEffect>("fire", std::move(m), o);
        e->setPublish(readPublish(d));
        e->setMaxVoxels(readMaxVoxels(d));
        return e;
    }
};

} // namespace

} // namespace frostvdb::gas

namespace frostvdb {
using gas::AttractorEffect;
using gas::BasicGasEffect;
using gas::FireEffect;
using gas::FogEffect;
using gas::LinearAttractorEffect;
using gas::RepulsorEffect;
using gas::SteamEffect;
using gas::VectorFieldEffect;
using gas::VortexEffect;

FROSTVDB_REGISTER_EFFECT(SteamEffect, "steam",
                         "Ebert's steam rising from a cup: turbulence slab with spherical and vertical ramp-off, helical path");
FROSTVDB_REGISTER_EFFECT(FogEffect, "fog", "Ebert's solid-textured-transparency fog rolling through a soft box");
FROSTVDB_REGISTER_EFFECT(FireEffect, "fire",
                         "Ebert's fire: base fire, sine flames, vertical ramp-off; density, flame, temperature, Cd");
FROSTVDB_REGISTER_EFFECT(BasicGasEffect, "gas", "Ebert's basic gas in a box: power shaping, sine veins or molten marble");
FROSTVDB_REGISTER_EFFECT(AttractorEffect, "attractor",
                         "spherical attractor moving the scene's gases (moving, angle-limited, animated strength)");
FROSTVDB_REGISTER_EFFECT(RepulsorEffect, "repulsor", "spherical repulsor (an attractor pushing the gases away)");
FROSTVDB_REGISTER_EFFECT(LinearAttractorEffect, "linear_attractor",
                         "attracts the scene's gases toward a line or a plane (flow along a wall)");
FROSTVDB_REGISTER_EFFECT(VortexEffect, "vortex", "spiral vortex (Sims or angular-momentum-conserving) swirling the gases");
FROSTVDB_REGISTER_EFFECT(VectorFieldEffect, "vector_field",
                         "3D vector-field table: a VDB `vel` grid, trilinear lookup, moving the gases");
} // namespace frostvdb
