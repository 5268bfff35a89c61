/// @file GG3D.cpp
/// @brief The Gravner-Griffeath 3D model as published: sparse active box, 1/24 fundamental
/// domain, TBB rows. See GG3D.h for the step and the symmetry argument.
#include <frostvdb/automata/GG3D.h>
#include <frostvdb/core/Random.h>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace frostvdb {
namespace automata {

namespace {
constexpr uint8_t kAttached = 1, kWall = 2;
constexpr double kVertical = 3.0 / 14.0; // per vertical neighbour; the centre keeps 8/14

/// Layers [lo, hi] of a prism of @a height layers symmetric under z -> m - z.
void prismLayers(int height, int m, int& lo, int& hi)
{
    if ((height + m) % 2 == 0) ++height; // the parity the mirror needs
    hi = (height - 1 + m) / 2;
    lo = m - hi;
}

void applySwitch(GG3DParams& p, const GG3DSwitch& s)
{
    if (s.hasBeta) p.beta = s.beta;
    if (s.hasKappa) p.kappa = s.kappa;
    if (s.hasMu) p.mu = s.mu;
    if (s.phi >= 0.0) p.phi = s.phi;
}

inline int cfgOf(uint8_t cnt)
{
    const int nh = cnt & 15, nv = cnt >> 4;
    return ggConfigIndex(std::min(3, nh), std::min(1, nv));
}
/// Bytes per cell of the solver's box: d, t, b (doubles), flags and counts, the attach step, and
/// the noise hold.
double boxCellBytes(const GG3DConfig& cfg)
{
    return 3.0 * sizeof(double) + 2.0 + sizeof(int32_t) + (cfg.p.noise > 0 ? sizeof(double) : 0.0);
}

} // namespace

const char* ggConfigName(int k)
{
    static const char* names[kGGConfigs] = {"01", "10", "20", "30", "11", "21", "31"};
    return k >= 0 && k < kGGConfigs ? names[k] : "00";
}

uint64_t gg3dMemoryEstimate(const GG3DConfig& cfg)
{
    const uint64_t R = uint64_t(std::max(1, cfg.domainRadius)), L = uint64_t(std::max(1, cfg.layers)) + 1;
    const bool halfZ = cfg.wedge && cfg.p.phi == 0.0;
    const uint64_t plane = cfg.wedge ? (R + 3) * (R / 2 + 3) : (2 * R + 3) * (2 * R + 3);
    const uint64_t layers = (halfZ ? L / 2 : L) + 3;
    // The box grows by reallocation: old and new arrays coexist for a moment.
    return uint64_t(double(plane * layers) * boxCellBytes(cfg)) * 2;
}

namespace {
/// Cramer's rate function of a lazy walk that steps +1 and -1 with probability @a p each:
/// P(displacement >= x n after n steps) ~ exp(-n I(x)).
double lazyWalkRate(double x, double p)
{
    if (x <= 0.0) return 0.0;
    if (x >= 1.0) return x > 1.0 ? HUGE_VAL : -std::log(p);
    const double a = 1.0 - 2.0 * p;
    const double u = (x * a + std::sqrt(x * x * a * a + 4.0 * p * p * (1.0 - x * x))) / (2.0 * p * (1.0 - x));
    return x * std::log(u) - std::log(a + p * (u + 1.0 / u));
}

/// The fastest the crystal's radius and half height can move a step under one parameter set (see
/// gg3dCrystalCellsEstimate).
void setSpeeds(const GG3DParams& q, double& vr, double& vz)
{
    const double betaMax = *std::max_element(q.beta.begin(), q.beta.end());
    const double muMax = *std::max_element(q.mu.begin(), q.mu.end());
    const double dMax = q.rho + muMax * betaMax; // vapour a boundary site can hold (melting adds to it)
    const double gain = std::max(1.0 - q.kappa[1], 1.0 - q.kappa[2]) * dMax;
    vr = std::min(1.0, gain / std::max(1e-9, std::min(q.beta[1], q.beta[2])));
    vz = std::min(1.0, (1.0 - q.kappa[0]) * dMax / std::max(1e-9, q.beta[0]));
}

/// The fastest the crystal's radius and half height can move a step (see gg3dCrystalCellsEstimate),
/// over the parameters the run will see; and the largest drift.
void kineticSpeeds(const GG3DConfig& cfg, double& vr, double& vz, double& usable, double& phi)
{
    std::vector<GG3DParams> sets{cfg.p};
    for (const auto& s : cfg.switches) {
        GG3DParams q = sets.back();
        applySwitch(q, s);
        sets.push_back(q);
    }
    vr = vz = usable = phi = 0.0;
    for (const GG3DParams& q : sets) {
        // growth stalls where the vapour falls to mu beta / (1 - kappa) (the guard rail's
        // inequality) in the easiest direction (01 up, 10 and 20 out): that much stays vapour
        double stall = q.rho;
        for (size_t k : {0, 1, 2}) stall = std::min(stall, q.mu[k] * q.beta[k] / std::max(1e-9, 1.0 - q.kappa[k]));
        usable = std::max(usable, std::max(0.05, 1.0 - stall / q.rho));
        double r, z;
        setSpeeds(q, r, z);
        vr = std::max(vr, r);
        vz = std::max(vz, z);
        phi = std::max(phi, q.phi);
    }
}
} // namespace

GG3DSolverBytes gg3dSolverBytes(const GG3DConfig& cfg, int64_t steps)
{
    // The solver's own layout (GG3D::GG3D, boxFor, growActiveBox), replayed step by step with the
    // disturbance's reach in place of the lattice.
    const int R = std::max(4, cfg.domainRadius);
    const int m = (cfg.seedHeight % 2 == 0) ? 1 : 0;
    int zDomLo, zDomHi, slo, shi;
    prismLayers(std::max(3, cfg.layers), m, zDomLo, zDomHi);
    prismLayers(cfg.seedHeight, m, slo, shi);
    if (cfg.seedRadius2 >= 0) {
        int lo2, hi2;
        prismLayers(cfg.seedHeight2, m, lo2, hi2);
        slo = std::min(slo, lo2);
        shi = std::max(shi, hi2);
    }
    double vr, vz, usable, phi;
    kineticSpeeds(cfg, vr, vz, usable, phi);
    const bool halfZ = cfg.wedge && phi == 0.0;
    auto cells = [&](int ra, int zlo, int zhi) {
        const double W = cfg.wedge ? ra + 3 : 2 * ra + 3, H = cfg.wedge ? ra / 2 + 3 : 2 * ra + 3;
        return W * H * double(zhi - (halfZ ? m : zlo) + 3);
    };
    const double seedR = std::max(cfg.seedRadius, cfg.seedRadius2);
    const int stop = cfg.stopRadius > 0 ? cfg.stopRadius : int(0.8 * cfg.domainRadius);
    const double stopR = std::min(stop, R - 2);
    int ra = std::min(R, int(seedR) + 3), zlo = halfZ ? m : std::max(zDomLo, slo - 3), zhi = std::min(zDomHi, shi + 3);
    double now = cells(ra, zlo, zhi), peak = now;
    // A cell leaves the background (d differs from rho in a bit) once the diffusion has carried
    // the crystal's pull to it in more than rho's last bit (2^-53; or the sparse tolerance): the
    // chance that a lazy walk (out along a hex axis 2/7 a step each way; 3/14 a layer, plus the
    // drift) got that far, exp(-n I(k / n)) by Cramer's bound. One cell a step at first, then
    // slower (the 60-step run of radius 40, 120 layers: its box's rings and layers within a cell).
    double T = 53.0 * std::log(2.0);
    if (cfg.sparseTolerance > 0.0) T = std::min(T, std::log(cfg.p.rho / cfg.sparseTolerance));
    const double pr = 2.0 / 7.0, pz = std::min(0.49, kVertical + phi);
    int64_t kr = 0, kz = 0;
    const int64_t last = std::min<int64_t>(steps, 20000000);
    for (int64_t s = 1; s <= last; ++s) {
        const double n = double(s);
        while (kr < s && n * lazyWalkRate(double(kr + 1) / n, pr) <= T) ++kr;
        while (kz < s && n * lazyWalkRate(double(kz + 1) / n, pz) <= T) ++kz;
        // from the crystal as fast as it can grow
        const double reachR = std::min(stopR, seedR + vr * n) + double(kr);
        const double reachZ = vz * n + double(kz);
        const bool disturbed = (ra < R && reachR >= ra - 1) || (zhi < zDomHi && shi + reachZ >= zhi - 1) ||
                               (!halfZ && zlo > zDomLo && slo - reachZ <= zlo + 1);
        if (disturbed) {
            const int nra = std::min(R, ra + std::max(4, ra / 4));
            const int span = std::max(2, (zhi - zlo) / 4);
            const int nzhi = std::min(zDomHi, zhi + span), nzlo = halfZ ? m : std::max(zDomLo, zlo - span);
            const double grown = cells(nra, nzlo, nzhi);
            peak = std::max(peak, now + grown); // old and new arrays side by side (GG3D::resize)
            ra = nra;
            zlo = nzlo;
            zhi = nzhi;
            now = grown;
        }
        if (ra == R && zhi == zDomHi && (halfZ || zlo == zDomLo)) break;
    }
    if (steps > last) { // not replayed that far: the whole domain after its last growth
        const double whole = cells(R, zDomLo, zDomHi);
        peak = std::max(peak, now + whole);
        now = whole;
    }
    const double perCell = boxCellBytes(cfg);
    return {now * perCell, peak * perCell, ra, halfZ ? 2 * zhi - m + 1 : zhi - zlo + 1};
}

namespace {
/// Share of the domain's usable vapour (rho x cells, less what stays below the stall density)
/// that the crystal holds at the end of a run (see gg3dCrystalCellsEstimate): with reflecting
/// walls 0.19-0.55 at the end of the shipped scenes (stopped or at their step counts). Chosen so
/// that the shipped scenes' estimates read 0.7-1.5 of their measured peaks (docs/guide.md, the
/// estimate table): thin crystals (needles) hold fewer cells than charged but take more bytes per
/// cell.
constexpr double kMassShare = 0.45;
/// The reservoir inflow model (gg3dReservoirInflow). Measured on seven reservoir runs of five
/// presets (radius 30-60, 31-201 layers; docs/guide.md, issue 25): the direction that reaches its
/// stop first moves at 0.11-0.19 of its kinetic speed (the vapour at the tip is depleted to that
/// share of rho), the other at 0.04-0.10 of its own; ...
constexpr double kLeadShare = 0.15, kSideShare = 0.05;
/// ... the crystal's faces stand on average halfway between the seed and the hull's face (ridged
/// and domed plates; the hull's face alone over-charged the thin-domain plates 1.5x) ...
constexpr double kFaceHeight = 0.5;
/// ... and an attached cell holds its boundary mass at attachment, beta (1-6), while the faces'
/// unattached boundary cells hold mass too: 0.28-0.66 attached cells per unit of mass the crystal
/// took, with its real hull and step count.
constexpr double kCellsPerMass = 0.5;

double hexCells(double r) { return 3.0 * r * (r + 1.0) + 1.0; }
} // namespace

GG3DReservoirInflow gg3dReservoirInflow(const GG3DConfig& cfg, int64_t steps)
{
    // Quasi-steady diffusion from the reservoir (rho beyond the domain's walls) into the crystal's
    // hull, a hex prism of radius a and half height z, held near empty (vapour freezes on at
    // 1 - kappa of it a step): through the layers above and below (3/14 per vertical neighbour,
    // the face's area over its distance to the reservoir's layer) and through the rings around it
    // (1/7 per horizontal neighbour: (12 r + 6) / 7 between rings r and r + 1, in series out to
    // the reservoir's ring R + 1), in parallel. The hull grows from the seed, the leading
    // direction (the faster kinetic speed under the parameters of the moment) at kLeadShare of its
    // kinetic speed, the other at kSideShare, until one reaches its stop or the steps run out.
    GG3DReservoirInflow out;
    const int R = std::max(4, cfg.domainRadius);
    const int m = (cfg.seedHeight % 2 == 0) ? 1 : 0;
    int zlo, zhi;
    prismLayers(std::max(3, cfg.layers), m, zlo, zhi);
    const double faceToReservoir = double(zhi + 1 - m);
    const double stopZ = std::max(1, int(0.8 * (zhi - m)));
    const int stop = cfg.stopRadius > 0 ? cfg.stopRadius : int(0.8 * cfg.domainRadius);
    const double stopR = std::min(stop, R - 2);
    std::vector<double> ringSum(size_t(R) + 2, 0.0); // sum over rings r >= a of 1 / (r + 1/2)
    for (int r = R; r >= 0; --r) ringSum[size_t(r)] = ringSum[size_t(r) + 1] + 1.0 / (double(r) + 0.5);
    std::vector<GG3DSwitch> switches = cfg.switches;
    std::sort(switches.begin(), switches.end(),
              [](const GG3DSwitch& x, const GG3DSwitch& y) { return x.step < y.step; });
    GG3DParams q = cfg.p;
    size_t next = 0;
    double a = std::max(cfg.seedRadius, cfg.seedRadius2);
    double z = 0.5 * std::max(cfg.seedHeight, cfg.seedRadius2 >= 0 ? cfg.seedHeight2 : 1);
    int64_t t = 0;
    double mass = 0.0;
    while (t < steps && a < stopR && z < stopZ) {
        while (next < switches.size() && switches[next].step <= t) applySwitch(q, switches[next++]);
        const int64_t until = next < switches.size() ? std::min(steps, switches[next].step) : steps;
        double vr, vz;
        setSpeeds(q, vr, vz);
        const double dr = (vr >= vz ? kLeadShare : kSideShare) * vr;
        const double dz = (vr >= vz ? kSideShare : kLeadShare) * vz;
        if (dr <= 0.0 && dz <= 0.0) break;
        // chunks in which the hull moves a quarter cell, evaluated at their middle
        const double quarter = std::floor(0.25 / std::max(dr, dz));
        const int64_t k = std::max<int64_t>(1, int64_t(std::min(double(until - t), quarter)));
        const double am = a + 0.5 * double(k) * dr, zm = z + 0.5 * double(k) * dz;
        const double faces = 2.0 * hexCells(am) * kVertical / std::max(1.0, faceToReservoir - kFaceHeight * zm);
        const double sides = (2.0 * zm + 1.0) * (12.0 / 7.0) / ringSum[size_t(std::min(R, int(am)))];
        mass += q.rho * (faces + sides) * double(k);
        a += double(k) * dr;
        z += double(k) * dz;
        t += k;
    }
    out.mass = mass;
    out.steps = t;
    out.radius = std::min(a, stopR);
    out.halfHeight = std::min(z, stopZ);
    return out;
}

double gg3dCrystalCellsEstimate(const GG3DConfig& cfg, int64_t steps, std::string* detail)
{
    const double R = std::max(1, cfg.domainRadius), L = std::max(3, cfg.layers);
    // the fastest the tip and the basal face can move, over the parameters the run will see
    double vr, vz, usable, phi;
    kineticSpeeds(cfg, vr, vz, usable, phi);
    const double n = double(std::max<int64_t>(0, steps));
    const int stop = cfg.stopRadius > 0 ? cfg.stopRadius : int(0.8 * cfg.domainRadius);
    const double stopR = std::min(stop, cfg.domainRadius - 2);
    const double seedR = std::max(cfg.seedRadius, cfg.seedRadius2);
    const double seedZ = 0.5 * std::max(cfg.seedHeight, cfg.seedRadius2 >= 0 ? cfg.seedHeight2 : 1);
    const double halfH = 0.5 * L;
    const double r = std::min(std::max(seedR, stopR), seedR + std::ceil(vr * n));
    const double z = std::min(std::max(seedZ, std::max(1.0, 0.8 * halfH)), seedZ + std::ceil(vz * n));
    const double kinetic = hexCells(r) * (2.0 * z + 1.0);
    // what a closed domain's vapour gives; a reservoir feeds the crystal on, at least that much
    const double closed = kMassShare * usable * cfg.p.rho * hexCells(R) * L;
    const bool reservoir = cfg.walls == GG3DWalls::Reservoir;
    GG3DReservoirInflow inflow;
    if (reservoir) inflow = gg3dReservoirInflow(cfg, steps);
    const double vapour = std::max(closed, kCellsPerMass * inflow.mass);
    const double seed = hexCells(seedR) * (2.0 * seedZ);
    const double cells = std::max(seed, std::min(kinetic, vapour));
    if (detail) {
        char buf[300];
        if (reservoir)
            std::snprintf(buf, sizeof buf,
                          "%.3g attached cells (kinetic bound %.3g: radius %.0f, half height %.0f; vapour share %.3g; "
                          "reservoir inflow %.3g over %lld steps to radius %.0f, half height %.0f)",
                          cells, kinetic, r, z, closed, kCellsPerMass * inflow.mass, (long long)inflow.steps,
                          inflow.radius, inflow.halfHeight);
        else
            std::snprintf(buf, sizeof buf, "%.3g attached cells (kinetic bound %.3g: radius %.0f, half height %.0f; %s %.3g)",
                          cells, kinetic, r, z, "vapour share", closed);
        *detail = buf;
    }
    return cells;
}

GG3D::GG3D(const GG3DConfig& cfg) : mCfg(cfg), mP(cfg.p)
{
    if (mCfg.domainRadius < 4) throw std::invalid_argument("gg3d: domain radius must be at least 4");
    std::sort(mCfg.switches.begin(), mCfg.switches.end(),
              [](const GG3DSwitch& a, const GG3DSwitch& b) { return a.step < b.step; });
    mM = (mCfg.seedHeight % 2 == 0) ? 1 : 0;
    int layers = std::max(3, mCfg.layers);
    prismLayers(layers, mM, mZDomLo, mZDomHi);
    // Drift (now or after a switch) breaks the up/down mirror; the seeds are always D6-symmetric.
    bool drift = mP.phi != 0.0;
    for (const auto& s : mCfg.switches) drift = drift || s.phi > 0.0;
    mWedgeH = mCfg.wedge;
    mZSym = !drift;
    mHalfZ = mCfg.wedge && !drift;
    int slo, shi;
    prismLayers(mCfg.seedHeight, mM, slo, shi);
    int s2 = std::max(mCfg.seedRadius, mCfg.seedRadius2);
    if (mCfg.seedRadius2 >= 0) {
        int lo2, hi2;
        prismLayers(mCfg.seedHeight2, mM, lo2, hi2);
        slo = std::min(slo, lo2);
        shi = std::max(shi, hi2);
    }
    if (s2 + 3 > mCfg.domainRadius || shi + 2 > mZDomHi)
        throw std::invalid_argument("gg3d: the seed does not fit the domain");
    const int stop = mCfg.stopRadius > 0 ? mCfg.stopRadius : int(0.8 * mCfg.domainRadius);
    mCfg.stopRadius = std::min(stop, mCfg.domainRadius - 2);
    resize(std::min(mCfg.domainRadius, s2 + 3), std::max(mZDomLo, slo - 3), std::min(mZDomHi, shi + 3));
    initSeed();
}

void GG3D::initSeed()
{
    auto put = [&](int rad, int height) {
        int lo, hi;
        prismLayers(height, mM, lo, hi);
        for (int z = lo; z <= hi; ++z)
            for (int r = -rad; r <= rad; ++r)
                for (int q = -rad; q <= rad; ++q) {
                    if (hexDistance(q, r) > rad) continue;
                    int qq = q, rr = r, zz = z;
                    if (!storedOf(qq, rr, zz)) continue;
                    bool in;
                    const size_t i = storedIndex(qq, rr, zz, in);
                    if (!in || (mFlags[i] & kAttached)) continue;
                    mFlags[i] = kAttached;
                    mB[i] = 1.0;
                    mD[i] = mT[i] = 0.0;
                    mAttach[i] = 0;
                    mCrystalR = std::max(mCrystalR, hexDistance(q, r));
                    if (mCrystalZHi < mCrystalZLo) mCrystalZLo = mCrystalZHi = z;
                    mCrystalZLo = std::min(mCrystalZLo, z);
                    mCrystalZHi = std::max(mCrystalZHi, z);
                }
    };
    put(mCfg.seedRadius, mCfg.seedHeight);
    if (mCfg.seedRadius2 >= 0) put(mCfg.seedRadius2, mCfg.seedHeight2);
    syncGhosts(mFlags);
    for (const RowSpan& row : mRows)
        for (int q = row.qa; q <= row.qb; ++q) recount(q, row.r, row.z);
}

// ---------------------------------------------------------------------------------------------
// Storage.

bool GG3D::storedOf(int& q, int& r, int& z) const
{
    if (mWedgeH) {
        const Axial c = canonical(q, r);
        q = c.q;
        r = c.r;
    }
    if (mHalfZ && z < mM) z = mM - z;
    return true;
}

size_t GG3D::storedIndex(int q, int r, int z, bool& inBox) const
{
    // Computed region only: hexdist <= Ra and z in the active layers.
    const int zlo = mHalfZ ? mM : mZlo;
    inBox = hexDistance(q, r) <= mRa && z >= zlo && z <= mZa && mBox.contains(q, r, z);
    return inBox ? mBox.index(q, r, z) : 0;
}

uint8_t GG3D::flagAt(int q, int r, int z) const
{
    if (!inDomain(q, r, z)) return mCfg.walls == GG3DWalls::Reflecting ? kWall : 0;
    storedOf(q, r, z);
    bool in;
    const size_t i = storedIndex(q, r, z, in);
    return in ? mFlags[i] : 0;
}

GG3D::Box GG3D::boxFor(int ra, int zlo, int zhi) const
{
    Box nb;
    if (mWedgeH) {
        nb.q0 = -1; nb.q1 = ra + 1; nb.r0 = -1; nb.r1 = ra / 2 + 1;
    } else {
        nb.q0 = nb.r0 = -(ra + 1);
        nb.q1 = nb.r1 = ra + 1;
    }
    if (mHalfZ) zlo = mM;
    nb.z0 = zlo - 1;
    nb.z1 = zhi + 1;
    nb.W = nb.q1 - nb.q0 + 1;
    nb.H = nb.r1 - nb.r0 + 1;
    nb.plane = size_t(nb.W) * size_t(nb.H);
    nb.size = nb.plane * size_t(nb.z1 - nb.z0 + 1);
    return nb;
}

void GG3D::adoptBox(const Box& nb, int ra, int zlo, int zhi)
{
    mBox = nb;
    mRa = ra;
    mZlo = mHalfZ ? mM : zlo;
    mZa = zhi;
    for (int k = 0; k < 6; ++k) mN[size_t(k)] = int64_t(kNeighbours[size_t(k)].r) * nb.W + kNeighbours[size_t(k)].q;
    buildRows();
}

void GG3D::resize(int ra, int zlo, int zhi)
{
    if (mHalfZ) zlo = mM;
    const Box nb = boxFor(ra, zlo, zhi);
    std::vector<double> d(nb.size), b(nb.size, 0.0), t;
    std::vector<uint8_t> f(nb.size, 0), c(nb.size, 0);
    std::vector<int32_t> at(nb.size, -1);
    const bool had = !mD.empty();
    const uint64_t oldBytes = had ? bytes() : 0; // held until the swap below
    const int oldZlo = mHalfZ ? mM : mZlo;
    tbb::parallel_for(nb.z0, nb.z1 + 1, [&](int z) {
        for (int r = nb.r0; r <= nb.r1; ++r)
            for (int q = nb.q0; q <= nb.q1; ++q) {
                const size_t i = nb.index(q, r, z);
                const bool oldComputed = had && hexDistance(q, r) <= mRa && z >= oldZlo && z <= mZa &&
                                         mBox.contains(q, r, z);
                if (oldComputed) {
                    const size_t o = mBox.index(q, r, z);
                    d[i] = mD[o]; b[i] = mB[o]; f[i] = mFlags[o]; c[i] = mCnt[o]; at[i] = mAttach[o];
                } else if (!inDomain(q, r, z)) {
                    d[i] = mP.rho;
                    f[i] = mCfg.walls == GG3DWalls::Reflecting ? kWall : 0;
                } else {
                    d[i] = mP.rho;
                }
            }
    });
    t = d;
    mD.swap(d); mB.swap(b); mT.swap(t); mFlags.swap(f); mCnt.swap(c); mAttach.swap(at);
    if (mP.noise > 0.0) mHold.assign(nb.size, 0.0);
    adoptBox(nb, ra, zlo, zhi);
    syncGhosts(mD);
    syncGhosts(mFlags);
    // the old arrays and the new ones were both held while copying (gg3dSolverBytes' peak)
    mPeakBytes = std::max(mPeakBytes, bytes() + oldBytes);
}

std::vector<int64_t> GG3D::stateScalars() const
{
    return {mStep, mStopped ? 1 : 0, int64_t(mSwitchNext), mRa, mZlo, mZa,
            mCrystalR, mCrystalZLo, mCrystalZHi, int64_t(mPeakBytes)};
}

void GG3D::restoreScalars(const std::vector<int64_t>& s)
{
    if (s.size() != 10) throw std::runtime_error("gg3d state: expected 10 counters, got " + std::to_string(s.size()));
    const int ra = int(s[3]), zlo = int(s[4]), zhi = int(s[5]);
    if (s[0] < 0 || s[2] < 0 || size_t(s[2]) > mCfg.switches.size() || ra < 1 || ra > mCfg.domainRadius ||
        zlo < mZDomLo || zhi > mZDomHi || zlo > zhi)
        throw std::runtime_error("gg3d state: counters out of range for this domain (another scene?)");
    mStep = s[0];
    mStopped = s[1] != 0;
    // The parameters in force: the configured ones with the switches passed so far.
    mP = mCfg.p;
    mSwitchNext = 0;
    while (mSwitchNext < size_t(s[2])) applySwitch(mP, mCfg.switches[mSwitchNext++]);
    adoptBox(boxFor(ra, zlo, zhi), ra, zlo, zhi);
    mCrystalR = int(s[6]);
    mCrystalZLo = int(s[7]);
    mCrystalZHi = int(s[8]);
    mPeakBytes = uint64_t(s[9]);
}

uint64_t GG3D::bytes() const
{
    return mD.size() * 8 * 3 + mFlags.size() * 2 + mAttach.size() * 4 + mHold.size() * 8 +
           mGhosts.size() * 16 + mRows.size() * sizeof(RowSpan);
}

void GG3D::buildRows()
{
    mRows.clear();
    const int zlo = mHalfZ ? mM : mZlo;
    for (int z = zlo; z <= mZa; ++z) {
        if (mWedgeH) {
            for (int r = 0; 2 * r <= mRa; ++r) mRows.push_back({z, r, r, mRa - r});
        } else {
            for (int r = -mRa; r <= mRa; ++r)
                mRows.push_back({z, r, std::max(-mRa, -mRa - r), std::min(mRa, mRa - r)});
        }
    }
    // Horizontal ghosts (one plane; applied to every computed layer): neighbours of wedge cells
    // that lie outside the wedge read their canonical image.
    mGhosts.clear();
    if (!mWedgeH) return;
    std::vector<uint8_t> seen(mBox.plane, 0);
    for (int r = 0; 2 * r <= mRa; ++r)
        for (int q = r; q <= mRa - r; ++q)
            for (const Axial& n : kNeighbours) {
                const int qq = q + n.q, rr = r + n.r;
                if (rr >= 0 && qq >= rr) continue;
                const size_t g = mBox.index(qq, rr, mBox.z0);
                if (seen[g]) continue;
                seen[g] = 1;
                const Axial c = canonical(qq, rr);
                mGhosts.emplace_back(g, mBox.index(c.q, c.r, mBox.z0));
            }
}

void GG3D::syncGhosts(std::vector<double>& v)
{
    const int zlo = mHalfZ ? mM : mZlo;
    if (mWedgeH)
        tbb::parallel_for(zlo, mZa + 1, [&](int z) {
            const size_t off = size_t(z - mBox.z0) * mBox.plane;
            for (const auto& g : mGhosts) v[g.first + off] = v[g.second + off];
        });
    if (mHalfZ) // the mirrored layer below the stored half is layer 1's image
        std::copy_n(v.begin() + std::ptrdiff_t(mBox.index(mBox.q0, mBox.r0, 1)), mBox.plane,
                    v.begin() + std::ptrdiff_t(mBox.index(mBox.q0, mBox.r0, mBox.z0)));
}

void GG3D::syncGhosts(std::vector<uint8_t>& v)
{
    const int zlo = mHalfZ ? mM : mZlo;
    if (mWedgeH)
        for (int z = zlo; z <= mZa; ++z) {
            const size_t off = size_t(z - mBox.z0) * mBox.plane;
            for (const auto& g : mGhosts) v[g.first + off] = v[g.second + off];
        }
    if (mHalfZ)
        std::copy_n(v.begin() + std::ptrdiff_t(mBox.index(mBox.q0, mBox.r0, 1)), mBox.plane,
                    v.begin() + std::ptrdiff_t(mBox.index(mBox.q0, mBox.r0, mBox.z0)));
}

void GG3D::recount(int q, int r, int z)
{
    bool in;
    const size_t i = storedIndex(q, r, z, in);
    if (!in) return;
    int nh = 0;
    for (int k = 0; k < 6; ++k) nh += mFlags[size_t(int64_t(i) + mN[size_t(k)])] & kAttached;
    const int nv = (mFlags[i + mBox.plane] & kAttached) + (mFlags[i - mBox.plane] & kAttached);
    mCnt[i] = uint8_t(nh | (nv << 4));
}

// ---------------------------------------------------------------------------------------------
// The step.

void GG3D::applySwitches()
{
    while (mSwitchNext < mCfg.switches.size() && mCfg.switches[mSwitchNext].step <= mStep)
        applySwitch(mP, mCfg.switches[mSwitchNext++]);
}

template <typename Fn>
void GG3D::forRows(Fn&& fn) const
{
    tbb::parallel_for(tbb::blocked_range<size_t>(0, mRows.size(), 4), [&](const tbb::blocked_range<size_t>& rg) {
        for (size_t k = rg.begin(); k < rg.end(); ++k) {
            const RowSpan& row = mRows[k];
            fn(row, mBox.index(row.qa, row.r, row.z));
        }
    });
}

void GG3D::step()
{
    if (mStopped) return;
    applySwitches();
    if (mP.noise > 0.0) holdNoise();
    syncGhosts(mD);
    diffuseHorizontal();
    attach(diffuseVerticallyAndFreeze());
    melt();
    ++mStep;
    const int extent = std::max(mCrystalZHi - mM, mM - mCrystalZLo);
    const int halfH = mZDomHi - mM;
    if (mCrystalR >= mCfg.stopRadius || extent >= std::max(1, int(0.8 * halfH))) mStopped = true;
    growActiveBox();
}

/// Noise: a fraction xi of each cell's vapour sits out the diffusion (keyed by the canonical
/// cell, so every image of a cell draws the same xi).
void GG3D::holdNoise()
{
    double* D = mD.data();
    double* Hd = mHold.data();
    const uint8_t* F = mFlags.data();
    const double noise = mP.noise;
    const uint64_t key = hashCounters(mCfg.seed, 0x47473344ull, uint64_t(mStep));
    forRows([&](const RowSpan& row, size_t i0) {
        for (int q = row.qa; q <= row.qb; ++q) {
            const size_t i = i0 + size_t(q - row.qa);
            Hd[i] = 0.0;
            if (F[i] & kAttached) continue;
            const Axial c = canonical(q, row.r);
            const int zc = mZSym && row.z < mM ? mM - row.z : row.z;
            const uint64_t h = hashCounters(key, uint64_t(uint32_t(c.q)), uint64_t(uint32_t(c.r)),
                                            uint64_t(uint32_t(zc)));
            if (h & 1) {
                Hd[i] = noise * D[i];
                D[i] -= Hd[i];
            }
        }
    });
}

/// 1. Horizontal diffusion d -> T: d + (1/7) sum(d_n - d), attached or wall neighbours reflect
/// (difference 0).
void GG3D::diffuseHorizontal()
{
    const auto& N = mN;
    const double* D = mD.data();
    double* T = mT.data();
    const uint8_t* F = mFlags.data();
    forRows([&](const RowSpan& row, size_t i0) {
        for (size_t i = i0, e = i0 + size_t(row.qb - row.qa); i <= e; ++i) {
            if (F[i] & kAttached) { T[i] = 0.0; continue; }
            const double c = D[i];
            double v[6];
            for (int k = 0; k < 6; ++k) {
                const size_t n = size_t(int64_t(i) + N[size_t(k)]);
                v[k] = F[n] ? 0.0 : D[n] - c;
            }
            T[i] = c + symSum6(v[0], v[1], v[2], v[3], v[4], v[5]) / 7.0;
        }
    });
    if (mHalfZ)
        std::copy_n(mT.begin() + std::ptrdiff_t(mBox.index(mBox.q0, mBox.r0, 1)), mBox.plane,
                    mT.begin() + std::ptrdiff_t(mBox.index(mBox.q0, mBox.r0, mBox.z0)));
}

/// 2-3. Vertical diffusion (+ drift), freezing and the attachment decision: the cells that
/// attach this step, sorted.
std::vector<size_t> GG3D::diffuseVerticallyAndFreeze()
{
    const size_t P = mBox.plane;
    double* D = mD.data();
    double* T = mT.data();
    double* B = mB.data();
    const uint8_t* F = mFlags.data();
    const uint8_t* C = mCnt.data();
    const GG3DParams& p = mP;
    tbb::enumerable_thread_specific<std::vector<size_t>> newly;
    const double* Hd = p.noise > 0.0 ? mHold.data() : nullptr;
    auto settle = [&](size_t i, double v, std::vector<size_t>& out) {
        if (Hd) v += Hd[i];
        const uint8_t cn = C[i];
        if (cn == 0) { D[i] = v; return; }
        const int k = cfgOf(cn);
        const double dn = p.kappa[size_t(k)] * v;
        const double bn = B[i] + (v - dn);
        const int nh = cn & 15, nv = cn >> 4;
        if (bn >= p.beta[size_t(k)] || (p.holeFill && nh >= 4 && (!p.holeFillNeedsVertical || nv >= 1))) {
            B[i] = bn + dn;
            D[i] = 0.0;
            out.push_back(i);
        } else {
            B[i] = bn;
            D[i] = dn;
        }
    };
    auto vertical = [&](size_t i) {
        const double c = T[i];
        const double up = F[i + P] ? 0.0 : T[i + P] - c;
        const double dn = F[i - P] ? 0.0 : T[i - P] - c;
        return c + (up + dn) * kVertical;
    };
    if (p.phi == 0.0) {
        forRows([&](const RowSpan& row, size_t i0) {
            auto& out = newly.local();
            for (size_t i = i0, e = i0 + size_t(row.qb - row.qa); i <= e; ++i)
                if (!(F[i] & kAttached)) settle(i, vertical(i), out);
        });
    } else {
        // Drift along -z: a fraction phi of d'' moves one layer down unless that cell is ice
        // (or wall). Difference form keeps background cells exactly at rho.
        forRows([&](const RowSpan& row, size_t i0) {
            for (size_t i = i0, e = i0 + size_t(row.qb - row.qa); i <= e; ++i)
                if (!(F[i] & kAttached)) D[i] = vertical(i);
        });
        const double phi = p.phi;
        forRows([&](const RowSpan& row, size_t i0) {
            for (size_t i = i0, e = i0 + size_t(row.qb - row.qa); i <= e; ++i) {
                if (F[i] & kAttached) continue;
                const double out = F[i - P] ? 0.0 : phi * D[i];
                const double in = F[i + P] ? 0.0 : phi * D[i + P];
                T[i] = D[i] + (in - out);
            }
        });
        forRows([&](const RowSpan& row, size_t i0) {
            auto& out = newly.local();
            for (size_t i = i0, e = i0 + size_t(row.qb - row.qa); i <= e; ++i)
                if (!(F[i] & kAttached)) settle(i, T[i], out);
        });
    }
    std::vector<size_t> all;
    for (auto& v : newly) all.insert(all.end(), v.begin(), v.end());
    std::sort(all.begin(), all.end());
    return all;
}

/// Commits the attachments (order-independent), then refreshes the neighbour counts around them.
void GG3D::attach(const std::vector<size_t>& all)
{
    const size_t P = mBox.plane;
    const int32_t stepNo = int32_t(mStep + 1);
    auto decode = [&](size_t i, int& q, int& r, int& z) {
        z = int(i / P) + mBox.z0;
        const size_t rem = i % P;
        r = int(rem / size_t(mBox.W)) + mBox.r0;
        q = int(rem % size_t(mBox.W)) + mBox.q0;
    };
    for (size_t i : all) {
        mFlags[i] |= kAttached;
        mAttach[i] = stepNo;
        int q, r, z;
        decode(i, q, r, z);
        mCrystalR = std::max(mCrystalR, hexDistance(q, r));
        mCrystalZHi = std::max(mCrystalZHi, z);
        mCrystalZLo = std::min(mCrystalZLo, mHalfZ ? mM - z : z);
    }
    if (all.empty()) return;
    syncGhosts(mFlags);
    for (size_t i : all) {
        int q, r, z;
        decode(i, q, r, z);
        for (int k = 0; k < 8; ++k) {
            int qq = q, rr = r, zz = z;
            if (k < 6) { qq += kNeighbours[size_t(k)].q; rr += kNeighbours[size_t(k)].r; }
            else zz += k == 6 ? 1 : -1;
            storedOf(qq, rr, zz);
            recount(qq, rr, zz);
        }
    }
}

/// 4. Melting on boundary sites (configuration after attachment).
void GG3D::melt()
{
    double* D = mD.data();
    double* B = mB.data();
    const uint8_t* F = mFlags.data();
    const uint8_t* C = mCnt.data();
    const GG3DParams& p = mP;
    forRows([&](const RowSpan& row, size_t i0) {
        for (size_t i = i0, e = i0 + size_t(row.qb - row.qa); i <= e; ++i) {
            const uint8_t cn = C[i];
            if (cn == 0 || (F[i] & kAttached)) continue;
            const double m = p.mu[size_t(cfgOf(cn))] * B[i];
            D[i] += m;
            B[i] -= m;
        }
    });
}

/// Grows the active box when the disturbance reaches its last two rings / layers.
void GG3D::growActiveBox()
{
    if (!edgeDisturbed()) return;
    const int ra = std::min(mCfg.domainRadius, mRa + std::max(4, mRa / 4));
    const int span = std::max(2, (mZa - mZlo) / 4);
    const int zhi = std::min(mZDomHi, mZa + span);
    const int zlo = mHalfZ ? mM : std::max(mZDomLo, mZlo - span);
    if (ra != mRa || zhi != mZa || zlo != mZlo) resize(ra, zlo, zhi);
}

bool GG3D::edgeDisturbed() const
{
    const bool growR = mRa < mCfg.domainRadius;
    const bool growUp = mZa < mZDomHi;
    const bool growDown = !mHalfZ && mZlo > mZDomLo;
    const double tol = mCfg.sparseTolerance;
    auto disturbed = [&](size_t i) {
        return mFlags[i] == kAttached || mB[i] != 0.0 || std::abs(mD[i] - mP.rho) > tol;
    };
    for (const RowSpan& row : mRows) {
        const bool layerEdge = (growUp && row.z >= mZa - 1) || (growDown && row.z <= mZlo + 1);
        const size_t i0 = mBox.index(row.qa, row.r, row.z);
        for (int q = row.qa; q <= row.qb; ++q) {
            const bool ringEdge = growR && hexDistance(q, row.r) >= mRa - 1;
            if ((layerEdge || ringEdge) && disturbed(i0 + size_t(q - row.qa))) return true;
            // Interior cells of a row that is not at a layer edge: jump to the row's far end.
            if (!layerEdge && q > row.qa + 1 && q < row.qb - 1 && std::abs(row.r) < mRa - 1) q = row.qb - 2;
        }
    }
    return false;
}

// ---------------------------------------------------------------------------------------------
// Queries.

bool GG3D::attached(int q, int r, int z) const { return (flagAt(q, r, z) & kAttached) != 0; }

double GG3D::diffusive(int q, int r, int z) const
{
    if (!inDomain(q, r, z)) return 0.0;
    storedOf(q, r, z);
    bool in;
    const size_t i = storedIndex(q, r, z, in);
    return in ? mD[i] : mP.rho;
}

double GG3D::boundaryMass(int q, int r, int z) const
{
    if (!inDomain(q, r, z)) return 0.0;
    storedOf(q, r, z);
    bool in;
    const size_t i = storedIndex(q, r, z, in);
    return in ? mB[i] : 0.0;
}

int32_t GG3D::attachStep(int q, int r, int z) const
{
    if (!inDomain(q, r, z)) return -1;
    storedOf(q, r, z);
    bool in;
    const size_t i = storedIndex(q, r, z, in);
    return in ? mAttach[i] : -1;
}

uint64_t GG3D::attachedCount() const
{
    uint64_t n = 0;
    const int R = mCrystalR + 1;
    for (int z = mCrystalZLo - 1; z <= mCrystalZHi + 1; ++z)
        for (int r = -R; r <= R; ++r)
            for (int q = -R; q <= R; ++q)
                if (hexDistance(q, r) <= R && attached(q, r, z)) ++n;
    return n;
}

double GG3D::totalMass() const
{
    double m = 0.0;
    const int R = mCfg.domainRadius;
    for (int z = mZDomLo; z <= mZDomHi; ++z)
        for (int r = -R; r <= R; ++r)
            for (int q = -R; q <= R; ++q)
                if (hexDistance(q, r) <= R) m += diffusive(q, r, z) + boundaryMass(q, r, z);
    return m;
}

uint64_t GG3D::cellsPerStep() const
{
    uint64_t n = 0;
    for (const RowSpan& r : mRows) n += uint64_t(r.qb - r.qa + 1);
    return n;
}

} // namespace automata
} // namespace frostvdb
