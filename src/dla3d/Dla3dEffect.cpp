/// @file Dla3dEffect.cpp
/// @brief [dla3d]: keys, growth schedule over the run's steps, frame output.
#include <frostvdb/dla3d/Dla3dEffect.h>

#include <frostvdb/core/Error.h>
#include <frostvdb/core/Progress.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/io/Preview.h>

#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>

namespace frostvdb::dla3d {

using openvdb::Vec3d;
using Clock = std::chrono::steady_clock;
/// Rasterisations above this many voxel visits (about a second of one core) report progress.
constexpr double kProgressVisits = 1e8;
/// Steps growing at least this many particles report progress (tens of seconds at the default
/// stick distance; measured: 1e6 particles take about 100 s on one core).
constexpr size_t kProgressParticles = size_t(1) << 17;
/// Bytes per particle of its arrays: position 24 + parent and generation 8 + hash chain 4 +
/// attach time 4 bytes, hash slots (16 bytes at load 0.6, two levels) about 54, doubled by vector
/// growth.
constexpr double kParticleBytes = 190.0;
/// Bytes per 8^3 leaf holding particles of the points grid and its index grid (each leaf a 2 KiB
/// offset table, plus attribute arrays): measured 62.7 MiB for 40,000 particles at 1.5 mm.
constexpr double kPointLeafBytes = 4500.0;
/// Peak bytes of a frame's level set per leaf of it, in leaves of floatLeafBytes(): the tree
/// with its interior, the threads' partial trees joined into it, then the fog made from it
/// (measured: 4,350 bytes per leaf at 1.5 mm, 40,000 particles).
constexpr double kRasterPeakPerLeaf = 2.0;
/// The keys' model of the leaves (modelledLeaves): a typical branch carries this many particles,
/// a leaf's voxels reach this many voxels beyond what it holds (a cube of 8 has a mean half
/// width of 6), and a ball of radius R around a particle of the aggregate holds
/// (R / spacing)^D / cover particles at these scales (measured on free aggregates of 40,000
/// particles at 0.75-5 mm voxels and 1.5-5 mm radii: D 2.0, cover 3.9 in 3D; D 1.71, cover 4.3
/// for a flat one, dimension = 2).
constexpr double kTypicalCarried = 3.0;
constexpr double kLeafReachVoxels = 6.0;
constexpr double kClusterDimension3 = 2.0, kClusterCover3 = 3.9;
constexpr double kClusterDimension2 = 1.71, kClusterCover2 = 4.3;

namespace {

Vec3d vec3(const std::vector<double>& v, size_t at = 0) { return Vec3d(v[at], v[at + 1], v[at + 2]); }

MeshPlacement readPlacement(ParamDict& d, const std::string& prefix, const std::string& what)
{
    MeshPlacement m;
    const auto s = d.getFloatArray(prefix + "_scale", {1.0}, {1, 3}, -1e6, 1e6, "",
                                   "scale of the " + what + " mesh (one factor or x, y, z), applied first");
    m.scale = s.size() == 1 ? Vec3d(s[0]) : vec3(s);
    m.rotateDegrees = vec3(d.getFloatArray(prefix + "_rotate", {0, 0, 0}, {3}, -3600, 3600, "deg",
                                           "rotation of the " + what + " mesh about x, then y, then z"));
    m.translate = vec3(d.getFloatArray(prefix + "_translate", {0, 0, 0}, {3}, -1e6, 1e6, "m",
                                       "translation of the " + what + " mesh, applied last"));
    return m;
}

/// A mesh path as written, or relative to the scene file's folder when it exists there.
std::string resolvePath(const std::string& file, const std::string& sceneLabel)
{
    namespace fs = std::filesystem;
    if (file.empty() || fs::path(file).is_absolute() || fs::exists(file)) return file;
    const fs::path beside = fs::path(sceneLabel).parent_path() / file;
    return fs::exists(beside) ? beside.string() : file;
}

} // namespace

std::unique_ptr<Effect> Dla3dEffect::create(ParamDict& d, const World& world)
{
    auto fx = std::make_unique<Dla3dEffect>();
    DlaSettings& s = fx->mSettings;
    Options& o = fx->mOptions;
    o.sceneLabel = world.sceneLabel;
    s.dimension = int(d.getInt("dimension", 3, 2, 3, "", "3: a volume aggregate; 2: a flat one in the z = 0 plane"));
    o.particles = d.getInt("particles", 20000, 1, 100000000, "",
                           "particles at the end of the run (seeds included), grown evenly over its steps");
    s.radius = d.getFloat("radius", 0.005, 1e-6, 1e3, "m", "particle radius; joined particles sit 2 radius apart");
    const double stick = d.getFloat("stick_distance", 0.0, 0.0, 1e3, "m",
                                    "a walker touches the aggregate within 2 radius + this of a particle "
                                    "(0: radius / 2); larger gives coarser, hairier growth and faster runs");
    s.stickDistance = stick > 0 ? stick : 0.5 * s.radius;
    s.stickiness = d.getFloat("stickiness", 1.0, 1e-4, 1.0, "",
                              "probability to attach per touch; below 1 walkers slip deeper: denser aggregates");
    const std::string launch = d.getString("launch", "sphere", {"sphere", "axis", "plane", "surface"},
                                           "where walkers start: a sphere around the aggregate, along an axis "
                                           "segment, on a plane rectangle, or on a mesh surface");
    s.launch = launch == "axis" ? Launch::Axis : launch == "plane" ? Launch::Plane
             : launch == "surface" ? Launch::Surface : Launch::Sphere;
    s.launchMargin = d.getFloat("launch_margin", 0.0, 0.0, 1e6, "m",
                                "sphere launch: launch radius = aggregate radius + this (0: 2 particle spacings + stick)");
    const auto axis = d.getFloatArray("launch_axis", {0, 0, 0, 0, 0, 1}, {6}, -1e6, 1e6, "m",
                                      "axis launch: segment end points A (x, y, z) then B (x, y, z)");
    s.axisA = vec3(axis, 0);
    s.axisB = vec3(axis, 3);
    s.axisSpread = d.getFloat("launch_spread", 0.0, 0.0, 1e6, "m",
                              "axis launch: start points spread uniformly over a disc of this radius around the axis");
    const auto plane = d.getFloatArray("launch_plane", {-0.5, -0.5, 0.5, 1, 0, 0, 0, 1, 0}, {9}, -1e6, 1e6, "m",
                                       "plane launch: origin O, edge U, edge V; starts at O + s U + t V, s, t in [0, 1]");
    s.planeOrigin = vec3(plane, 0);
    s.planeU = vec3(plane, 3);
    s.planeV = vec3(plane, 6);
    o.launchFile = d.getString("launch_mesh", "", {},
                               "surface launch: mesh file (OBJ/STL/PLY) to start on, area-uniform (default: the "
                               "constraint mesh)");
    o.launchPlacement = readPlacement(d, "launch_mesh", "launch");
    s.launchOffset = d.getFloat("launch_offset", 0.0, -1e6, 1e6, "m",
                                "surface launch: start this far off the surface along the triangle normals");
    s.bias = vec3(d.getFloatArray("bias", {0, 0, 0}, {3}, -100, 100, "",
                                  "drift added to each unit step direction (gravity, wind); 0.1-0.5 is gentle"));
    s.rotationAxis = vec3(d.getFloatArray("rotation_axis", {0, 0, 1}, {3}, -1e6, 1e6, "",
                                          "axis (through the centre) the aggregate turns about"));
    const double rot = d.getFloat("rotation", 0.0, -1e6, 1e6, "deg",
                                  "degrees the aggregate turns per 1000 attached particles (turns the launch "
                                  "region and the bias around it; the aggregate's frame is written)");
    s.rotationPerParticle = rot * M_PI / 180.0 / 1000.0;
    if (d.has("centre")) {
        s.centre = vec3(d.getFloatArray("centre", {0, 0, 0}, {3}, -1e6, 1e6, "m",
                                        "centre of the sphere launch, rotation and kill sphere (default: seed centroid)"));
        s.centreGiven = true;
    } else {
        d.getFloatArray("centre", {0, 0, 0}, {3}, -1e6, 1e6, "m",
                        "centre of the sphere launch, rotation and kill sphere (default: seed centroid)");
    }
    o.seedsOnMesh = d.getInt("seeds_on_mesh", 0, 0, 1000000, "",
                             "extra seeds placed area-uniformly on the constraint mesh, one radius off it on "
                             "constraint_side (without a seeds key, the only seeds)");
    const bool seedsGiven = d.has("seeds");
    const auto seeds = d.getFloatArray("seeds", {0, 0, 0}, {}, -1e6, 1e6, "m",
                                       "seed particle positions, x y z triples (several seeds grow several trees); "
                                       "default one seed at the origin unless seeds_on_mesh is set");
    if (seeds.size() % 3 != 0) d.fail("seeds", "needs x, y, z triples (got " + std::to_string(seeds.size()) + " numbers)");
    s.seeds.clear();
    if (seedsGiven || o.seedsOnMesh == 0)
        for (size_t i = 0; i + 2 < seeds.size(); i += 3) s.seeds.push_back(vec3(seeds, i));
    o.constraintFile = d.getString("constraint_mesh", "", {},
                                   "mesh file (OBJ/STL/PLY) growth may not cross: branches crossing a triangle and "
                                   "particles reaching into it are refused (the walker walks on)");
    o.constraintPlacement = readPlacement(d, "constraint", "constraint");
    o.side = d.getString("constraint_side", "front", {"front", "back"},
                         "side of the constraint mesh for seeds_on_mesh: front (where normals point, outside of a "
                         "closed mesh) or back (inside)");
    o.constraintVoxel = d.getFloat("constraint_voxel", 0.0, 0.0, 1e3, "m",
                                   "voxel size of the constraint's distance field pre-test (0: 2 radius)");
    s.killFactor = d.getFloat("kill_factor", 3.0, 1.1, 100.0, "",
                              "non-sphere launches or bias: walkers beyond this x the growth extent restart");
    s.maxBatch = int(d.getInt("batch", 256, 1, 65536, "",
                              "most speculative walkers per parallel batch (see batch_fraction); part of the "
                              "result: changing it changes the aggregate"));
    s.batchFraction = d.getFloat("batch_fraction", 0.0005, 0.0, 1.0, "",
                                 "batch = clamp(particles x this, 1, batch): larger batches run more walkers in "
                                 "parallel but lose more to conflicts (part of the result)");
    s.maxStepsPerWalker = d.getInt("max_walker_steps", 5000000, 100, 1000000000, "",
                                   "steps before a walker gives up (a constraint that blocks all growth)");
    o.voxelSize = d.getFloat("voxel_size", 0.0, 0.0, 1e3, "m", "voxel size of ice_sdf and ice (0: radius)");
    o.style.tipRadius = d.getFloat("branch_radius", 0.0, 0.0, 1e3, "m",
                                   "branch radius at the tips of ice_sdf (0: the particle radius)");
    o.style.taper = d.getFloat("taper", 0.35, 0.0, 1.0, "",
                               "branch radius grows as (particles carried)^taper from the tips to the root");
    o.style.maxScale = d.getFloat("max_thickness", 4.0, 1.0, 100.0, "", "cap on root radius / tip radius");
    o.halfWidth = d.getFloat("half_width", 3.0, 1.0, 20.0, "voxels", "narrow-band half width of ice_sdf");
    o.maxVoxels = d.getFloat("max_voxels", 2e9, 1e3, 1e15, "voxels",
                             "refuse a frame whose ice_sdf and ice would visit more voxels than this (each branch's "
                             "box at voxel_size, summed; counted before a voxel is touched, and a lower bound from "
                             "the keys alone is checked when the scene loads); one core visits about 5e7 per second, so 2e9 is about 40 "
                             "CPU-seconds");
    o.points = d.getBool("write_points", true, "write the PointDataGrid `points`");
    o.sdf = d.getBool("write_sdf", true, "write the level set `ice_sdf`");
    o.fog = d.getBool("write_fog", true, "write the fog volume `aggregate_ice` (from ice_sdf)");
    o.mesh = d.getString("mesh", "none", {"none", "obj", "ply"},
                         "also write ice_sdf as a polygon mesh beside the last preview (<scene>.<frame>.obj/ply)");
    s.seed = world.seed;
    fx->checkOutputKeys(d);
    return fx;
}

/// The output's voxel size (voxel_size, or the particle radius) must be one OpenVDB can build a
/// transform for, and the branches must fit max_voxels even at their thinnest: each particle's
/// capsule box spans at least 2 (tip radius + half_width voxels) on every axis. Refused while
/// loading, before any step.
void Dla3dEffect::checkOutputKeys(ParamDict& d) const
{
    const auto& o = mOptions;
    if (!o.sdf && !o.fog && o.mesh == "none" && !o.points) return;
    const double vox = o.voxelSize > 0 ? o.voxelSize : mSettings.radius;
    const std::string voxKey = o.voxelSize > 0 ? "voxel_size" : "radius";
    // OpenVDB's ScaleMap refuses a determinant below 3e-15 ("Non-zero scale values required")
    if (vox * vox * vox < 3.0001e-15) {
        char buf[240];
        std::snprintf(buf, sizeof buf,
                      "the output voxel of %.3g m is below OpenVDB's smallest (1.45e-05 m: a transform needs a voxel "
                      "volume of 3e-15 m^3)%s",
                      vox, o.voxelSize > 0 ? "" : " (voxel_size = 0 uses the radius)");
        d.fail(voxKey, buf);
    }
    if (!o.sdf && !o.fog && o.mesh == "none") return;
    const double tip = std::max(o.style.tipRadius > 0 ? o.style.tipRadius : mSettings.radius, 0.5 * vox);
    const double side = std::floor(2.0 * (tip + o.halfWidth * vox) / vox);
    const double lower = double(o.particles) * side * side * side;
    if (lower > o.maxVoxels) {
        char buf[400];
        std::snprintf(buf, sizeof buf,
                      "the last frame's branches visit at least %.3g voxels (%lld particles, each a box of at least "
                      "%.0f^3 voxels: branch radius %.3g m plus half_width %.3g voxels at voxel_size %.3g m), more "
                      "than dla3d.max_voxels = %.3g allows: raise voxel_size, lower the radii or particles, or raise "
                      "max_voxels",
                      lower, static_cast<long long>(o.particles), side, tip, o.halfWidth, vox, o.maxVoxels);
        d.fail(o.voxelSize > 0 ? "voxel_size" : "radius", buf);
    }
}

void Dla3dEffect::initialize(World& world)
{
    auto& s = mSettings;
    auto& o = mOptions;
    o.progress = world.progress;
    if (o.style.tipRadius <= 0) o.style.tipRadius = s.radius;
    if (o.voxelSize <= 0) o.voxelSize = s.radius;
    std::shared_ptr<TriangleMesh> constraintMesh;
    auto load = [&](const std::string& key, const std::string& file, const MeshPlacement& pl) {
        try {
            return std::make_shared<TriangleMesh>(loadMesh(resolvePath(file, o.sceneLabel), pl));
        } catch (const std::exception& e) {
            throw SceneError(o.sceneLabel, 0, "dla3d." + key, e.what());
        }
    };
    if (!o.constraintFile.empty()) {
        constraintMesh = load("constraint_mesh", o.constraintFile, o.constraintPlacement);
        const double reach = 2.0 * s.contact() + s.stickDistance;
        const double vox = o.constraintVoxel > 0 ? o.constraintVoxel : s.contact();
        s.constraint = std::make_shared<MeshConstraint>(*constraintMesh, reach, vox);
    }
    if (s.launch == Launch::Surface) {
        if (!o.launchFile.empty()) s.launchMesh = load("launch_mesh", o.launchFile, o.launchPlacement);
        else if (constraintMesh) s.launchMesh = constraintMesh;
        else throw SceneError(o.sceneLabel, 0, "dla3d.launch", "surface launch needs launch_mesh or constraint_mesh");
    }
    if (o.seedsOnMesh > 0) {
        if (!constraintMesh) throw SceneError(o.sceneLabel, 0, "dla3d.seeds_on_mesh", "needs constraint_mesh");
        std::vector<double> cdf;
        double acc = 0;
        for (size_t t = 0; t < constraintMesh->triangles.size(); ++t) cdf.push_back(acc += constraintMesh->area(t));
        const double sign = o.side == "front" ? 1.0 : -1.0;
        CounterRng rng(s.seed, 0x5EED5, 0);
        for (int64_t i = 0; i < o.seedsOnMesh; ++i) {
            const size_t t = std::min<size_t>(
                size_t(std::upper_bound(cdf.begin(), cdf.end(), rng.uniform() * acc) - cdf.begin()), cdf.size() - 1);
            double u = rng.uniform(), v = rng.uniform();
            if (u + v > 1) { u = 1 - u; v = 1 - v; }
            const auto& f = constraintMesh->triangles[t];
            const Vec3d a(constraintMesh->points[f[0]]), b(constraintMesh->points[f[1]]), c(constraintMesh->points[f[2]]);
            s.seeds.push_back(a + (b - a) * u + (c - a) * v + constraintMesh->normal(t) * (sign * s.radius * 1.001));
        }
    }
    if (s.seeds.empty()) throw SceneError(o.sceneLabel, 0, "dla3d.seeds", "no seeds (give seeds or seeds_on_mesh)");
    if (o.particles < int64_t(s.seeds.size()))
        throw SceneError(o.sceneLabel, 0, "dla3d.particles",
                         "fewer particles (" + std::to_string(o.particles) + ") than seeds (" +
                             std::to_string(s.seeds.size()) + ")");
    try {
        mAggregate = std::make_unique<Aggregate>(s);
    } catch (const std::invalid_argument& e) {
        throw SceneError(o.sceneLabel, 0, "dla3d", e.what());
    }
    mAttach.assign(mAggregate->size(), 0.f);
    mTotalSteps = std::max<int64_t>(1, world.frames * world.stepsPerFrame);
}

void Dla3dEffect::step(World& world, const StepInfo& info)
{
    const auto t0 = Clock::now();
    const size_t seeds = mSettings.seeds.size();
    const double grown = double(mOptions.particles - int64_t(seeds));
    const size_t target = seeds + size_t(std::llround(grown * double(info.step + 1) / double(mTotalSteps)));
    // A step of many particles is one long step (a million take minutes): a progress bar says
    // how far it is instead of going silent (issue 25's probe re-run).
    std::unique_ptr<Progress> progress;
    std::function<void(size_t)> report;
    const size_t before = mAggregate->size();
    // (world.progress, read now: the driver sets it after the effects are initialised)
    if (world.progress && target > before && target - before >= kProgressParticles) {
        progress = std::make_unique<Progress>("dla3d step " + std::to_string(info.step + 1), int64_t(target - before),
                                              "particles", true);
        report = [&](size_t size) { progress->update(int64_t(size - before)); };
    }
    const bool grew = mAggregate->growTo(target, report);
    if (progress) progress->finish();
    if (!grew)
        throw SimulationError("dla3d: no walker could attach at step " + std::to_string(info.step) + " with " +
                              std::to_string(mAggregate->size()) +
                              " particles (the constraint blocks all growth, or max_walker_steps is too small)");
    const double denom = std::max(1.0, grown);
    for (size_t i = mAttach.size(); i < mAggregate->size(); ++i) mAttach.push_back(float(double(i - seeds + 1) / denom));
    mGrowSeconds += std::chrono::duration<double>(Clock::now() - t0).count();
}

void Dla3dEffect::addToFrame(World& world, Frame& frame)
{
    const auto t0 = Clock::now();
    const auto& agg = *mAggregate;
    for (const auto& p : agg.positions())
        if (!std::isfinite(p.x()) || !std::isfinite(p.y()) || !std::isfinite(p.z()))
            throw SimulationError("dla3d: non-finite particle position at frame " + std::to_string(frame.frame));
    const auto radii = branchRadii(agg.parents(), mOptions.style);
    if (mOptions.points)
        frame.add(out::kPoints,
                  makePointGrid(agg.positions(), radii, agg.parents(), agg.generations(), mAttach, mOptions.voxelSize));
    mSdf.reset();
    if (mOptions.sdf || mOptions.fog || mOptions.mesh != "none") {
        // Counted before a voxel is touched: a frame over max_voxels is refused, a long one reports progress.
        const double visits = branchVoxelVisits(agg.positions(), agg.parents(), radii, mOptions.voxelSize,
                                                mOptions.halfWidth);
        if (visits > mOptions.maxVoxels) {
            char buf[400];
            std::snprintf(buf, sizeof buf,
                          "frame %lld: the branches of %zu particles visit about %.3g voxels at voxel_size %.3g m "
                          "(thickest branch %.3g m), more than dla3d.max_voxels = %.3g allows: raise voxel_size, "
                          "lower branch_radius or max_thickness, or raise max_voxels",
                          static_cast<long long>(frame.frame), agg.size(), visits, mOptions.voxelSize,
                          radii.empty() ? 0.0 : double(*std::max_element(radii.begin(), radii.end())),
                          mOptions.maxVoxels);
            throw SceneError(mOptions.sceneLabel, 0, mOptions.voxelSize > 0 ? "dla3d.voxel_size" : "dla3d.radius", buf);
        }
        checkFrameBudget(world, frame.frame, radii);
        std::unique_ptr<Progress> progress;
        std::function<void(size_t, size_t)> report;
        if ((mOptions.progress || world.progress) && visits > kProgressVisits) {
            progress = std::make_unique<Progress>("dla3d frame " + std::to_string(frame.frame) + " ice_sdf",
                                                  int64_t(agg.size()), "particles", true);
            report = [&](size_t done, size_t) { progress->update(int64_t(done)); };
        }
        mSdf = rasterizeBranches(agg.positions(), agg.parents(), radii, mOptions.voxelSize, mOptions.halfWidth,
                                 report);
        if (progress) progress->finish();
        mSdf->insertMeta("frostvdb_dla3d_particles", openvdb::Int64Metadata(int64_t(agg.size())));
        if (mOptions.sdf) frame.add(out::kIceSdf, mSdf);
        if (mOptions.fog) {
            auto fog = mSdf->deepCopy();
            openvdb::tools::sdfToFogVolume(*fog);
            frame.add(out::kAggregateIce, fog);
        }
    }
    mOutputSeconds += std::chrono::duration<double>(Clock::now() - t0).count();
}

bool Dla3dEffect::writePreview(World& world, const Frame& frame, const std::string& pngPath)
{
    if (mOptions.mesh != "none" && mSdf) {
        std::vector<openvdb::Vec3s> points;
        std::vector<openvdb::Vec3I> tris;
        std::vector<openvdb::Vec4I> quads;
        openvdb::tools::volumeToMesh(*mSdf, points, tris, quads, 0.0, 0.0);
        const std::string base = pngPath.substr(0, pngPath.size() - 4);
        if (mOptions.mesh == "obj") writeObj(base + ".obj", points, tris, quads);
        else writePly(base + ".ply", points, tris, quads);
    }
    return false; // the driver draws `aggregate_ice` (ray-marched)
}

/// The 8^3 leaves at voxel_size that hold everything within @a reach of the aggregate's
/// particles at the last frame, modelled from the keys before anything grows: each particle adds
/// the volume within reach along its 2 radius to its parent, less what its neighbours share. A
/// cluster of the aggregate within reach holds (reach / spacing)^D / cover particles, so the
/// union takes cover x spacing^D x reach^(3 - D) per particle; a sparse one (reach below the
/// spacing) takes its swept tubes.
double Dla3dEffect::modelledLeaves(double reach) const
{
    const double vox = mOptions.voxelSize > 0 ? mOptions.voxelSize : mSettings.radius;
    const double spacing = 2.0 * mSettings.radius;
    const double tube = M_PI * reach * reach * spacing;
    const bool flat = mSettings.dimension == 2;
    const double dim = flat ? kClusterDimension2 : kClusterDimension3;
    const double shared = (flat ? kClusterCover2 : kClusterCover3) * std::pow(spacing, dim) * std::pow(reach, 3.0 - dim);
    return double(mOptions.particles) * std::min(tube, shared) / (512.0 * vox * vox * vox);
}

/// The level set's leaves: a typical branch (the tip grown by the taper), its half width, and the
/// reach of a leaf's voxels.
double Dla3dEffect::modelledSdfLeaves() const
{
    const auto& o = mOptions;
    const double vox = o.voxelSize > 0 ? o.voxelSize : mSettings.radius;
    const double tip = o.style.tipRadius > 0 ? o.style.tipRadius : mSettings.radius;
    const double branch = std::max(tip * std::min(o.style.maxScale, std::pow(kTypicalCarried, o.style.taper)), 0.5 * vox);
    return modelledLeaves(branch + o.halfWidth * vox + kLeafReachVoxels * vox);
}

/// The frame's points grid and its index grid, by their leaves.
double Dla3dEffect::pointsBytes() const
{
    if (!mOptions.points) return 0.0;
    const double vox = mOptions.voxelSize > 0 ? mOptions.voxelSize : mSettings.radius;
    // (a particle sits in one leaf: never more leaves than particles)
    return std::min(double(mOptions.particles), modelledLeaves(kLeafReachVoxels * vox)) * kPointLeafBytes;
}

MemoryEstimate Dla3dEffect::memoryEstimate(const World&) const
{
    const double n = double(mOptions.particles);
    const bool sdf = mOptions.sdf || mOptions.fog || mOptions.mesh != "none";
    const double leaves = sdf ? modelledSdfLeaves() : 0.0;
    char what[240];
    std::snprintf(what, sizeof what,
                  "%.4g particles x %.0f bytes of arrays and hash, %.3g MiB of points grid, and about %.3g leaves of "
                  "8^3 voxels of level set at the last frame",
                  n, kParticleBytes, pointsBytes() / 1048576.0, leaves);
    const double grids = pointsBytes() + leaves * floatLeafBytes() * kRasterPeakPerLeaf;
    // the key to change: the voxel size when the grids outweigh the particles' arrays
    return {n * kParticleBytes + grids, grids > n * kParticleBytes ? "dla3d.voxel_size" : "dla3d.particles", what};
}

/// Refuses a frame whose level set would not fit run.memory_limit, from its leaves counted before
/// a voxel is written (memoryEstimate models the branches from the keys; this counts them).
void Dla3dEffect::checkFrameBudget(const World& world, int64_t frame, const std::vector<float>& radii)
{
    const auto& agg = *mAggregate;
    mSdfLeaves = double(branchLeafCount(agg.positions(), agg.parents(), radii, mOptions.voxelSize, mOptions.halfWidth));
    const double bytes =
        mSdfLeaves * floatLeafBytes() * kRasterPeakPerLeaf + double(agg.size()) * kParticleBytes + pointsBytes();
    char detail[300];
    std::snprintf(detail, sizeof detail,
                  "frame %lld: the level set of the branches of %zu particles, %.4g leaves of 8^3 voxels at "
                  "voxel_size %.3g m, and the particles",
                  static_cast<long long>(frame), agg.size(), mSdfLeaves, mOptions.voxelSize);
    checkMemoryEstimate({bytes, mOptions.voxelSize > 0 ? "dla3d.voxel_size" : "dla3d.radius", detail},
                        world.memoryLimitBytes, mOptions.sceneLabel);
}

std::vector<std::pair<std::string, double>> Dla3dEffect::counters() const { return {{"sdf_leaves", mSdfLeaves}}; }

std::vector<std::pair<std::string, double>> Dla3dEffect::timings() const
{
    // the run's summary asks after a failed initialisation too (a missing constraint mesh), when
    // there is no aggregate yet
    const double walk = mAggregate ? mAggregate->stats().walkSeconds : 0.0;
    const double commit = mAggregate ? mAggregate->stats().commitSeconds : 0.0;
    return {{"grow", mGrowSeconds}, {"walk", walk}, {"commit", commit}, {"output", mOutputSeconds}};
}

} // namespace frostvdb::dla3d

namespace frostvdb {
using dla3d::Dla3dEffect;
FROSTVDB_REGISTER_EFFECT(Dla3dEffect, "dla3d",
                         "Bourke's off-lattice 3D/2D DLA: stickiness, launch sphere/axis/plane/surface, bias, rotation, "
                         "mesh constraints; points, ice_sdf and ice from tapering sphere-swept branches");
} // namespace frostvdb
