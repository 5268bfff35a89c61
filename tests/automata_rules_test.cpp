// Tests of the hexagonal automata on plain arrays: symmetry, wedge == full, classes, growth,
// mass conservation.
#include <catch2/catch.hpp>

#include <frostvdb/automata/Automata.h>

#include <cstring>
#include <tbb/global_control.h>
#include <set>

using namespace frostvdb::automata;

namespace {

AutomatonConfig config(Rule r, int radius, bool wedge)
{
    AutomatonConfig c;
    c.rule = r;
    c.radius = radius;
    c.layers = r == Rule::GravnerGriffeath3D ? 9 : 1;
    c.wedge = wedge;
    return c;
}

/// True if every cell of the hexagon (all layers) agrees bit for bit between a and b.
bool sameBits(const HexAutomaton& a, const HexAutomaton& b)
{
    const HexLayout& L = a.layout();
    auto eq = [](double x, double y) { return std::memcmp(&x, &y, sizeof(double)) == 0; };
    for (int l = 0; l < a.layers(); ++l)
        for (const Row& row : L.fullRows(l))
            for (int q = row.q0; q <= row.q1; ++q) {
                const size_t i = a.cellIndex(q, row.r, l);
                if (!eq(a.value(i), b.value(i)) || !eq(a.vapour(i), b.vapour(i)) ||
                    !eq(a.boundaryMass(i), b.boundaryMass(i)) || a.frozen(i) != b.frozen(i) ||
                    a.freezeStep(i) != b.freezeStep(i) || a.thickStep(i) != b.thickStep(i))
                    return false;
            }
    return true;
}

const Rule kAllRules[] = {Rule::Packard, Rule::CoxeReiter, Rule::Probabilistic, Rule::Reiter,
                          Rule::GravnerGriffeath, Rule::GravnerGriffeath3D};

} // namespace

TEST_CASE("canonical() maps every cell into the 1/12 wedge, orbits have 1, 6 or 12 cells",
          "[automata][fast]")
{
    for (int r = -12; r <= 12; ++r)
        for (int q = -12; q <= 12; ++q) {
            const Axial c = canonical(q, r);
            CHECK(HexLayout::inWedge(c.q, c.r));
            CHECK(hexDistance(c.q, c.r) == hexDistance(q, r));
            const size_t n = d6Orbit(q, r).size();
            CHECK((n == 1 || n == 6 || n == 12));
        }
    CHECK(d6Orbit(0, 0).size() == 1);
    CHECK(d6Orbit(3, 0).size() == 6);  // on a mirror axis
    CHECK(d6Orbit(2, 2).size() == 6);  // on the other mirror axis
    CHECK(d6Orbit(3, 1).size() == 12); // generic
}

TEST_CASE("symSum6 is bit-identical under every D6 permutation", "[automata][fast]")
{
    const double v[6] = {0.1, 1e-17, 0.3, 1e16, 0.7, 3.3};
    const double ref = symSum6(v[0], v[1], v[2], v[3], v[4], v[5]);
    for (int k = 0; k < 6; ++k)
        for (int refl = 0; refl < 2; ++refl) {
            double w[6];
            for (int j = 0; j < 6; ++j) w[j] = v[refl ? (6 + k - j) % 6 : (k + j) % 6];
            const double s = symSum6(w[0], w[1], w[2], w[3], w[4], w[5]);
            CHECK(std::memcmp(&s, &ref, sizeof(double)) == 0);
        }
}

TEST_CASE("the 6-neighbourhood has 12 classes under rotation and reflection", "[automata][fast]")
{
    const auto cls = neighbourhoodClasses();
    CHECK(countNeighbourhoodClasses() == 12);
    CHECK(cls[0] == -1);
    std::set<int> seen;
    for (int m = 1; m < 64; ++m) {
        REQUIRE(cls[m] >= 0);
        seen.insert(cls[m]);
    }
    CHECK(seen.size() == 12);
    // Classes are numbered as the post's Gather finds them (its pFreeze table relies on it):
    CHECK(cls[0b000001] == 0);  // one ice neighbour
    CHECK(cls[0b000011] == 1);  // two adjacent
    CHECK(cls[0b000101] == 2);  // two, one apart
    CHECK(cls[0b000111] == 3);  // three in a row
    CHECK(cls[0b001001] == 4);  // two opposite
    CHECK(cls[0b001011] == 5);  // pair + one
    CHECK(cls[0b001111] == 6);  // four in a row
    CHECK(cls[0b010101] == 7);  // alternate three
    CHECK(cls[0b010111] == 8);  // three in a row + one
    CHECK(cls[0b011011] == 9);  // two opposite pairs
    CHECK(cls[0b011111] == 10); // five
    CHECK(cls[0b111111] == 11); // six
    // Invariance: every rotation and reflection of a mask has its class.
    for (int m = 1; m < 64; ++m) {
        const int rot = ((m << 1) | (m >> 5)) & 63;
        int refl = 0;
        for (int b = 0; b < 6; ++b)
            if (m & (1 << b)) refl |= 1 << ((6 - b) % 6);
        CHECK(cls[rot] == cls[m]);
        CHECK(cls[refl] == cls[m]);
    }
}

TEST_CASE("Coxe-Reiter cases: 11 distinct (C, N, P) cases", "[automata][fast]")
{
    std::set<int> cases;
    for (int C = 0; C <= 1; ++C)
        for (int N = 0; N <= 6; ++N)
            for (int P = 0; P <= N; ++P) cases.insert(coxeReiterCase(C, N, P));
    CHECK(cases.size() == size_t(kCoxeReiterCases));
    CHECK(coxeReiterCase(0, 0, 0) == 1);
    CHECK(coxeReiterTable1()[1] == std::array<double, 4>{1, 0, 0, 0}); // (0,0,0) keeps the centre
    CHECK(coxeReiterCase(1, 0, 0) == 0);
    CHECK(coxeReiterTable1()[0][1] == Approx(1.0 / 300.0));          // isolated ice: slow increase
    CHECK(coxeReiterTable1()[size_t(coxeReiterCase(0, 1, 1))][2] > 0); // P = 1 favoured
}

TEST_CASE("every rule stays exactly D6-symmetric over many steps (full computation)", "[automata][fast]")
{
    for (Rule r : kAllRules) {
        AutomatonConfig c = config(r, r == Rule::GravnerGriffeath3D ? 24 : 60, false);
        c.gg.sigma = 0.02; // noise is keyed by canonical cell: symmetry survives it
        HexAutomaton a(c);
        const int steps = r == Rule::GravnerGriffeath3D ? 60 : 150;
        for (int s = 0; s < steps; ++s) a.step();
        INFO(ruleName(r));
        CHECK(!a.usesWedge());
        CHECK(a.frozenCount() > 1);
        CHECK(a.isD6Symmetric());
    }
}

TEST_CASE("the 1/12 wedge computation equals the full computation bit for bit", "[automata][fast]")
{
    for (Rule r : kAllRules) {
        AutomatonConfig c = config(r, r == Rule::GravnerGriffeath3D ? 24 : 50, false);
        c.gg.sigma = 0.01;
        HexAutomaton full(c);
        c.wedge = true;
        HexAutomaton wedge(c);
        REQUIRE(wedge.usesWedge());
        CHECK(wedge.cellsPerStep() * 10 < full.cellsPerStep()); // about 1/12 of the work
        const int steps = r == Rule::GravnerGriffeath3D ? 50 : 120;
        for (int s = 0; s < steps; ++s) {
            full.step();
            wedge.step();
        }
        wedge.expand();
        INFO(ruleName(r));
        CHECK(full.frozenCount() > 1);
        CHECK(sameBits(full, wedge));
    }
}

TEST_CASE("symmetry-breaking seeds turn the wedge off and keep their own symmetry", "[automata][fast]")
{
    AutomatonConfig c = config(Rule::CoxeReiter, 40, true);
    c.cr.background = 0.163;
    for (int seeds : {2, 3, 4}) {
        c.seedCells = seeds;
        HexAutomaton a(c);
        CHECK(!a.usesWedge());
        for (int s = 0; s < 60; ++s) a.step();
        CHECK(a.frozenCount() > 4);
        CHECK(!a.isD6Symmetric());
    }
    // Three cells (0,0), (1,0), (0,1): 120-degree rotation about their common corner.
    c.seedCells = 3;
    HexAutomaton a(c);
    for (int s = 0; s < 60; ++s) a.step();
    for (int r = -20; r <= 20; ++r)
        for (int q = -20; q <= 20; ++q) {
            // Rotation by 120 degrees about the seeds' common corner: cube (x, y, z) -> (z, x, y),
            // i.e. (q, r) -> (r, -q - r), then shifted by (0, 1) so the seed triangle maps onto itself.
            const int q2 = r, r2 = -q - r + 1;
            if (!a.layout().inside(q, r) || !a.layout().inside(q2, r2)) continue;
            const double u = a.value(a.cellIndex(q, r)), v = a.value(a.cellIndex(q2, r2));
            REQUIRE(u == v);
        }
}

TEST_CASE("Coxe-Reiter grows slower at background 0.156 than at 0.3", "[automata][fast]")
{
    auto grow = [](double bg) {
        AutomatonConfig c = config(Rule::CoxeReiter, 150, true);
        c.cr.background = bg;
        HexAutomaton a(c);
        for (int s = 0; s < 127; ++s) a.step();
        a.expand();
        return std::make_pair(a.frozenCount(), a.frozenRadius());
    };
    const auto slow = grow(0.156), fast = grow(0.3);
    INFO("0.156: " << slow.first << " cells, radius " << slow.second << "; 0.3: " << fast.first
                   << " cells, radius " << fast.second);
    CHECK(slow.first > 100);
    CHECK(slow.first * 2 < fast.first);
    CHECK(slow.second < fast.second);
}

TEST_CASE("Coxe-Reiter oscillating background alternates every band of rings", "[automata][fast]")
{
    AutomatonConfig c = config(Rule::CoxeReiter, 60, true);
    c.cr.background = 0.2;
    c.cr.background2 = 0.18;
    c.cr.band = 16;
    HexAutomaton a(c);
    CHECK(a.value(a.cellIndex(10, 0)) == 0.2);
    CHECK(a.value(a.cellIndex(20, 0)) == 0.18);
    CHECK(a.value(a.cellIndex(-40, 5)) == 0.2);   // ring 40: band 2
    CHECK(a.value(a.cellIndex(-50, 10)) == 0.18); // ring 50: band 3
}

TEST_CASE("Packard-Wolfram: frozen cells stay, single-neighbour cells freeze", "[automata][fast]")
{
    HexAutomaton a(config(Rule::Packard, 40, true));
    a.step();
    a.expand();
    CHECK(a.frozenCount() == 7); // the seed and its six neighbours
    for (int s = 1; s < 30; ++s) a.step();
    a.expand();
    const uint64_t before = a.frozenCount();
    a.step();
    a.expand();
    CHECK(a.frozenCount() >= before);
    CHECK(a.frozenRadius() == 31); // tips advance one cell per step
}

TEST_CASE("Gravner-Griffeath conserves vapour + boundary + crystal mass without noise", "[automata][fast]")
{
    for (Rule r : {Rule::GravnerGriffeath, Rule::GravnerGriffeath3D}) {
        AutomatonConfig c = config(r, r == Rule::GravnerGriffeath3D ? 20 : 50, true);
        c.gg.closed = true;
        c.gg.sigma = 0.0;
        HexAutomaton a(c);
        a.expand();
        const double m0 = a.totalMass();
        for (int s = 0; s < 200; ++s) a.step();
        a.expand();
        INFO(ruleName(r));
        CHECK(a.frozenCount() > 1);
        CHECK(a.totalMass() == Approx(m0).epsilon(1e-12));
        // With the reservoir edge, vapour flows in: mass grows.
        c.gg.closed = false;
        HexAutomaton open(c);
        for (int s = 0; s < 200; ++s) open.step();
        open.expand();
        CHECK(open.totalMass() > m0 * (1 + 1e-9));
    }
}

TEST_CASE("probabilistic rule: same seed same flake, other seed other flake", "[automata][fast]")
{
    AutomatonConfig c = config(Rule::Probabilistic, 40, true);
    c.seed = 7;
    HexAutomaton a(c), b(c);
    c.seed = 8;
    HexAutomaton d(c);
    for (int s = 0; s < 40; ++s) {
        a.step();
        b.step();
        d.step();
    }
    a.expand();
    b.expand();
    d.expand();
    CHECK(sameBits(a, b));
    CHECK(!sameBits(a, d));
}

TEST_CASE("results do not depend on the thread count", "[automata][fast]")
{
    for (Rule r : {Rule::CoxeReiter, Rule::GravnerGriffeath, Rule::Probabilistic}) {
        AutomatonConfig c = config(r, 40, false);
        c.gg.sigma = 0.02;
        HexAutomaton many(c);
        for (int s = 0; s < 80; ++s) many.step();
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        HexAutomaton single(c);
        for (int s = 0; s < 80; ++s) single.step();
        INFO(ruleName(r));
        CHECK(sameBits(many, single));
    }
}
