// [fluid] with solver = "sparse": the band-limited MAC solver of fluid/SparseFluid.h on plane and
// box domains. The ice (p > obstacle_threshold) is solid, `flow_vel` is written on the band with
// the free stream as the grid's background (or densely for non-uniform inflow profiles), and T is
// carried by the flow with no diffusion of its own.
#include <frostvdb/fluid/Fluid.h>
#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/io/Png.h>

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>

namespace frostvdb {

namespace {
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
} // namespace

double FluidEffect::cellsPerUnit(const World& world) const { return 1.0 / world.domain.lattice().spacing(); }

void FluidEffect::initializeSparse(World& world)
{
    const Domain& dom = world.domain;
    mOrigin = dom.bbox().min();
    fluid::SparseFluidParams p = mSparseParams;
    // PDE units -> cells: a speed U moves U dt / h cells per step.
    p.inflowSpeed = mParams.inflowSpeed * cellsPerUnit(world);
    p.poisson.relativeTolerance = 0;
    p.poisson.absoluteTolerance = mParams.tolerance * std::max(p.inflowSpeed, 1e-12);
    p.poisson.maxIterations = mParams.maxIterations;
    mSparse = std::make_unique<fluid::SparseFluid>(p, dom.bbox().dim(), dom.flat() ? 2 : 3);
    updateObstaclesSparse(world);
    mSparse->setFreeStream();
    mSparse->project();
    notePressureSolve(mSparse->pressureStats().converged, mSparse->pressureStats().iterations,
                      mSparse->pressureStats().relativeResidual, -1);
    writeVelocitySparse(world);
}

void FluidEffect::updateObstaclesSparse(World& world)
{
    const auto t0 = Clock::now();
    auto p = world.fields.get<openvdb::FloatGrid>(ice::kPhase);
    const openvdb::Coord n = mSparse->dims();
    std::vector<uint8_t> solid(size_t(n.x()) * n.y() * n.z(), 0);
    if (p) {
        const float thr = float(mParams.solidThreshold);
        tbb::parallel_for(tbb::blocked_range<int>(0, n.y() * n.z()), [&](const tbb::blocked_range<int>& r) {
            auto acc = p->getConstAccessor();
            for (int row = r.begin(); row != r.end(); ++row) {
                const int j = row % n.y(), k = row / n.y();
                for (int i = 0; i < n.x(); ++i)
                    solid[(size_t(k) * n.y() + j) * n.x() + i] = acc.getValue(mOrigin + openvdb::Coord(i, j, k)) > thr;
            }
        });
    }
    mSparse->setSolid([&](int i, int j, int k) { return solid[(size_t(k) * n.y() + j) * n.x() + i] != 0; });
    mObstacleSeconds += since(t0);
}

void FluidEffect::writeVelocitySparse(World& world)
{
    const auto t0 = Clock::now();
    const double speed = mSparse->maxSpeed();
    if (!std::isfinite(speed))
        throw SimulationError("fluid velocity went non-finite (pressure solve " +
                              std::to_string(mSparse->pressureStats().iterations) +
                              " iterations); nothing of this step was written");
    // Cells per unit time -> world metres per unit time.
    const double scale = world.domain.voxelSize();
    const openvdb::Coord n = mSparse->dims();
    const bool uniform = mSparseParams.profile == fluid::Profile::Uniform;
    openvdb::Vec3s background(0.f);
    if (uniform) {
        const int a = mSparseParams.inflowSide / 2;
        background[a] = float(mSparse->freeStream(a, 0, 0, 0) * scale);
    }
    auto vel = openvdb::Vec3SGrid::create(background);
    vel->setTransform(world.domain.transform()->copy());
    vel->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
    if (!uniform) {
        vel->denseFill(world.domain.bbox(), background, true);
    } else {
        auto acc = vel->getAccessor();
        for (int k = 0; k < n.z(); ++k)
            for (int j = 0; j < n.y(); ++j)
                for (int i = 0; i < n.x(); ++i)
                    if (mSparse->active(i, j, k) || mSparse->solid(i, j, k))
                        acc.setValueOn(mOrigin + openvdb::Coord(i, j, k), background);
    }
    openvdb::tree::LeafManager<openvdb::Vec3STree> leaves(vel->tree());
    tbb::parallel_for(leaves.leafRange(16), [&](const openvdb::tree::LeafManager<openvdb::Vec3STree>::LeafRange& r) {
        for (auto leaf = r.begin(); leaf; ++leaf)
            for (auto it = leaf->beginValueOn(); it; ++it) {
                const openvdb::Coord c = it.getCoord() - mOrigin;
                const openvdb::Vec3d u = mSparse->sample(c.asVec3d());
                it.setValue(openvdb::Vec3s(u * scale));
            }
    });
    world.fields.replace(ice::kVelocity, vel);
    mVelOutSeconds += since(t0);
}

void FluidEffect::advectTemperatureSparse(World& world, double dt)
{
    const auto t0 = Clock::now();
    auto T = world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
    if (!T || mSparse->maxSpeed() == 0.0) return; // still air: T unchanged, bit for bit
    // Only the band cells move (the solver reads T where its traces leave the band); the grid's
    // copy takes their new values.
    const auto changes = mSparse->advectScalar(*T, mOrigin, dt);
    auto tNew = T->deepCopy();
    auto acc = tNew->getAccessor();
    for (const auto& ch : changes) acc.setValue(mOrigin + ch.cell, float(ch.value));
    if (!world.region.dense) truncateToTolerance(*tNew, world.region.tolerance);
    world.fields.replace(ice::kTemperature, tNew);
    mAdvectTSeconds += since(t0);
}

void FluidEffect::stepSparse(World& world, const StepInfo& info)
{
    const double dt = ice::shared(world).dt; // read every step: the phase field owns the clock
    updateObstaclesSparse(world);
    mSparse->step(dt);
    notePressureSolve(mSparse->pressureStats().converged, mSparse->pressureStats().iterations,
                      mSparse->pressureStats().relativeResidual, info.step);
    writeVelocitySparse(world);
    advectTemperatureSparse(world, dt);
}

bool FluidEffect::writePreviewSparse(World& world, const std::string& pngPath)
{
    // A slice through the domain centre containing the flow axis: speed as a blue ramp, warm tint
    // where T departs from T_inf, ice white. Planes: the plane; boxes: the x-y slice for flow along
    // x or y, the x-z slice for flow along z.
    auto p = world.fields.get<openvdb::FloatGrid>(ice::kPhase);
    auto T = world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
    const openvdb::Coord n = mSparse->dims();
    const bool xz = mSparse->dim() == 3 && mSparseParams.inflowSide / 2 == 2;
    const int W = n.x(), H = xz ? n.z() : n.y();
    const int mid = xz ? n.y() / 2 : n.z() / 2;
    const int px = std::max(1, 512 / std::max(W, H));
    ImageRGB img(W * px, H * px);
    const double U = std::max(1e-12, mSparse->freeStream(mSparseParams.inflowSide / 2, 0.5 * n.x(), 0.5 * n.y(), 0.5 * n.z()) != 0
                                         ? std::fabs(mSparse->freeStream(mSparseParams.inflowSide / 2, 0.5 * n.x(), 0.5 * n.y(), 0.5 * n.z()))
                                         : mSparseParams.inflowSpeed);
    const double tInf = ice::shared(world).farTemperature;
    const double tSpan = std::max(1e-6, std::fabs(ice::shared(world).meltTemperature - tInf));
    auto pa = p->getConstAccessor();
    auto ta = T->getConstAccessor();
    for (int b = 0; b < H; ++b)
        for (int a = 0; a < W; ++a) {
            const openvdb::Coord c = xz ? openvdb::Coord(a, mid, b) : openvdb::Coord(a, b, mid);
            const double speed = std::min(1.5, mSparse->sample(c.asVec3d()).length() / U) / 1.5;
            const double heat = std::min(1.0, std::fabs(ta.getValue(mOrigin + c) - tInf) / tSpan);
            const double ice = std::min(1.0, std::max(0.0, double(pa.getValue(mOrigin + c))));
            const bool band = mSparse->active(c.x(), c.y(), c.z());
            double cr = 0.05 + 0.15 * speed, cg = 0.10 + 0.45 * speed, cb = 0.25 + 0.65 * speed;
            if (!band) { cr *= 0.6; cg *= 0.6; cb *= 0.6; } // outside the band: the free stream, dimmed
            cr += (1.0 - cr) * heat * 0.9;
            cg += (0.55 - cg) * heat * 0.9;
            cb += (0.15 - cb) * heat * 0.9;
            for (int y = 0; y < px; ++y)
                for (int x = 0; x < px; ++x)
                    img.set(a * px + x, (H - 1 - b) * px + y, float(cr + (1 - cr) * ice), float(cg + (1 - cg) * ice),
                            float(cb + (1 - cb) * ice));
        }
    writePngRGB(pngPath, img);
    return true;
}

} // namespace frostvdb
