/// @file DlaEffect.cpp
/// @brief Section [dla]: reads its keys, runs the walkers of each step in deterministic batches
/// and applies their sticks (hits, freezing, heat, growth) in walker order.
#include <frostvdb/core/FieldEdits.h>
#include <frostvdb/core/FieldWriters.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/core/Progress.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/core/Stopwatch.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/ice/DlaBackend.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <map>
#include <sstream>
#include <string>

namespace frostvdb {
namespace ice {

FROSTVDB_REGISTER_EFFECT(DlaEffect, "dla",
                         "DLA walkers on the ice p field (ice paper 4.1, 4.3, 4.4): humidity H, sticking (melt) map, "
                         "multiple hits n, heat release L, flow drift, steam humidity, empty-space jumps.");

namespace {
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
constexpr uint64_t kResumeSalt = 0x5E5D3E11ull;
} // namespace

std::unique_ptr<Effect> DlaEffect::create(ParamDict& d, const World& world)
{
    DlaParams p;
    p.humidity = d.getInt("humidity", 300, 0, int64_t(1) << 32, "walkers/step",
                          "H: walkers released per step (all of them, not only those that stick; paper 4.1)");
    const auto sched = d.getFloatArray("humidity_schedule", {}, {}, 0, 1e15, "[step, walkers/step, ...]",
                                       "pairs (from step, H): from that step on H is the new value, e.g. [75, 350] "
                                       "(the paper's Figure 6: 300, then 350 after step 75); empty: H throughout");
    if (sched.size() % 2 != 0) d.fail("humidity_schedule", "needs pairs [step, H, step, H, ...]");
    for (size_t i = 0; i < sched.size(); i += 2) {
        if (sched[i] != std::floor(sched[i]) || sched[i + 1] != std::floor(sched[i + 1]))
            d.fail("humidity_schedule", "steps and walker counts must be whole numbers");
        if (i > 0 && sched[i] <= sched[i - 2]) d.fail("humidity_schedule", "steps must increase");
        p.schedule.emplace_back(int64_t(sched[i]), int64_t(sched[i + 1]));
    }
    const std::string rel = d.getString("release", "uniform", {"uniform", "perimeter"},
                                        "where walkers start: uniform over the domain's empty cells, or on its "
                                        "perimeter (the cells of its edges/faces); on a shell: uniform by area "
                                        "over the surface, or on the open mesh's border");
    p.release = rel == "perimeter" ? DlaRelease::Perimeter : DlaRelease::Uniform;
    p.hits = int(d.getInt("hits", 1, 1, 1000000, "walkers",
                          "n, multiple-hit averaging: a cell freezes after n walkers stuck at it (1: plain DLA; "
                          "larger is more regular)"));
    p.heatRelease = d.getFloat("heat_release", -1.0, -1.0, 100.0, "",
                               "L, heat released into T per unit of p a walker freezes (eq. 6); -1: K/6 with K "
                               "the phase field's latent_heat");
    p.dt = d.getFloat("dt", 0.0002, 1e-8, 1e3, "",
                      "time step of the ice clock when no [phase_field] runs (freeze_time = step * dt, drift vel*dt)");
    p.flowDrift = d.getFloat("flow_drift", 1.0, 0.0, 1e6, "",
                             "scale of the flow drift: each walker step adds flow_drift * vel * dt (in cells) "
                             "where the field flow_vel ([fluid]) exists (paper 4.3)");
    p.maxSteps = d.getInt("max_steps", 0, 0, int64_t(1) << 50, "steps",
                          "walker lifetime in lattice steps (a jump counts its mean duration); 0: until it "
                          "sticks or leaves the domain");
    p.jumps = d.getBool("jumps", true,
                        "empty-space jumps: far from the ice a walker jumps to the exact first-passage point of "
                        "the largest free lattice ball around it (same statistics, far fewer steps)");
    p.sphereJumps = d.getBool("sphere_jumps", true,
                              "beyond the largest jump table: walk-on-spheres jumps (a uniform exit point on the "
                              "largest free circle/sphere, the lattice walk's continuum limit), so a walker far "
                              "from the ice needs a few jumps whatever the domain size; false: tables only");
    p.jumpMinRadius = int(d.getInt("jump_min_radius", 3, 2, 1000, "cells",
                                   "smallest jump radius (below it walkers step cell by cell)"));
    p.jumpMaxRadius = int(d.getInt("jump_max_radius", 0, 0, 1000, "cells",
                                   "largest exact jump table radius (beyond it: sphere_jumps); 0: 128 on a plane, "
                                   "32 in a box; on a shell the largest geodesic jump, 0: 64"));
    p.batch = int(d.getInt("batch", 1024, 1, int64_t(1) << 30, "walkers",
                           "walkers per parallel batch: a batch walks against the ice at its start, sticks are "
                           "applied in walker order (smaller is closer to the paper's one-by-one release)"));
    p.steamHumidity = d.getFloat("steam_humidity", 0.0, 0.0, 1e6, "1/density",
                                 "gain of the local steam density (field `density` of the gas effects) on the "
                                 "release: cells release H/N (1 + gain * density) walkers per step; 0: off");
    p.steamReach = d.getFloat("steam_reach", 0.05, 0.0, 1e3, "m",
                              "on a plane: steam up to this height above it counts, weighted 1 - height/reach "
                              "(column maximum); 0: the plane's own height only");
    d.onlyWhen(p.jumps, "jump_min_radius", "jumps = false");
    d.onlyWhen(p.jumps, "jump_max_radius", "jumps = false");
    if (p.jumpMaxRadius > 0 && p.jumpMaxRadius < p.jumpMinRadius)
        d.fail("jump_max_radius", "must be 0 or >= jump_min_radius");
    // the walkers the domain's discretisation asks for (ice/DlaBackend.h)
    const std::string discretisation = world.domain ? world.domain.discretisation() : "lattice";
    const DlaBackendFactory* make = DlaBackends::find(discretisation);
    if (!make)
        throw SceneError(world.sceneLabel, 0, "domain.kind",
                         "[dla] has no walkers for the domain's discretisation \"" + discretisation + "\"");
    return (*make)(p, d, world);
}

namespace {

/// A walk's end in the step's statistics.
void accountWalk(DlaStats& stats, const WalkEnd& e)
{
    stats.moves += e.moves;
    stats.jumps += e.jumps;
    stats.latticeSteps += e.latticeSteps;
    if (e.kind == WalkEnd::Killed) ++stats.killed;
    if (e.kind == WalkEnd::Exhausted) ++stats.exhausted;
}

/// A step of millions of walkers is one long step (minutes with a high humidity on a small
/// domain, where every walker must find the ice): a progress bar says how far it is instead of
/// going silent (null for shorter steps, or without a terminal).
std::unique_ptr<Progress> stepProgress(const World& world, int64_t step, uint64_t total)
{
    constexpr uint64_t kProgressWalkers = uint64_t(1) << 20;
    if (!world.progress || total < kProgressWalkers) return nullptr;
    return std::make_unique<Progress>("dla step " + std::to_string(step), int64_t(total), "walkers");
}

std::unique_ptr<Effect> makeLatticeDla(const DlaParams& p, ParamDict&, const World& world)
{
    if (world.domain && world.domain.bbox().min() != openvdb::Coord(0)) // the dense walker arrays index from 0
        throw SceneError(world.sceneLabel, 0, "domain.origin",
                         "[dla] needs a domain whose first cell is at the world origin (origin = [0, 0, 0])");
    return std::make_unique<DlaEffect>(p);
}

std::map<std::string, DlaBackendFactory>& dlaBackendRegistry()
{
    static std::map<std::string, DlaBackendFactory> r;
    return r;
}

} // namespace

void DlaBackends::add(const std::vector<std::string>& discretisations, DlaBackendFactory make)
{
    for (const auto& name : discretisations) dlaBackendRegistry()[name] = make;
}

const DlaBackendFactory* DlaBackends::find(const std::string& discretisation)
{
    const auto it = dlaBackendRegistry().find(discretisation);
    return it == dlaBackendRegistry().end() ? nullptr : &it->second;
}

FROSTVDB_REGISTER_DLA_BACKEND(lattice, {"lattice"}, makeLatticeDla);

FieldDeclaration DlaEffect::declaration() const
{
    FieldDeclaration d;
    d.stage = Stage::Walkers;
    d.use(kClock, kReadsAtInit | kReads) // falls back to its own dt without [phase_field]
        .use(kPhase, kReadsAtInit | kReads | kWrites)
        .use(kTemperature, kInitialises | kWrites)
        .use(kGrowth, kInitialises | kWrites)
        .use(kFreezeTime, kInitialises | kWrites)
        .use(kMelt, kReads)
        .use(kVelocity, kReads)
        .use(gas::kDensity, kReads);
    if (mParams.hits > 1) d.use(kDlaHits, kInitialises | kReads | kWrites);
    d.output(out::kIce).output(out::kIceTemperature).output(out::kGrowth).output(out::kFreezeTime);
    return d;
}

void DlaEffect::initialize(World& world)
{
    IceShared& sh = shared(world);
    if (!sh.dtOwnedByPhaseField) sh.dt = mParams.dt;
    requireIceFields(world);
    mHeat = mParams.heatRelease < 0 ? sh.latentHeat / 6.0 : mParams.heatRelease;
    // Every cell this effect writes in p and T is listed (freezeCell), so the phase field can grow
    // its active region around the new ice instead of rebuilding it (core/FieldEdits.h).
    FieldEdits& edits = world.state<FieldEdits>();
    edits.reports(kPhase.name, this);
    edits.reports(kTemperature.name, this);
    // The phase field lists the cells where p crossed 1/2: the distance map reads those alone
    // when every other writer of p lists them (step()).
    edits.listenCrossings(kPhase.name);
    edits.crossingCells(kPhase.name).clear(); // sync() below reads all of p
    if (mParams.hits > 1 && !world.fields.has(kDlaHits)) {
        auto g = world.fields.require<openvdb::Int32Grid>(kDlaHits, 0);
        if (plane::foldsPlaneFields(world.domain)) plane::markFolded(*g); // 8x denser (core/PlaneFold.h)
    }
    const auto t0 = Clock::now();
    mEngine = std::make_unique<DlaEngine>(world.domain, mParams, world.seed);
    if (mParams.hits > 1) {
        // counts in a flat hash map while walking (a VDB probe per stick costs more than the walk
        // near the ice); the field dla_hits is refreshed from them at the end of every step
        loadHitCounts(world);
    }
    mStats.tableSeconds += since(t0);
    mEngine->sync(*world.fields.get<openvdb::FloatGrid>(kPhase));
    mTime = 0;
}

void DlaEffect::updateSteam(World& world)
{
    auto density = world.fields.get<openvdb::FloatGrid>(gas::kDensity);
    if (!density) {
        mSteamSource.reset();
        mSteamCdf.clear();
        mSteamCells.clear();
        mSteamSum = 0;
        return;
    }
    if (density == mSteamSource) return; // the gas publishes a new grid each frame
    mSteamSource = density;
    mSteamCdf.clear();
    mSteamCells.clear();
    mSteamSum = 0;
    if (density->activeVoxelCount() == 0) return;
    const Domain& dom = world.domain;
    const auto xf = dom.transform();
    const auto& dxf = density->transform();
    const bool surface = dom.hasFrame(); // steam above the surface along its normal counts
    const bool plane = dom.flat();       // a flat surface: project the gas's bounds onto its layer
    const double reach = surface ? mParams.steamReach : 0.0;
    const double dz = dxf.voxelSize()[2];
    const int samples = reach > 0 ? std::max(1, int(std::ceil(reach / dz))) : 0;
    // the domain cells under the density's world bounding box
    const openvdb::CoordBBox ib = density->evalActiveVoxelBoundingBox();
    openvdb::CoordBBox cells;
    for (int cx = 0; cx < 2; ++cx)
        for (int cy = 0; cy < 2; ++cy)
            for (int cz = 0; cz < 2; ++cz) {
                const openvdb::Vec3d corner(cx ? ib.max().x() + 0.5 : ib.min().x() - 0.5,
                                            cy ? ib.max().y() + 0.5 : ib.min().y() - 0.5,
                                            cz ? ib.max().z() + 0.5 : ib.min().z() - 0.5);
                const openvdb::Vec3d w = dxf.indexToWorld(corner);
                openvdb::Vec3d q = xf->worldToIndex(w);
                if (plane) q.z() = dom.bbox().min().z();
                cells.expand(openvdb::Coord::floor(q));
                cells.expand(openvdb::Coord::floor(q) + openvdb::Coord(1));
            }
    cells.intersect(dom.bbox());
    if (cells.empty()) return;
    const openvdb::Coord lo = cells.min(), dim = cells.dim();
    std::vector<float> w(size_t(dim.x()) * dim.y() * dim.z(), 0.f);
    tbb::parallel_for(tbb::blocked_range<int>(0, dim.y() * dim.z()), [&](const tbb::blocked_range<int>& r) {
        auto acc = density->getConstAccessor();
        for (int row = r.begin(); row != r.end(); ++row) {
            const int j = lo.y() + row % dim.y(), k = lo.z() + row / dim.y();
            for (int i = lo.x(); i < lo.x() + dim.x(); ++i) {
                const openvdb::Vec3d p = xf->indexToWorld(openvdb::Vec3d(i, j, k));
                const openvdb::Vec3d up = surface ? dom.frame(openvdb::Coord(i, j, k)).normal : openvdb::Vec3d(0, 0, 1);
                float best = 0.f;
                for (int s = 0; s <= samples; ++s) {
                    const double h = s * dz;
                    if (reach > 0 && h > reach) break;
                    const float wgt = reach > 0 ? float(1.0 - h / reach) : 1.f;
                    const float v = acc.getValue(dxf.worldToIndexNodeCentered(p + up * h));
                    best = std::max(best, v * wgt);
                }
                w[size_t(i - lo.x()) + size_t(dim.x()) * size_t(row)] = best;
            }
        }
    });
    double sum = 0;
    for (int row = 0; row < dim.y() * dim.z(); ++row)
        for (int i = 0; i < dim.x(); ++i) {
            const float v = w[size_t(i) + size_t(dim.x()) * size_t(row)];
            if (!(v > 0.f)) continue;
            sum += v;
            mSteamCdf.push_back(sum);
            mSteamCells.push_back(mEngine->index(
                openvdb::Coord(lo.x() + i, lo.y() + row % dim.y(), lo.z() + row / dim.y())));
        }
    mSteamSum = sum;
}

void DlaEffect::syncDistances(World& world, const openvdb::FloatGrid& p)
{
    // The cells where p crossed 1/2 since the last step, when every other writer of p lists
    // them (core/FieldEdits.h); else all of p is read. FROSTVDB_FULL_DISTANCE_SYNC=1 forces
    // the full read (tests compare the two).
    FieldEdits& edits = world.state<FieldEdits>();
    const FieldWriters* w = world.hasState<FieldWriters>() ? &world.state<FieldWriters>() : nullptr;
    const char* full = std::getenv("FROSTVDB_FULL_DISTANCE_SYNC");
    const bool listed = w && w->of(kPhase.name) - 1 == edits.crossingReporters(kPhase.name) &&
                        !(full && *full && std::string(full) != "0");
    auto& cells = edits.crossingCells(kPhase.name);
    if (listed) mEngine->syncCells(p, cells);
    else mEngine->sync(p);
    cells.clear();
}

int64_t DlaEffect::walkerInputs(World& world, const StepInfo& info, double dt, int64_t H,
                                const openvdb::FloatGrid* melt, const openvdb::Vec3SGrid* vel, DlaEngine::Inputs& in)
{
    int64_t extra = 0;
    in.melt = melt;
    in.baseWalkers = H;
    if (mParams.steamHumidity > 0) {
        const auto t0 = Clock::now();
        updateSteam(world);
        if (mSteamSum > 0) {
            const double e = double(H) * mParams.steamHumidity * mSteamSum / double(mEngine->cellCount());
            extra = int64_t(std::floor(e));
            if (toUnit(hashCounters(mEngine->seed(), 0x57EA4ull, uint64_t(info.step))) < e - std::floor(e)) ++extra;
            in.steamCdf = &mSteamCdf;
            in.steamCells = &mSteamCells;
        }
        mStats.steamSeconds += since(t0);
    }
    if (vel) {
        in.vel = vel;
        in.velOnDomainTransform = vel->transform() == *world.domain.transform();
        // world displacement -> index cells, times dt and the user's scale
        const auto xf = world.domain.transform();
        const openvdb::Vec3d o = xf->worldToIndex(openvdb::Vec3d(0.0));
        for (int b = 0; b < 3; ++b) {
            openvdb::Vec3d e(0.0);
            e[b] = 1.0;
            const openvdb::Vec3d col = xf->worldToIndex(e) - o;
            for (int a = 0; a < 3; ++a) in.velToCells(a, b) = col[a] * dt * mParams.flowDrift;
        }
    }
    return extra;
}

int64_t DlaEffect::resumeStart(const WalkEnd& e, const Domain& domain, int64_t step, uint64_t walker) const
{
    int64_t start = e.prev >= 0 && !mEngine->isIce(e.prev) ? e.prev : -1;
    if (start < 0) {
        const auto& nb = mEngine->neighbours();
        const openvdb::Coord c = mEngine->coord(e.cell);
        const uint64_t h = hashCounters(mEngine->seed(), kResumeSalt, uint64_t(step), walker);
        for (size_t k = 0; k < nb.size() && start < 0; ++k) {
            const openvdb::Coord q = c + nb[(h + k) % nb.size()];
            if (domain.contains(q) && !mEngine->isIce(mEngine->index(q))) start = mEngine->index(q);
        }
    }
    return start;
}

void DlaEffect::loadHitCounts(const World& world)
{
    mHitCount.clear();
    if (auto g = world.fields.get<openvdb::Int32Grid>(kDlaHits)) {
        const bool fold = plane::isFolded(*g);
        for (auto it = g->cbeginValueOn(); it; ++it) {
            const openvdb::Coord c = fold ? plane::unfold(it.getCoord()) : it.getCoord();
            if (world.domain.contains(c)) mHitCount.insert(uint64_t(mEngine->index(c))).first->count = *it;
        }
    }
}

bool DlaEffect::countHit(int64_t cell, uint32_t listedStamp, std::vector<int64_t>& touched)
{
    HitCount& h = *mHitCount.insert(uint64_t(cell)).first;
    if (h.listed != listedStamp) { // the first stick at this cell this step
        h.listed = listedStamp;
        touched.push_back(cell);
    }
    if (++h.count < mParams.hits) return false;
    h.count = 0;
    return true;
}

void DlaEffect::updateHitCounts(const openvdb::FloatGrid& p, openvdb::Int32Grid& hits, std::vector<int64_t>& touched,
                                int64_t step)
{
    std::sort(touched.begin(), touched.end()); // each cell once (countHit); sorted for the accessor
    // dla_hits may be folded (core/PlaneFold.h): cells are plane cells, leaves stored leaves
    const bool fold = plane::isFolded(hits);
    auto stored = [fold](const openvdb::Coord& c) { return fold ? plane::fold(c) : c; };
    auto hAcc = hits.getAccessor();
    std::vector<openvdb::Coord> emptied; // stored leaves where a count went back to 0 (the cell froze)
    for (int64_t cell : touched) {
        const HitCount* found = mHitCount.find(uint64_t(cell));
        const int32_t n = found ? found->count : 0;
        const openvdb::Coord c = stored(mEngine->coord(cell));
        if (n > 0) hAcc.setValue(c, n);
        else {
            hAcc.setValueOff(c, 0);
            emptied.push_back(c & ~openvdb::Coord::ValueType(openvdb::Int32Tree::LeafNodeType::DIM - 1));
        }
    }
    // Counts live at the front only. A count under ice (p > 1/2, frozen by the walkers or
    // grown over by the phase field) is dead: walkers stick beside the ice, never on it, and
    // a cell that melts again starts from zero. Leaves left without counts are deleted, so
    // the field follows the front, not the ice (it held a leaf wherever ice grew: 150 MB on
    // the 16384^2 pane). The sweep over all counts runs every 16th step (keyed by the step,
    // so a resumed run sweeps when an uninterrupted one does); every step it cost Figure 7
    // 0.5 s.
    const bool sweep = (step + 1) % 16 == 0;
    if (sweep) {
        auto pAcc = p.getConstAccessor();
        const bool foldP = plane::isFolded(p);
        std::vector<openvdb::Coord> underIce;
        for (auto it = hits.cbeginValueOn(); it; ++it) {
            const openvdb::Coord c = fold ? plane::unfold(it.getCoord()) : it.getCoord();
            if (pAcc.getValue(foldP ? plane::fold(c) : c) > 0.5f) underIce.push_back(c);
        }
        for (const auto& c : underIce) {
            hAcc.setValueOff(stored(c), 0);
            if (HitCount* n = mHitCount.find(uint64_t(mEngine->index(c)))) n->count = 0;
            emptied.push_back(stored(c) & ~(openvdb::Int32Tree::LeafNodeType::DIM - 1));
        }
    }
    std::sort(emptied.begin(), emptied.end());
    emptied.erase(std::unique(emptied.begin(), emptied.end()), emptied.end());
    hAcc.clear(); // leaves are deleted below
    for (const auto& o : emptied) {
        using HitLeaf = openvdb::Int32Tree::LeafNodeType;
        const HitLeaf* leaf = hits.tree().probeConstLeaf(o);
        if (leaf && leaf->isEmpty()) delete hits.tree().stealNode<HitLeaf>(o, 0, false);
    }
    // The map keeps a slot for every cell ever hit (zeroed when it froze): rebuilt from the
    // live counts when those are under a quarter of it, so it follows the front as well.
    if (sweep && mHitCount.size() > 4 * hits.activeVoxelCount() + 4096) {
        KeyMap<HitCount> fresh;
        for (auto it = hits.cbeginValueOn(); it; ++it)
            fresh.insert(uint64_t(mEngine->index(fold ? plane::unfold(it.getCoord()) : it.getCoord()))).first->count = *it;
        mHitCount = std::move(fresh);
    }
}

void DlaEffect::step(World& world, const StepInfo& info)
{
    IceShared& sh = shared(world);
    auto p = world.fields.get<openvdb::FloatGrid>(kPhase);
    auto T = world.fields.get<openvdb::FloatGrid>(kTemperature);
    if (T && T->treePtr().use_count() > 2) { // (the grid's + this copy) a frame shares it: keep its snapshot
        T = T->deepCopy();
        world.fields.replace(kTemperature, T);
    }
    auto growth = world.fields.get<openvdb::FloatGrid>(kGrowth);
    auto freeze = world.fields.get<openvdb::FloatGrid>(kFreezeTime);
    auto hitsGrid = world.fields.get<openvdb::Int32Grid>(kDlaHits);
    auto melt = world.fields.get<openvdb::FloatGrid>(kMelt);
    auto vel = world.fields.get<openvdb::Vec3SGrid>(kVelocity);

    auto t0 = Clock::now();
    syncDistances(world, *p);
    mStats.syncSeconds += since(t0);

    const int64_t H = mParams.humidityAt(info.step);
    DlaEngine::Inputs in;
    const int64_t extra = walkerInputs(world, info, sh.dt, H, melt.get(), vel.get(), in);

    ownTree(*growth); // written in place: a frame may share the trees
    ownTree(*freeze);
    auto pAcc = p->getAccessor();
    auto gAcc = growth->getAccessor();
    auto fAcc = freeze->getAccessor();
    // On a plane the accumulators, and p and T once the phase field folds them, are written at fold(c).
    const bool foldAcc = plane::isFolded(*growth);
    if (foldAcc != plane::isFolded(*freeze)) throw std::logic_error("growth_acc and freeze_time differ in layout");
    const bool foldP = plane::isFolded(*p), foldT = T && plane::isFolded(*T);
    std::unique_ptr<openvdb::FloatGrid::Accessor> tAcc;
    if (T && sh.temperatureEvolves && mHeat != 0) tAcc = std::make_unique<openvdb::FloatGrid::Accessor>(T->getAccessor());
    const bool counting = hitsGrid && mParams.hits > 1;
    std::vector<int64_t> touched;
    const uint32_t listedStamp = uint32_t(info.step + 1);
    // the cells written in p (and T at the same cell) for whoever keeps state about them
    std::vector<openvdb::Coord>* editsP = world.state<FieldEdits>().sink(kPhase.name);
    std::vector<openvdb::Coord>* editsT = tAcc ? world.state<FieldEdits>().sink(kTemperature.name) : nullptr;
    const double time = sh.timeAtStep(info.step);

    std::vector<int64_t> frozenInBatch; // cells frozen since the batch's walks began
    auto freezeCell = [&](int64_t cell) {
        frozenInBatch.push_back(cell);
        const openvdb::Coord c = mEngine->coord(cell);
        const openvdb::Coord cp = foldP ? plane::fold(c) : c, ct = foldT ? plane::fold(c) : c;
        const float before = pAcc.getValue(cp);
        pAcc.setValue(cp, 1.f);
        if (editsP) editsP->push_back(c);
        if (editsT) editsT->push_back(c);
        recordPhaseChange(gAcc, fAcc, foldAcc ? plane::fold(c) : c, before, 1.f, time);
        if (tAcc) tAcc->setValue(ct, tAcc->getValue(ct) + float(mHeat * (1.0 - double(before))));
        mEngine->freezeDeferred(cell); // distances relaxed once per batch (or before a resumed walk)
        ++mStats.frozen;
        mStats.dpDla += 1.0 - double(before);
    };
    auto hit = [&](int64_t cell) {
        ++mStats.stuck;
        if (!counting || countHit(cell, listedStamp, touched)) freezeCell(cell);
    };
    auto account = [this](const WalkEnd& e) { accountWalk(mStats, e); };

    const uint64_t total = uint64_t(H + extra);
    mStats.released += total;
    std::vector<WalkEnd> ends;
    std::unique_ptr<Progress> progress = stepProgress(world, info.step, total);
    for (uint64_t first = 0; first < total; first += uint64_t(mParams.batch)) {
        const uint64_t count = std::min<uint64_t>(uint64_t(mParams.batch), total - first);
        t0 = Clock::now();
        const double c0 = processCpuSeconds();
        mEngine->walkBatch(info.step, first, count, in, ends);
        mStats.walkSeconds += since(t0);
        mStats.walkCpuSeconds += processCpuSeconds() - c0;
        t0 = Clock::now();
        frozenInBatch.clear();
        // The walks stuck next to the ice of the batch's start, never on it, so a stick cell is
        // ice now only if it froze in this batch: a short list, not a random probe per walker.
        auto frozeInBatch = [&](int64_t cell) {
            if (frozenInBatch.size() > 64) return mEngine->isIce(cell); // the same answer, cheaper now
            return std::find(frozenInBatch.begin(), frozenInBatch.end(), cell) != frozenInBatch.end();
        };
        constexpr uint64_t kAhead = 8; // hit counts: start loading the slot a few walkers ahead
        for (uint64_t w = 0; w < count; ++w) {
            if (counting && w + kAhead < count && ends[size_t(w + kAhead)].kind == WalkEnd::Stuck)
                mHitCount.prefetch(uint64_t(ends[size_t(w + kAhead)].cell));
            WalkEnd e = ends[size_t(w)];
            account(e);
            if (e.kind != WalkEnd::Stuck) continue;
            if (frozeInBatch(e.cell)) {
                // its cell froze earlier in this batch: the walker goes on from where it came
                // from (or a free neighbour), serially, against the current ice
                ++mStats.conflicts;
                const int64_t start = resumeStart(e, world.domain, info.step, first + w);
                if (start < 0) continue;
                mEngine->flushDistances();
                e = mEngine->walk(info.step, first + w, kResumeSalt, start, in);
                account(e);
                if (e.kind != WalkEnd::Stuck) continue;
            }
            hit(e.cell);
        }
        mEngine->flushDistances();
        mStats.applySeconds += since(t0);
        if (progress) progress->update(int64_t(first + count));
    }
    if (progress) progress->finish();
    if (counting) {
        t0 = Clock::now();
        updateHitCounts(*p, *hitsGrid, touched, info.step);
        mStats.applySeconds += since(t0);
    }
    mTime = sh.timeAtStep(info.step + 1);
}

MemoryEstimate DlaEffect::memoryEstimate(const World& world) const
{
    // Walkers released over the run (the humidity schedule's segments), each freezing at most
    // 1/hits of a cell.
    const int64_t steps = world.frames * world.stepsPerFrame;
    double walkers = 0;
    int64_t from = 0;
    for (size_t i = 0; i <= mParams.schedule.size() && from < steps; ++i) {
        const int64_t to = i < mParams.schedule.size() ? std::min(steps, std::max(from, mParams.schedule[i].first)) : steps;
        walkers += double(mParams.humidityAt(from)) * double(to - from);
        from = to;
    }
    const double frozen = walkers / double(mParams.hits);
    // Per frozen cell, measured on a 512^2 plane where 200,000 walkers froze 64,000 cells in one
    // step: 22 MiB above the program's own, about 350 bytes (the four fields' leaves around the
    // ice, the walkers' distance bricks and block pyramid, the frame's copies).
    constexpr double kPerFrozenCell = 350.0;
    // However many walkers, the ice fills at most the domain: then the fields are the dense
    // phase field's, 80 bytes per plane cell (a box's leaves hold 8 layers, 1/8 of that per
    // cell). Measured on the 512^2 plane 200,000 walkers fill in one step: 16.2 MiB above the
    // program's own on the square and the hexagonal lattice, 65 bytes per cell, since frames
    // export the folded fields in place and make freeze_time only when written (session 14;
    // 112 bytes before, the plane-layout copies included). Session 18 (the staging per region
    // plane leaf, the streamed writer, the walkers' brick directory): 13.0-15.9 MiB, 52-64 bytes;
    // charged 70 (80 read 1.53x of a 13.0 MiB peak in a parallel ctest, over Probe 25.2's 1.5).
    const Domain& dom = world.domain;
    const double cells = double(dom.bbox().volume());
    const double perCell = 70.0 / std::clamp(double(dom.bbox().dim().z()), 1.0, 8.0);
    const bool filled = cells * perCell < frozen * kPerFrozenCell;
    char what[240];
    if (filled)
        std::snprintf(what, sizeof what, "the ice filling the domain: %.4g cells x %.0f bytes of fields (%.3g walkers)",
                      cells, perCell, walkers);
    else
        std::snprintf(what, sizeof what, "%.3g walkers freezing at most %.4g cells x %.0f bytes of fields and distances",
                      walkers, frozen, kPerFrozenCell);
    return {filled ? cells * perCell : frozen * kPerFrozenCell, filled ? "domain.size" : "dla.humidity", what};
}

void DlaEffect::addToFrame(World& world, Frame& frame) { addIceOutputs(world, frame); }

// Walkers live within one step and draw from streams keyed by (seed, step, walker), so the step
// counter (saved by the driver) is their whole random state. The engine's distance maps are a
// pure function of the ice (p > 1/2: the capped BFS minimum), the hit counts are the field
// dla_hits and the steam map is rebuilt from the field density: all come back from the fields.
void DlaEffect::saveState(const World&, StateWriter& out) const
{
    out.putDouble("time", mTime);
    const uint64_t counters[] = {mStats.released, mStats.stuck,     mStats.frozen, mStats.killed,
                                 mStats.exhausted, mStats.conflicts, mStats.moves,  mStats.jumps};
    out.putArray("stats", std::vector<uint64_t>(std::begin(counters), std::end(counters)));
    out.putDouble("lattice_steps", mStats.latticeSteps);
    out.putDouble("dp_dla", mStats.dpDla);
}

void DlaEffect::loadState(World& world, const StateReader& in)
{
    mTime = in.getDouble("time");
    std::vector<uint64_t> c;
    in.getArray("stats", c);
    if (c.size() != 8) in.fail("stats", "expected 8 counters");
    mStats.released = c[0], mStats.stuck = c[1], mStats.frozen = c[2], mStats.killed = c[3];
    mStats.exhausted = c[4], mStats.conflicts = c[5], mStats.moves = c[6], mStats.jumps = c[7];
    mStats.latticeSteps = in.getDouble("lattice_steps");
    mStats.dpDla = in.getDouble("dp_dla");
    mEngine->sync(*world.fields.get<openvdb::FloatGrid>(kPhase));
    world.state<FieldEdits>().crossingCells(kPhase.name).clear(); // all of p was read
    if (mParams.hits > 1) {
        loadHitCounts(world);
    }
    mSteamSource.reset(); // rebuilt from the restored density at the next step
}

std::vector<std::pair<std::string, double>> DlaEffect::timings() const
{
    return {{"walkers", mStats.walkSeconds},
            {"walkers_cpu", mStats.walkCpuSeconds},
            {"apply", mStats.applySeconds},
            {"distance", mStats.syncSeconds},
            {"steam", mStats.steamSeconds},
            {"tables", mStats.tableSeconds},
            // the distance work by part (walkers' freezes included: their passes run in "apply")
            {"distance_scan", mEngine ? mEngine->work().scanSeconds : 0.0},
            {"distance_relax", mEngine ? mEngine->work().relaxSeconds : 0.0},
            {"distance_blocks", mEngine ? mEngine->work().coarseSeconds : 0.0},
            {"distance_repair", mEngine ? mEngine->work().repairSeconds : 0.0},
            {"distance_rebuild", mEngine ? mEngine->work().rebuildSeconds : 0.0}};
}

std::vector<std::pair<std::string, double>> DlaEffect::counters() const
{
    if (!mEngine) return {{"distance_rebuilds", 0.0}};
    const DlaEngine::Work& w = mEngine->work();
    return {{"distance_rebuilds", double(mEngine->rebuildCount())},
            {"distance_fresh", double(w.fresh)},
            {"distance_melted", double(w.melted)},
            {"distance_relaxed", double(w.relaxed)}};
}

} // namespace ice
} // namespace frostvdb
