/// @file Automata.cpp
/// @brief The hexagonal snowflake automata (see Automata.h). No OpenVDB in this file.
#include <frostvdb/automata/Automata.h>
#include <frostvdb/core/Random.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <stdexcept>

namespace frostvdb {
namespace automata {

const char* ruleName(Rule r)
{
    switch (r) {
    case Rule::Packard: return "packard";
    case Rule::CoxeReiter: return "coxe_reiter";
    case Rule::Probabilistic: return "probabilistic_ca";
    case Rule::Reiter: return "reiter";
    case Rule::GravnerGriffeath: return "gravner_griffeath";
    case Rule::GravnerGriffeath3D: return "gravner_griffeath_3d";
    }
    return "?";
}

bool isSymmetricRule(Rule) { return true; }

int coxeReiterCase(int C, int N, int P)
{
    if (C) return N == 0 ? 0 : 2;
    if (N == 0) return 1;
    if (N == 1) return P ? 3 : 4;
    return (N == 2 ? 5 : 8) + std::min(P, 2);
}

std::array<std::array<double, 4>, kCoxeReiterCases> coxeReiterTable1()
{
    return {{{1.0, 1.0 / 300.0, 0.0, 0.0},
             {1.0, 0.0, 0.0, 0.0},
             {1.0, 1.0 / 6.0, -1.0 / 12.0, -1.0 / 12.0},
             {1.0 / 5.0, 3.0 / 10.0, 1.0 / 10.0, -1.0 / 10.0},
             {1.0 / 20.0, 2.0 / 5.0, -3.0 / 20.0, -3.0 / 20.0},
             {1.0 / 10.0, 3.0 / 10.0, -1.0 / 10.0, -1.0 / 10.0},
             {1.0 / 22.0, 4.0 / 11.0, -3.0 / 22.0, -3.0 / 22.0},
             {1.0 / 18.0, 4.0 / 9.0, -1.0 / 6.0, -1.0 / 6.0},
             {1.0 / 10.0, 3.0 / 10.0, -1.0 / 10.0, -1.0 / 10.0},
             {1.0 / 22.0, 4.0 / 22.0, -3.0 / 22.0, -3.0 / 22.0},
             {1.0 / 18.0, 4.0 / 9.0, -1.0 / 6.0, -1.0 / 6.0}}};
}

namespace {

int rotateMask(int m, int k) { return ((m << k) | (m >> (6 - k))) & 63; }
int reflectMask(int m)
{
    int out = 0;
    for (int b = 0; b < 6; ++b)
        if (m & (1 << b)) out |= 1 << ((6 - b) % 6);
    return out;
}
int canonicalMask(int m)
{
    int best = 64;
    for (int k = 0; k < 6; ++k) {
        best = std::min(best, rotateMask(m, k));
        best = std::min(best, rotateMask(reflectMask(m), k));
    }
    return best;
}

} // namespace

std::array<int8_t, 64> neighbourhoodClasses()
{
    std::array<int8_t, 64> cls;
    cls.fill(-1);
    std::map<int, int> found;
    for (int t = 1; t < 64; ++t) {
        // Tuple entry p (p = 0 most significant, as Mathematica's Tuples) is neighbour p.
        int mask = 0;
        for (int p = 0; p < 6; ++p)
            if ((t >> (5 - p)) & 1) mask |= 1 << p;
        const int key = canonicalMask(mask);
        auto it = found.find(key);
        if (it == found.end()) it = found.emplace(key, int(found.size())).first;
        cls[mask] = int8_t(it->second);
    }
    return cls;
}

int countNeighbourhoodClasses()
{
    const auto c = neighbourhoodClasses();
    return 1 + *std::max_element(c.begin(), c.end());
}

std::array<double, 12> defaultPFreeze() { return {1, 0, 0.6, 0, 0.3, 0.15, 0, 0.2, 0, 0.2, 0, 0.8}; }
std::array<double, 12> defaultPMelt() { return {0, 0.7, 0.5, 0.7, 0.7, 0.5, 0.3, 0.5, 0.3, 0.2, 0.1, 0}; }

std::array<float, 3> coxeReiterColour(double v, bool thick, double age)
{
    auto lerp = [](float a, float b, double t) { return float(a + (b - a) * std::clamp(t, 0.0, 1.0)); };
    if (thick) // red -> purple with age
        return {lerp(1.0f, 0.45f, age), 0.0f, lerp(0.0f, 0.75f, age)};
    if (v >= 0.5) { // yellow -> red
        const double t = (v - 0.5) / 0.5;
        return {1.0f, lerp(1.0f, 0.1f, t), 0.0f};
    }
    const double t = std::max(0.0, v) / 0.5; // darkened cyan -> green
    return {lerp(0.0f, 0.15f, t), lerp(0.22f, 0.65f, t), lerp(0.28f, 0.2f, t)};
}

std::vector<Axial> d6Orbit(int q, int r)
{
    const Axial c = canonical(q, r);
    const int dist = hexDistance(q, r);
    std::vector<Axial> out;
    for (int rr = -dist; rr <= dist; ++rr)
        for (int qq = -dist; qq <= dist; ++qq)
            if (hexDistance(qq, rr) == dist && canonical(qq, rr) == c) out.push_back({qq, rr});
    return out;
}

// ---------------------------------------------------------------------------------------------

HexAutomaton::HexAutomaton(const AutomatonConfig& cfg) : mCfg(cfg)
{
    if (cfg.radius < 2) throw std::invalid_argument("automaton radius must be >= 2");
    if (cfg.seedCells < 1 || cfg.seedCells > 4) throw std::invalid_argument("seed cells must be 1..4");
    mGG = cfg.rule == Rule::GravnerGriffeath || cfg.rule == Rule::GravnerGriffeath3D;
    m3D = cfg.rule == Rule::GravnerGriffeath3D;
    mLayers = m3D ? std::max(1, cfg.layers) : 1;
    mLayerPad = m3D ? 1 : 0;
    mLayout = HexLayout(cfg.radius, 2);
    bool symmetricSeeds = cfg.seedCells == 1;
    for (const Axial& s : cfg.extraSeeds)
        for (const Axial& o : d6Orbit(s.q, s.r))
            if (std::find(cfg.extraSeeds.begin(), cfg.extraSeeds.end(), o) == cfg.extraSeeds.end())
                symmetricSeeds = false;
    mWedge = cfg.wedge && symmetricSeeds && isSymmetricRule(cfg.rule);
    mClass = neighbourhoodClasses();
    initialise();
}

uint64_t HexAutomaton::latticeCells() const
{
    const uint64_t R = uint64_t(mLayout.radius());
    return (3 * R * (R + 1) + 1) * uint64_t(mLayers);
}

uint64_t HexAutomaton::cellsPerStep() const
{
    uint64_t n = 0;
    for (const Row& r : mRows) n += uint64_t(r.q1 - r.q0 + 1);
    return n;
}

void HexAutomaton::initialise()
{
    const size_t S = mLayout.size();
    const int totalLayers = mLayers + 2 * mLayerPad;
    const size_t N = S * size_t(totalLayers);
    const int R = mLayout.radius();
    mV.assign(N, 0.0);
    mWall.assign(N, 1);
    mFreeze.assign(N, -1);
    mThick.assign(N, -1);
    mA.assign(N, 0);
    if (mGG) {
        mB.assign(N, 0.0);
        mC.assign(N, 0.0);
    }

    for (int l = 0; l < totalLayers; ++l) {
        const bool wallLayer = l < mLayerPad || l >= mLayerPad + mLayers;
        for (size_t k = 0; k < S; ++k) {
            const Axial a = mLayout.axial(k);
            const size_t i = size_t(l) * S + k;
            if (!wallLayer && mLayout.inside(a.q, a.r)) mWall[i] = 0;
            double v = 0.0;
            switch (mCfg.rule) {
            case Rule::Packard:
            case Rule::Probabilistic: v = 0.0; break;
            case Rule::CoxeReiter: {
                const auto& p = mCfg.cr;
                const int ring = hexDistance(a.q, a.r) / std::max(1, p.band);
                v = (p.background2 >= 0.0 && (ring & 1)) ? p.background2 : p.background;
                break;
            }
            case Rule::Reiter: v = mCfg.reiter.beta; break;
            default: v = mCfg.gg.rho; break;
            }
            mV[i] = v;
        }
    }

    static const Axial seeds[4] = {{0, 0}, {1, 0}, {0, 1}, {1, 1}};
    std::vector<Axial> all(seeds, seeds + mCfg.seedCells);
    all.insert(all.end(), mCfg.extraSeeds.begin(), mCfg.extraSeeds.end());
    const int lc = mLayerPad + (mLayers - 1) / 2;
    for (const Axial& sd : all) {
        if (!mLayout.inside(sd.q, sd.r)) continue;
        const size_t i = size_t(lc) * S + mLayout.index(sd.q, sd.r);
        mFreeze[i] = 0;
        mThick[i] = 0;
        if (mGG) {
            mA[i] = 1;
            mC[i] = 1.0;
            mV[i] = 0.0;
        } else {
            mV[i] = 1.0;
        }
    }
    mV2 = mV;
    mA2 = mA;

    mRows.clear();
    for (int l = 0; l < mLayers; ++l) {
        auto rows = mWedge ? mLayout.wedgeRows(l) : mLayout.fullRows(l);
        mRows.insert(mRows.end(), rows.begin(), rows.end());
    }
    mGhosts = mWedge ? mLayout.ghosts(2) : std::vector<std::pair<uint32_t, uint32_t>>{};
    mImages = mLayout.images();
    mCanon.resize(S);
    for (size_t k = 0; k < S; ++k) mCanon[k] = uint32_t(k);
    for (const auto& im : mImages) mCanon[im.first] = im.second;
    (void)R;
}

template <typename Fn>
void HexAutomaton::forRows(Fn&& fn)
{
    const size_t S = mLayout.size();
    tbb::parallel_for(tbb::blocked_range<size_t>(0, mRows.size(), 1),
                      [&](const tbb::blocked_range<size_t>& range) {
                          for (size_t k = range.begin(); k != range.end(); ++k) {
                              const Row& row = mRows[k];
                              const size_t base = size_t(row.layer + mLayerPad) * S;
                              for (int q = row.q0; q <= row.q1; ++q)
                                  fn(base + mLayout.index(q, row.r));
                          }
                      });
}

void HexAutomaton::syncGhosts(std::vector<double>& a)
{
    if (!mWedge) return;
    const size_t S = mLayout.size();
    for (int l = 0; l < mLayers; ++l) {
        const size_t base = size_t(l + mLayerPad) * S;
        for (const auto& g : mGhosts) a[base + g.first] = a[base + g.second];
    }
}

void HexAutomaton::syncGhosts(std::vector<uint8_t>& a)
{
    if (!mWedge) return;
    const size_t S = mLayout.size();
    for (int l = 0; l < mLayers; ++l) {
        const size_t base = size_t(l + mLayerPad) * S;
        for (const auto& g : mGhosts) a[base + g.first] = a[base + g.second];
    }
}

inline void HexAutomaton::track(size_t i, bool isFrozen, bool isThick)
{
    const int32_t now = int32_t(mStep + 1);
    if (isFrozen) {
        if (mFreeze[i] < 0) mFreeze[i] = now;
    } else {
        mFreeze[i] = -1;
    }
    if (isThick) {
        if (mThick[i] < 0) mThick[i] = now;
    } else {
        mThick[i] = -1;
    }
}

void HexAutomaton::step()
{
    switch (mCfg.rule) {
    case Rule::Packard: stepPackard(); break;
    case Rule::CoxeReiter: stepCoxeReiter(); break;
    case Rule::Probabilistic: stepProbabilistic(); break;
    case Rule::Reiter: stepReiter(); break;
    default: stepGG(); break;
    }
    ++mStep;
}

void HexAutomaton::stepPackard()
{
    const auto& n = mLayout.n();
    const double* v = mV.data();
    double* out = mV2.data();
    forRows([&](size_t i) {
        bool f = v[i] >= 0.5;
        if (!f) {
            int count = 0;
            for (int k = 0; k < 6; ++k) count += v[i + n[k]] >= 0.5;
            f = count == 1;
        }
        out[i] = f ? 1.0 : 0.0;
        track(i, f, f);
    });
    mV.swap(mV2);
    syncGhosts(mV);
}

void HexAutomaton::stepProbabilistic()
{
    const auto& n = mLayout.n();
    const double* v = mV.data();
    double* out = mV2.data();
    // One draw per class per step: every cell seeing the same class sees the same number.
    std::array<double, 12> draw;
    for (int c = 0; c < 12; ++c)
        draw[c] = toUnit(hashCounters(mCfg.seed, 0x50524f42ull, uint64_t(mStep), uint64_t(c)));
    const auto& pf = mCfg.prob.pFreeze;
    const auto& pm = mCfg.prob.pMelt;
    forRows([&](size_t i) {
        const bool cv = v[i] >= 0.5;
        int mask = 0;
        for (int k = 0; k < 6; ++k) mask |= int(v[i + n[k]] >= 0.5) << k;
        bool f = cv;
        if (mask != 0) {
            const int c = mClass[mask];
            f = cv ? !(draw[c] < pm[c]) : (draw[c] < pf[c]);
        }
        out[i] = f ? 1.0 : 0.0;
        track(i, f, f);
    });
    mV.swap(mV2);
    syncGhosts(mV);
}

void HexAutomaton::stepCoxeReiter()
{
    const auto& n = mLayout.n();
    const auto& p = mLayout.p();
    const auto& e = mLayout.e();
    const auto& w = mCfg.cr.weights;
    const double* v = mV.data();
    double* out = mV2.data();
    forRows([&](size_t i) {
        const int C = v[i] >= 0.5;
        int N = 0, P = 0;
        for (int k = 0; k < 6; ++k) {
            const bool fn = v[i + n[k]] >= 0.5;
            N += fn;
            P += fn && v[i + p[k]] >= 0.5;
        }
        const auto& c = w[coxeReiterCase(C, N, P)];
        const double SN = symSum6(v[i + n[0]], v[i + n[1]], v[i + n[2]], v[i + n[3]], v[i + n[4]], v[i + n[5]]);
        const double SP = symSum6(v[i + p[0]], v[i + p[1]], v[i + p[2]], v[i + p[3]], v[i + p[4]], v[i + p[5]]);
        const double SE = symSum6(v[i + e[0]], v[i + e[1]], v[i + e[2]], v[i + e[3]], v[i + e[4]], v[i + e[5]]);
        double S = ((c[0] * v[i] + c[1] * SN) + c[2] * SP) + c[3] * SE;
        S = std::clamp(S, 0.0, 1.0);
        out[i] = S;
        track(i, S >= 0.5, S >= 1.0);
    });
    mV.swap(mV2);
    syncGhosts(mV);
}

void HexAutomaton::stepReiter()
{
    const auto& n = mLayout.n();
    const double alpha = mCfg.reiter.alpha, gamma = mCfg.reiter.gamma;
    const double* v = mV.data();
    uint8_t* rec = mA.data();
    forRows([&](size_t i) {
        bool r = v[i] >= 1.0;
        for (int k = 0; k < 6 && !r; ++k) r = v[i + n[k]] >= 1.0;
        rec[i] = r;
    });
    syncGhosts(mA);
    double* out = mV2.data();
    const double a12 = alpha / 12.0;
    forRows([&](size_t i) {
        double u[6];
        for (int k = 0; k < 6; ++k) {
            const size_t j = i + n[k];
            u[k] = rec[j] ? 0.0 : v[j];
        }
        const double sum = symSum6(u[0], u[1], u[2], u[3], u[4], u[5]);
        double s;
        if (rec[i]) s = (v[i] + gamma) + a12 * sum;
        else s = v[i] + a12 * (sum - 6.0 * v[i]);
        out[i] = s;
        track(i, s >= 1.0, s >= 1.0);
    });
    mV.swap(mV2);
    syncGhosts(mV);
}

void HexAutomaton::stepGG()
{
    const auto& n = mLayout.n();
    const auto& g = mCfg.gg;
    const int64_t S = int64_t(mLayout.size());
    const bool closed = g.closed;
    uint8_t* a = mA.data();
    const uint8_t* wall = mWall.data();
    double* d = mV.data();
    double* tmp = mV2.data();
    double* b = mB.data();
    double* c = mC.data();
    auto blocked = [&](size_t y) { return a[y] || (closed && wall[y]); };
    auto counts = [&](size_t i, int& nt, int& nv) {
        nt = 0;
        for (int k = 0; k < 6; ++k) nt += a[i + n[k]];
        nv = m3D ? int(a[i + S]) + int(a[i - S]) : 0;
    };

    // (1) diffusion: horizontal 1/7 average, reflecting at the crystal (and at a closed wall).
    forRows([&](size_t i) {
        if (a[i]) { tmp[i] = d[i]; return; }
        const double dx = d[i];
        double u[6];
        for (int k = 0; k < 6; ++k) {
            const size_t y = i + n[k];
            u[k] = blocked(y) ? dx : d[y];
        }
        tmp[i] = (dx + symSum6(u[0], u[1], u[2], u[3], u[4], u[5])) / 7.0;
    });
    if (m3D) {
        syncGhosts(mV2);
        const double phi = g.phi, keep = 1.0 - 2.0 * phi;
        forRows([&](size_t i) {
            if (a[i]) { d[i] = tmp[i]; return; }
            const double dx = tmp[i];
            const double up = blocked(i + S) ? dx : tmp[i + S];
            const double dn = blocked(i - S) ? dx : tmp[i - S];
            d[i] = keep * dx + phi * (up + dn);
        });
    } else {
        mV.swap(mV2);
        d = mV.data();
        tmp = mV2.data();
    }
    syncGhosts(mV);

    // (2) freezing at boundary sites.
    forRows([&](size_t i) {
        if (a[i]) return;
        int nt, nv;
        counts(i, nt, nv);
        if (nt + nv == 0) return;
        const double k = g.kappa[std::min(3, nt)][std::min(1, nv)];
        b[i] += (1.0 - k) * d[i];
        c[i] += k * d[i];
        d[i] = 0.0;
    });
    syncGhosts(mV);

    // (3) attachment (decided on the old attached set, applied synchronously).
    uint8_t* a2 = mA2.data();
    forRows([&](size_t i) {
        if (a[i]) { a2[i] = 1; return; }
        int nt, nv;
        counts(i, nt, nv);
        bool attach = false;
        if (nt + nv > 0) {
            const int ti = std::min(3, nt), vj = std::min(1, nv);
            if (nt >= 4) {
                attach = true;
            } else if (ti == 3 && vj == 0) {
                attach = b[i] >= g.beta[3][0];
                if (!attach && b[i] >= g.alpha) {
                    double u[6];
                    for (int k = 0; k < 6; ++k) u[k] = d[i + n[k]];
                    double sum = d[i] + symSum6(u[0], u[1], u[2], u[3], u[4], u[5]);
                    if (m3D) sum += d[i + S] + d[i - S];
                    attach = sum < g.theta;
                }
            } else {
                attach = b[i] >= g.beta[ti][vj];
            }
        }
        a2[i] = attach;
        if (attach) {
            c[i] += b[i];
            b[i] = 0.0;
            mFreeze[i] = mThick[i] = int32_t(mStep + 1);
        }
    });
    mA.swap(mA2);
    a = mA.data();
    syncGhosts(mA);

    // (4) melting at boundary sites, (5) noise on the vapour.
    const uint64_t key = hashCounters(mCfg.seed, 0x47474e4full, uint64_t(mStep));
    forRows([&](size_t i) {
        if (a[i]) return;
        int nt, nv;
        counts(i, nt, nv);
        if (nt + nv > 0) {
            const int ti = std::min(3, nt), vj = std::min(1, nv);
            const double mb = g.mu[ti][vj] * b[i];
            const double mc = g.gamma * c[i];
            b[i] -= mb;
            c[i] -= mc;
            d[i] += mb + mc;
        }
        if (g.sigma > 0.0) {
            const size_t layer = i / size_t(S);
            const uint64_t cell = mCanon[i % size_t(S)];
            const uint64_t h = hashCounters(key, cell, layer);
            d[i] *= (h & 1) ? 1.0 + g.sigma : 1.0 - g.sigma;
        }
    });
    syncGhosts(mV);
}

void HexAutomaton::expand()
{
    if (!mWedge) return;
    const size_t S = mLayout.size();
    for (int l = 0; l < mLayers; ++l) {
        const size_t base = size_t(l + mLayerPad) * S;
        for (const auto& im : mImages) {
            if (im.first == im.second) continue;
            const size_t i = base + im.first, j = base + im.second;
            mV[i] = mV[j];
            mA[i] = mA[j];
            mFreeze[i] = mFreeze[j];
            mThick[i] = mThick[j];
            if (mGG) {
                mB[i] = mB[j];
                mC[i] = mC[j];
            }
        }
    }
}

double HexAutomaton::value(size_t i) const
{
    if (mGG) return mA[i] ? mC[i] : 0.0;
    return mV[i];
}

bool HexAutomaton::frozen(size_t i) const
{
    switch (mCfg.rule) {
    case Rule::Reiter: return mV[i] >= 1.0;
    case Rule::GravnerGriffeath:
    case Rule::GravnerGriffeath3D: return mA[i] != 0;
    default: return mV[i] >= 0.5;
    }
}

double HexAutomaton::totalMass() const
{
    double m = 0.0;
    const size_t S = mLayout.size();
    for (int l = 0; l < mLayers; ++l) {
        const size_t base = size_t(l + mLayerPad) * S;
        for (const auto& im : mImages) {
            const size_t i = base + im.first;
            m += mV[i] + (mGG ? mB[i] + mC[i] : 0.0);
        }
    }
    return m;
}

uint64_t HexAutomaton::frozenCount() const
{
    uint64_t count = 0;
    const size_t S = mLayout.size();
    for (int l = 0; l < mLayers; ++l)
        for (const auto& im : mImages) count += frozen(size_t(l + mLayerPad) * S + im.first);
    return count;
}

int HexAutomaton::frozenRadius() const
{
    int rad = -1;
    const size_t S = mLayout.size();
    for (int l = 0; l < mLayers; ++l)
        for (const auto& im : mImages)
            if (frozen(size_t(l + mLayerPad) * S + im.first)) {
                const Axial ax = mLayout.axial(im.first);
                rad = std::max(rad, hexDistance(ax.q, ax.r));
            }
    return rad;
}

bool HexAutomaton::isD6Symmetric() const
{
    const size_t S = mLayout.size();
    auto same = [](double x, double y) { return std::memcmp(&x, &y, sizeof(double)) == 0; };
    for (int l = 0; l < mLayers; ++l) {
        const size_t base = size_t(l + mLayerPad) * S;
        for (const auto& im : mImages) {
            const size_t i = base + im.first, j = base + im.second;
            if (!same(mV[i], mV[j]) || mA[i] != mA[j] || mFreeze[i] != mFreeze[j] ||
                mThick[i] != mThick[j])
                return false;
            if (mGG && (!same(mB[i], mB[j]) || !same(mC[i], mC[j]))) return false;
        }
    }
    return true;
}

} // namespace automata
} // namespace frostvdb
