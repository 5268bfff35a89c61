// The second-order phase-field scheme (lw_cn): its implicit solvers, its Lax-Wendroff term on
// both lattices, substeps and the stability refusal.
#include "test_util.h"

#include <frostvdb/core/Error.h>
#include <frostvdb/icephysics/ImplicitSystem.h>
#include <frostvdb/icephysics/Kobayashi.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <vector>

using namespace frostvdb;
using namespace frostvdb::test;

namespace {

/// A disc of active voxels on the z = 0 plane.
openvdb::FloatGrid::Ptr discTopology(int radius)
{
    auto g = openvdb::FloatGrid::create(0.f);
    for (int j = -radius; j <= radius; ++j)
        for (int i = -radius; i <= radius; ++i)
            if (i * i + j * j <= radius * radius) g->tree().setValueOn(openvdb::Coord(i, j, 0), 0.f);
    return g;
}

double hashUnit(int a, int b) { return std::fmod(std::fabs(std::sin(a * 12.9898 + b * 78.233)) * 43758.5453, 1.0); }

} // namespace

TEST_CASE("Gauss-Seidel and BiCGSTAB solve the same implicit system to the tolerance", "[fast][lw_cn]")
{
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        const Stencil st = Lattice(kind, 3.0 / 64.0).stencil(false);
        auto topo = discTopology(21);
        openvdb::tree::LeafManager<openvdb::FloatTree> leaves(topo->tree());
        const SlotLayout layout(leaves, st, true);
        ImplicitSystem a(layout), b(layout);
        // A Crank-Nicolson-like system with a varying, non-symmetric row scale.
        for (size_t li = 0; li < leaves.leafCount(); ++li)
            for (auto it = leaves.leaf(li).cbeginValueOn(); it; ++it) {
                const auto c = it.getCoord();
                const size_t s = size_t(layout.row(li, c));
                const double scale = 0.2 + 0.5 * hashUnit(c.x(), c.y());
                for (ImplicitSystem* sys : {&a, &b}) {
                    sys->scale[s] = scale;
                    sys->diag[s] = 1.0 + scale * -st.wLapCentre;
                    sys->rhs[s] = hashUnit(c.y(), c.x());
                    sys->x[s] = 0.0;
                }
            }
        a.setOutside(0.25);
        b.setOutside(0.25);
        const double tol = 1e-10;
        const SolveReport ra = a.solve(LinearSolverKind::GaussSeidel, tol, 5000);
        const SolveReport rb = b.solve(LinearSolverKind::BiCGSTAB, tol, 5000);
        INFO("lattice " << Lattice::kindName(kind) << ": GS " << ra.iterations << " it, BiCGSTAB " << rb.iterations);
        REQUIRE(ra.converged);
        REQUIRE(rb.converged);
        CHECK(a.residualMaxNorm() <= 1e-9);
        CHECK(b.residualMaxNorm() <= tol);
        double diff = 0;
        for (size_t s = 0; s < layout.rowCount(); ++s) diff = std::max(diff, std::fabs(a.x[s] - b.x[s]));
        CHECK(diff < 1e-8);
        // The Dirichlet value is really used: the solution near the rim feels it.
        CHECK(ra.iterations > 1);
    }
}

TEST_CASE("Gauss-Seidel gives the same bits whatever the leaf order of the rows, and from a mask's leaves",
          "[fast][lw_cn]")
{
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        const Stencil st = Lattice(kind, 3.0 / 64.0).stencil(false);
        auto topo = discTopology(40);
        openvdb::tree::LeafManager<openvdb::FloatTree> leaves(topo->tree());
        openvdb::MaskTree maskTree(topo->tree(), false, openvdb::TopologyCopy());
        openvdb::tree::LeafManager<const openvdb::MaskTree> maskLeaves(maskTree);
        REQUIRE(maskLeaves.leafCount() == leaves.leafCount());
        std::vector<size_t> reversed(leaves.leafCount());
        for (size_t i = 0; i < reversed.size(); ++i) reversed[i] = reversed.size() - 1 - i;
        const SlotLayout plain(leaves, st, true), byOrder(leaves, st, true, nullptr, &reversed),
            ofMask(maskLeaves, st, true, nullptr, &reversed);
        // the same system in each numbering, solved to a loose tolerance (few sweeps)
        auto solve = [&](const SlotLayout& layout) {
            ImplicitSystem sys(layout);
            for (size_t li = 0; li < leaves.leafCount(); ++li)
                for (auto it = leaves.leaf(li).cbeginValueOn(); it; ++it) {
                    const auto c = it.getCoord();
                    const size_t s = size_t(layout.row(li, c));
                    sys.scale[s] = 0.2 + 0.5 * hashUnit(c.x(), c.y());
                    sys.diag[s] = 1.0 + sys.scale[s] * -st.wLapCentre;
                    sys.rhs[s] = hashUnit(c.y(), c.x());
                }
            sys.setOutside(0.25);
            sys.solve(LinearSolverKind::GaussSeidel, 1e-3, 50);
            std::vector<double> byVoxel;
            for (size_t li = 0; li < leaves.leafCount(); ++li)
                for (auto it = leaves.leaf(li).cbeginValueOn(); it; ++it)
                    byVoxel.push_back(sys.x[size_t(layout.row(li, it.getCoord()))]);
            return byVoxel;
        };
        INFO("lattice " << Lattice::kindName(kind));
        const auto a = solve(plain), b = solve(byOrder), c = solve(ofMask);
        REQUIRE(a.size() == b.size());
        REQUIRE(a.size() == c.size());
        bool rowsMoved = false;
        for (size_t li = 0; li < leaves.leafCount() && !rowsMoved; ++li)
            for (auto it = leaves.leaf(li).cbeginValueOn(); it; ++it)
                rowsMoved = rowsMoved || plain.row(li, it.getCoord()) != byOrder.row(li, it.getCoord());
        CHECK(rowsMoved);
        CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
        CHECK(std::memcmp(a.data(), c.data(), a.size() * sizeof(double)) == 0);
    }
}

TEST_CASE("Hexagonal colouring never gives neighbours the same colour", "[fast][lw_cn]")
{
    for (bool withZ : {false, true}) {
        const Stencil st = Lattice(LatticeKind::Hexagonal, 1.0).stencil(withZ);
        auto topo = openvdb::FloatGrid::create(0.f);
        topo->tree().denseFill(openvdb::CoordBBox(openvdb::Coord(-9, -9, withZ ? -9 : 0), openvdb::Coord(9, 9, withZ ? 9 : 0)),
                               0.f, true);
        openvdb::tree::LeafManager<openvdb::FloatTree> leaves(topo->tree());
        const SlotLayout layout(leaves, st, !withZ);
        REQUIRE(layout.colours == 3);
        // each voxel's colour: the colour range its row lies in
        openvdb::Int32Grid colours(-1);
        for (size_t li = 0; li < leaves.leafCount(); ++li)
            for (auto it = leaves.leaf(li).cbeginValueOn(); it; ++it) {
                const size_t r = size_t(layout.rowAt(li, it.pos()));
                int c = 0;
                while (r >= layout.colourStart[size_t(c) + 1]) ++c;
                colours.tree().setValue(it.getCoord(), c);
            }
        REQUIRE(colours.activeVoxelCount() == openvdb::Index64(layout.rowCount()));
        int clashes = 0;
        for (auto it = colours.cbeginValueOn(); it; ++it)
            for (const auto& t : st.taps) {
                const auto n = it.getCoord() + t.offset;
                if (colours.tree().isValueOn(n) && colours.tree().getValue(n) == *it) ++clashes;
            }
        CHECK(clashes == 0);
    }
}

TEST_CASE("lw_cn's advection-diffusion operator: exact on quadratics, positive coefficients", "[fast][lw_cn]")
{
    // u = q0 x + q1 y + A x^2 + B xy + C y^2 and a linear coefficient field a = a0 + ax x + ay y
    // in world units: L u = a lap u + grad a . grad u = a0 (2A + 2C) + ax q0 + ay q1 at the origin.
    const double q0 = 0.3, q1 = -0.8, A = 0.7, B = -1.3, C = 0.4;
    for (auto kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        const double h = 0.1;
        const Lattice lat(kind, h);
        const int W = 5;
        const FlatStencil st(lat.stencil(false), W, 0);
        for (double slope : {0.2, 1.0, 40.0}) { // 40: Peclet > 1, a is raised on the dominated taps
            const double a0 = 1.0, ax = slope * 0.6, ay = -slope * 0.8;
            std::vector<float> u(W * W), a(W * W);
            for (int j = 0; j < W; ++j)
                for (int i = 0; i < W; ++i) {
                    const auto pos = lat.planePosition(i - 2, j - 2) * h;
                    const double x = pos.x(), y = pos.y();
                    u[j * W + i] = float(q0 * x + q1 * y + A * x * x + B * x * y + C * y * y);
                    a[j * W + i] = float(a0 + ax * x + ay * y);
                }
            double coef[FlatStencil::kMaxTaps];
            const size_t centre = 2 * W + 2;
            const double sum = advectionDiffusionCoefficients(a.data(), centre, st, coef);
            const double Lu = symmetricTapSum(u.data(), centre, st, coef);
            INFO(Lattice::kindName(kind) << " slope " << slope);
            double total = 0;
            for (int q = 0; q < st.n; ++q) {
                CHECK(coef[q] >= 0.0);
                total += coef[q];
            }
            CHECK(sum == Approx(total).epsilon(1e-12));
            const double exact = a0 * (2 * A + 2 * C) + ax * q0 + ay * q1;
            if (slope < 10) CHECK(Lu == Approx(exact).epsilon(1e-4));
            // Raised diffusion where the advection dominates: a_eff = |c.e| h/2 on those taps.
            else CHECK(Lu != Approx(exact).epsilon(1e-2));
        }
    }
}

namespace {
const char* kSecondOrderScene = R"(
[scene]
name = "second"
frames = 1
steps_per_frame = 40
[domain]
size = [48, 48]
[phase_field]
scheme = "lw_cn"
anisotropy_mode = 4
)";
}

TEST_CASE("A dt above the stability limit is refused, or split into substeps when asked", "[fast][lw_cn]")
{
    for (const char* scheme : {"euler", "lw_cn"}) {
        Scene probe = Scene::fromString(kSecondOrderScene, "test.toml");
        probe.applyOverride(std::string("phase_field.scheme=") + scheme);
        KobayashiParams k;
        k.scheme = std::string(scheme) == "euler" ? PhaseFieldScheme::Euler : PhaseFieldScheme::SecondOrder;
        const Domain dom = Simulation(std::move(probe)).world().domain;
        const double limit = k.stabilityLimit(dom.stencil(), false);
        auto exact = [](double v) {
            std::ostringstream os;
            os.precision(17);
            os << v;
            return os.str();
        };
        const double dtAbove = 1.1 * limit;
        const std::string dt = "phase_field.dt=" + exact(dtAbove);
        try {
            makeSim(kSecondOrderScene, {std::string("phase_field.scheme=") + scheme, dt});
            FAIL("a dt 10% above the limit was accepted for " << scheme);
        } catch (const SceneError& e) {
            CHECK(std::string(e.what()).find("stability limit") != std::string::npos);
        }
        // substeps = auto: the same bits as two steps of dt/2.
        auto a = makeSim(kSecondOrderScene,
                         {std::string("phase_field.scheme=") + scheme, dt, "phase_field.substeps=auto",
                          "scene.steps_per_frame=10"});
        auto b = makeSim(kSecondOrderScene, {std::string("phase_field.scheme=") + scheme,
                                             "phase_field.dt=" + exact(dtAbove / 2.0),
                                             "scene.steps_per_frame=20"});
        RunOptions ro;
        ro.progress = false;
        ro.writeFiles = false;
        a.run(ro);
        b.run(ro);
        auto pa = a.world().fields.get<openvdb::FloatGrid>("p");
        auto pb = b.world().fields.get<openvdb::FloatGrid>("p");
        CHECK(pa->activeVoxelCount() == pb->activeVoxelCount());
        float worst = 0;
        for (auto it = pa->cbeginValueOn(); it; ++it) worst = std::max(worst, std::fabs(*it - pb->tree().getValue(it.getCoord())));
        CHECK(worst == 0.f);
    }
}
