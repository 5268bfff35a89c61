#include <frostvdb/ice/PhaseFieldSolver.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/ice/ImplicitSystem.h>

#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <cmath>
#include <mutex>
#include <sstream>

namespace frostvdb {

namespace {

using FloatLeaf = openvdb::FloatTree::LeafNodeType;
using Clock = std::chrono::steady_clock;
constexpr int kDim = FloatLeaf::DIM; // 8
constexpr int kHalo = 2;             // stencil reach of one Kobayashi step

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

/// A leaf's voxels plus a halo of kHalo cells, as flat arrays (x fastest).
struct Block {
    int bx, by, bz;
    bool plane;
    std::vector<float> p, T, a, cx, cy, gx, gy, gz;
    std::vector<float> melt, pe, te; ///< melt map; midpoint estimates (second-order scheme)
    explicit Block(bool isPlane)
        : bx(kDim + 2 * kHalo), by(kDim + 2 * kHalo), bz(isPlane ? 1 : kDim + 2 * kHalo), plane(isPlane)
    {
        const size_t n = size_t(bx) * by * bz;
        for (auto* v : {&p, &T, &a, &cx, &cy, &gx, &gy, &gz, &melt, &pe, &te}) v->assign(n, 0.f);
    }
    size_t index(int x, int y, int z) const { return (size_t(z) * by + y) * bx + x; }
    openvdb::Coord origin(const openvdb::Coord& leafOrigin) const
    {
        return leafOrigin - openvdb::Coord(kHalo, kHalo, plane ? 0 : kHalo);
    }
};

/// Copies the grid's values over the block's footprint, leaf by leaf (the leaf and its
/// neighbours), falling back to the tile or background value where no leaf exists.
void gather(const openvdb::FloatGrid::ConstAccessor& acc, const Block& b, const openvdb::Coord& leafOrigin,
            std::vector<float>& out)
{
    const openvdb::Coord bo = b.origin(leafOrigin);
    const int zr = b.plane ? 0 : 1;
    for (int lz = -zr; lz <= zr; ++lz)
        for (int ly = -1; ly <= 1; ++ly)
            for (int lx = -1; lx <= 1; ++lx) {
                const openvdb::Coord lo = leafOrigin + openvdb::Coord(lx * kDim, ly * kDim, lz * kDim);
                const int x0 = std::max(lo.x(), bo.x()), x1 = std::min(lo.x() + kDim, bo.x() + b.bx);
                const int y0 = std::max(lo.y(), bo.y()), y1 = std::min(lo.y() + kDim, bo.y() + b.by);
                const int z0 = b.plane ? leafOrigin.z() : std::max(lo.z(), bo.z());
                const int z1 = b.plane ? leafOrigin.z() + 1 : std::min(lo.z() + kDim, bo.z() + b.bz);
                if (x0 >= x1 || y0 >= y1 || z0 >= z1) continue;
                if (const FloatLeaf* leaf = acc.probeConstLeaf(lo)) {
                    const float* buf = leaf->buffer().data();
                    for (int z = z0; z < z1; ++z)
                        for (int y = y0; y < y1; ++y) {
                            float* dst = &out[b.index(x0 - bo.x(), y - bo.y(), z - bo.z())];
                            const float* src = buf + ((((x0 & 7) << 6) | ((y & 7) << 3) | (z & 7)));
                            for (int x = x0; x < x1; ++x, src += 64) *dst++ = *src;
                        }
                } else {
                    const float v = acc.getValue(lo);
                    for (int z = z0; z < z1; ++z)
                        for (int y = y0; y < y1; ++y) {
                            float* dst = &out[b.index(x0 - bo.x(), y - bo.y(), z - bo.z())];
                            for (int x = x0; x < x1; ++x) *dst++ = v;
                        }
                }
            }
}

/// Pass 1 over the block's cells that have a full ring of neighbours, on @a phase.
void auxPass(Block& b, const std::vector<float>& phase, const FlatStencil& st, const Anisotropy& an)
{
    const int zs = b.plane ? 0 : 1, ze = b.plane ? 1 : b.bz - 1;
    for (int z = zs; z < ze; ++z)
        for (int y = 1; y < b.by - 1; ++y)
            for (int x = 1; x < b.bx - 1; ++x)
                kobayashiAux(phase.data(), b.index(x, y, z), st, an, b.a.data(), b.cx.data(), b.cy.data(),
                             b.gx.data(), b.gy.data(), b.gz.data());
}

/// Kobayashi's noise chi in [-1/2, 1/2] for a voxel and step (0 when the noise is off): a pure
/// function of (seed, step, voxel), so both schemes draw the same values whatever the threads.
inline double noiseDraw(const KobayashiParams& k, uint64_t seed, int64_t stepIndex, const openvdb::Coord& c)
{
    if (k.noise == 0) return 0.0;
    return toUnit(hashCounters(seed, uint64_t(stepIndex), coordKey(c.x(), c.y(), c.z()))) - 0.5;
}

/// Local T_e from the melt map (1 where there is none).
inline double meltTemperatureAt(const KobayashiParams& k, const Block& b, size_t i, bool haveMelt)
{
    return haveMelt ? k.localMeltTemperature(b.melt[i]) : k.meltTemperature;
}

} // namespace

/// The first bad voxel found (smallest coordinate, so the report does not depend on threads).
struct PhaseFieldSolver::Failure {
    std::mutex mutex;
    bool any = false;
    openvdb::Coord where;
    std::string field;
    float value = 0;
    void report(const openvdb::Coord& c, const char* f, float v)
    {
        std::lock_guard<std::mutex> lock(mutex);
        if (!any || c < where) { any = true; where = c; field = f; value = v; }
    }
};

namespace {
using Failure = PhaseFieldSolver::Failure;

/// The kernel over every leaf of the new grids (whose topology is the region): gather, pass 1,
/// pass 2. Accumulator leaves and the failure report are optional (benchmarks pass none).
struct LeafKernel {
    const KobayashiParams& k;
    const Domain& domain;
    const openvdb::FloatGrid& p;
    const openvdb::FloatGrid& T;
    const openvdb::FloatGrid* melt = nullptr;
    int64_t stepIndex = 0;
    double tNext = 0;
    uint64_t seed = 0;
    const std::vector<FloatLeaf*>* growthLeaves = nullptr;
    const std::vector<FloatLeaf*>* freezeLeaves = nullptr;
    Failure* failure = nullptr;

    void run(openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
             openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves) const
    {
        const bool plane = domain.isPlane();
        const Block proto(plane);
        const FlatStencil st(domain.stencil(), proto.bx, std::ptrdiff_t(proto.bx) * proto.by);
        const Anisotropy an(k);
        tbb::enumerable_thread_specific<Block> blocks([plane] { return Block(plane); });
        tbb::parallel_for(tbb::blocked_range<size_t>(0, pLeaves.leafCount(), 8), [&](const tbb::blocked_range<size_t>& r) {
            Block& b = blocks.local();
            auto pAcc = p.getConstAccessor();
            auto tAcc = T.getConstAccessor();
            std::unique_ptr<openvdb::FloatGrid::ConstAccessor> mAcc;
            if (melt) mAcc = std::make_unique<openvdb::FloatGrid::ConstAccessor>(melt->getConstAccessor());
            for (size_t li = r.begin(); li != r.end(); ++li) {
                FloatLeaf& pl = pLeaves.leaf(li);
                FloatLeaf& tl = tLeaves.leaf(li);
                const openvdb::Coord origin = pl.origin();
                gather(pAcc, b, origin, b.p);
                gather(tAcc, b, origin, b.T);
                if (mAcc) gather(*mAcc, b, origin, b.melt);
                auxPass(b, b.p, st, an);
                FloatLeaf* gl = growthLeaves ? (*growthLeaves)[li] : nullptr;
                FloatLeaf* fl = freezeLeaves ? (*freezeLeaves)[li] : nullptr;
                for (auto it = pl.cbeginValueOn(); it; ++it) {
                    const openvdb::Index n = it.pos();
                    const openvdb::Coord c = it.getCoord();
                    const openvdb::Coord l = c - origin;
                    const size_t i = b.index(l.x() + kHalo, l.y() + kHalo, plane ? 0 : l.z() + kHalo);
                    const double chi = noiseDraw(k, seed, stepIndex, c);
                    float pn, tn;
                    const double dp = kobayashiEuler(b.p.data(), b.T.data(), b.a.data(), b.cx.data(), b.cy.data(),
                                                     b.gx.data(), b.gy.data(), b.gz.data(), i, st, k,
                                                     meltTemperatureAt(k, b, i, melt != nullptr), chi, pn, tn);
                    if (failure) {
                        if (!std::isfinite(pn) || pn < -0.05f || pn > 1.05f) failure->report(c, "p (ice)", pn);
                        if (!std::isfinite(tn)) failure->report(c, "T (temperature)", tn);
                    }
                    pl.setValueOnly(n, pn);
                    tl.setValueOnly(n, tn);
                    if (gl && dp > 0) gl->setValueOn(n, gl->getValue(n) + float(dp));
                    if (fl && pn > 0.5f && !fl->isValueOn(n)) fl->setValueOn(n, float(tNext));
                }
            }
        });
    }
};

} // namespace

PhaseFieldSolver::PhaseFieldSolver(const KobayashiParams& params, const Domain& domain, const RegionSettings& region)
    : mParams(params), mDomain(domain), mRegion(region)
{
}

void PhaseFieldSolver::step(openvdb::FloatGrid::Ptr& p, openvdb::FloatGrid::Ptr& T, openvdb::FloatGrid* growth,
                            openvdb::FloatGrid* freezeTime, int64_t stepIndex, double time, uint64_t seed,
                            PhaseFieldStepStats* stats)
{
    if (mParams.scheme == PhaseFieldScheme::SecondOrder && !mLastInP) {
        // Rannacher start-up: the sharp seed (p jumps from 0 to 1 within a cell) excites modes
        // that Crank-Nicolson does not damp (its amplification tends to -1 for stiff modes),
        // which costs the observed order. The first step is two implicit-Euler half-steps,
        // which damp them; their O(dt^2) error does not accumulate over the run.
        const double dt = mParams.dt;
        mParams.dt = 0.5 * dt;
        mTheta = 1.0;
        stepOnce(p, T, growth, freezeTime, stepIndex, time, seed, stats);
        stepOnce(p, T, growth, freezeTime, stepIndex, time + 0.5 * dt, seed, stats);
        mParams.dt = dt;
        mTheta = 0.5;
        return;
    }
    stepOnce(p, T, growth, freezeTime, stepIndex, time, seed, stats);
}

void PhaseFieldSolver::stepOnce(openvdb::FloatGrid::Ptr& p, openvdb::FloatGrid::Ptr& T, openvdb::FloatGrid* growth,
                                openvdb::FloatGrid* freezeTime, int64_t stepIndex, double time, uint64_t seed,
                                PhaseFieldStepStats* stats)
{
    auto t0 = Clock::now();
    auto region = buildActiveRegion({p.get(), T.get()}, mRegion, kHalo, mDomain);
    auto pNew = openvdb::FloatGrid::create(p->background());
    auto tNew = openvdb::FloatGrid::create(T->background());
    pNew->setTransform(p->transformPtr());
    tNew->setTransform(T->transformPtr());
    pNew->setGridClass(p->getGridClass());
    pNew->tree().topologyUnion(region->tree());
    tNew->tree().topologyUnion(region->tree());

    openvdb::tree::LeafManager<openvdb::FloatTree> pLeaves(pNew->tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> tLeaves(tNew->tree());
    const size_t nLeaves = pLeaves.leafCount();
    // Leaves of the accumulators are created serially up front; the kernel then writes into
    // distinct leaves from many threads without touching topology.
    std::vector<FloatLeaf*> gLeaves(nLeaves, nullptr), fLeaves(nLeaves, nullptr);
    for (size_t i = 0; i < nLeaves; ++i) {
        if (growth) gLeaves[i] = growth->tree().touchLeaf(pLeaves.leaf(i).origin());
        if (freezeTime) fLeaves[i] = freezeTime->tree().touchLeaf(pLeaves.leaf(i).origin());
    }
    if (stats) {
        stats->regionVoxels = pNew->activeVoxelCount();
        stats->regionSeconds += since(t0);
    }

    t0 = Clock::now();
    const KobayashiParams& k = mParams;
    const double tNext = time + k.dt;
    Failure failure;
    if (k.scheme == PhaseFieldScheme::Euler) {
        LeafKernel kernel{k, mDomain, *p, *T, mMelt, stepIndex, tNext, seed, &gLeaves, &fLeaves, &failure};
        kernel.run(pLeaves, tLeaves);
    } else {
        stepSecondOrder(*p, *T, pLeaves, tLeaves, gLeaves, fLeaves, stepIndex, tNext, seed, failure, stats);
    }
    if (stats) stats->kernelSeconds += since(t0);
    if (failure.any) {
        std::ostringstream os;
        os << "phase field left its bounds: " << failure.field << " = " << failure.value << " at voxel "
           << failure.where << " in step " << stepIndex + 1 << " (t = " << tNext << "); dt = " << k.dt
           << ", stability limit " << k.stabilityLimit(mDomain.stencil(), !mDomain.isPlane())
           << ". Lower phase_field.dt or the anisotropy/latent heat; nothing of this step was written.";
        throw SimulationError(os.str());
    }

    t0 = Clock::now();
    if (!mRegion.dense) {
        truncateToTolerance(*pNew, mRegion.tolerance);
        truncateToTolerance(*tNew, mRegion.tolerance);
    }
    if (growth) openvdb::tools::pruneInactive(growth->tree());
    if (freezeTime) openvdb::tools::pruneInactive(freezeTime->tree());
    if (stats) stats->truncateSeconds += since(t0);
    p = pNew;
    T = tNew;
}

void PhaseFieldSolver::stepSecondOrder(const openvdb::FloatGrid& p, const openvdb::FloatGrid& T,
                                       openvdb::tree::LeafManager<openvdb::FloatTree>& pLeaves,
                                       openvdb::tree::LeafManager<openvdb::FloatTree>& tLeaves,
                                       const std::vector<FloatLeaf*>& gLeaves, const std::vector<FloatLeaf*>& fLeaves,
                                       int64_t stepIndex, double tNext, uint64_t seed, Failure& failure,
                                       PhaseFieldStepStats* stats)
{
    const KobayashiParams& k = mParams;
    const bool plane = mDomain.isPlane();
    const Stencil stencil = mDomain.stencil();
    const SlotLayout layout(pLeaves, stencil, plane);
    ImplicitSystem ps(layout), ts(layout);
    ps.useCoefficients();
    ps.setOutside(p.background());
    ts.setOutside(T.background());
    std::vector<double> p0(ps.rows(), 0.0), T0(ps.rows(), 0.0);
    const double theta = mTheta;
    const double tScale = theta * k.dt, tDiag = 1.0 + theta * k.dt * -stencil.wLapCentre;
    const openvdb::FloatGrid* dP = mLastInP.get();
    const openvdb::FloatGrid* dT = mLastInT.get();
    // Coefficients at theta of the step (the midpoint for Crank-Nicolson, the end for implicit
    // Euler), extrapolated along the last step's increment, scaled to this step's dt.
    const float extrapolate = dP ? float(theta * k.dt / mLastStepDt) : 0.f;
    const int taps = ps.taps();

    // Explicit parts, per leaf on the padded block.
    {
        const Block proto(plane);
        const FlatStencil st(stencil, proto.bx, std::ptrdiff_t(proto.bx) * proto.by);
        const Anisotropy an(k);
        tbb::enumerable_thread_specific<Block> blocks([plane] { return Block(plane); });
        tbb::parallel_for(tbb::blocked_range<size_t>(0, pLeaves.leafCount(), 8), [&](const tbb::blocked_range<size_t>& r) {
            Block& b = blocks.local();
            std::vector<float>& incP = b.cx;
            std::vector<float>& incT = b.cy;
            auto pAcc = p.getConstAccessor();
            auto tAcc = T.getConstAccessor();
            std::unique_ptr<openvdb::FloatGrid::ConstAccessor> mAcc, dpAcc, dtAcc;
            if (mMelt) mAcc = std::make_unique<openvdb::FloatGrid::ConstAccessor>(mMelt->getConstAccessor());
            if (dP) dpAcc = std::make_unique<openvdb::FloatGrid::ConstAccessor>(dP->getConstAccessor());
            if (dT) dtAcc = std::make_unique<openvdb::FloatGrid::ConstAccessor>(dT->getConstAccessor());
            for (size_t li = r.begin(); li != r.end(); ++li) {
                const FloatLeaf& pl = pLeaves.leaf(li);
                const openvdb::Coord origin = pl.origin();
                gather(pAcc, b, origin, b.p);
                gather(tAcc, b, origin, b.T);
                if (mAcc) gather(*mAcc, b, origin, b.melt);
                // cx, cy are free in this scheme and hold the increments since the last step's
                // start, p - p^{n-1}: the last step's own change plus whatever other effects did
                // since (a walker froze the cell, the flow carried heat), so the extrapolation
                // starts from the p the step really sees (the last step's dp alone, after a walker
                // set p = 1, put the reaction's tangent at the old p and pushed p to 1.013).
                if (dpAcc) {
                    gather(*dpAcc, b, origin, incP);
                    for (size_t i = 0; i < incP.size(); ++i) incP[i] = b.p[i] - incP[i];
                } else std::fill(incP.begin(), incP.end(), 0.f);
                if (dtAcc) {
                    gather(*dtAcc, b, origin, incT);
                    for (size_t i = 0; i < incT.size(); ++i) incT[i] = b.T[i] - incT[i];
                } else std::fill(incT.begin(), incT.end(), 0.f);
                // pf (in gz, free in this scheme): p extrapolated to the end of the step.
                for (size_t i = 0; i < b.p.size(); ++i) {
                    b.pe[i] = std::min(1.f, std::max(0.f, b.p[i] + extrapolate * incP[i]));
                    b.te[i] = b.T[i] + extrapolate * incT[i];
                    b.gz[i] = std::min(1.f, std::max(0.f, b.p[i] + extrapolate / float(theta) * incP[i]));
                }
                // eps^2 of the extrapolated phase on the cells with a full ring (the rows read it
                // at the voxels' neighbours for its gradient).
                {
                    const int zs = plane ? 0 : 1, ze = plane ? 1 : b.bz - 1;
                    for (int z = zs; z < ze; ++z)
                        for (int y = 1; y < b.by - 1; ++y)
                            for (int x = 1; x < b.bx - 1; ++x) {
                                const size_t i = b.index(x, y, z);
                                b.a[i] = float(kobayashiEpsSquared(b.pe.data(), i, st, an));
                            }
                }
                for (auto it = pl.cbeginValueOn(); it; ++it) {
                    const openvdb::Coord c = it.getCoord();
                    const openvdb::Coord l = c - origin;
                    const size_t i = b.index(l.x() + kHalo, l.y() + kHalo, plane ? 0 : l.z() + kHalo);
                    const double chi = noiseDraw(k, seed, stepIndex, c);
                    const SecondOrderRow row = kobayashiSecondOrderRow(
                        b.p.data(), b.T.data(), b.pe.data(), b.te.data(), b.gz.data(), b.a.data(), i, st, k,
                        meltTemperatureAt(k, b, i, mMelt != nullptr), chi, theta);
                    const size_t s = size_t(layout.row(li, c));
                    ps.diag[s] = row.diag;
                    std::copy(row.coef, row.coef + taps, &ps.coef[s * size_t(taps)]);
                    ps.rhs[s] = row.rhs;
                    ps.x[s] = row.predictor;
                    p0[s] = b.p[i];
                    T0[s] = b.T[i];
                    // Temperature: theta-weighted lap T; the latent heat is added once p' is known.
                    ts.diag[s] = tDiag;
                    ts.scale[s] = tScale;
                    ts.rhs[s] = b.T[i] + (1.0 - theta) * k.dt * row.lapT;
                }
            }
        });
    }
    auto t0 = Clock::now();
    const LinearSolverKind kind = k.useBiCGSTAB ? LinearSolverKind::BiCGSTAB : LinearSolverKind::GaussSeidel;
    const SolveReport rp = ps.solve(kind, k.solverTolerance, k.solverMaxIterations);
    // The advection and diffusion keep p within [0, 1] (positive coefficients). The linearised
    // reaction still overshoots next to cells a walker froze since the last step (p 1.013 with
    // H 400 on 96^2, 1.05 in the Figure 7 snowflake at step 5): until that is fixed, p is clipped
    // back within [-0.25, 1.25] (the latent heat below uses the clipped change) and counted.
    std::atomic<int64_t> outside{0};
    tbb::parallel_for(tbb::blocked_range<size_t>(0, ps.rows(), 4096), [&](const tbb::blocked_range<size_t>& r) {
        int64_t local = 0;
        for (size_t s = r.begin(); s != r.end(); ++s) {
            double& v = ps.x[s];
            if (v < 0.0 && v >= -0.25) v = 0.0, ++local;
            else if (v > 1.0 && v <= 1.25) v = 1.0, ++local;
        }
        outside += local;
    });
    const auto tHeat = Clock::now();
    // Latent heat, energy-consistent at any solver tolerance: K (p' - p^n) of the p actually
    // taken enters T once, and the T solve starts from T^n + K dp. Its iterates are then convex
    // combinations of that start, the explicit half's old values (positive weights below the
    // stability limit) and the far field, so T never exceeds T^n + K max dp, even after one
    // sweep at reduced precision (a forward-Euler start, dt |w0| > 1, did: frozen cells thawed).
    tbb::parallel_for(tbb::blocked_range<size_t>(0, ts.rows(), 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t s = r.begin(); s != r.end(); ++s) {
            const double heat = k.latentHeat * (ps.x[s] - p0[s]);
            ts.rhs[s] += heat;
            ts.x[s] = T0[s] + heat;
        }
    });
    const SolveReport rt = ts.solve(kind, k.solverTolerance, k.solverMaxIterations);
    if (stats) {
        stats->solveSeconds += since(t0);
        stats->heatSeconds += since(tHeat);
        stats->solverIterationsP += rp.iterations;
        stats->solverIterationsT += rt.iterations;
        stats->solves += 1;
        if (!rp.converged || !rt.converged) stats->unconverged += 1;
        stats->lastResidual = std::max(rp.residual, rt.residual);
        stats->clippedVoxels += outside;
    }

    // Write back, record growth and freezing, remember this step's start values.
    auto lastDp = openvdb::FloatGrid::create(p.background()), lastDt = openvdb::FloatGrid::create(T.background());
    lastDp->tree().topologyUnion(pLeaves.tree());
    lastDt->tree().topologyUnion(pLeaves.tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> dpLeaves(lastDp->tree()), dtLeaves(lastDt->tree());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, pLeaves.leafCount(), 16), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t li = r.begin(); li != r.end(); ++li) {
            FloatLeaf& pl = pLeaves.leaf(li);
            FloatLeaf& tl = tLeaves.leaf(li);
            FloatLeaf& dpl = dpLeaves.leaf(li);
            FloatLeaf& dtl = dtLeaves.leaf(li);
            FloatLeaf* gl = gLeaves[li];
            FloatLeaf* fl = fLeaves[li];
            for (auto it = pl.cbeginValueOn(); it; ++it) {
                const openvdb::Index n = it.pos();
                const openvdb::Coord c = it.getCoord();
                const size_t s = size_t(layout.row(li, c));
                const float pn = float(ps.x[s]), tn = float(ts.x[s]);
                if (!std::isfinite(pn) || pn < -0.05f || pn > 1.05f) failure.report(c, "p (ice)", pn);
                if (!std::isfinite(tn)) failure.report(c, "T (temperature)", tn);
                pl.setValueOnly(n, pn);
                tl.setValueOnly(n, tn);
                const double dp = ps.x[s] - p0[s];
                dpl.setValueOnly(n, float(p0[s]));
                dtl.setValueOnly(n, float(T0[s]));
                if (gl && dp > 0) gl->setValueOn(n, gl->getValue(n) + float(dp));
                if (fl && pn > 0.5f && !fl->isValueOn(n)) fl->setValueOn(n, float(tNext));
            }
        }
    });
    mLastInP = lastDp;
    mLastInT = lastDt;
    mLastStepDt = k.dt;
}

uint64_t PhaseFieldSolver::kernelOnly(const openvdb::MaskGrid& region, const openvdb::FloatGrid& p,
                                      const openvdb::FloatGrid& T, openvdb::FloatGrid& pOut,
                                      openvdb::FloatGrid& tOut) const
{
    pOut.tree().topologyUnion(region.tree());
    tOut.tree().topologyUnion(region.tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> pLeaves(pOut.tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> tLeaves(tOut.tree());
    LeafKernel{mParams, mDomain, p, T, mMelt}.run(pLeaves, tLeaves);
    return pOut.activeVoxelCount();
}

DensePhaseField::DensePhaseField(const KobayashiParams& params, const Lattice& lattice, int nx, int ny)
    : mParams(params), mStencil(lattice.stencil(false)), mNx(nx), mNy(ny), mStride(size_t(nx + 2 * kHalo))
{
    const size_t n = mStride * size_t(ny + 2 * kHalo);
    mP.assign(n, 0.f);
    mT.assign(n, float(params.farTemperature));
    mTn.assign(n, float(params.farTemperature));
    for (auto* v : {&mPn, &mA, &mCx, &mCy, &mGx, &mGy, &mGz}) v->assign(n, 0.f);
}

void DensePhaseField::step()
{
    const FlatStencil st(mStencil, std::ptrdiff_t(mStride), 0);
    const Anisotropy an(mParams);
    const int W = mNx + 2 * kHalo;
    // Pass 1 on every cell with a full ring of neighbours, pass 2 on the domain cells; the halo
    // keeps the far-field values (Dirichlet), as the sparse solver's reads outside the domain do.
    tbb::parallel_for(tbb::blocked_range<int>(1, mNy + 2 * kHalo - 1, 16), [&](const tbb::blocked_range<int>& r) {
        for (int y = r.begin(); y != r.end(); ++y)
            for (int x = 1; x < W - 1; ++x)
                kobayashiAux(mP.data(), size_t(y) * mStride + x, st, an, mA.data(), mCx.data(), mCy.data(),
                             mGx.data(), mGy.data(), mGz.data());
    });
    tbb::parallel_for(tbb::blocked_range<int>(0, mNy, 16), [&](const tbb::blocked_range<int>& r) {
        for (int j = r.begin(); j != r.end(); ++j)
            for (int i = 0; i < mNx; ++i) {
                const size_t idx = index(i, j);
                kobayashiEuler(mP.data(), mT.data(), mA.data(), mCx.data(), mCy.data(), mGx.data(), mGy.data(),
                               mGz.data(), idx, st, mParams, mParams.meltTemperature, 0.0, mPn[idx], mTn[idx]);
            }
    });
    // Halo cells are never written, so both buffer pairs keep the far field there.
    std::swap(mP, mPn);
    std::swap(mT, mTn);
}

} // namespace frostvdb
