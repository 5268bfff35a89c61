/// @file ShellDlaEffect.cpp
/// @brief `[dla]` on a shell domain, the back end of discretisations "surface" and
/// "closest_point" (ice/DlaBackend.h): the plane's keys and semantics (humidity H and its
/// schedule, hits n, heat_release L, melt map as sticking probability, max_steps, jumps, batch,
/// flow_drift) with walkers on the surface (shell/ShellWalkers.h). release = "uniform" picks
/// surface points uniformly by area, "perimeter" the open mesh's border. Steam humidity is not
/// available on shells. The drift is the tangential wind of `[phase_field]` (key surface_wind).
/// Each step releases the walkers in deterministic batches and applies their sticks in walker
/// order to the band's p, T, growth and freeze_time (key surface_fields). Runs at the Walkers
/// stage, before the phase field. Walkers roam the whole surface, so makeShellDla builds the
/// (lazy) band whole when the scene is read.
#include <frostvdb/ice/DlaBackend.h>

#include <frostvdb/core/Budget.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/core/FieldKeys.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/shell/ShellBudget.h>
#include <frostvdb/shell/ShellDomain.h>
#include <frostvdb/shell/ShellGrids.h>
#include <frostvdb/shell/ShellPhaseField.h>
#include <frostvdb/shell/ShellTexture.h>
#include <frostvdb/shell/ShellWalkers.h>
#include <frostvdb/shell/ShellWind.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace frostvdb::shell {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
constexpr uint64_t kResumeSalt = 0x5E5D3E11ull; // the plane's salt for resumed walks

class ShellDlaEffect : public Effect {
public:
    explicit ShellDlaEffect(const ice::DlaParams& p) : mParams(p) {}

    std::string name() const override { return "dla"; }
    /// The whole band the walkers built (makeShellDla); the phase field reports the same one.
    MemoryEstimate memoryEstimate(const World& world) const override { return wholeBandEstimate(world.domain); }

    FieldDeclaration declaration() const override
    {
        FieldDeclaration d;
        d.stage = Stage::Walkers;
        d.use(ice::kClock, kReadsAtInit | kReads)
            .use(ice::kPhase, kReadsAtInit | kReads | kWrites)
            .use(ice::kTemperature, kInitialises | kWrites)
            .use(ice::kGrowth, kInitialises | kWrites)
            .use(ice::kFreezeTime, kInitialises | kWrites)
            .use(ice::kMelt, kReads);
        if (mParams.steamHumidity > 0) d.use(gas::kDensity, kReads);
        d.use(kSurfaceFields, kReads | kWrites).use(kSurfaceWind, kReads);
        d.output(out::kIce).output(out::kIceSdf).output(out::kIceTemperature).output(out::kGrowth).output(out::kFreezeTime);
        return d;
    }

    void initialize(World& world) override
    {
        ice::IceShared& sh = ice::shared(world);
        if (!sh.dtOwnedByPhaseField) sh.dt = mParams.dt;
        ice::requireIceFields(world);
        mHeat = mParams.heatRelease < 0 ? sh.latentHeat / 6.0 : mParams.heatRelease;
        mBand = bandOf(world.domain);
        mWalkers = std::make_unique<ShellWalkers>(mBand, mParams, world.seed);
        mHits.assign(mParams.hits > 1 ? mBand->size() : 0, 0);
        // the colour melt map x melt_texture: fixed (the band is whole, see makeShellDla)
        mStaticMelt = meltMap(*mBand, nullptr, texturesOf(world.domain));
        mTime = 0;
    }

    void step(World& world, const StepInfo& info) override;
    void addToFrame(World& world, Frame& frame) override;

    double time() const override { return mTime; }
    // Checkpoints: the walkers' ice (stick points are off the lattice: p cannot rebuild it), p as
    // this effect left it (the next step's incremental sync), the hit counts and the clock. The
    // walks are keyed by (seed, step, walker): no stream to save.
    bool supportsCheckpoint() const override { return true; }
    void saveState(const World&, StateWriter& out) const override
    {
        out.putDouble("time", mTime);
        out.putArray("ice_points", mWalkers->icePointList());
        out.putArray("p_left", mPLeft);
        out.putArray("hits", mHits);
        out.putInt("melted_since_full_sync", mMeltedSinceFullSync ? 1 : 0); // the next full sync's condition
        std::vector<double> sticks; // what the next full sync removes
        for (const auto& x : mSticks) sticks.insert(sticks.end(), {x.x(), x.y(), x.z()});
        out.putArray("sticks_since_full_sync", sticks);
        out.putArray("ice_nodes", mWalkers->iceNodes());
    }
    void loadState(World&, const StateReader& in) override
    {
        mTime = in.getDouble("time");
        std::vector<double> ice;
        in.getArray("ice_points", ice);
        mWalkers->restoreIce(ice);
        if (in.has("ice_nodes")) {
            std::vector<uint8_t> nodes;
            in.getArray("ice_nodes", nodes);
            mWalkers->restoreIceNodes(nodes);
        }
        in.getArray("p_left", mPLeft);
        in.getArray("hits", mHits);
        mMeltedSinceFullSync = in.has("melted_since_full_sync") && in.getInt("melted_since_full_sync") != 0;
        mSticks.clear();
        if (in.has("sticks_since_full_sync")) {
            std::vector<double> xyz;
            in.getArray("sticks_since_full_sync", xyz);
            for (size_t k = 0; k + 2 < xyz.size(); k += 3) mSticks.emplace_back(xyz[k], xyz[k + 1], xyz[k + 2]);
        }
        if ((!mPLeft.empty() && mPLeft.size() != mBand->size()) || (mParams.hits > 1 && mHits.size() != mBand->size()))
            throw CheckpointError("[dla] on a shell: the checkpoint's band does not match this scene's");
    }

    std::vector<std::pair<std::string, double>> timings() const override
    {
        return {{"walkers", mStats.walkSeconds}, {"apply", mStats.applySeconds}, {"sync", mStats.syncSeconds},
                {"clearances", mStats.clearanceSeconds}, {"steam", mStats.steamSeconds}};
    }
    std::vector<std::pair<std::string, double>> counters() const override
    {
        return {{"released", double(mStats.released)}, {"stuck", double(mStats.stuck)},
                {"frozen", double(mStats.frozen)},     {"killed", double(mStats.killed)},
                {"jumps", double(mStats.jumps)},       {"moves", double(mStats.moves)},
                {"conflicts", double(mStats.conflicts)}, {"lattice_steps", mStats.latticeSteps}};
    }

private:
    /// One step's shared state between its stages (step() lists them).
    struct StepContext {
        StepContext(World& w, const ice::IceShared& s) : world(w), shared(s) {}
        World& world;
        const ice::IceShared& shared;
        ShellPhaseField* solver = nullptr; ///< [phase_field]'s arrays, borrowed for the step
        bool read = false;                 ///< T, growth and freeze_time borrowed too
        bool changed = false;              ///< something froze
        bool heat = false;                 ///< freezing releases heat
        double time = 0;                   ///< the step's start (freeze_time)
        std::vector<size_t> written;       ///< voxels frozen (the solver's active region rescans their leaves)
    };
    void borrowPhase(StepContext& ctx);
    void borrowRest(StepContext& ctx);
    void handBack(StepContext& ctx);
    void updateMelt(World& world, ShellWalkers::Inputs& in);
    void updateDrift(World& world, double dt, ShellWalkers::Inputs& in);
    /// H walkers, plus the steam's extra walkers (in's steam inputs set).
    uint64_t walkersToRelease(World& world, int64_t step, ShellWalkers::Inputs& in);
    /// Walks them in batches and applies their sticks in walker order.
    void walkAndFreeze(StepContext& ctx, int64_t step, uint64_t total, const ShellWalkers::Inputs& in);
    void account(const ShellWalkEnd& e);
    void hit(StepContext& ctx, const openvdb::Vec3d& x);
    void freezeAt(StepContext& ctx, const openvdb::Vec3d& x);

    ice::DlaParams mParams;
    double mHeat = 0, mTime = 0;
    std::shared_ptr<const ShellBand> mBand;
    std::unique_ptr<ShellWalkers> mWalkers;
    std::vector<int32_t> mHits; ///< walkers stuck per site since its last freeze (hits > 1)
    ice::DlaStats mStats;
    std::vector<float> mP, mT, mGrowth, mFreeze, mMelt, mStaticMelt;
    std::vector<openvdb::Vec3f> mDrift;
    std::vector<float> mPLeft; ///< p as this effect left it last step, on the right side of 1/2 (empty: none yet)
    std::vector<size_t> mSynced; ///< voxels whose ice syncIce added or removed this step
    bool mFullSync = true, mMeltedSinceFullSync = false;
    std::vector<openvdb::Vec3d> mSticks; ///< stick points added since the last full sync
    std::vector<uint32_t> mCrossedLeaves; ///< scratch: leaves where p crossed 1/2 (ShellPhaseField)
    // steam humidity (the plane's rule, DlaEffect::updateSteam): per layer site, the largest
    // density x (1 - h / reach) along its outward normal up to steam_reach; rebuilt when the gas
    // publishes a new density grid
    openvdb::FloatGrid::ConstPtr mSteamSource;
    openvdb::FloatGrid::ConstPtr mMeltSource; ///< the melt grid mMelt was made from
    std::vector<double> mSteamCdf;
    std::vector<size_t> mSteamSites;
    double mSteamSum = 0;

    void updateSteam(World& world)
    {
        auto density = world.fields.get<openvdb::FloatGrid>(gas::kDensity);
        if (density == mSteamSource) return;
        mSteamSource = density;
        mSteamCdf.clear();
        mSteamSites.clear();
        mSteamSum = 0;
        if (!density || density->activeVoxelCount() == 0) return;
        const ShellBand& b = *mBand;
        const auto& sites = mWalkers->layer();
        const auto& xf = *b.transform();
        const auto& dxf = density->transform();
        const double reach = mParams.steamReach, dz = dxf.voxelSize()[2];
        const int samples = reach > 0 ? std::max(1, int(std::ceil(reach / dz))) : 0;
        std::vector<float> w(sites.size(), 0.f);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, sites.size(), 256), [&](const tbb::blocked_range<size_t>& r) {
            auto acc = density->getConstAccessor();
            for (size_t k = r.begin(); k < r.end(); ++k) {
                const openvdb::Vec3d p = xf.indexToWorld(b.closestPoint(sites[k]));
                const openvdb::Vec3d up = b.normal(sites[k]);
                float best = 0.f;
                for (int s = 0; s <= samples; ++s) {
                    const double h = s * dz;
                    if (reach > 0 && h > reach) break;
                    const float wgt = reach > 0 ? float(1.0 - h / reach) : 1.f;
                    best = std::max(best, acc.getValue(dxf.worldToIndexNodeCentered(p + up * h)) * wgt);
                }
                w[k] = best;
            }
        });
        for (size_t k = 0; k < sites.size(); ++k) {
            if (!(w[k] > 0.f)) continue;
            mSteamSum += w[k];
            mSteamCdf.push_back(mSteamSum);
            mSteamSites.push_back(sites[k]);
        }
    }

    /// The walkers' ice from p: built in full at the first step; then the voxels another effect
    /// (the phase field) turned to ice or melted since our last step are added or removed, and
    /// every kFullSyncSteps steps when ice melted since the last full sync the stick points go
    /// (a melted node's stick points with them), which leaves what a full build would.
    static constexpr int64_t kFullSyncSteps = 64;
    void syncIce(int64_t step, ShellPhaseField* solver)
    {
        mSynced.clear();
        // the leaves where [phase_field] moved p across 1/2 since our last look (when it knows)
        const bool onlyCrossed = solver && solver->takeCrossedLeaves(mCrossedLeaves);
        mFullSync = mPLeft.size() != mP.size();
        if (mFullSync) {
            mWalkers->sync(mP);
            mSticks.clear();
            mMeltedSinceFullSync = false;
            return;
        }
        // index ranges to compare, in ascending order: the crossed leaves' (a leaf's voxels are
        // contiguous, and later slots hold later voxels), or everything in fixed chunks
        constexpr size_t kChunk = size_t(1) << 16;
        std::vector<std::pair<size_t, size_t>> ranges;
        if (onlyCrossed) {
            const auto& leaves = mBand->leaves();
            for (uint32_t s : mCrossedLeaves) ranges.emplace_back(leaves[s].begin, leaves[s].end);
        } else {
            for (size_t i = 0; i < mP.size(); i += kChunk) ranges.emplace_back(i, std::min(mP.size(), i + kChunk));
        }
        // in parallel over the ranges, joined in order (the same lists at any thread count)
        std::vector<std::vector<size_t>> grownIn(ranges.size()), meltedIn(ranges.size());
        tbb::parallel_for(size_t(0), ranges.size(), [&](size_t c) {
            for (size_t i = ranges[c].first; i < ranges[c].second; ++i) {
                const bool was = mPLeft[i] > 0.5f, is = mP[i] > 0.5f;
                if (was && !is) meltedIn[c].push_back(i);
                else if (is && !was) grownIn[c].push_back(i);
            }
        });
        std::vector<size_t> grown, melted;
        for (size_t c = 0; c < ranges.size(); ++c) {
            grown.insert(grown.end(), grownIn[c].begin(), grownIn[c].end());
            melted.insert(melted.end(), meltedIn[c].begin(), meltedIn[c].end());
        }
        mMeltedSinceFullSync = mMeltedSinceFullSync || !melted.empty();
        mWalkers->removeIceVoxels(melted);
        mWalkers->addIceVoxels(grown);
        mSynced = std::move(grown);
        mSynced.insert(mSynced.end(), melted.begin(), melted.end());
        // A full sync when ice melted: the incremental set is the full one plus the stick points
        // (a melted node's stick points stay until then), so removing the stick points is the
        // full sync (rebuilding it from p took 1.4 s for 2.5 M ice nodes on the windshield hero).
        if (step % kFullSyncSteps == 0 && mMeltedSinceFullSync) {
            mWalkers->forgetSticks(mSticks, mP);
            mSticks.clear();
            mMeltedSinceFullSync = false;
        }
    }
    /// What this step leaves for the next one's comparison: p's side of 1/2 is all syncIce reads,
    /// so only the voxels that crossed it (synced here or frozen by walkers) are copied, not p.
    void rememberIce(const std::vector<size_t>& written)
    {
        if (mFullSync) {
            mPLeft = mP;
            return;
        }
        for (size_t i : mSynced) mPLeft[i] = mP[i];
        for (size_t i : written) mPLeft[i] = mP[i];
    }
};

void ShellDlaEffect::step(World& world, const StepInfo& info)
{
    const ice::IceShared& sh = ice::shared(world);
    StepContext ctx(world, sh);
    ctx.time = sh.timeAtStep(info.step);
    ctx.heat = sh.temperatureEvolves && mHeat != 0;
    auto t0 = Clock::now();
    borrowPhase(ctx);
    syncIce(info.step, ctx.solver);
    mStats.syncSeconds += since(t0);
    ShellWalkers::Inputs in;
    updateMelt(world, in);
    updateDrift(world, sh.dt, in);
    const uint64_t total = walkersToRelease(world, info.step, in);
    mStats.released += total;
    walkAndFreeze(ctx, info.step, total, in);
    rememberIce(ctx.written); // the next step adds only ice grown by others
    handBack(ctx);
    mTime = sh.timeAtStep(info.step + 1);
}

void ShellDlaEffect::borrowPhase(StepContext& ctx)
{
    // With [phase_field] in the scene, its band arrays are the fields: read and freeze into them
    // in place. Alone, the World grids are the fields (converted to band order and back).
    World& world = ctx.world;
    ctx.solver = world.hasState<SurfaceFields>() ? world.state<SurfaceFields>().solver : nullptr;
    if (ctx.solver) mP.swap(ctx.solver->pForEdit());
    else fromGrid(*mBand, *world.fields.get<openvdb::FloatGrid>(ice::kPhase), mP);
}

void ShellDlaEffect::borrowRest(StepContext& ctx)
{
    if (ctx.read) return; // T, growth and freeze_time only when something freezes
    if (ctx.solver) {
        mT.swap(ctx.solver->TForEdit());
        mGrowth.swap(ctx.solver->growthValues());
        mFreeze.swap(ctx.solver->freezeValues());
    } else {
        const World& world = ctx.world;
        fromGrid(*mBand, *world.fields.get<openvdb::FloatGrid>(ice::kTemperature), mT);
        fromGrid(*mBand, *world.fields.get<openvdb::FloatGrid>(ice::kGrowth), mGrowth);
        fromGrid(*mBand, *world.fields.get<openvdb::FloatGrid>(ice::kFreezeTime), mFreeze);
    }
    ctx.read = true;
}

void ShellDlaEffect::handBack(StepContext& ctx)
{
    const ShellBand& band = *mBand;
    if (ctx.solver) { // hand the arrays back, and the voxels written
        mP.swap(ctx.solver->pForEdit());
        if (ctx.read) {
            mT.swap(ctx.solver->TForEdit());
            mGrowth.swap(ctx.solver->growthValues());
            mFreeze.swap(ctx.solver->freezeValues());
        }
        ctx.solver->touched(ctx.written);
    } else if (ctx.changed) {
        World& world = ctx.world;
        world.fields.replace(ice::kPhase, toGrid(band, mP, 0.f, ice::kPhase.name));
        world.fields.replace(ice::kTemperature, toGrid(band, mT, float(ctx.shared.farTemperature), ice::kTemperature.name));
        world.fields.replace(ice::kGrowth, toGrid(band, mGrowth, 0.f, ice::kGrowth.name));
        world.fields.replace(ice::kFreezeTime, toGrid(band, mFreeze, 0.f, ice::kFreezeTime.name));
    }
}

void ShellDlaEffect::updateMelt(World& world, ShellWalkers::Inputs& in)
{
    // sticking probability: the melt field times the mesh's colour melt map (as the phase field),
    // converted again only when the melt grid is replaced
    auto melt = world.fields.get<openvdb::FloatGrid>(ice::kMelt);
    if (melt != mMeltSource || mMelt.size() != mBand->size()) {
        mMeltSource = melt;
        if (melt) {
            fromGrid(*mBand, *melt, mMelt);
            if (!mStaticMelt.empty())
                for (size_t i = 0; i < mMelt.size(); ++i) mMelt[i] *= mStaticMelt[i];
        } else {
            mMelt = mStaticMelt;
        }
    }
    if (!mMelt.empty()) in.melt = &mMelt;
}

void ShellDlaEffect::updateDrift(World& world, double dt, ShellWalkers::Inputs& in)
{
    // drift: the tangential wind (cells per unit ice time) times dt and flow_drift, per step
    mDrift.clear();
    if (!world.hasState<ShellWindState>() || mParams.flowDrift <= 0) return;
    const auto& w = world.state<ShellWindState>().tangential;
    if (w.size() != mBand->size()) return;
    mDrift.resize(w.size());
    const float s = float(dt * mParams.flowDrift);
    for (size_t i = 0; i < w.size(); ++i) mDrift[i] = w[i] * s;
    in.drift = &mDrift;
}

uint64_t ShellDlaEffect::walkersToRelease(World& world, int64_t step, ShellWalkers::Inputs& in)
{
    const int64_t H = mParams.humidityAt(step);
    uint64_t total = uint64_t(H);
    in.baseWalkers = H;
    if (mParams.steamHumidity <= 0) return total;
    // extra walkers H x gain x mean steam weight, released in the steam
    const auto t0 = Clock::now();
    updateSteam(world);
    const size_t cells = mWalkers->layer().size();
    if (mSteamSum > 0 && cells > 0) {
        const double e = double(H) * mParams.steamHumidity * mSteamSum / double(cells);
        uint64_t extra = uint64_t(std::floor(e));
        if (toUnit(hashCounters(world.seed, 0x57EA4ull, uint64_t(step))) < e - std::floor(e)) ++extra;
        total += extra;
        in.steamCdf = &mSteamCdf;
        in.steamSites = &mSteamSites;
    }
    mStats.steamSeconds += since(t0);
    return total;
}

void ShellDlaEffect::walkAndFreeze(StepContext& ctx, int64_t step, uint64_t total, const ShellWalkers::Inputs& in)
{
    std::vector<ShellWalkEnd> ends;
    for (uint64_t first = 0; first < total; first += uint64_t(mParams.batch)) {
        const uint64_t count = std::min<uint64_t>(uint64_t(mParams.batch), total - first);
        auto t0 = Clock::now();
        mWalkers->flushIce();
        mStats.clearanceSeconds += since(t0);
        t0 = Clock::now();
        mWalkers->walkBatch(step, first, count, in, ends);
        mStats.walkSeconds += since(t0);
        t0 = Clock::now();
        for (uint64_t w = 0; w < count; ++w) {
            ShellWalkEnd e = ends[size_t(w)];
            account(e);
            if (e.kind != ShellWalkEnd::Stuck) continue;
            if (mWalkers->iceNearer(e.point, 0.5)) {
                // ice froze on top of it earlier in this batch: the walk goes on from its last
                // step's point, serially, against the current ice (the plane's rule)
                ++mStats.conflicts;
                if (!e.hasPrev || mWalkers->iceNearer(e.prev, 0.5)) continue;
                const openvdb::Vec3d start = e.prev;
                e = mWalkers->walk(step, first + w, kResumeSalt, &start, in);
                account(e);
                if (e.kind != ShellWalkEnd::Stuck) continue;
            }
            hit(ctx, e.point);
        }
        mStats.applySeconds += since(t0);
    }
}

void ShellDlaEffect::account(const ShellWalkEnd& e)
{
    mStats.moves += e.moves;
    mStats.jumps += e.jumps;
    mStats.latticeSteps += e.latticeSteps;
    if (e.kind == ShellWalkEnd::Killed) ++mStats.killed;
    if (e.kind == ShellWalkEnd::Exhausted) ++mStats.exhausted;
}

void ShellDlaEffect::hit(StepContext& ctx, const openvdb::Vec3d& x)
{
    ++mStats.stuck;
    if (mParams.hits > 1) {
        const int32_t site = mWalkers->siteOf(x);
        if (site >= 0 && ++mHits[size_t(site)] < mParams.hits) return;
        if (site >= 0) mHits[size_t(site)] = 0;
    }
    freezeAt(ctx, x);
}

void ShellDlaEffect::freezeAt(StepContext& ctx, const openvdb::Vec3d& x)
{
    borrowRest(ctx);
    std::vector<size_t> disc;
    if (mBand->surfaceNodes()) { // the free node next to the ice, as a plane's walker freezes its cell
        const int32_t id = mWalkers->freeNodeNear(x, mP);
        if (id >= 0) disc.push_back(size_t(id));
    } else {
        disc = mWalkers->markDisc(x);
    }
    for (size_t i : disc) {
        const float before = mP[i];
        mP[i] = 1.f;
        if (before < 1.f) mGrowth[i] += 1.f - before;
        if (before <= 0.5f && mFreeze[i] == 0.f) mFreeze[i] = float(ctx.time);
        if (ctx.heat) mT[i] += float(mHeat * (1.0 - double(before)));
        mStats.dpDla += 1.0 - double(before);
    }
    ctx.written.insert(ctx.written.end(), disc.begin(), disc.end());
    mWalkers->addIce(x);
    mSticks.push_back(x);
    mWalkers->addIceVoxels(disc); // the frozen nodes too, as a full sync would add them
    ++mStats.frozen;
    ctx.changed = true;
}

void ShellDlaEffect::addToFrame(World& world, Frame& frame)
{
    if (ice::shared(world).dtOwnedByPhaseField) return; // [phase_field] writes the ice outputs
    for (const auto& g : frame.grids)
        if (g->getName() == out::kIce.name) return; // another effect wrote them
    // `ice` is the frost layer grown outward along the normal (as the shell's phase field writes it)
    fromGrid(*mBand, *world.fields.get<openvdb::FloatGrid>(ice::kPhase), mP);
    fromGrid(*mBand, *world.fields.get<openvdb::FloatGrid>(ice::kGrowth), mGrowth);
    auto fog = frostFog(*mBand, mP, mGrowth);
    frame.add(fog);
    ice::addIceFieldOutputs(world, frame);
    frame.add(mBand->surfaceNodes() ? frostLevelSetOnNodes(*mBand, mP, mGrowth) : frostLevelSet(*fog));
}

} // namespace

namespace {

/// [dla] on a shell domain (DlaEffect::create hands over through ice/DlaBackend.h).
std::unique_ptr<Effect> makeShellDla(const ice::DlaParams& params, ParamDict& d, const World& world)
{
    if (params.release == ice::DlaRelease::Perimeter) {
        if (bandOf(world.domain)->borderEdgeCount() == 0) d.fail("release", "perimeter on a shell releases on the open mesh's border; this mesh is closed (allowed: uniform)");
    }
    // Walkers are released over the whole surface and walk anywhere on it, so the lazily built
    // band is built whole here, before any effect sizes its arrays to it (docs/shells.md: with
    // [dla] memory follows the mesh's area; the phase field's active region still steps only
    // the leaves near the ice).
    const auto band = bandOf(world.domain);
    checkMemoryEstimate(wholeBandEstimate(world.domain), world.memoryLimitBytes, world.sceneLabel);
    try {
        band->materialiseAll();
    } catch (const std::runtime_error& e) {
        d.fail("release", std::string("walkers need the whole shell band: ") + e.what());
    }
    return std::make_unique<ShellDlaEffect>(params);
}

} // namespace

FROSTVDB_REGISTER_DLA_BACKEND(shell, (std::vector<std::string>{"surface", "closest_point"}), makeShellDla);

} // namespace frostvdb::shell
