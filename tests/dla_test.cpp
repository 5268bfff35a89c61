// [dla]: lattice symmetry of the arms, multiple hits, humidity, heat release (eq. 6), exact
// empty-space jumps, determinism, melt map, flow drift, steam humidity.
#include "test_util.h"
#include "plane_layout_util.h"

#include <frostvdb/core/Error.h>
#include <frostvdb/ice/Dla.h>
#include <frostvdb/icephysics/IceState.h>

#include <catch2/catch.hpp>

#include <tbb/global_control.h>

#include <cmath>
#include <complex>
#include <ctime>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

std::string dlaScene(const std::string& lattice, int size, const std::string& extra = "")
{
    return "[scene]\nname = \"dla\"\nframes = 1\nsteps_per_frame = 100\nseed = 7\n"
           "[domain]\nlattice = \"" + lattice + "\"\nsize = [" + std::to_string(size) + ", " + std::to_string(size) +
           "]\nvoxel_size = 0.0001\n[dla]\n" + extra;
}

std::unique_ptr<Simulation> runSteps(const std::string& text, int steps, const std::vector<std::string>& overrides = {})
{
    Scene scene = Scene::fromString(text, "test.toml");
    for (auto& o : overrides) scene.applyOverride(o);
    auto sim = std::make_unique<Simulation>(std::move(scene));
    sim->initialize();
    for (int s = 0; s < steps; ++s) sim->step();
    return sim;
}

ice::DlaEffect& dla(Simulation& sim) { return dynamic_cast<ice::DlaEffect&>(*sim.effect("dla")); }
ice::DlaEffect& dla(const std::unique_ptr<Simulation>& sim) { return dla(*sim); }

openvdb::Vec2d centre2(const Domain& dom)
{
    const auto c = dom.centre();
    return dom.lattice().planePosition(c.x(), c.y());
}

/// Angular Fourier amplitudes of the frozen cells beyond 40% of the largest radius (the arms),
/// weighted by radius, normalised by the total weight: 0 for an isotropic cloud, 1 for one ray.
std::vector<double> armModes(const openvdb::FloatGrid& p, const Domain& dom)
{
    const auto c = centre2(dom);
    double rmax = 0;
    for (auto it = p.cbeginValueOn(); it; ++it)
        if (*it > 0.5f) rmax = std::max(rmax, (dom.lattice().planePosition(it.getCoord().x(), it.getCoord().y()) - c).length());
    std::vector<std::complex<double>> f(9);
    double total = 0;
    for (auto it = p.cbeginValueOn(); it; ++it) {
        if (*it <= 0.5f) continue;
        const auto q = dom.lattice().planePosition(it.getCoord().x(), it.getCoord().y()) - c;
        const double r = q.length();
        if (r < 0.4 * rmax) continue;
        const double phi = std::atan2(q.y(), q.x());
        total += r;
        for (int m = 1; m <= 8; ++m) f[m] += r * std::polar(1.0, m * phi);
    }
    std::vector<double> a(9, 0.0);
    for (int m = 1; m <= 8; ++m) a[m] = total > 0 ? std::abs(f[m]) / total : 0.0;
    return a;
}

/// Ice cells and ice/non-ice neighbour pairs (the perimeter) on the domain's own lattice.
std::pair<double, double> areaPerimeter(const openvdb::FloatGrid& p, const Domain& dom)
{
    auto acc = p.getConstAccessor();
    double area = 0, perim = 0;
    for (auto it = p.cbeginValueOn(); it; ++it) {
        if (*it <= 0.5f) continue;
        area += 1;
        for (const auto& o : dom.lattice().planeNeighbours())
            if (!(acc.getValue(it.getCoord() + o) > 0.5f)) perim += 1;
    }
    return {area, perim};
}

/// Sum of (value - background) over active voxels, in double.
double excess(const openvdb::FloatGrid& g)
{
    double s = 0;
    for (auto it = g.cbeginValueOn(); it; ++it) s += double(*it) - double(g.background());
    return s;
}

/// Ice cells left and right of x = xs (index space).
std::pair<int, int> leftRight(const openvdb::FloatGrid& p, double xs)
{
    int l = 0, r = 0;
    for (auto it = p.cbeginValueOn(); it; ++it)
        if (*it > 0.5f) (it.getCoord().x() < xs ? l : r) += 1;
    return {l, r};
}

std::string modesText(const std::vector<double>& m)
{
    std::ostringstream os;
    for (int k = 1; k <= 8; ++k) os << " m" << k << "=" << m[k];
    return os.str();
}

/// A reproducible stream of integers in [0, n) for the random-ice tests (a 64-bit LCG).
struct Draw {
    uint64_t h;
    int operator()(int n)
    {
        h = h * 6364136223846793005ull + 1442695040888963407ull;
        return int((h >> 33) % uint64_t(n));
    }
};

/// Sets p = 1 on @a length cells from @a c along @a axis (clamped at n - 1: the last cell may
/// repeat) and records each cell set in @a ice.
void iceSegment(openvdb::FloatGrid& p, openvdb::Coord c, int axis, int length, int n, std::vector<openvdb::Coord>& ice)
{
    for (int l = 0; l < length; ++l, c[axis] = std::min(c[axis] + 1, n - 1)) {
        p.tree().setValue(c, 1.f);
        ice.push_back(c);
    }
}

} // namespace

TEST_CASE("Hexagonal DLA grows 6 arms and square DLA 4 arms", "[fast][dla]")
{
    for (const std::string lattice : {"hexagonal", "square"}) {
        const int j = lattice == "hexagonal" ? 6 : 4;
        auto sim = runSteps(dlaScene(lattice, 160, "humidity = 1500\nhits = 24\n"), 150);
        auto p = planeLayout(sim->world(), "p");
        const auto modes = armModes(*p, sim->world().domain);
        INFO(lattice << " modes:" << modesText(modes) << " frozen " << dla(sim).stats().frozen);
        int best = 2;
        for (int m = 2; m <= 8; ++m)
            if (modes[m] > modes[best]) best = m;
        CHECK(best == j);
        for (int m = 2; m <= 8; ++m)
            if (m != j && 2 * m != j && m != 2 * j) CHECK(modes[j] > 2.0 * modes[m]);
        CHECK(dla(sim).stats().frozen > 800);
    }
}

TEST_CASE("More hits per cell give more regular arms", "[fast][dla]")
{
    // at about the same mass (~2000 cells), the 6-fold arm mode is much stronger with n = 24.
    // One realisation is too noisy to judge (seed 7 alone gives an n = 1 cluster with a 6-fold
    // mode of 0.28, seed 8 one with a dominance of 1.46): means over three seeds.
    auto dominance = [](const std::vector<double>& m) {
        double other = 0;
        for (int k = 2; k <= 8; ++k)
            if (k != 6 && k != 3) other = std::max(other, m[k]);
        return m[6] / other;
    };
    double m1six = 0, m8six = 0, dom1 = 0, dom8 = 0;
    for (int seed = 1; seed <= 3; ++seed) {
        const std::string o = "scene.seed=" + std::to_string(seed);
        auto plain = runSteps(dlaScene("hexagonal", 160, "humidity = 60\nhits = 1\n"), 100, {o});
        auto noiseReduced = runSteps(dlaScene("hexagonal", 160, "humidity = 1500\nhits = 24\n"), 150, {o});
        const auto m1 = armModes(*planeLayout(plain->world(), "p"), plain->world().domain);
        const auto m8 = armModes(*planeLayout(noiseReduced->world(), "p"), noiseReduced->world().domain);
        INFO("seed " << seed << ": n=1 frozen " << dla(plain).stats().frozen << modesText(m1));
        INFO("seed " << seed << ": n=24 frozen " << dla(noiseReduced).stats().frozen << modesText(m8));
        CHECK(dla(plain).stats().frozen > 500);
        m1six += m1[6] / 3;
        m8six += m8[6] / 3;
        dom1 += dominance(m1) / 3;
        dom8 += dominance(m8) / 3;
    }
    // dominance of the 6-fold mode over the strongest other mode
    INFO("mean 6-fold mode n=1 " << m1six << ", n=24 " << m8six << "; dominance n=1 " << dom1 << ", n=24 " << dom8);
    CHECK(m8six > 2.0 * m1six);
    CHECK(dom8 > 2.0 * dom1);
}

TEST_CASE("Higher humidity makes hybrid ice more branched", "[fast][dla][hybrid]")
{
    // phase field + DLA, compared when the ice first covers 800 cells: more walkers per step give
    // more perimeter per unit of ice area (the phase field alone smooths; DLA branches)
    const std::string scene = "[scene]\nname = \"hy\"\nframes = 1\nsteps_per_frame = 100\nseed = 3\n"
                              "[domain]\nlattice = \"hexagonal\"\nsize = [112, 112]\n"
                              "[phase_field]\nanisotropy_mode = 6\n[dla]\n";
    std::vector<double> ratio;
    for (int H : {3, 30, 150}) {
        auto sim = runSteps(scene, 0, {"dla.humidity=" + std::to_string(H)});
        std::pair<double, double> ap;
        int s = 0;
        for (; s < 400; ++s) {
            sim->step();
            ap = areaPerimeter(*planeLayout(sim->world(), "p"), sim->world().domain);
            if (ap.first >= 800) break;
        }
        ratio.push_back(ap.second / ap.first);
        WARN("H=" << H << ": area " << ap.first << " at step " << s + 1 << ", perimeter " << ap.second << ", ratio "
                  << ratio.back());
        CHECK(ap.first >= 800);
    }
    CHECK(ratio[1] > ratio[0] * 1.1);
    CHECK(ratio[2] > ratio[1] * 1.1);
}

TEST_CASE("DLA heat release adds L times the DLA change of p to T", "[fast][dla][heat]")
{
    // no [phase_field]: T is otherwise constant; L = K/6 by default and a set value when given
    for (double L : {-1.0, 0.7}) {
        auto sim = makeSim(dlaScene("hexagonal", 64, "humidity = 100\nhits = 2\nheat_release = " + std::to_string(L) + "\n"));
        sim.initialize();
        ice::shared(sim.world()).temperatureEvolves = true; // as if a heat solver owned T
        auto& w = sim.world();
        const double p0 = excess(*w.fields.get<openvdb::FloatGrid>("p"));
        const double T0 = excess(*w.fields.get<openvdb::FloatGrid>("T"));
        for (int s = 0; s < 30; ++s) sim.step();
        const double dp = excess(*w.fields.get<openvdb::FloatGrid>("p")) - p0;
        const double dT = excess(*w.fields.get<openvdb::FloatGrid>("T")) - T0;
        const double Lused = L < 0 ? ice::shared(w).latentHeat / 6.0 : L;
        INFO("L " << Lused << " dp " << dp << " dT " << dT << " dpDla " << dla(sim).stats().dpDla);
        REQUIRE(dp > 50);
        CHECK(dla(sim).stats().dpDla == Approx(dp).epsilon(1e-6));
        CHECK(dT == Approx(Lused * dp).epsilon(1e-5));
    }
    // and nothing is added while T is not a live field
    auto sim = runSteps(dlaScene("square", 64, "humidity = 100\n"), 10);
    CHECK(excess(*sim->world().fields.get<openvdb::FloatGrid>("T")) == 0.0);
}

TEST_CASE("Hybrid heat balance is K dp_PF plus L dp_DLA", "[fast][dla][heat][hybrid]")
{
    // the front stays far from the edge, so no heat leaves: sum(T - T_inf) = K dp_PF + L dp_DLA
    const std::string scene = "[scene]\nname = \"hb\"\nframes = 1\nsteps_per_frame = 100\nseed = 3\n"
                              "[domain]\nlattice = \"hexagonal\"\nsize = [128, 128]\n[region]\ntolerance = 0\n"
                              "[phase_field]\nanisotropy_mode = 6\n[dla]\nhumidity = 40\nheat_release = ";
    for (double L : {0.25, 1.0}) {
        auto sim = makeSim(scene + std::to_string(L) + "\n");
        sim.initialize();
        auto& w = sim.world();
        const double K = ice::shared(w).latentHeat;
        const double p0 = excess(*w.fields.get<openvdb::FloatGrid>("p"));
        const double T0 = excess(*w.fields.get<openvdb::FloatGrid>("T"));
        for (int s = 0; s < 150; ++s) sim.step();
        const double dp = excess(*w.fields.get<openvdb::FloatGrid>("p")) - p0;
        const double dT = excess(*w.fields.get<openvdb::FloatGrid>("T")) - T0;
        const double dpDla = dla(sim).stats().dpDla, dpPf = dp - dpDla;
        INFO("L " << L << " K " << K << " dp " << dp << " dpDla " << dpDla << " dT " << dT << " expected "
                  << K * dpPf + L * dpDla);
        REQUIRE(dpDla > 20);
        REQUIRE(dpPf > 20);
        CHECK(dT == Approx(K * dpPf + L * dpDla).epsilon(2e-3));
    }
}

TEST_CASE("Empty-space jumps keep the hitting statistics of the plain walk", "[fast][dla][jumps]")
{
    // A fixed, asymmetric seed; walkers released uniformly and never frozen. Histogram of where
    // they stick (angle and distance from the centre) plus those that leave the domain, for the
    // plain walk and the jumping walk (independent seeds); chi-square test of homogeneity.
    for (auto kind : {LatticeKind::Hexagonal, LatticeKind::Square}) {
        const Domain dom = makePlaneDomain(Lattice(kind), openvdb::Coord(64, 64, 1), 1e-4);
        auto p = openvdb::FloatGrid::create(0.f);
        for (int j = 28; j <= 35; ++j)
            for (int i = 28; i <= 35; ++i)
                if ((i - 31.5) * (i - 31.5) + (j - 31.5) * (j - 31.5) < 12) p->tree().setValue(openvdb::Coord(i, j, 0), 1.f);
        for (int i = 42; i <= 47; ++i) p->tree().setValue(openvdb::Coord(i, 40, 0), 1.f); // a bar off centre
        const int bins = 2 * 12 + 1;
        auto histogram = [&](bool jumps, double bias, uint64_t seed, ice::DlaStats* st) {
            ice::DlaParams prm;
            prm.jumps = jumps;
            prm.testJumpBias = bias;
            prm.jumpMinRadius = 2;
            ice::DlaEngine eng(dom, prm, seed);
            eng.sync(*p);
            std::vector<double> h(bins, 0.0);
            std::vector<ice::WalkEnd> ends;
            ice::DlaEngine::Inputs in;
            const uint64_t n = 120000;
            eng.walkBatch(0, 0, n, in, ends);
            for (const auto& e : ends) {
                st->moves += e.moves;
                st->latticeSteps += e.latticeSteps;
                st->jumps += e.jumps;
                if (e.kind != ice::WalkEnd::Stuck) {
                    h[bins - 1] += 1;
                    continue;
                }
                const auto c = eng.coord(e.cell);
                const auto q = dom.lattice().planePosition(c.x(), c.y()) - dom.lattice().planePosition(31.5, 31.5);
                const int a = std::min(11, int((std::atan2(q.y(), q.x()) + M_PI) / (2 * M_PI) * 12));
                h[size_t(a + (q.length() > 7 ? 12 : 0))] += 1;
            }
            return h;
        };
        auto chi2 = [&](const std::vector<double>& a, const std::vector<double>& b) {
            double c = 0;
            for (int k = 0; k < bins; ++k)
                if (a[k] + b[k] > 0) c += (a[k] - b[k]) * (a[k] - b[k]) / (a[k] + b[k]);
            return c;
        };
        ice::DlaStats sPlain, sJump, sBias;
        const auto plain = histogram(false, 0.0, 11, &sPlain);
        const auto jump = histogram(true, 0.0, 12, &sJump);
        const auto biased = histogram(true, 0.3, 12, &sBias);
        const double c0 = chi2(plain, jump), c1 = chi2(plain, biased);
        // 24 degrees of freedom: P(chi2 > 51.2) = 0.001
        WARN(Lattice::kindName(kind) << ": chi2 plain vs jump " << c0 << ", plain vs biased jump " << c1
                                     << "; stuck " << (120000 - plain[bins - 1]) << " / " << (120000 - jump[bins - 1])
                                     << "; moves per walker " << sPlain.moves / 120000.0 << " -> "
                                     << sJump.moves / 120000.0 << " (" << sJump.jumps / 120000.0 << " jumps)");
        CHECK(c0 < 51.2);
        CHECK(c1 > 51.2);                          // the test sees a bias in the jump
        CHECK(sJump.moves * 3 < sPlain.moves);     // and jumps save steps
        CHECK(sJump.latticeSteps == Approx(sPlain.latticeSteps).epsilon(0.05)); // same walk length on average
    }
}

TEST_CASE("Walk-on-spheres jumps keep the hitting statistics of the exact-table walk", "[fast][dla][jumps]")
{
    // Beyond the largest exact table the walkers jump to a uniform point of the largest free
    // circle. Two separated pieces of ice in a 256^2 plane; tables capped at radius 8 so the
    // circles are used from radius 8 on (the harshest case: the default cap is 128). Where the
    // walkers stick (piece, angle) and how many leave, against tables only: chi-square.
    for (auto kind : {LatticeKind::Hexagonal, LatticeKind::Square}) {
        Domain dom = makePlaneDomain(Lattice(kind), openvdb::Coord(256, 256, 1), 1e-4);
        auto p = openvdb::FloatGrid::create(0.f);
        for (int j = 120; j <= 136; ++j)
            for (int i = 90; i <= 106; ++i)
                if ((i - 98) * (i - 98) + (j - 128) * (j - 128) < 40) p->tree().setValue(openvdb::Coord(i, j, 0), 1.f);
        for (int j = 60; j <= 75; ++j) p->tree().setValue(openvdb::Coord(180, j, 0), 1.f); // a bar
        const int bins = 2 * 12 + 1;
        auto histogram = [&](bool spheres, uint64_t seed, ice::DlaStats* st) {
            ice::DlaParams prm;
            prm.jumpMaxRadius = 8;
            prm.sphereJumps = spheres;
            ice::DlaEngine eng(dom, prm, seed);
            eng.sync(*p);
            std::vector<double> h(bins, 0.0);
            std::vector<ice::WalkEnd> ends;
            ice::DlaEngine::Inputs in;
            const uint64_t n = 40000;
            eng.walkBatch(0, 0, n, in, ends);
            for (const auto& e : ends) {
                st->moves += e.moves;
                st->latticeSteps += e.latticeSteps;
                if (e.kind != ice::WalkEnd::Stuck) {
                    h[bins - 1] += 1;
                    continue;
                }
                const auto c = eng.coord(e.cell);
                const bool bar = c.x() > 150;
                const auto q = dom.lattice().planePosition(c.x(), c.y()) -
                               dom.lattice().planePosition(bar ? 180 : 98, bar ? 67.5 : 128);
                const int a = std::min(11, int((std::atan2(q.y(), q.x()) + M_PI) / (2 * M_PI) * 12));
                h[size_t(a + (bar ? 12 : 0))] += 1;
            }
            return h;
        };
        ice::DlaStats sTable, sSphere;
        const auto table = histogram(false, 21, &sTable);
        const auto sphere = histogram(true, 22, &sSphere);
        double c = 0;
        for (int k = 0; k < bins; ++k)
            if (table[k] + sphere[k] > 0) c += (table[k] - sphere[k]) * (table[k] - sphere[k]) / (table[k] + sphere[k]);
        WARN(Lattice::kindName(kind) << ": chi2 tables vs spheres " << c << "; leaving " << table[bins - 1] << " / "
                                     << sphere[bins - 1] << "; moves per walker " << sTable.moves / 40000.0 << " -> "
                                     << sSphere.moves / 40000.0);
        CHECK(c < 51.2); // 24 degrees of freedom, P(chi2 > 51.2) = 0.001
        CHECK(sSphere.moves * 2 < sTable.moves);
        CHECK(sSphere.latticeSteps == Approx(sTable.latticeSteps).epsilon(0.05));
    }
}

TEST_CASE("DLA memory follows the ice, not the domain", "[fast][dla]")
{
    // The same small seed in a 512^2 and a 8192^2 plane: the sparse structures hold the same
    // number of distance bricks, and the engine's memory is far below one byte per cell.
    size_t bricks[2], bytes[2];
    int k = 0;
    for (int n : {512, 8192}) {
        Domain dom = makePlaneDomain(Lattice(LatticeKind::Square), openvdb::Coord(n, n, 1), 1e-4);
        auto p = openvdb::FloatGrid::create(0.f);
        for (int j = -3; j <= 3; ++j)
            for (int i = -3; i <= 3; ++i) p->tree().setValue(openvdb::Coord(n / 2 + i, n / 2 + j, 0), 1.f);
        ice::DlaParams prm;
        ice::DlaEngine eng(dom, prm, 5);
        eng.sync(*p);
        CHECK(eng.iceCount() == 49);
        CHECK(eng.iceDistance(openvdb::Coord(n / 2 + 3, n / 2 + 4, 0)) == 1);
        CHECK(eng.iceDistance(openvdb::Coord(n / 2, n / 2 + 10, 0)) == 7);
        // far away: an uncapped lower bound, never more than the true Chebyshev distance
        const int far = eng.iceDistance(openvdb::Coord(n / 2, 0, 0));
        CHECK(far >= n / 8);
        CHECK(far <= n / 2 - 3);
        bricks[k] = eng.brickCount();
        bytes[k] = eng.memoryBytes();
        ++k;
    }
    CHECK(bricks[0] == bricks[1]);
    CHECK(bytes[1] < 4 * bytes[0]);
    CHECK(bytes[1] < size_t(8192) * 8192 / 1000);
}

TEST_CASE("Melted ice repairs the walker distances to those of a rebuild from the ice", "[fast][dla]")
{
    // Grow and melt random ice over a few syncs; after each, every cell's distance (exact below
    // the cap, the pyramid's bound above it) equals that of an engine synced afresh, and the
    // melts were repaired in place (no full rebuild).
    struct Case { LatticeKind kind; bool box; int n; };
    for (const Case cs : {Case{LatticeKind::Square, false, 120}, Case{LatticeKind::Hexagonal, false, 120},
                          Case{LatticeKind::Square, true, 40}}) {
        const openvdb::Coord size(cs.n, cs.n, cs.box ? cs.n : 1);
        Domain dom = cs.box ? makeBoxDomain(Lattice(cs.kind), size, 1e-4) : makePlaneDomain(Lattice(cs.kind), size, 1e-4);
        auto p = openvdb::FloatGrid::create(0.f);
        ice::DlaParams prm;
        ice::DlaEngine eng(dom, prm, 5);
        Draw draw{12345};
        std::vector<openvdb::Coord> ice;
        for (int round = 0; round < 6; ++round) {
            for (int a = 0; a < 60; ++a) { // new ice: short random segments
                const int x = draw(cs.n), y = draw(cs.n);
                iceSegment(*p, openvdb::Coord(x, y, cs.box ? draw(cs.n) : 0), 0, 5, cs.n, ice);
            }
            for (int a = 0; a < 8 && round > 0; ++a) // melts: p falls to 0.3 (still active)
                p->tree().setValue(ice[size_t(draw(int(ice.size())))], 0.3f);
            eng.sync(*p);
            ice::DlaEngine fresh(dom, prm, 5);
            fresh.sync(*p);
            REQUIRE(eng.iceCount() == fresh.iceCount());
            int differ = 0;
            for (auto it = dom.bbox().begin(); it; ++it) differ += eng.iceDistance(*it) != fresh.iceDistance(*it);
            INFO("lattice " << Lattice::kindName(cs.kind) << (cs.box ? " box" : " plane") << ", round " << round);
            CHECK(differ == 0);
        }
        CHECK(eng.rebuildCount() == 0);
    }
}

namespace {

/// A random growth history of the ice in @a p, one round at a time, as a run makes it: new seeds,
/// fronts that advance (Eden growth next to random ice cells: the phase field's crossings), the
/// walkers' own freezes (told to the engine, not listed), melts (p back to 0.3, listed).
struct GrowthHistory {
    const Domain& dom;
    openvdb::FloatGrid& p;
    ice::DlaEngine& eng;
    Draw draw;
    std::vector<openvdb::Coord> nbr, ice, crossed;

    GrowthHistory(const Domain& d, openvdb::FloatGrid& g, ice::DlaEngine& e, uint64_t seed)
        : dom(d), p(g), eng(e), draw{seed}, nbr(ice::walkerNeighbours(d)) {}
    openvdb::Coord randomCell()
    {
        const auto& b = dom.bbox();
        return b.min() + openvdb::Coord(draw(b.dim().x()), draw(b.dim().y()), draw(b.dim().z()));
    }
    openvdb::Coord besideIce() { return ice[size_t(draw(int(ice.size())))] + nbr[size_t(draw(int(nbr.size())))]; }
    bool isIce(const openvdb::Coord& c) const { return p.tree().getValue(c) > 0.5f; }
    void crossUp(const openvdb::Coord& c)
    {
        if (!dom.bbox().isInside(c) || isIce(c)) return;
        p.tree().setValue(c, 1.f);
        ice.push_back(c);
        crossed.push_back(c);
    }
    /// One round: @a seeds new seeds, @a front cells of growth, @a walkers freezes, @a melts melts.
    void round(int seeds, int front, int walkers, int melts)
    {
        for (int a = 0; a < seeds; ++a) crossUp(randomCell());
        for (int a = 0; a < front && !ice.empty(); ++a) crossUp(besideIce());
        for (int a = 0; a < walkers && !ice.empty(); ++a) {
            const openvdb::Coord c = besideIce();
            if (!dom.bbox().isInside(c) || isIce(c)) continue;
            p.tree().setValue(c, 1.f);
            ice.push_back(c);
            eng.freezeDeferred(eng.index(c));
            if (a % 7 == 6) eng.flushDistances(); // a resumed walk reads them mid-batch
        }
        eng.flushDistances();
        for (int a = 0; a < melts && !ice.empty(); ++a) {
            const openvdb::Coord c = ice[size_t(draw(int(ice.size())))];
            if (!isIce(c)) continue;
            p.tree().setValue(c, 0.3f);
            crossed.push_back(c);
        }
    }
};

/// Cells (and planes' blocks) whose distance differs between @a a and @a b.
int64_t distanceDifferences(const Domain& dom, const ice::DlaEngine& a, const ice::DlaEngine& b)
{
    int64_t differ = 0;
    for (auto it = dom.bbox().begin(); it; ++it)
        differ += (a.iceDistance(*it) != b.iceDistance(*it)) + (a.blockDistance(*it) != b.blockDistance(*it));
    return differ;
}

} // namespace

TEST_CASE("The walkers' distance map kept up to date equals a rebuild from the ice after random growth histories",
          "[fast][dla]")
{
    // The map follows the ice: each sync relaxes the distances around the ice frozen since the
    // last one (listed crossings, all of p, the walkers' own freezes) and repairs them around
    // melts. After every round of a random history, every cell's distance (exact below the cap,
    // the bound above it) and every block distance equal those of an engine built afresh from
    // the same ice, and no round needed a full rebuild.
    struct Case { LatticeKind kind; bool box; int n; uint64_t seed; };
    for (const Case cs : {Case{LatticeKind::Hexagonal, false, 160, 101}, Case{LatticeKind::Square, false, 160, 202},
                          Case{LatticeKind::Hexagonal, false, 96, 303}, Case{LatticeKind::Square, true, 32, 404}}) {
        const openvdb::Coord size(cs.n, cs.n, cs.box ? cs.n : 1);
        Domain dom = cs.box ? makeBoxDomain(Lattice(cs.kind), size, 1e-4) : makePlaneDomain(Lattice(cs.kind), size, 1e-4);
        auto p = openvdb::FloatGrid::create(0.f);
        ice::DlaParams prm;
        ice::DlaEngine eng(dom, prm, 5);
        GrowthHistory h(dom, *p, eng, cs.seed);
        int64_t compared = 0;
        for (int round = 0; round < 12; ++round) {
            h.round(round < 2 ? 4 : 1, cs.box ? 60 : 150, 25, round >= 4 && round % 3 == 2 ? 3 : 0);
            if (round % 4 == 3) eng.sync(*p); // all of p read
            else eng.syncCells(*p, h.crossed); // the listed crossings alone
            h.crossed.clear();
            ice::DlaEngine fresh(dom, prm, 5);
            fresh.sync(*p);
            INFO(Lattice::kindName(cs.kind) << (cs.box ? " box" : " plane") << " " << cs.n << ", round " << round);
            REQUIRE(eng.iceCount() == fresh.iceCount());
            CHECK(distanceDifferences(dom, eng, fresh) == 0);
            CHECK(eng.rebuildCount() == 0); // every round was an update, never a rebuild
            compared += dom.bbox().volume();
        }
        CHECK(eng.work().fresh > 400);
        CHECK(eng.work().melted > 0);
        CHECK(eng.work().relaxed > 5000);
        CHECK(compared > 0);
    }
}

TEST_CASE("Walker distance map: CPU time of a large random growth history", "[.][dla][bench]")
{
    // Not a check: the distance work of a 4096^2 hexagonal plane growing 300 seeds by fronts
    // (Eden growth, listed crossings) and a few melts in 200 syncs: the syncs' process CPU time.
    const int n = 4096;
    Domain dom = makePlaneDomain(Lattice(LatticeKind::Hexagonal), openvdb::Coord(n, n, 1), 1e-4);
    auto p = openvdb::FloatGrid::create(0.f);
    ice::DlaParams prm;
    ice::DlaEngine eng(dom, prm, 5);
    GrowthHistory h(dom, *p, eng, 99);
    h.round(300, 0, 0, 0);
    eng.syncCells(*p, h.crossed);
    h.crossed.clear();
    double cpu = 0; // process CPU seconds of the syncs (the walkers' flushes are in round())
    for (int round = 0; round < 200; ++round) {
        h.round(0, 4000, 0, 10);
        const std::clock_t c0 = std::clock();
        eng.syncCells(*p, h.crossed);
        cpu += double(std::clock() - c0) / CLOCKS_PER_SEC;
        h.crossed.clear();
    }
    const auto& w = eng.work();
    WARN("ice " << eng.iceCount() << ", syncs' CPU " << cpu << " s; distance work (wall): scan " << w.scanSeconds
                << " s, cell BFS " << w.relaxSeconds << " s, block BFS " << w.coarseSeconds << " s, repair "
                << w.repairSeconds << " s; cells frozen " << w.fresh << ", lowered " << w.relaxed << ", melted "
                << w.melted << ", bricks " << eng.brickCount());
}

TEST_CASE("Walker distances beyond the cap are lower bounds within two blocks of the lattice distance", "[fast][dla][jumps]")
{
    // Random short segments of ice (and a few melts) in a 200^2 plane; the true lattice distance
    // of every cell by a plain BFS over the whole plane. Jumps are exact only while the engine's
    // distance never exceeds it; beyond the exact cap (16) the block distances keep it within
    // twice the blocks' diameter (the pyramid alone was within a factor 2).
    for (auto kind : {LatticeKind::Hexagonal, LatticeKind::Square}) {
        const int n = 200;
        Domain dom = makePlaneDomain(Lattice(kind), openvdb::Coord(n, n, 1), 1e-4);
        const auto nbr = ice::walkerNeighbours(dom);
        auto p = openvdb::FloatGrid::create(0.f);
        ice::DlaParams prm;
        ice::DlaEngine eng(dom, prm, 5);
        Draw draw{777};
        std::vector<openvdb::Coord> ice;
        int checked = 0, far = 0, worstGap = 0;
        bool below = true;
        for (int round = 0; round < 3; ++round) {
            for (int a = 0; a < 4; ++a) {
                const int x = draw(n), y = draw(n);
                iceSegment(*p, openvdb::Coord(x, y, 0), 1, 6, n, ice);
            }
            if (round > 0) // a melt that empties a block: the block distances are repaired
                for (int l = 0; l < 6; ++l) p->tree().setValue(ice[size_t(l)], 0.2f);
            eng.sync(*p);
            std::vector<int> truth(size_t(n) * n, -1);
            std::vector<openvdb::Coord> queue;
            for (auto it = p->cbeginValueOn(); it; ++it)
                if (*it > 0.5f) {
                    truth[size_t(it.getCoord().x() + n * it.getCoord().y())] = 0;
                    queue.push_back(it.getCoord());
                }
            for (size_t q = 0; q < queue.size(); ++q)
                for (const auto& o : nbr) {
                    const openvdb::Coord v = queue[q] + o;
                    if (v.x() < 0 || v.y() < 0 || v.x() >= n || v.y() >= n) continue;
                    int& t = truth[size_t(v.x() + n * v.y())];
                    if (t >= 0) continue;
                    t = truth[size_t(queue[q].x() + n * queue[q].y())] + 1;
                    queue.push_back(v);
                }
            for (int y = 0; y < n; ++y)
                for (int x = 0; x < n; ++x) {
                    const int t = truth[size_t(x + n * y)], d = eng.iceDistance(openvdb::Coord(x, y, 0));
                    below = below && d <= t;
                    ++checked;
                    if (t >= 16 && t <= 150) {
                        ++far;
                        worstGap = std::max(worstGap, t - d);
                    }
                }
        }
        INFO(Lattice::kindName(kind) << ": " << far << " cells 16..150 from the ice, largest gap " << worstGap);
        CHECK(below);
        CHECK(far > 1000);
        CHECK(worstGap <= 2 * 6); // twice the largest distance within a block (6 steps on both lattices)
    }
}

TEST_CASE("Lattice sphere tables are normalised and lattice symmetric", "[fast][dla][jumps]")
{
    for (auto kind : {LatticeKind::Hexagonal, LatticeKind::Square}) {
        const Domain dom = makePlaneDomain(Lattice(kind), openvdb::Coord(64, 64, 1), 1e-4);
        for (int r : {2, 5, 16}) {
            auto t = ice::sphereTable(ice::walkerNeighbours(dom), r);
            CHECK(t->exits.size() == size_t(kind == LatticeKind::Hexagonal ? 6 * r : 4 * r));
            double sum = 0, mx = 0;
            openvdb::Vec2d mean(0.0);
            for (size_t k = 0; k < t->exits.size(); ++k) {
                sum += t->prob[k];
                mean += t->prob[k] * dom.lattice().planePosition(t->exits[k].x(), t->exits[k].y());
                mx = std::max(mx, t->prob[k]);
            }
            CHECK(sum == Approx(1.0).epsilon(1e-12));
            CHECK(mean.length() < 1e-9); // no drift
            CHECK(t->solverResidual < 1e-12);
            // the walk from the centre of a ball of radius r takes ~r^2 steps
            CHECK(t->meanSteps > 0.5 * r * r);
            CHECK(t->meanSteps < 1.0 * r * r);
        }
    }
    const Domain box = makeBoxDomain(Lattice(LatticeKind::Square), openvdb::Coord(32, 32, 32), 1e-4);
    auto t = ice::sphereTable(ice::walkerNeighbours(box), 6);
    CHECK(t->exits.size() == size_t(4 * 36 + 2));
}

TEST_CASE("Same seed gives bit-identical DLA files with 1 and 2 threads", "[fast][dla][determinism]")
{
    const std::string scene = dlaScene("hexagonal", 96, "humidity = 600\nhits = 2\nbatch = 100\n") +
                              "[phase_field]\nanisotropy_mode = 6\n";
    std::string paths[2];
    for (int threads : {1, 2}) {
        auto sim = makeSim(scene, {"scene.steps_per_frame=60"});
        RunOptions ro;
        ro.progress = false;
        ro.threads = threads;
        ro.outDir = tempDir("dla_det" + std::to_string(threads));
        sim.run(ro);
        paths[threads - 1] = ro.outDir + "/dla.0001.vdb";
        CHECK(dla(sim).stats().conflicts > 0); // the conflict path is exercised
    }
    std::string why;
    CHECK(sameVdbContent(paths[0], paths[1], &why));
    INFO(why);
    auto other = makeSim(scene, {"scene.steps_per_frame=60", "scene.seed=8"});
    RunOptions ro;
    ro.progress = false;
    ro.outDir = tempDir("dla_det_other");
    other.run(ro);
    CHECK(!sameVdbContent(ro.outDir + "/dla.0001.vdb", paths[0]));
}

TEST_CASE("A melt map of 0 gets no sticking", "[fast][dla][melt]")
{
    const std::string scene = dlaScene("square", 96, "humidity = 300\n");
    const double xs = 48 - 6; // melt 0 left of this
    auto run = [&](bool withMelt) {
        auto sim = makeSim(scene);
        sim.initialize();
        if (withMelt) {
            auto melt = sim.world().fields.require<openvdb::FloatGrid>(ice::kMelt, 1.f);
            melt->tree().fill(openvdb::CoordBBox(openvdb::Coord(0, 0, 0), openvdb::Coord(int(xs) - 1, 95, 0)), 0.f);
        }
        for (int s = 0; s < 60; ++s) sim.step();
        return leftRight(*sim.world().fields.get<openvdb::FloatGrid>("p"), xs);
    };
    const auto free = run(false), masked = run(true);
    INFO("without melt map: " << free.first << " left, " << free.second << " right; with: " << masked.first << ", "
                              << masked.second);
    REQUIRE(free.first > 50); // it would grow there
    CHECK(masked.first == 0);
    CHECK(masked.second > 100);
}

TEST_CASE("Flow drift makes DLA grow into the flow", "[fast][dla][flow]")
{
    // vel = +x: walkers are carried from the left onto the crystal's upstream (left) side
    const std::string scene = dlaScene("square", 96, "humidity = 300\n");
    auto sim = makeSim(scene);
    sim.initialize();
    auto vel = sim.world().fields.require<openvdb::Vec3SGrid>(ice::kVelocity, openvdb::Vec3s(0.f));
    // 0.15 cells per step: v dt / h = 0.075 * 0.0002 / 0.0001
    vel->tree().fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(95, 95, 0)), openvdb::Vec3s(0.075f, 0.f, 0.f));
    for (int s = 0; s < 60; ++s) sim.step();
    const auto lr = leftRight(*sim.world().fields.get<openvdb::FloatGrid>("p"), 47.5);
    INFO("left (upstream) " << lr.first << ", right " << lr.second);
    CHECK(lr.first > 2 * lr.second);
}

TEST_CASE("Steam density raises the walker release and the growth on its side", "[fast][dla][steam]")
{
    auto run = [](double gain) {
        auto sim = makeSim(dlaScene("square", 96, "humidity = 50\nsteam_reach = 0.0005\nsteam_humidity = " +
                                                      std::to_string(gain) + "\n"));
        sim.initialize();
        auto& w = sim.world();
        // steam on the right third, a little above the plate (world z = 0.0002 m)
        auto density = openvdb::FloatGrid::create(0.f);
        density->setTransform(w.fields.transform());
        density->tree().fill(openvdb::CoordBBox(openvdb::Coord(64, 0, 2), openvdb::Coord(95, 95, 2)), 2.f);
        w.fields.replace("density", density);
        for (int s = 0; s < 60; ++s) sim.step();
        const auto lr = leftRight(*w.fields.get<openvdb::FloatGrid>("p"), 47.5);
        return std::make_tuple(lr.first, lr.second, dla(sim).stats().released);
    };
    const auto off = run(0.0), on = run(4.0);
    INFO("gain 0: left " << std::get<0>(off) << " right " << std::get<1>(off) << " walkers " << std::get<2>(off));
    INFO("gain 4: left " << std::get<0>(on) << " right " << std::get<1>(on) << " walkers " << std::get<2>(on));
    CHECK(std::get<2>(off) == 50u * 60u);
    CHECK(std::get<2>(on) > std::get<2>(off) * 2); // 1/3 of the cells at 1 + 4 * 2 * 0.6
    CHECK(std::get<1>(on) > 1.5 * std::get<0>(on));
}

TEST_CASE("The humidity schedule changes H from its step on", "[fast][dla]")
{
    auto sim = runSteps(dlaScene("square", 48, "humidity = 30\nhumidity_schedule = [5, 50, 8, 10]\n"), 10);
    CHECK(dla(sim).stats().released == 5u * 30u + 3u * 50u + 2u * 10u);
    CHECK_THROWS_AS(makeSim(dlaScene("square", 48, "humidity_schedule = [5, 50, 8]\n")), SceneError);
}

