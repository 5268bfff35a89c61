/// @file Aggregate.cpp
/// @brief The [dla3d] growth loop: speculative walker batches and their deterministic commit.
#include <frostvdb/dla3d/Aggregate.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

namespace frostvdb::dla3d {

using openvdb::Vec3d;
using Clock = std::chrono::steady_clock;

struct Aggregate::Environment {
    openvdb::Mat3d rot = openvdb::Mat3d::identity(); ///< turns the launch region and the bias
    bool rotated = false;
    Vec3d bias{0, 0, 0};
    bool exactFar = false; ///< sphere launch without bias: exact escape/return outside the sphere
    double launchR = 0;    ///< sphere launch radius
    double killR = 0;      ///< other launches: relaunch beyond this distance from the centre
};

Aggregate::Aggregate(DlaSettings s)
    : mSettings(std::move(s)), mHash(mSettings.cellFactor * (mSettings.contact() + mSettings.stickDistance),
                                     mSettings.dimension)
{
    auto& st = mSettings;
    if (st.dimension != 2 && st.dimension != 3) throw std::invalid_argument("dla3d: dimension must be 2 or 3");
    if (!(st.radius > 0) || !(st.stickDistance > 0)) throw std::invalid_argument("dla3d: radius and stick distance must be > 0");
    if (st.cellFactor < 1.0) throw std::invalid_argument("dla3d: cell factor must be >= 1");
    if (st.seeds.empty()) throw std::invalid_argument("dla3d: at least one seed is needed");
    if (st.launch == Launch::Surface && (!st.launchMesh || st.launchMesh->empty()))
        throw std::invalid_argument("dla3d: surface launch needs a mesh");
    if (st.dimension == 2) {
        for (auto& p : st.seeds) p.z() = 0;
        st.bias.z() = 0;
        st.centre.z() = 0;
        st.rotationAxis = Vec3d(0, 0, 1);
    }
    if (!st.centreGiven) {
        Vec3d c(0, 0, 0);
        for (const auto& p : st.seeds) c += p;
        st.centre = c / double(st.seeds.size());
    }
    if (st.rotationAxis.length() > 0) st.rotationAxis.normalize();
    else st.rotationAxis = Vec3d(0, 0, 1);
    if (st.launchMargin <= 0) st.launchMargin = 2.0 * st.contact() + st.stickDistance;
    mCentre = st.centre;
    if (st.launchMesh) {
        double acc = 0;
        for (size_t t = 0; t < st.launchMesh->triangles.size(); ++t) mLaunchCdf.push_back(acc += st.launchMesh->area(t));
    }
    for (const auto& p : st.seeds) add(p, -1);
}

void Aggregate::add(const Vec3d& p, int32_t parent)
{
    const uint32_t id = uint32_t(mPos.size());
    mPos.push_back(p);
    mParent.push_back(parent);
    mGeneration.push_back(parent < 0 ? 0 : mGeneration[size_t(parent)] + 1);
    mHash.insert(id, p);
    mRadius = std::max(mRadius, (p - mCentre).length() + mSettings.radius);
    mBox.expand(p);
}

Vec3d Aggregate::randomDirection(CounterRng& rng) const
{
    const double phi = 2.0 * M_PI * rng.uniform();
    if (mSettings.dimension == 2) return Vec3d(std::cos(phi), std::sin(phi), 0.0);
    const double u = 2.0 * rng.uniform() - 1.0;
    const double s = std::sqrt(std::max(0.0, 1.0 - u * u));
    return Vec3d(s * std::cos(phi), s * std::sin(phi), u);
}

Vec3d Aggregate::launchPoint(CounterRng& rng, const Environment& env) const
{
    const auto& st = mSettings;
    Vec3d p;
    switch (st.launch) {
    case Launch::Sphere: return mCentre + randomDirection(rng) * env.launchR;
    case Launch::Axis: {
        const Vec3d d = st.axisB - st.axisA;
        p = st.axisA + d * rng.uniform();
        if (st.axisSpread > 0) {
            // uniform on a disc (3D) or segment (2D) across the axis
            Vec3d n = d.length() > 0 ? d.unit() : Vec3d(0, 0, 1);
            Vec3d e1 = std::abs(n.x()) < 0.9 ? n.cross(Vec3d(1, 0, 0)) : n.cross(Vec3d(0, 1, 0));
            e1.normalize();
            if (st.dimension == 2) {
                e1 = Vec3d(-n.y(), n.x(), 0);
                p += e1 * (st.axisSpread * (2.0 * rng.uniform() - 1.0));
            } else {
                const Vec3d e2 = n.cross(e1);
                const double r = st.axisSpread * std::sqrt(rng.uniform()), a = 2.0 * M_PI * rng.uniform();
                p += e1 * (r * std::cos(a)) + e2 * (r * std::sin(a));
            }
        }
        break;
    }
    case Launch::Plane: p = st.planeOrigin + st.planeU * rng.uniform() + st.planeV * rng.uniform(); break;
    case Launch::Surface: {
        const double x = rng.uniform() * mLaunchCdf.back();
        const size_t t = std::min<size_t>(size_t(std::upper_bound(mLaunchCdf.begin(), mLaunchCdf.end(), x) -
                                                 mLaunchCdf.begin()), mLaunchCdf.size() - 1);
        const auto& m = *st.launchMesh;
        const auto& f = m.triangles[t];
        double u = rng.uniform(), v = rng.uniform();
        if (u + v > 1.0) { u = 1.0 - u; v = 1.0 - v; }
        const Vec3d a(m.points[f[0]]), b(m.points[f[1]]), c(m.points[f[2]]);
        p = a + (b - a) * u + (c - a) * v + m.normal(t) * st.launchOffset;
        break;
    }
    }
    if (env.rotated) p = mCentre + env.rot * (p - mCentre);
    if (st.dimension == 2) p.z() = 0;
    return p;
}

Aggregate::Candidate Aggregate::walk(uint64_t walkerId, const Environment& env) const
{
    const auto& st = mSettings;
    Candidate c;
    CounterRng rng(st.seed, walkerId, 0xD1A3D);
    const double contact = st.contact(), touch = contact + st.stickDistance;
    const bool biased = env.bias.lengthSqr() > 0;
    Vec3d p = launchPoint(rng, env);
    int hint = 8;
    const double launchR2 = env.launchR * env.launchR, killR2 = env.killR * env.killR;
    for (int64_t s = 0; s < st.maxStepsPerWalker; ++s) {
        const Vec3d rel = p - mCentre;
        const double r2 = rel.lengthSqr();
        if (env.exactFar) {
            if (r2 > launchR2) {
                const double r = std::sqrt(r2), a = env.launchR;
                if (st.dimension == 3 && rng.uniform() * r >= a) {
                    // escaped to infinity: a fresh walker from infinity lands uniformly
                    ++c.escapes;
                    p = launchPoint(rng, env);
                } else {
                    // first passage to the launch sphere, drawn from the harmonic measure seen from p
                    ++c.returns;
                    const Vec3d w = rel / r;
                    if (st.dimension == 3) {
                        const double lo = 1.0 / (r + a), hi = 1.0 / (r - a);
                        const double sInv = lo + rng.uniform() * (hi - lo);
                        double u = (r * r + a * a - 1.0 / (sInv * sInv)) / (2.0 * a * r);
                        u = std::min(1.0, std::max(-1.0, u));
                        Vec3d e1 = std::abs(w.x()) < 0.9 ? w.cross(Vec3d(1, 0, 0)) : w.cross(Vec3d(0, 1, 0));
                        e1.normalize();
                        const Vec3d e2 = w.cross(e1);
                        const double phi = 2.0 * M_PI * rng.uniform(), sn = std::sqrt(std::max(0.0, 1.0 - u * u));
                        p = mCentre + (w * u + e1 * (sn * std::cos(phi)) + e2 * (sn * std::sin(phi))) * a;
                    } else {
                        const double rho = a / r;
                        const double th =
                            2.0 * std::atan((1.0 - rho) / (1.0 + rho) * std::tan(M_PI * (rng.uniform() - 0.5)));
                        const double cs = std::cos(th), sn = std::sin(th);
                        p = mCentre + Vec3d(w.x() * cs - w.y() * sn, w.x() * sn + w.y() * cs, 0.0) * a;
                    }
                }
            }
        } else if (r2 > killR2) {
            ++c.relaunches;
            p = launchPoint(rng, env);
        }
        const ParticleHash::Result q = mHash.query(p, mPos, hint);
        ++c.steps;
        if (q.nearest >= 0 && q.distance <= touch) {
            ++c.touches;
            const Vec3d& par = mPos[size_t(q.nearest)];
            Vec3d dir = p - par;
            const double l = dir.length();
            dir = l > 1e-12 ? dir / l : randomDirection(rng);
            if (rng.uniform() < st.stickiness) {
                const Vec3d at = par + dir * contact;
                if (!st.constraint || st.constraint->allows(par, at, st.radius)) {
                    c.pos = at;
                    c.parent = q.nearest;
                    c.ok = true;
                    return c;
                }
                ++c.refusedConstraint;
            } else {
                ++c.refusedStick;
            }
            // not attached: step back out of the touch shell and walk on
            p = par + dir * (touch + st.radius);
            continue;
        }
        Vec3d d = randomDirection(rng);
        if (biased) {
            d += env.bias;
            const double l = d.length();
            d = l > 1e-12 ? d / l : randomDirection(rng);
        }
        p += d * (q.distance - contact);
    }
    return c;
}

bool Aggregate::growTo(size_t total, const std::function<void(size_t)>& onBatch)
{
    const auto& st = mSettings;
    while (mPos.size() < total) {
        // the environment of this batch: rotation so far, launch and kill radii
        Environment env;
        const double angle = st.rotationPerParticle * double(mPos.size());
        if (angle != 0.0) {
            env.rot = openvdb::math::rotation<openvdb::Mat3d>(st.rotationAxis, -angle);
            env.rotated = true;
        }
        env.bias = env.rotated ? env.rot * st.bias : st.bias;
        env.exactFar = st.launch == Launch::Sphere && st.bias.lengthSqr() == 0;
        env.launchR = mRadius + st.launchMargin;
        double extent = mRadius;
        if (st.launch == Launch::Axis)
            extent = std::max({extent, (st.axisA - mCentre).length(), (st.axisB - mCentre).length()}) + st.axisSpread;
        else if (st.launch == Launch::Plane)
            for (double s : {0.0, 1.0})
                for (double t : {0.0, 1.0})
                    extent = std::max(extent, (st.planeOrigin + st.planeU * s + st.planeV * t - mCentre).length());
        else if (st.launch == Launch::Surface) {
            const auto b = st.launchMesh->bbox();
            for (int i = 0; i < 8; ++i) {
                const Vec3d corner((i & 1) ? b.max().x() : b.min().x(), (i & 2) ? b.max().y() : b.min().y(),
                                   (i & 4) ? b.max().z() : b.min().z());
                extent = std::max(extent, (corner - mCentre).length() + std::abs(st.launchOffset));
            }
        } else extent = env.launchR;
        env.killR = st.killFactor * extent;

        const size_t batch = size_t(std::clamp<double>(std::floor(double(mPos.size()) * st.batchFraction), 1.0,
                                                       double(std::max(1, st.maxBatch))));
        std::vector<Candidate> cands(batch);
        const auto t0 = Clock::now();
        const uint64_t first = mNextWalker;
        tbb::parallel_for(size_t(0), batch, [&](size_t i) { cands[i] = walk(first + i, env); });
        mNextWalker += batch;
        const auto t1 = Clock::now();

        // commit in walker order; drop candidates too close to one accepted in this batch
        const double conflict2 = std::pow(st.conflictFactor * (st.contact() + st.stickDistance), 2);
        const size_t firstNew = mPos.size();
        bool any = false;
        for (const Candidate& c : cands) {
            mStats.walkers++;
            mStats.steps += c.steps;
            mStats.touches += c.touches;
            mStats.refusedStickiness += c.refusedStick;
            mStats.refusedConstraint += c.refusedConstraint;
            mStats.escapes += c.escapes;
            mStats.returns += c.returns;
            mStats.relaunches += c.relaunches;
            if (!c.ok) { ++mStats.exhausted; continue; }
            any = true;
            if (mPos.size() >= total) continue;
            bool clash = false;
            for (size_t j = firstNew; j < mPos.size() && !clash; ++j) clash = (mPos[j] - c.pos).lengthSqr() < conflict2;
            if (clash) { ++mStats.conflicts; continue; }
            add(c.pos, c.parent);
        }
        ++mStats.batches;
        mStats.walkSeconds += std::chrono::duration<double>(t1 - t0).count();
        mStats.commitSeconds += std::chrono::duration<double>(Clock::now() - t1).count();
        if (!any) return false;
        if (onBatch) onBatch(mPos.size());
    }
    return true;
}

size_t Aggregate::memoryBytes() const
{
    return mPos.capacity() * sizeof(Vec3d) + (mParent.capacity() + mGeneration.capacity()) * sizeof(int32_t) +
           mHash.memoryBytes();
}

} // namespace frostvdb::dla3d
