/// @file ShellPhaseField.cpp
/// @brief Closest-point heat and phase-field steps on a shell band (see ShellPhaseField.h).
#include <frostvdb/shell/ShellPhaseField.h>

#include <frostvdb/core/Random.h>

#include <tbb/parallel_for.h>

#include <chrono>
#include <algorithm>
#include <cmath>

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

void heatStep(const ShellBand& band, std::vector<float>& u, double dt, double h, std::vector<float>& scratch)
{
    scratch.assign(band.size(), 0.f);
    const double r = dt / (h * h);
    forEachVoxel(band.size(), [&](size_t i) {
        if (band.inUpdateSet(i)) scratch[i] = float(u[i] + r * laplacianSum(band, u, i));
    });
    band.extend(scratch, u, false);
}

ShellPhaseField::ShellPhaseField(std::shared_ptr<const ShellBand> band, const KobayashiParams& params, double h)
    : mBand(std::move(band)), mParams(params), mAniso(params), mH(h)
{
    const size_t n = mBand->size();
    mP.assign(n, 0.f);
    mT.assign(n, float(params.farTemperature));
    mGrowth.assign(n, 0.f);
    mFreeze.assign(n, 0.f);
    for (auto* v : {&mA, &mCx, &mCy, &mCz, &mGx, &mGy, &mGz}) v->assign(n, 0.f);
    for (size_t i = 0; i < n; ++i) mUpdateCount += mBand->inUpdateSet(i) ? 1 : 0;
}

void ShellPhaseField::setWind(const openvdb::Vec3d& wind)
{
    mWind.clear();
    if (wind.lengthSqr() == 0.0) return;
    mWind.resize(mBand->size());
    for (size_t i = 0; i < mBand->size(); ++i) {
        const openvdb::Vec3d& n = mBand->frame(i).normal;
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

void ShellPhaseField::extendAll()
{
    mBand->extendPhase(mP, mPn, mA);
    mBand->extend(mT, mTn, false);
    mP.swap(mPn);
    mT.swap(mTn);
}

void ShellPhaseField::step(double time, int64_t stepIndex, uint64_t seed, ShellStepStats* stats)
{
    const ShellBand& b = *mBand;
    const KobayashiParams& k = mParams;
    const double invH = 1.0 / mH, invH2 = invH * invH;
    const auto t0 = Clock::now();
    // Pass 1: eps^2 and C = eps eps' (n x g) on the coefficient set, g the tangential gradient.
    forEachVoxel(b.size(), [&](size_t i) {
        if (!b.inCoefficientSet(i)) return;
        const VoxelFrame& f = b.frame(i);
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
    // Pass 2: the Euler update on the update set.
    mPn.assign(b.size(), 0.f);
    mTn.assign(b.size(), 0.f);
    forEachVoxel(b.size(), [&](size_t i) {
        if (!b.inUpdateSet(i)) return;
        const double p0 = mP[i], t0v = mT[i];
        const double lapP = laplacianSum(b, mP, i) * invH2, lapT = laplacianSum(b, mT, i) * invH2;
        const double dax = centralDiff(b, mA, i, 0) * invH, day = centralDiff(b, mA, i, 1) * invH,
                     daz = centralDiff(b, mA, i, 2) * invH;
        const double divC = (centralDiff(b, mCx, i, 0) + centralDiff(b, mCy, i, 1) + centralDiff(b, mCz, i, 2)) * invH;
        const double div = double(mA[i]) * lapP + dax * mGx[i] + day * mGy[i] + daz * mGz[i];
        const double Te = k.localMeltTemperature(mMelt.empty() ? 1.0 : double(mMelt[i]));
        const double m = k.alpha / M_PI * std::atan(k.gamma * (Te - t0v));
        double chi = 0; // the plane's noiseDraw: same hash, keyed by the voxel's coordinate
        if (k.noise != 0) {
            const openvdb::Coord& c = b.coord(i);
            chi = toUnit(hashCounters(seed, uint64_t(stepIndex), coordKey(c.x(), c.y(), c.z()))) - 0.5;
        }
        const double reaction = p0 * (1.0 - p0) * (p0 - 0.5 + m + k.noise * chi);
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
    std::vector<float>& pOld = mPOld;
    pOld = mP;
    b.extendPhase(mPn, mP, mA); // mA is scratch here: pass 1 rewrites it where it is read
    b.extend(mTn, mT, false);
    const float tNext = float(time);
    forEachVoxel(b.size(), [&](size_t i) {
        const float d = mP[i] - pOld[i];
        if (d > 0.f) mGrowth[i] += d;
        if (mFreeze[i] == 0.f && mP[i] > 0.5f) mFreeze[i] = tNext;
    });
    if (stats) {
        stats->kernelSeconds += std::chrono::duration<double>(t1 - t0).count();
        stats->extendSeconds += since(t1);
        stats->voxelUpdates += mUpdateCount;
    }
}

} // namespace frostvdb::shell
