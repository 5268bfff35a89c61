// Section [fluid]: obstacles from p, the stable-fluid step, `vel` for the walkers and the
// semi-Lagrangian advection of T (no diffusion: eq. 7 with kappa = 0).
#include <frostvdb/fluid/Fluid.h>
#include <frostvdb/core/ActiveRegion.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/geometry/HexLattice.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/io/Png.h>

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/ValueTransformer.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <iostream>
#include <sstream>

namespace frostvdb {

FROSTVDB_REGISTER_EFFECT(FluidEffect, "fluid",
                         "Stam stable fluid around the crystal (ice paper 4.2-4.3): the ice is an obstacle, T is carried by the flow.");

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

ice::FluidEdge parseEdge(const std::string& s)
{
    if (s == "right") return ice::FluidEdge::Right;
    if (s == "bottom") return ice::FluidEdge::Bottom;
    if (s == "top") return ice::FluidEdge::Top;
    return ice::FluidEdge::Left;
}

} // namespace

std::unique_ptr<Effect> FluidEffect::create(ParamDict& d, const World& world)
{
    auto fx = std::make_unique<FluidEffect>();
    ice::FluidParams& f = fx->mParams;
    const bool flat = world.domain.flat();
    const std::string solverKind = d.getString("solver", flat ? "dense2d" : "sparse", {"dense2d", "sparse"},
        "dense2d: the dense MAC grid over the whole plane (planes only; the reference); sparse: a MAC grid solved "
        "only in a band around the ice and its wake, in 2D or 3D (the default on box domains; see docs/fluid.md)");
    const bool sparse = solverKind == "sparse";
    fx->mSparseMode = sparse;
    const std::string edge = d.getString("inflow_edge", "left", {"left", "right", "bottom", "top", "front", "back"},
        "the domain side the flow enters through (left -x, right +x, bottom -y, top +y, front -z, back +z; front "
        "and back on box domains); the opposite side is always an outflow");
    f.inflowEdge = parseEdge(edge);
    const std::string profile = d.getString("inflow_profile", "uniform",
        {"uniform", "parabolic", "ramp_quadratic", "linear", "quadratic"},
        "inflow speed across the inflow side: uniform; parabolic (speed at the centre, 0 at the ends, the paper's "
        "Figure 10); ramp_quadratic or quadratic (0 at the start rising as s^2 to speed at the end, Figure 6); "
        "linear (rising as s). s runs along x for inflow on y or z sides, along y for inflow on x sides");
    f.profile = profile == "parabolic" ? fluid::Profile::Parabolic
              : profile == "linear" ? fluid::Profile::Linear
              : (profile == "ramp_quadratic" || profile == "quadratic") ? fluid::Profile::Quadratic
              : fluid::Profile::Uniform;
    if (!sparse && profile == "linear")
        throw SceneError(world.sceneLabel, 0, "fluid.inflow_profile",
                         "[fluid] inflow_profile = \"linear\" needs solver = \"sparse\"");
    f.inflowSpeed = d.getFloat("inflow_speed", 3.5, 0.0, 1000.0, "",
        "peak inflow speed in PDE units (lengths in units where one cell = [domain] spacing, time in the ice clock); the paper uses 3.5");
    f.closedWalls = d.getString("walls", "outflow", {"outflow", "closed"},
        "the sides beside the inflow: outflow (zero-gradient velocity, p = 0) or closed (free-slip solid walls, a channel)") == "closed";
    f.viscosity = d.getFloat("viscosity", 0.0, 0.0, 100.0, "",
        "dense2d: kinematic viscosity nu (PDE units), solved implicitly; 0 = inviscid");
    f.tolerance = d.getFloat("tolerance", 1e-5, 1e-12, 0.1, "",
        "projection (and viscosity) solve tolerance: max |div u| h / inflow_speed after the projection");
    f.maxIterations = int(d.getInt("max_iterations", 2000, 1, 1000000, "",
        "conjugate-gradient iteration cap per linear solve (a solve that hits it is reported)"));
    f.multigrid = d.getString("pressure_solver", "multigrid", {"multigrid", "jacobi_cg"},
        "dense2d projection solver: multigrid (multigrid-preconditioned CG, McAdams et al. 2010; iterations about "
        "constant in the grid size) or jacobi_cg (the Jacobi-preconditioned CG kept as the reference)") == "multigrid";
    f.solidThreshold = d.getFloat("obstacle_threshold", 0.5, 0.0, 1.0, "",
        "cells with p above this are solid obstacles (the paper: 0.5)");
    fluid::SparseFluidParams& sp = fx->mSparseParams;
    sp.bandWidth = d.getFloat("band_width", 8.0, 0.0, 10000.0, "",
        "sparse: cells within this many cells of the ice are solved (the tolerance of the band, like the phase "
        "field's); beyond, the free stream is the background; 0 = the whole domain");
    sp.wakeLength = d.getFloat("wake_length", 24.0, 0.0, 100000.0, "",
        "sparse: the band is stretched this many cells downstream of the ice (the wake)");
    sp.advection = d.getString("advection", "maccormack", {"semi_lagrangian", "maccormack"},
        "sparse: advection of velocity and T: semi_lagrangian (RK2 trace, linear interpolation) or maccormack "
        "(second order, limited to the sampled cells' range, so bounded at any CFL)") == "maccormack"
        ? fluid::Advection::MacCormack : fluid::Advection::SemiLagrangian;
    d.onlyWhen(sparse, "band_width", "solver = \"dense2d\"");
    d.onlyWhen(sparse, "wake_length", "solver = \"dense2d\"");
    d.onlyWhen(sparse, "advection", "solver = \"dense2d\"");
    d.onlyWhen(!sparse, "viscosity", "solver = \"sparse\"");
    d.onlyWhen(!sparse, "pressure_solver", "solver = \"sparse\"");
    static const std::map<std::string, int> sides{{"left", 0}, {"right", 1}, {"bottom", 2}, {"top", 3}, {"front", 4}, {"back", 5}};
    sp.inflowSide = sides.at(edge);
    sp.profile = f.profile; // one vocabulary for both solvers (fluid/Boundary.h)
    sp.lateral = f.closedWalls ? fluid::SideKind::Wall : fluid::SideKind::Outflow;
    if (flat) sp.sides[4] = sp.sides[5] = 1; // a plane: no flow across it
    if (!flat && !sparse)
        throw SceneError(world.sceneLabel, 0, "fluid.solver",
                         "[fluid] solver = \"dense2d\" runs on flat domains only, not on \"" + world.domain.kind() + "\"; use \"sparse\"");
    if (sparse && world.domain.lattice().kind() != LatticeKind::Square)
        throw SceneError(world.sceneLabel, 0, "fluid.solver",
                         "[fluid] solver = \"sparse\" needs a square lattice; use \"dense2d\" on hexagonal planes");
    if (flat && sp.inflowSide >= 4)
        throw SceneError(world.sceneLabel, 0, "fluid.inflow_edge",
                         "[fluid] inflow_edge = \"" + edge + "\" needs a box domain (allowed on planes: left, right, bottom, top)");
    // The MAC grid covers the domain's bounds in index space: a flat domain or a solid (3D) one;
    // a curved surface (not flat, intrinsically 2D: a shell) is not supported yet. Decided from
    // properties, not the kind.
    if (!flat && world.domain.intrinsicDimension() != 3)
        throw SceneError(world.sceneLabel, 0, "fluid",
                         "[fluid] runs on flat or solid 3D domains (plane, box), not on the surface domain \"" +
                             world.domain.kind() + "\"");
    const auto& bb = world.domain.bbox();
    if (bb.dim().x() < 4 || bb.dim().y() < 4 || (!flat && bb.dim().z() < 4))
        throw SceneError(world.sceneLabel, 0, "fluid", "[fluid] needs a domain of at least 4 cells along each axis");
    return fx;
}

openvdb::Vec2d FluidEffect::auxPosition(double i, double j) const
{
    if (!mHex) return {i, j};
    return {i + 0.5 * j, j * hex::kRowHeight};
}

FieldDeclaration FluidEffect::declaration() const
{
    FieldDeclaration d;
    d.stage = Stage::ObstacleCopy; // then its fluid step and the heat advection (the paper's last three stages)
    d.use(ice::kClock, kReadsAtInit | kReads)
        .use(ice::kPhase, kReadsAtInit | kReads)
        .use(ice::kTemperature, kInitialises | kReads | kWrites)
        .use(ice::kGrowth, kInitialises)
        .use(ice::kFreezeTime, kInitialises)
        .use(ice::kVelocity, kInitialises | kWrites);
    d.output(out::kIce).output(out::kIceTemperature).output(out::kGrowth).output(out::kFreezeTime).output(out::kFlowVel);
    return d;
}

void FluidEffect::initialize(World& world)
{
    ice::requireIceFields(world);
    if (mSparseMode) { initializeSparse(world); return; }
    const Domain& dom = world.domain;
    mHex = dom.lattice().kind() == LatticeKind::Hexagonal;
    mOrigin = dom.bbox().min(); // aux cell (0, 0) sits on the domain's first cell
    const int nx = dom.bbox().dim().x(), ny = dom.bbox().dim().y();
    int ax = nx, ay = ny;
    if (mHex) { // the axis-aligned rectangle around the sheared domain, same spacing
        ax = int(std::ceil(nx - 1 + 0.5 * (ny - 1) - 1e-9)) + 1;
        ay = int(std::ceil((ny - 1) * hex::kRowHeight - 1e-9)) + 1;
    }
    mFluid = std::make_unique<ice::StableFluid2D>(mParams, ax, ay, dom.lattice().spacing());
    updateObstacles(world);
    mFluid->setFreeStream();
    mFluid->project();
    notePressureSolve(mFluid->stats().pressureConverged, mFluid->stats().pressureIterations,
                      mFluid->stats().pressureResidual, -1);
    writeVelocityField(world);
}

MemoryEstimate FluidEffect::memoryEstimate(const World& world) const
{
    const Domain& dom = world.domain;
    const double cells = double(dom.bbox().volume());
    if (mSparseMode)
        return perVoxelEstimate(cells, 190.0, "domain.size", "band fluid: face arrays and the multigrid, worst case");
    // The solver's MAC grid: the domain, or on a hexagonal lattice the axis-aligned rectangle
    // around the sheared domain (initialize()).
    const int nx = dom.bbox().dim().x(), ny = dom.bbox().dim().y();
    double aux = double(nx) * double(ny);
    if (dom.lattice().kind() == LatticeKind::Hexagonal)
        aux = (std::ceil(nx - 1 + 0.5 * (ny - 1) - 1e-9) + 1.0) * (std::ceil((ny - 1) * hex::kRowHeight - 1e-9) + 1.0);
    // Held from step to step, per MAC cell: u, v and the pressure (3 doubles), the obstacles and
    // the obstacles the multigrid was built for (2 bytes); with multigrid, its finest level (cell
    // index, row position and colour lists 3 x 4 bytes, diagonal 1, x, b, r 3 x 8) and the
    // coarser levels (1/3 more in 2D), and the conjugate-gradient vectors r, z, p, q (4 x 8).
    const double held = 24.0 + 2.0 + (mParams.multigrid ? 37.0 * 4.0 / 3.0 + 32.0 : 0.0);
    // A projection's scratch: link bits, inverse diagonal, divergence, the unknowns' b and x
    // (jacobi_cg: its four CG vectors instead of the multigrid's).
    const double scratch = 1.0 + 8.0 + 8.0 + 1.0 + 16.0 + (mParams.multigrid ? 0.0 : 32.0);
    // `vel` (Vec3s) is filled over the whole domain: whole leaves of 8^3 voxels, of which a plane
    // uses one layer of 8 x 8; the frame holds a deep copy of it (addToFrame) while the
    // projection's scratch is gone.
    using VelLeaf = openvdb::Vec3STree::LeafNodeType;
    const double leafBytes = double(sizeof(VelLeaf)) + double(VelLeaf::SIZE) * sizeof(openvdb::Vec3s);
    const double perLeaf = 64.0 * std::clamp(double(dom.bbox().dim().z()), 1.0, 8.0);
    const double velBytes = cells * leafBytes / perLeaf;
    const double bytes = aux * held + velBytes + std::max(aux * scratch, velBytes);
    char what[240];
    std::snprintf(what, sizeof what,
                  "%.4g MAC cells x %.0f bytes of solver arrays (+ %.0f of projection scratch), `vel` and its "
                  "frame copy %.0f bytes per domain cell",
                  aux, held, scratch, 2.0 * velBytes / std::max(1.0, cells));
    return {bytes, "domain.size", what};
}

void FluidEffect::notePressureSolve(bool converged, int iterations, double residual, int64_t step)
{
    mMostIterations = std::max(mMostIterations, iterations);
    if (converged) return;
    if (mCappedSolves++ == 0)
        std::cerr << "frostvdb: [fluid] warning: the pressure solve " << (step < 0 ? std::string("at initialisation")
                                                                               : "of step " + std::to_string(step))
                  << " stopped at fluid.max_iterations = " << mParams.maxIterations << " (residual " << residual
                  << ", tolerance " << mParams.tolerance
                  << "); the flow is not divergence-free. Capped solves are counted in the summary "
                     "(fluid.capped_solves)\n";
}

std::vector<std::pair<std::string, double>> FluidEffect::counters() const
{
    return {{"capped_solves", double(mCappedSolves)}, {"max_pressure_iterations", double(mMostIterations)}};
}

void FluidEffect::updateObstacles(World& world)
{
    const auto t0 = Clock::now();
    auto p = world.fields.get<openvdb::FloatGrid>(ice::kPhase);
    const int W = mFluid->nx(), H = mFluid->ny();
    std::vector<uint8_t> solid(size_t(W) * H, 0);
    if (p) {
        const float thr = float(mParams.solidThreshold);
        tbb::parallel_for(tbb::blocked_range<int>(0, H, std::max(1, 16384 / W)), [&](const tbb::blocked_range<int>& r) {
            auto acc = p->getConstAccessor();
            for (int b = r.begin(); b != r.end(); ++b)
                for (int a = 0; a < W; ++a) {
                    float v;
                    if (!mHex) {
                        v = acc.getValue(mOrigin + openvdb::Coord(a, b, 0));
                    } else {
                        const double j = b / hex::kRowHeight, i = a - 0.5 * j;
                        v = openvdb::tools::BoxSampler::sample(acc, mOrigin.asVec3d() + openvdb::Vec3R(i, j, 0.0));
                    }
                    solid[size_t(b) * W + a] = v > thr ? 1 : 0;
                }
        });
    }
    mFluid->setSolid(std::move(solid));
    mObstacleSeconds += since(t0);
}

void FluidEffect::writeVelocityField(World& world)
{
    const auto t0 = Clock::now();
    auto vel = world.fields.require<openvdb::Vec3SGrid>(ice::kVelocity, openvdb::Vec3s(0.f));
    vel->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
    if (vel->activeVoxelCount() != world.domain.voxelCount()) {
        vel->clear();
        vel->denseFill(world.domain.bbox(), openvdb::Vec3s(0.f), true);
    }
    // World units (metres per unit of simulation time), as IceState.h and [dla] expect.
    const double scale = world.domain.voxelSize() / world.domain.lattice().spacing();
    openvdb::tree::LeafManager<openvdb::Vec3STree> leaves(vel->tree());
    tbb::parallel_for(leaves.leafRange(64), [&](const openvdb::tree::LeafManager<openvdb::Vec3STree>::LeafRange& r) {
        for (auto leaf = r.begin(); leaf; ++leaf)
            for (auto it = leaf->beginValueOn(); it; ++it) {
                const openvdb::Coord c = it.getCoord() - mOrigin;
                const openvdb::Vec2d q = auxPosition(c.x(), c.y());
                const openvdb::Vec2d u = mFluid->sample(q.x(), q.y());
                it.setValue(openvdb::Vec3s(float(u.x() * scale), float(u.y() * scale), 0.f));
            }
    });
    mVelOutSeconds += since(t0);
}

void FluidEffect::advectTemperature(World& world, double dt)
{
    const auto t0 = Clock::now();
    auto T = world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
    if (!T) return;
    const double h = world.domain.lattice().spacing();
    // Max displacement in index cells (a hexagonal index step is at most 2/sqrt(3) plane cells).
    double umax = 0;
    for (int j = 0; j <= mFluid->ny(); ++j) // cheap: one pass over the faces
        for (int i = 0; i <= mFluid->nx(); ++i) {
            if (j < mFluid->ny()) umax = std::max(umax, std::fabs(mFluid->u(i, j)));
            if (i < mFluid->nx()) umax = std::max(umax, std::fabs(mFluid->v(i, j)));
        }
    if (umax == 0.0) { mAdvectTSeconds += since(t0); return; } // still air: T unchanged, bit for bit
    const int reach = int(std::ceil(umax * std::sqrt(2.0) * dt / h * (mHex ? 1.155 : 1.0))) + 1;

    // Where the new T can differ from T_inf: the old T's stored voxels moved by the flow.
    openvdb::MaskTree region(false);
    region.topologyUnion(T->tree());
    openvdb::tools::dilateActiveValues(region, reach, openvdb::tools::NN_FACE_EDGE, openvdb::tools::EXPAND_TILES);
    region.clip(world.domain.bbox());

    auto tNew = openvdb::FloatGrid::create(T->background());
    tNew->setTransform(T->transformPtr());
    tNew->tree().topologyUnion(region);
    const double s = dt / h;
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(tNew->tree());
    tbb::parallel_for(leaves.leafRange(64), [&](const openvdb::tree::LeafManager<openvdb::FloatTree>::LeafRange& r) {
        auto acc = T->getConstAccessor();
        for (auto leaf = r.begin(); leaf; ++leaf)
            for (auto it = leaf->beginValueOn(); it; ++it) {
                const openvdb::Coord c = it.getCoord();
                const openvdb::Vec2d q = auxPosition(c.x() - mOrigin.x(), c.y() - mOrigin.y());
                const openvdb::Vec2d u = mFluid->sample(q.x(), q.y());
                if (u.x() == 0.0 && u.y() == 0.0) { it.setValue(acc.getValue(c)); continue; }
                const double x = q.x() - s * u.x(), y = q.y() - s * u.y();
                double i = x, j = y;
                if (mHex) { j = y / hex::kRowHeight; i = x - 0.5 * j; }
                it.setValue(openvdb::tools::BoxSampler::sample(
                    acc, openvdb::Vec3R(i + mOrigin.x(), j + mOrigin.y(), double(c.z()))));
            }
    });
    if (!world.region.dense) truncateToTolerance(*tNew, world.region.tolerance);
    world.fields.replace(ice::kTemperature, tNew);
    mAdvectTSeconds += since(t0);
}

void FluidEffect::step(World& world, const StepInfo& info)
{
    if (mSparseMode) { stepSparse(world, info); return; }
    const double dt = ice::shared(world).dt; // read every step: the phase field owns the clock
    updateObstacles(world);
    mFluid->step(dt);
    const auto& st = mFluid->stats();
    notePressureSolve(st.pressureConverged, st.pressureIterations, st.pressureResidual, info.step);
    for (int j = 0; j < mFluid->ny(); ++j)
        for (int i = 0; i <= mFluid->nx(); ++i)
            if (!std::isfinite(mFluid->u(i, j))) {
                std::ostringstream os;
                os << "fluid velocity went non-finite at aux cell (" << i << ", " << j << ") in step " << info.step + 1
                   << " (t = " << (info.step + 1) * dt << "); pressure solve " << st.pressureIterations
                   << " iterations, residual " << st.pressureResidual << ". Nothing of this step was written.";
                throw SimulationError(os.str());
            }
    writeVelocityField(world);
    advectTemperature(world, dt);
}

void FluidEffect::saveState(const World&, StateWriter& out) const
{
    if (mSparse) {
        for (auto& [name, a] : mSparse->historyArrays()) out.putArray(name, *a);
        return;
    }
    for (auto& [name, a] : mFluid->historyArrays()) out.putArray(name, *a);
}

void FluidEffect::loadState(World&, const StateReader& in)
{
    auto arrays = mSparse ? mSparse->historyArrays() : mFluid->historyArrays();
    for (auto& [name, a] : arrays) {
        const size_t n = a->size();
        in.getArray(name, *a);
        if (a->size() != n) in.fail(name, "holds " + std::to_string(a->size()) + " values, this grid needs " + std::to_string(n));
    }
}

void FluidEffect::addToFrame(World& world, Frame& frame)
{
    ice::addIceOutputs(world, frame);
    auto vel = world.fields.get<openvdb::Vec3SGrid>(ice::kVelocity);
    if (!vel) return;
    auto out = vel->deepCopy(); // already in world units
    out->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
    out->insertMeta("units", openvdb::StringMetadata("m per unit simulation time"));
    frame.add(out::kFlowVel, out); // not `vel`: that is the gas's m/s
}

bool FluidEffect::writePreview(World& world, const Frame& frame, const std::string& pngPath)
{
    if (mSparseMode) return writePreviewSparse(world, pngPath);
    // Top view of the flow: speed as a blue ramp, warm tint where T departs from T_inf, ice white.
    auto p = world.fields.get<openvdb::FloatGrid>(ice::kPhase);
    auto T = world.fields.get<openvdb::FloatGrid>(ice::kTemperature);
    const int W = mFluid->nx(), H = mFluid->ny();
    const int width = std::min(1024, std::max(512, W));
    const double px = double(W - 1) / (width - 1);
    const int height = std::max(1, int(std::round((H - 1) / px)) + 1);
    ImageRGB img(width, height);
    const double U = mParams.inflowSpeed > 0 ? mParams.inflowSpeed : 1.0;
    const double tInf = ice::shared(world).farTemperature;
    const double tSpan = std::max(1e-6, std::fabs(ice::shared(world).meltTemperature - tInf));
    const auto& bb = world.domain.bbox();
    tbb::parallel_for(tbb::blocked_range<int>(0, height, 8), [&](const tbb::blocked_range<int>& r) {
        auto pa = p->getConstAccessor();
        auto ta = T->getConstAccessor();
        for (int y = r.begin(); y != r.end(); ++y)
            for (int x = 0; x < width; ++x) {
                const double qx = x * px, qy = (height - 1 - y) * px;
                double i = qx, j = qy;
                if (mHex) { j = qy / hex::kRowHeight; i = qx - 0.5 * j; }
                i += mOrigin.x();
                j += mOrigin.y();
                if (i < bb.min().x() - 0.5 || i > bb.max().x() + 0.5 || j < bb.min().y() - 0.5 || j > bb.max().y() + 0.5) {
                    img.set(x, y, 0, 0, 0);
                    continue;
                }
                const openvdb::Vec3R ijk(i, j, double(mOrigin.z()));
                const double speed = std::min(1.5, mFluid->sample(qx, qy).length() / U) / 1.5;
                const double heat = std::min(1.0, std::fabs(openvdb::tools::BoxSampler::sample(ta, ijk) - tInf) / tSpan);
                const double ice = std::min(1.0, std::max(0.0, double(openvdb::tools::BoxSampler::sample(pa, ijk))));
                double cr = 0.05 + 0.15 * speed, cg = 0.10 + 0.45 * speed, cb = 0.25 + 0.65 * speed;
                cr += (1.0 - cr) * heat * 0.9;
                cg += (0.55 - cg) * heat * 0.9;
                cb += (0.15 - cb) * heat * 0.9;
                img.set(x, y, float(cr + (1 - cr) * ice), float(cg + (1 - cg) * ice), float(cb + (1 - cb) * ice));
            }
    });
    writePngRGB(pngPath, img);
    return true;
}

std::vector<std::pair<std::string, double>> FluidEffect::timings() const
{
    if (mSparse)
        return {{"obstacles", mObstacleSeconds}, {"advect_u", mSparse->advectSeconds},
                {"project", mSparse->projectSeconds}, {"vel_out", mVelOutSeconds}, {"advect_T", mAdvectTSeconds}};
    if (!mFluid) return {};
    return {{"obstacles", mObstacleSeconds}, {"advect_u", mFluid->advectSeconds},
            {"viscosity", mFluid->viscositySeconds}, {"project", mFluid->projectSeconds},
            {"vel_out", mVelOutSeconds}, {"advect_T", mAdvectTSeconds}};
}

} // namespace frostvdb
