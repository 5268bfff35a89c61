/// @file ShellPhaseField.cpp
/// @brief Closest-point heat and phase-field steps on a shell band (see ShellPhaseField.h).
#include <frostvdb/shell/ShellPhaseField.h>

#include <frostvdb/base/Atan.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Lattice.h>
#include <frostvdb/core/Random.h>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <chrono>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace frostvdb::shell {

namespace {
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

template <typename Fn>
void forEachVoxel(size_t n, const Fn& fn)
{
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) fn(i);
    });
}

/// 7-point Laplacian sum_k (u_k - u_i) (times 1/h^2 by the caller); pairs summed x, y, z.
inline double laplacianSum(const ShellBand& b, const std::vector<float>& u, size_t i)
{
    const double u0 = u[i];
    double s = 0;
    for (int a = 0; a < 3; ++a)
        s += (double(u[size_t(b.neighbour(i, 2 * a))]) - u0) + (double(u[size_t(b.neighbour(i, 2 * a + 1))]) - u0);
    return s;
}

/// Central difference (u(+e_a) - u(-e_a)) / 2 along axis a (times 1/h by the caller).
inline double centralDiff(const ShellBand& b, const std::vector<float>& u, size_t i, int a)
{
    return 0.5 * (double(u[size_t(b.neighbour(i, 2 * a + 1))]) - double(u[size_t(b.neighbour(i, 2 * a))]));
}
} // namespace

namespace {
/// Surface nodes: sum_j w_j (u_j - u_i) over node i's stencil, for the weight @a W
/// (&SurfaceTap::lap, ::du or ::dv), in the stencil's fixed order.
template <float SurfaceTap::*W>
inline double tapSum(const ShellBand& b, const float* u, size_t i)
{
    const double u0 = u[i];
    double s = 0;
    for (const SurfaceTap* t = b.tapsBegin(i); t != b.tapsEnd(i); ++t) s += double(t->*W) * (double(u[t->node]) - u0);
    return s;
}
/// The noise draw chi in [-1/2, 1/2) at band voxel @a i: the plane's hash, keyed by the voxel's
/// coordinate (0 without noise).
/// f(first, n) over a leaf's nodes [begin, end) (at least 4) in groups of n = 8, then 4: a tail
/// of 1-3 nodes as the leaf's last four again (each node's values depend on the fields only, so
/// those written twice are written the same): the vector passes' cost.
template <class F>
inline void forEachGroup(size_t begin, size_t end, const F& f)
{
    size_t i = begin;
    for (; i + 8 <= end; i += 8) f(i, 8);
    if (i + 4 <= end) {
        f(i, 4);
        i += 4;
    }
    if (i < end) f(end - 4, 4);
}

/// Asks for a leaf's taps and frames ahead of pass 1: each leaf's taps are a block of their own
/// (about 8 KB), which the hardware's prefetcher only follows after a few misses per page.
inline void prefetchLeaf(const ShellBand& b, const ShellBand::Leaf& l)
{
    if (l.begin == l.end) return;
    auto lines = [](const void* from, const void* to) {
        for (const char* c = static_cast<const char*>(from); c < static_cast<const char*>(to); c += 64)
            __builtin_prefetch(c);
    };
    lines(b.tapsBegin(l.begin), b.tapsEnd(l.end - 1));
    lines(&b.frameFloats(l.begin), &b.frameFloats(l.end - 1) + 1);
}

/// Nodes i .. i + n - 1's new values into pn and tn, a ghost's the background (beyond an open
/// border: 0 and the far temperature, as outside a plane).
inline void storeUpdates(const ShellBand& b, size_t i, size_t n, const float* pNew, const float* tNew, float tInf,
                         float* pn, float* tn)
{
    for (size_t m = 0; m < n; ++m) {
        const bool ghost = b.ghost(i + m);
        pn[i + m] = ghost ? 0.f : pNew[m];
        tn[i + m] = ghost ? tInf : tNew[m];
    }
}

inline double noiseChi(const KobayashiParams& k, const ShellBand& b, size_t i, uint64_t seed, int64_t stepIndex)
{
    if (k.noise == 0) return 0.0;
    const openvdb::Coord& c = b.coord(i);
    return toUnit(hashCounters(seed, uint64_t(stepIndex), coordKey(c.x(), c.y(), c.z()))) - 0.5;
}
/// Kobayashi's reaction p (1 - p) (p - 1/2 + m(T) + a chi) at band voxel @a i: m from the local
/// melt temperature (atan as the surface nodes' vector update takes it: base/Atan.h).
inline double reactionAt(const KobayashiParams& k, const ShellBand& b, const std::vector<float>& melt, size_t i,
                         double p0, double t0v, uint64_t seed, int64_t stepIndex)
{
    const double Te = k.localMeltTemperature(melt.empty() ? 1.0 : double(melt[i]));
    const double m = k.alpha / M_PI * atanCephes(k.gamma * (Te - t0v));
    const double chi = noiseChi(k, b, i, seed, stepIndex);
    return p0 * (1.0 - p0) * (p0 - 0.5 + m + k.noise * chi);
}

/// The explicit steps' timings: kernel [t0, t1), then the extension (or copy-back) until now.
inline void addExplicitStats(ShellStepStats* stats, Clock::time_point t0, Clock::time_point t1, uint64_t updates)
{
    if (!stats) return;
    stats->kernelSeconds += std::chrono::duration<double>(t1 - t0).count();
    stats->extendSeconds += since(t1);
    stats->voxelUpdates += updates;
}
} // namespace

void heatStep(const ShellBand& band, std::vector<float>& u, double dt, double h, std::vector<float>& scratch)
{
    scratch.assign(band.size(), 0.f);
    const double r = dt / (h * h);
    if (band.surfaceNodes()) { // Laplace-Beltrami by the nodes' stencils; nothing to extend
        forEachVoxel(band.size(), [&](size_t i) { scratch[i] = float(u[i] + r * tapSum<&SurfaceTap::lap>(band, u.data(), i)); });
        u.swap(scratch);
        return;
    }
    forEachVoxel(band.size(), [&](size_t i) {
        if (band.inUpdateSet(i)) scratch[i] = float(u[i] + r * laplacianSum(band, u, i));
    });
    band.extend(scratch, u, false);
}

ShellPhaseField::ShellPhaseField(std::shared_ptr<const ShellBand> band, const KobayashiParams& params, double h)
    : mBand(std::move(band)), mParams(params), mAniso(params), mH(h)
{
    // a whole band is stepped whole (the reference); a lazy one around the ice, exactly (tol 0)
    mActive = !mBand->whole();
    grow();
}

void ShellPhaseField::setActiveRegion(bool active, double tolerance)
{
    mActive = active;
    mTolerance = std::max(0.0, tolerance);
    if (!active) mBand->materialiseAll();
    mStepped.clear();
    mOff.clear();
    mInStepped.clear();
    mSlotsSeen = 0;
    mDirty = true;
    grow();
}

size_t ShellPhaseField::steppedVoxels() const
{
    size_t n = 0;
    for (uint32_t s : mStepped) n += mBand->leaves()[s].end - mBand->leaves()[s].begin;
    return n;
}

void ShellPhaseField::setMeltSource(std::function<float(const ShellBand&, size_t)> melt, std::vector<float> now)
{
    mMeltSource = std::move(melt);
    mMelt.clear();
    if (!mMeltSource) return;
    if (now.size() == mBand->size()) {
        mMelt = std::move(now);
        return;
    }
    mMelt.resize(mBand->size());
    const ShellBand& b = *mBand;
    mBand->forEachVoxel(nullptr, [&](size_t i) { mMelt[i] = mMeltSource(b, i); });
}

void ShellPhaseField::grow()
{
    const ShellBand& b = *mBand;
    const size_t n = b.size(), old = mPOld.size();
    if (old == n && mP.size() == n) return;
    const float tInf = float(mParams.farTemperature);
    mP.resize(n, 0.f);
    mT.resize(n, tInf);
    mGrowth.resize(n, 0.f);
    mFreeze.resize(n, 0.f);
    // Voxels never stepped sit at the background with a background neighbourhood: their pass-1
    // coefficients are those of a zero gradient, their extension variable phi that of p = 0
    // (exactly what pass 1 and extendPhase compute there on a whole band).
    double eps0, epsPrime0;
    mAniso(0.0, 0.0, eps0, epsPrime0);
    // lw_cn fades the anisotropy out where p is flat (the plane's kobayashiEpsSquared): eps_bar
    if (b.surfaceNodes()) { // the surface-node step needs no extension or lw_cn arrays
        mCoef.resize(n, SurfaceCoefficients{float(eps0 * eps0), 0.f, 0.f, 0.f});
        mFieldSums.resize(n);
        for (auto* v : {&mPn, &mTn, &mGx, &mGy}) v->resize(n, 0.f);
    } else {
        mA.resize(n, mParams.scheme == PhaseFieldScheme::SecondOrder ? float(mParams.epsBar * mParams.epsBar)
                                                                     : float(eps0 * eps0));
        mStartP.resize(n, 0.f);
        mStartT.resize(n, tInf);
        mPe.resize(n, 0.f);
        mPf.resize(n, 0.f);
        mPhi.resize(n, float(std::atanh(2.0 * 1e-6 - 1.0)));
        for (auto* v : {&mPn, &mTn, &mPOld, &mCx, &mCy, &mCz, &mGx, &mGy, &mGz}) v->resize(n, 0.f);
    }
    if (mMeltSource && mMelt.size() < n) { // the new leaves' melt values, computed as they are built
        const size_t from = mMelt.size();
        mMelt.resize(n);
        for (size_t i = from; i < n; ++i) mMelt[i] = mMeltSource(b, i);
    }
    // a per-voxel wind without a world direction cannot be extended to new voxels
    if (!mWind.empty() && mWind.size() < n && mWindWorld.lengthSqr() == 0.0)
        throw std::logic_error("shell phase field: a per-voxel wind was set before the band grew; build the band "
                               "whole first (ShellBand::materialiseAll)");
    if (mWindWorld.lengthSqr() > 0.0 && mWind.size() < n) {
        const size_t from = mWind.size();
        mWind.resize(n);
        for (size_t i = from; i < n; ++i) {
            const openvdb::Vec3d nr = b.normal(i);
            mWind[i] = openvdb::Vec3f(mWindWorld - nr * mWindWorld.dot(nr));
        }
    }
}

void ShellPhaseField::setWind(const openvdb::Vec3d& wind)
{
    mWind.clear();
    mWindWorld = wind;
    grow();
    if (wind.lengthSqr() == 0.0) return;
    mWind.resize(mBand->size());
    for (size_t i = 0; i < mBand->size(); ++i) {
        const openvdb::Vec3d n = mBand->normal(i);
        mWind[i] = openvdb::Vec3f(wind - n * wind.dot(n));
    }
}

double ShellPhaseField::windStabilityLimit() const
{
    double vmax = 0;
    for (const auto& v : mWind) vmax = std::max(vmax, double(std::fabs(v.x()) + std::fabs(v.y()) + std::fabs(v.z())));
    // dt (6 / h^2 + sum |v_a| / h) <= 1: the upwind heat update stays a positive combination
    return 1.0 / (6.0 / (mH * mH) + vmax / mH);
}

void ShellPhaseField::updateRegion()
{
    const ShellBand& b = *mBand;
    grow();
    const auto& leaves = b.leaves();
    auto recount = [&] {
        mUpdateCount = 0;
        for (uint32_t s : mStepped)
            for (size_t i = leaves[s].begin; i < leaves[s].end; ++i) mUpdateCount += b.inUpdateSet(i) ? 1 : 0;
    };
    if (!mActive) { // the whole band, every leaf
        if (mSlotsSeen == leaves.size()) return;
        mStepped.clear();
        for (uint32_t s = 0; s < leaves.size(); ++s)
            if (leaves[s].end > leaves[s].begin) mStepped.push_back(s);
        mSlotsSeen = leaves.size();
        recount();
        return;
    }
    // Per leaf, the box of its voxels off the background by more than the tolerance. Only
    // stepped leaves can change, unless someone wrote the fields (mDirty) or built leaves since
    // the last scan.
    mOff.resize(leaves.size());
    mInStepped.resize(leaves.size(), 0);
    // every leaf of a whole band is stepped: there is nothing left to add (a scan would only
    // grow the boxes, at 2.4 % of the pane's run on one thread)
    if (!mDirty && mSlotsSeen == leaves.size() && b.whole() && mStepped.size() == mNonEmptyLeaves) {
        mTouched.clear();
        return;
    }
    std::vector<uint32_t> scan;
    if (mDirty || mSlotsSeen != leaves.size()) {
        for (uint32_t s = 0; s < leaves.size(); ++s)
            if (leaves[s].end > leaves[s].begin) scan.push_back(s);
        mNonEmptyLeaves = scan.size();
    } else {
        scan = mStepped;
        for (uint32_t s : mTouched) // leaves another effect wrote (touched()), stepped or not
            if (!mInStepped[s]) scan.push_back(s);
    }
    mTouched.clear();
    mDirty = false;
    // One step reads at most kReach voxels away (see the file comment): every leaf within kReach
    // of an off-background voxel is stepped; the ring of leaves around those stays at the
    // background (built, for the stencils' indices).
    // Surface nodes read their stencil (kTapReach) in each of the two passes.
    const int kReach = b.surfaceNodes() ? 2 * ShellBand::kTapReach + 1 : 9;
    // A stepped leaf whose leaves within kReach are all built and stepped (or hold no voxel)
    // cannot add any: it is marked (mInStepped 2) and never scanned again, as the region only
    // grows (scanning every stepped voxel each step was 3 % of the pane's run).
    // A leaf at the region's edge stays unsaturated for many steps, blocked by the same
    // neighbour: that one is checked first (the 27 look-ups of each such leaf, every step, were
    // 1.3 % of the pane's run on one thread, and serial).
    mBlocker.resize(leaves.size(), 0);
    auto saturated = [&](uint32_t s) {
        if (mInStepped[s] != 1) return mInStepped[s] == 2;
        const openvdb::Coord o = leaves[s].origin;
        const openvdb::Coord lo = leafOrigin(o.offsetBy(-kReach)), hi = leafOrigin(o.offsetBy(kLeafDim - 1 + kReach));
        const int n = (hi.x() - lo.x()) / kLeafDim + 1, count = n * n * n;
        auto blocks = [&](int k) { // neighbour k (x slowest): not built (it may hold voxels), or unstepped
            const int32_t m = b.leafSlot(lo.offsetBy(kLeafDim * (k / (n * n)), kLeafDim * (k / n % n), kLeafDim * (k % n)));
            return m < 0 || (leaves[size_t(m)].end > leaves[size_t(m)].begin && !mInStepped[size_t(m)]);
        };
        if (mBlocker[s] < count && blocks(mBlocker[s])) return false;
        for (int k = 0; k < count; ++k)
            if (blocks(k)) {
                mBlocker[s] = uint8_t(k);
                return false;
            }
        mInStepped[s] = 2;
        return true;
    };
    scan.erase(std::remove_if(scan.begin(), scan.end(), saturated), scan.end());
    const float tol = float(mTolerance), tInf = float(mParams.farTemperature);
    std::vector<openvdb::CoordBBox> off(scan.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, scan.size(), 4), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t k = r.begin(); k < r.end(); ++k) {
            const auto& l = leaves[scan[k]];
            for (size_t i = l.begin; i < l.end; ++i)
                if (std::fabs(mP[i]) > tol || std::fabs(mT[i] - tInf) > tol) off[k].expand(b.coord(i));
        }
    });
    std::vector<openvdb::Coord> stepped;
    for (size_t k = 0; k < scan.size(); ++k) {
        if (off[k].empty()) continue;
        openvdb::CoordBBox& have = mOff[scan[k]];
        if (!have.empty() && have.isInside(off[k])) continue;
        have.expand(off[k]);
        openvdb::CoordBBox box = have;
        box.expand(kReach);
        const openvdb::Coord lo = leafOrigin(box.min()), hi = leafOrigin(box.max());
        for (int x = lo.x(); x <= hi.x(); x += kLeafDim)
            for (int y = lo.y(); y <= hi.y(); y += kLeafDim)
                for (int z = lo.z(); z <= hi.z(); z += kLeafDim) {
                    stepped.emplace_back(x, y, z);
                }
    }
    if (!stepped.empty()) {
        b.prepare(stepped); // builds the ring of leaves around them too
        grow();
        mOff.resize(leaves.size());
        mInStepped.resize(leaves.size(), 0);
        size_t before = mStepped.size();
        for (const auto& o : stepped) {
            const int32_t s = b.leafSlot(o);
            if (s < 0 || mInStepped[size_t(s)] || leaves[size_t(s)].end == leaves[size_t(s)].begin) continue;
            mInStepped[size_t(s)] = 1;
            mStepped.push_back(uint32_t(s));
        }
        if (mStepped.size() != before) {
            std::sort(mStepped.begin(), mStepped.end());
            recount();
        }
    }
    mSlotsSeen = leaves.size();
}

void ShellPhaseField::touched(const std::vector<size_t>& voxels)
{
    const auto& leaves = mBand->leaves();
    for (size_t i : voxels) {
        // the leaf holding band index i: leaves are contiguous index ranges, found by origin
        const int32_t s = mBand->leafSlot(leafOrigin(mBand->coord(i)));
        if (s >= 0 && leaves[size_t(s)].end > leaves[size_t(s)].begin) mTouched.push_back(uint32_t(s));
    }
    std::sort(mTouched.begin(), mTouched.end());
    mTouched.erase(std::unique(mTouched.begin(), mTouched.end()), mTouched.end());
}

void ShellPhaseField::regionState(openvdb::Int32Grid& boxes, openvdb::MaskGrid& stepped) const
{
    const auto& leaves = mBand->leaves();
    auto bacc = boxes.getAccessor();
    auto sacc = stepped.getAccessor();
    for (uint32_t s : mStepped) sacc.setValueOn(leaves[s].origin);
    for (size_t s = 0; s < mOff.size(); ++s) {
        if (mOff[s].empty()) continue;
        const openvdb::Coord d = mOff[s].max() - leaves[s].origin;
        bacc.setValue(mOff[s].min(), 1 + (d.x() << 6 | d.y() << 3 | d.z()));
    }
}

void ShellPhaseField::restoreRegion(const openvdb::Int32Grid& boxes, const openvdb::MaskGrid& stepped)
{
    if (!mActive) return;
    const ShellBand& b = *mBand;
    std::vector<openvdb::Coord> origins;
    for (auto it = stepped.cbeginValueOn(); it; ++it) origins.push_back(it.getCoord());
    b.prepare(origins);
    grow();
    const auto& leaves = b.leaves();
    mOff.assign(leaves.size(), openvdb::CoordBBox());
    mInStepped.assign(leaves.size(), 0);
    mStepped.clear();
    for (const auto& o : origins) {
        const int32_t s = b.leafSlot(o);
        if (s < 0 || leaves[size_t(s)].end == leaves[size_t(s)].begin || mInStepped[size_t(s)]) continue;
        mInStepped[size_t(s)] = 1;
        mStepped.push_back(uint32_t(s));
    }
    std::sort(mStepped.begin(), mStepped.end());
    for (auto it = boxes.cbeginValueOn(); it; ++it) {
        const openvdb::Coord lo = it.getCoord(), o = leafOrigin(lo);
        const int off = *it - 1;
        b.materialise({o});
        mOff.resize(leaves.size());
        mInStepped.resize(leaves.size(), 0);
        const int32_t s = b.leafSlot(o);
        mOff[size_t(s)] = openvdb::CoordBBox(lo, o + openvdb::Coord(off >> 6 & 7, off >> 3 & 7, off & 7));
    }
    grow();
    mUpdateCount = 0;
    for (uint32_t s : mStepped)
        for (size_t i = leaves[s].begin; i < leaves[s].end; ++i) mUpdateCount += b.inUpdateSet(i) ? 1 : 0;
    mDirty = true; // rescan: the boxes only grow from here
    mSlotsSeen = leaves.size();
}

bool ShellPhaseField::takeCrossedLeaves(std::vector<uint32_t>& slots)
{
    slots.clear();
    const bool known = !mCrossedAll;
    for (uint32_t s = 0; s < mCrossed.size(); ++s)
        if (mCrossed[s]) {
            if (known) slots.push_back(s);
            mCrossed[s] = 0;
        }
    mCrossedAll = false;
    return known;
}

void ShellPhaseField::extendAll()
{
    mCrossedAll = true;
    updateRegion();
    const ShellBand& b = *mBand;
    b.extendPhase(mP, mPn, mPhi, &mStepped, &mStepped);
    b.extend(mT, mTn, false, float(mParams.farTemperature), &mStepped);
    b.forEachVoxel(&mStepped, [&](size_t i) {
        mP[i] = mPn[i];
        mT[i] = mTn[i];
    });
}

void ShellPhaseField::step(double time, int64_t stepIndex, uint64_t seed, ShellStepStats* stats)
{
    if (!mBand->surfaceNodes() || mParams.scheme == PhaseFieldScheme::SecondOrder)
        mCrossedAll = true; // only the surface nodes' explicit step records where p crossed 1/2
    if (mParams.scheme == PhaseFieldScheme::SecondOrder) {
        updateRegion();
        const double dt = mParams.dt;
        if (!mHistory) { // Rannacher start-up (PhaseFieldSolver::step): two implicit-Euler half-steps
            stepImplicit(0.5 * dt, 1.0, time - 0.5 * dt, stepIndex, seed, stats);
            stepImplicit(0.5 * dt, 1.0, time, stepIndex, seed, stats);
        } else {
            stepImplicit(dt, 0.5, time, stepIndex, seed, stats);
        }
        return;
    }
    updateRegion();
    if (mBand->surfaceNodes()) {
        stepSurface(time, stepIndex, seed, stats);
        return;
    }
    const ShellBand& b = *mBand;
    const KobayashiParams& k = mParams;
    const double invH = 1.0 / mH, invH2 = invH * invH;
    const auto t0 = Clock::now();
    // Pass 1: eps^2 and C = eps eps' (n x g) on the coefficient set, g the tangential gradient.
    b.forEachVoxel(&mStepped, [&](size_t i) {
        if (!b.inCoefficientSet(i)) return;
        const VoxelFrame f = b.frame(i);
        openvdb::Vec3d g(centralDiff(b, mP, i, 0), centralDiff(b, mP, i, 1), centralDiff(b, mP, i, 2));
        g *= invH;
        g -= f.normal * g.dot(f.normal);
        double eps, epsPrime;
        mAniso(g.dot(f.tangent), g.dot(f.bitangent), eps, epsPrime);
        const openvdb::Vec3d c = f.normal.cross(g) * (eps * epsPrime);
        mA[i] = float(eps * eps);
        mCx[i] = float(c.x());
        mCy[i] = float(c.y());
        mCz[i] = float(c.z());
        mGx[i] = float(g.x());
        mGy[i] = float(g.y());
        mGz[i] = float(g.z());
    });
    // Pass 2: the Euler update on the update set (elsewhere the new values are the old ones:
    // only nodes, all in the update set, are read by the extension).
    mPn = mP;
    mTn = mT;
    b.forEachVoxel(&mStepped, [&](size_t i) {
        if (!b.inUpdateSet(i)) return;
        const double p0 = mP[i], t0v = mT[i];
        const double lapP = laplacianSum(b, mP, i) * invH2, lapT = laplacianSum(b, mT, i) * invH2;
        const double dax = centralDiff(b, mA, i, 0) * invH, day = centralDiff(b, mA, i, 1) * invH,
                     daz = centralDiff(b, mA, i, 2) * invH;
        const double divC = (centralDiff(b, mCx, i, 0) + centralDiff(b, mCy, i, 1) + centralDiff(b, mCz, i, 2)) * invH;
        const double div = double(mA[i]) * lapP + dax * mGx[i] + day * mGy[i] + daz * mGz[i];
        const double reaction = reactionAt(k, b, mMelt, i, p0, t0v, seed, stepIndex);
        const double dp = k.dt / k.tau * (div + divC + reaction);
        mPn[i] = float(p0 + dp);
        double adv = 0; // v . grad T, upwind
        if (!mWind.empty())
            for (int a = 0; a < 3; ++a) {
                const double v = mWind[i][a];
                if (v > 0) adv += v * (t0v - double(mT[size_t(b.neighbour(i, 2 * a))])) * invH;
                else if (v < 0) adv += v * (double(mT[size_t(b.neighbour(i, 2 * a + 1))]) - t0v) * invH;
            }
        mTn[i] = float(t0v + k.dt * (lapT - adv) + k.latentHeat * dp);
    });
    const auto t1 = Clock::now();
    // Re-extension: p through its sharp-profile variant (ShellBand::extendPhase), T plain.
    mPOld = mP;
    b.extendPhase(mPn, mP, mPhi, &mStepped, &mStepped);
    b.extend(mTn, mT, false, float(k.farTemperature), &mStepped);
    const float tNext = float(time);
    b.forEachVoxel(&mStepped, [&](size_t i) {
        recordGrowth(mGrowth[i], mFreeze[i], mP[i] - mPOld[i], mP[i], tNext);
    });
    addExplicitStats(stats, t0, t1, mUpdateCount);
}

void ShellPhaseField::stepSurface(double time, int64_t stepIndex, uint64_t seed, ShellStepStats* stats)
{
    // The plane's Euler step (kobayashiAux / kobayashiEuler) with its differences replaced by the
    // nodes' surface stencils, in each node's tangent frame (t, b, n):
    //   pass 1: g = (dp/dt, dp/db), a = eps^2(theta(g)), C = eps eps' (n x g) as a world vector;
    //   pass 2: tau dp/dt = a lap p + grad a . g + div C + reaction, where div C sums the
    //           neighbours' C projected on this node's t and b (exact for a tangent field: the
    //           surface divergence is the trace of its derivative on the tangent plane);
    //           T' = T + dt (lap T - w . grad T) + K dp, the wind w's advection centred with
    //           the upwind scheme's diffusion |w| h / 2 added (first order, as the plane's upwind).
    const ShellBand& b = *mBand;
    const KobayashiParams& k = mParams;
    const double invH = 1.0 / mH, invH2 = invH * invH;
    const auto t0 = Clock::now();
    const float* P = mP.data();
    const float* T = mT.data();
    const auto& leaves = b.leaves();
    // stage 1, pass 1: the sums of p and T, the gradient and coefficients (shell/SurfaceTapSums.h)
    const SurfaceCoefficients4 coefficients4 = fastestSurfaceCoefficients4(mAniso);
    const SurfaceCoefficients4 coefficients8 = fastestSurfaceCoefficients8(mAniso);
    // T's tangential derivatives only where a wind reads them
    if (mWind.empty()) std::vector<WindSums>().swap(mWindSums);
    else mWindSums.resize(b.size());
    WindSums* wind = mWind.empty() ? nullptr : mWindSums.data();
    SurfaceCoefficients* coef = mCoef.data();
    float *gx = mGx.data(), *gy = mGy.data();
    auto coefficientsOf = [&](uint32_t slot) {
        const ShellBand::Leaf& l = leaves[slot];
        if (l.end - l.begin < 4) {
            for (size_t i = l.begin; i < l.end; ++i)
                surfaceCoefficients(b, P, T, mAniso, invH, i, coef, gx, gy, mFieldSums.data(), wind);
            return;
        }
        forEachGroup(l.begin, l.end, [&](size_t i, size_t n) {
            (n == 8 ? coefficients8 : coefficients4)(b, P, T, mAniso, invH, i, coef, gx, gy, mFieldSums.data(), wind);
        });
    };
    const SurfaceCoefficients* C = mCoef.data();
    const FieldSums* sums = mFieldSums.data();
    const float tNext = float(time);
    const float tInf = float(k.farTemperature);
    // stage 2, pass 2: the sums of the coefficients, node i's update (shell/SurfaceTapSums.h)
    const SurfaceUpdateInputs inputs{P, T, C, gx, gy, mMelt.empty() ? nullptr : mMelt.data(), &k, invH, invH2};
    auto update = [&](size_t i, const TapSums& s) {
        if (b.ghost(i)) { // beyond an open border: the background, as outside a plane
            mPn[i] = 0.f;
            mTn[i] = tInf;
            return;
        }
        const double chi = noiseChi(k, b, i, seed, stepIndex);
        if (!wind) {
            surfaceUpdate(inputs, i, s, chi, mPn[i], mTn[i]);
            return;
        }
        // the wind's advection of T, centred, with the upwind scheme's diffusion |w| h / 2
        const VoxelFrame f = b.frame(i);
        const double wu = f.tangent.dot(mWind[i]), wv = f.bitangent.dot(mWind[i]);
        const double windHeat = -(wu * s.dtu + wv * s.dtv) * invH + 0.5 * std::sqrt(wu * wu + wv * wv) * s.lapT * invH;
        surfaceUpdate(inputs, i, s, chi, mPn[i], mTn[i], &windHeat);
    };
    const TapSums4 sums4 = fastestTapSums4();
    const SurfacePass2 pass2 = fastestSurfacePass2();
    const SurfacePass2 pass2x8 = fastestSurfacePass2x8();
    auto updateOf = [&](uint32_t slot) {
        const ShellBand::Leaf& l = leaves[slot];
        if (l.end - l.begin < 4) {
            for (size_t i = l.begin; i < l.end; ++i) update(i, tapSums(b, C, sums, wind, i));
            return;
        }
        forEachGroup(l.begin, l.end, [&](size_t i, size_t n) {
            if (wind) {
                for (size_t q = i; q < i + n; q += 4) {
                    TapSums s[4];
                    sums4(b, C, sums, wind, q, s);
                    for (size_t m = 0; m < 4; ++m) update(q + m, s[m]);
                }
                return;
            }
            double chi[8];
            float pNew[8], tNew[8];
            for (size_t m = 0; m < n; ++m) chi[m] = noiseChi(k, b, i + m, seed, stepIndex);
            (n == 8 ? pass2x8 : pass2)(b, inputs, sums, i, chi, pNew, tNew);
            storeUpdates(b, i, n, pNew, tNew, tInf, mPn.data(), mTn.data());
        });
    };
    // stage 3: the new values become the fields, growth and freeze time recorded, and per leaf
    // whether p crossed 1/2 anywhere in it ([dla] then rescans only those leaves)
    mCrossed.resize(leaves.size(), 0);
    const SurfaceCommitRange commit = fastestSurfaceCommit();
    const SurfaceCommit committed{mP.data(),  mT.data(),  mGrowth.data(),      mFreeze.data(),
                                  mPn.data(), mTn.data(), b.lateralOffsets(), b.hasGhosts(), tNext};
    auto commitOf = [&](uint32_t slot) {
        const ShellBand::Leaf& l = leaves[slot];
        if (commit(committed, l.begin, l.end)) mCrossed[slot] = 1;
    };
    if (mSlabSweep) {
        // one sweep, the stages a few slabs apart: the taps and frames read by pass 1 are still
        // in cache for pass 2 (shell/SlabSweep.h; the same bits as the three passes below)
        if (mSweepSlots != mStepped) {
            // a few ranges per thread: a thread slowed by the machine takes fewer of them
            mSweep.build(leaves, mStepped, 4 * size_t(tbb::this_task_arena::max_concurrency()));
            mSweepSlots = mStepped;
        }
        mSweep.run(coefficientsOf, updateOf, commitOf, [&](uint32_t slot) { prefetchLeaf(b, leaves[slot]); });
    } else {
        // the reference: three passes over every stepped leaf
        auto eachStepped = [&](const auto& stage) {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, mStepped.size(), 2), [&](const tbb::blocked_range<size_t>& r) {
                for (size_t q = r.begin(); q < r.end(); ++q) stage(mStepped[q]);
            });
        };
        eachStepped(coefficientsOf);
        eachStepped(updateOf);
        eachStepped(commitOf);
    }
    const auto t1 = Clock::now();
    addExplicitStats(stats, t0, t1, mUpdateCount);
}

namespace {
/// eps^2 of eq. 8 at voxel i from the central gradient of @a pe projected on the tangent plane,
/// the angle in the voxel's frame, faded out where p is flat exactly as the plane's
/// kobayashiEpsSquared (generic form) does.
inline double shellEpsSquared(const ShellBand& b, const std::vector<float>& pe, size_t i, double invH,
                              const Anisotropy& an, double flat2)
{
    const VoxelFrame f = b.frame(i);
    openvdb::Vec3d g(centralDiff(b, pe, i, 0), centralDiff(b, pe, i, 1), centralDiff(b, pe, i, 2));
    g *= invH;
    const double sx = g.dot(f.tangent), sy = g.dot(f.bitangent);
    double eps, epsPrime;
    an(sx, sy, eps, epsPrime);
    const double g2 = sx * sx + sy * sy;
    eps = an.epsBar + (eps - an.epsBar) * std::pow(g2 / (g2 + flat2), 0.5 * an.j);
    return eps * eps;
}
} // namespace

void ShellPhaseField::stepImplicit(double dt, double theta, double tNext, int64_t stepIndex, uint64_t seed,
                                   ShellStepStats* stats)
{
    KobayashiParams k = mParams;
    k.dt = dt; // the reaction part reads r = dt / tau
    const auto t0 = Clock::now();
    const BandRows& rows = implicitRows();
    // The theta-point estimates, extrapolated along the last step's increment p - p^{n-1} (which
    // holds whatever other effects wrote since, as on a plane), scaled to this step's dt.
    const float ex = mHistory ? float(theta * dt / mLastDt) : 0.f;
    thetaPointCoefficients(k, ex);
    implicitExtensions(rows, ex, float(theta));
    assembleImplicitRows(rows, k, theta, ex, stepIndex, seed);
    const auto t1 = Clock::now();
    const SolveReport rp = mSysP.solve(*mBand, rows, mXP, k.solverTolerance, k.solverMaxIterations);
    ClipCount clips = clipImplicitPhase(rows, tNext, dt);
    // Latent heat of the p actually taken, once; the T solve starts from T^n + K dp.
    for (size_t row = 0; row < rows.rows(); ++row) {
        const double heat = k.latentHeat * (mXP[row] - mP0[row]);
        mSysT.rhs[row] += heat;
        mXT[row] += heat;
    }
    const SolveReport rt = mSysT.solve(*mBand, rows, mXT, k.solverTolerance, k.solverMaxIterations);
    const auto t2 = Clock::now();
    writeBackImplicit(rows, tNext);
    mHistory = true;
    mLastDt = dt;
    if (stats) {
        stats->kernelSeconds += std::chrono::duration<double>(t1 - t0).count();
        stats->solveSeconds += std::chrono::duration<double>(t2 - t1).count();
        stats->extendSeconds += since(t2);
        stats->voxelUpdates += rows.rows();
        stats->solves += 1;
        stats->iterationsP += rp.iterations;
        stats->iterationsT += rt.iterations;
        stats->unconverged += (!rp.converged || !rt.converged) ? 1 : 0;
        stats->clippedVoxels += clips.clipped;
        stats->maxClip = std::max(stats->maxClip, clips.maxClip);
        stats->lastResidual = std::max(rp.residual, rt.residual);
    }
}

const BandRows& ShellPhaseField::implicitRows()
{
    const ShellBand& b = *mBand;
    if (!mRows) mRows = std::make_unique<BandRows>();
    if (mRowsStepped != mStepped.size() || mRowsBand != b.size()) { // the stepped set only grows
        mRows->build(b, mStepped);
        mRowsStepped = mStepped.size();
        mRowsBand = b.size();
    }
    return *mRows;
}

void ShellPhaseField::thetaPointCoefficients(const KobayashiParams& k, float ex)
{
    const ShellBand& b = *mBand;
    const double invH = 1.0 / mH;
    b.forEachVoxel(&mStepped, [&](size_t i) {
        mPe[i] = std::min(1.f, std::max(0.f, mP[i] + ex * (mP[i] - mStartP[i])));
    });
    // eps^2 of pe on the coefficient set (the rows' neighbours read it)
    const Anisotropy an(k);
    const double flat2 = (kFlatGradientPerCell * invH) * (kFlatGradientPerCell * invH);
    b.forEachVoxel(&mStepped, [&](size_t i) {
        if (b.inCoefficientSet(i)) mA[i] = float(shellEpsSquared(b, mPe, i, invH, an, flat2));
    });
}

void ShellPhaseField::implicitExtensions(const BandRows& rows, float ex, float theta)
{
    const ShellBand& b = *mBand;
    const float tInf = float(mParams.farTemperature);
    // T: the start values' extension at the rows' neighbours (the explicit half reads E T^n, as
    // the implicit half reads E T'), and the fixed nodes' part of it (right-hand side).
    rows.extendAt(b, mT, tInf, mET, mETFixed);
    // p: its interface is narrower than a voxel, where a cubic through p overshoots (tilted plates
    // grew 7 % more ice than the plane with E linear in p). The neighbours read the explicit
    // path's extension of atanh(2p - 1) (ShellBand::extendPhase, Ep below) instead, linearised
    // about pf, p extrapolated to the end of the step: E p' ~ Ep(pf) + E (p' - pf). The implicit
    // operator stays linear (E on the increment, O(dt^2) small) and the step second order.
    b.forEachVoxel(&mStepped, [&](size_t i) {
        mPf[i] = std::min(1.f, std::max(0.f, mP[i] + (ex / theta) * (mP[i] - mStartP[i])));
    });
    b.extendPhase(mP, mPn, mPhi, &mStepped, &mStepped);  // Ep(p^n)
    b.extendPhase(mPf, mTn, mPhi, &mStepped, &mStepped); // Ep(pf)
    rows.extendAt(b, mPf, 0.0, mEP, mEPFixed);            // E pf: full, and its fixed nodes' part
    mEPhiN.resize(rows.points());
    mEPhiF.resize(rows.points());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, rows.points(), 4096), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t m = range.begin(); m < range.end(); ++m) {
            const size_t q = rows.pointVoxel(m);
            if (rows.pointFixed(m)) { // a leaf not stepped: its own value, fixed
                mEPhiN[m] = mEPhiF[m] = mP[q];
                mEP[m] = 0.0;
            } else {
                mEPhiN[m] = mPn[q];
                mEPhiF[m] = mTn[q];
                mEP[m] -= mEPFixed[m]; // E pf over the rows' nodes only (the unknowns' part)
            }
        }
    });
}

void ShellPhaseField::assembleImplicitRows(const BandRows& rows, const KobayashiParams& k, double theta, float ex,
                                           int64_t stepIndex, uint64_t seed)
{
    const ShellBand& b = *mBand;
    const double dt = k.dt, invH = 1.0 / mH;
    const float tInf = float(k.farTemperature);
    const size_t n = rows.rows();
    // The plane's 7-point stencil (taps +x, -x, +y, -y, +z, -z) over a 7-value local gather,
    // centre at 0, tap q at 1 + q: advectionDiffusionCoefficients runs unchanged on it.
    FlatStencil st(Lattice(LatticeKind::Square, mH).stencil(true), 0, 0);
    for (int q = 0; q < 6; ++q) st.off[q] = 1 + q;
    auto slotOf = [](int q) { return q ^ 1; }; // band neighbour order: -x, +x, -y, +y, -z, +z
    mSysP.resize(n);
    mSysT.resize(n);
    mXP.resize(n);
    mXT.resize(n);
    mP0.resize(n);
    const double r = dt / k.tau, invH2 = invH * invH;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 512), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t row = range.begin(); row < range.end(); ++row) {
            const size_t i = rows.voxel(row);
            float a7[7];
            a7[0] = mA[i];
            for (int q = 0; q < 6; ++q) a7[1 + q] = mA[size_t(b.neighbour(i, slotOf(q)))];
            double C[FlatStencil::kMaxTaps];
            const double sumC = advectionDiffusionCoefficients(a7, 0, st, C);
            const double p0 = mP[i], tau0 = double(mT[i]) - tInf;
            double Lp = 0, lapT = 0, sumCT = 0, CT[6];
            double correction = 0; // sum C_q (Ep(pf) - E pf)_q: the implicit half's known part
            for (int q = 0; q < 6; ++q) {
                const size_t m = rows.point(row, slotOf(q));
                Lp += C[q] * (mEPhiN[m] - p0);
                correction += C[q] * (mEPhiF[m] - mEP[m]);
                CT[q] = invH2;
            }
            if (!mWind.empty()) // v . grad T, upwind: the upwind neighbour's coefficient grows by |v| / h
                for (int a = 0; a < 3; ++a) {
                    const double v = mWind[i][a];
                    if (v > 0) CT[2 * a + 1] += v * invH;      // tap -a
                    else if (v < 0) CT[2 * a] += -v * invH;    // tap +a
                }
            for (int q = 0; q < 6; ++q) {
                const size_t m = rows.point(row, slotOf(q));
                lapT += CT[q] * (mET[m] - tau0);
                sumCT += CT[q];
            }
            // the reaction at the theta-point (the plane's kobayashiReactionPart)
            const double te = mT[i] + ex * (mT[i] - mStartT[i]);
            const double pf = mPf[i];
            const double Te = k.localMeltTemperature(mMelt.empty() ? 1.0 : double(mMelt[i]));
            double chi = 0;
            if (k.noise != 0) {
                const openvdb::Coord& c = b.coord(i);
                chi = toUnit(hashCounters(seed, uint64_t(stepIndex), coordKey(c.x(), c.y(), c.z()))) - 0.5;
            }
            const double x = k.gamma * (Te - te);
            const ReactionPart rp = kobayashiReactionPart(p0, mPe[i], pf, x, k.noise * chi, k, theta,
                                                          1.0 - (1.0 - theta) * r * sumC);
            double fixedT = 0;
            for (int q = 0; q < 6; ++q) {
                const int s = slotOf(q);
                const size_t m = rows.point(row, s);
                mSysP.coef[6 * row + size_t(s)] = theta * r * C[q];
                mSysT.coef[6 * row + size_t(s)] = theta * dt * CT[q];
                fixedT += theta * dt * CT[q] * mETFixed[m];
            }
            mSysP.diag[row] = 1.0 + theta * r * sumC + rp.diag;
            mSysP.rhs[row] = p0 + (1.0 - theta) * r * Lp + rp.rhs + theta * r * correction;
            const ReactionPart fe = kobayashiReactionPart(p0, mPe[i], pf, x, k.noise * chi, k, 0.0);
            mXP[row] = std::fmin(1.0, std::fmax(0.0, p0 + r * Lp + fe.rhs - fe.diag * p0)); // bounded guess
            mSysT.diag[row] = 1.0 + theta * dt * sumCT;
            mSysT.rhs[row] = tau0 + (1.0 - theta) * dt * lapT + fixedT;
            mXT[row] = tau0 + dt * lapT; // forward Euler: a first guess O(dt^2) from the answer
            mP0[row] = p0;
        }
    });
}

ShellPhaseField::ClipCount ShellPhaseField::clipImplicitPhase(const BandRows& rows, double tNext, double dt)
{
    // As on a plane: p' leaves [0, 1] by rounding (set back silently) or where the solve is not a
    // positive scheme, which the band system never is: the extension's cubic weights are not all
    // positive, so p' dips a little below 0 ahead of a tilted front (about 0.3 % of the row
    // updates on a 30-degree plate, by less than 1e-3). Within [-0.25, 1.25] it is clipped and
    // counted (with the largest distance); beyond, the step fails.
    constexpr double kRounding = 1e-12;
    ClipCount out;
    for (size_t row = 0; row < rows.rows(); ++row) {
        double& v = mXP[row];
        if (!std::isfinite(v) || v < -0.25 || v > 1.25) {
            std::ostringstream os;
            os << "shell phase field (lw_cn) left its bounds: p = " << v << " at voxel "
               << mBand->coord(rows.voxel(row)) << " (t = " << tNext << "); dt = " << dt
               << ". Lower phase_field.dt or tighten the solver tolerance";
            throw SimulationError(os.str());
        }
        out.maxClip = std::max({out.maxClip, -v, v - 1.0});
        if (v < 0.0) out.clipped += v < -kRounding, v = 0.0;
        else if (v > 1.0) out.clipped += v > 1.0 + kRounding, v = 1.0;
    }
    return out;
}

void ShellPhaseField::writeBackImplicit(const BandRows& rows, double tNext)
{
    // Write back: the start values become the history, rows take the solution, the voxels that
    // are not rows (d > 3.5) the extension of it.
    const ShellBand& b = *mBand;
    const float tInf = float(mParams.farTemperature);
    b.forEachVoxel(&mStepped, [&](size_t i) {
        mStartP[i] = mP[i];
        mStartT[i] = mT[i];
    });
    tbb::parallel_for(tbb::blocked_range<size_t>(0, rows.rows(), 4096), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t row = range.begin(); row < range.end(); ++row) {
            const size_t i = rows.voxel(row);
            mP[i] = float(mXP[row]);
            mT[i] = float(mXT[row] + tInf);
            if (!std::isfinite(mT[i])) throw SimulationError("shell phase field (lw_cn): T is not finite");
        }
    });
    b.extendPhase(mP, mPn, mPhi, &mStepped, &mStepped);
    b.extend(mT, mTn, false, tInf, &mStepped);
    const float tn = float(tNext);
    b.forEachVoxel(&mStepped, [&](size_t i) {
        if (rows.rowOf(i) < 0) {
            mP[i] = mPn[i];
            mT[i] = mTn[i];
        }
        const float d = mP[i] - mStartP[i];
        if (d > 0.f) mGrowth[i] += d;
        if (mFreeze[i] == 0.f && mP[i] > 0.5f) mFreeze[i] = tn;
    });
}

} // namespace frostvdb::shell
