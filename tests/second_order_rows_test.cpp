// Session 12 (issue 24 item 2, "vector rows for the hexagonal lattice"): the second-order
// scheme's (lw_cn) vector rows, eps^2 and the row assembly (SecondOrderRows.h), and the vector
// Gauss-Seidel relaxation (ImplicitSystem) give the plain code's bits: on random data, on runs
// of every length and start (row ends: the 4-lane body and the scalar tail), at leaf edges and
// the Dirichlet rim of a layout, at 1 and 2 threads. Whole frames of the hexagonal lw_cn scene
// with and without FROSTVDB_NO_VECTOR_ROWS are compared in planes_test.cpp.
#include "test_util.h"

#include <frostvdb/core/Lattice.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/icephysics/ImplicitSystem.h>
#include <frostvdb/icephysics/Kobayashi.h>
#include <frostvdb/icephysics/SecondOrderRows.h>

#include <catch2/catch.hpp>

#include <tbb/task_arena.h>

#include <cstdlib>
#include <cstring>
#include <vector>

using namespace frostvdb;

namespace {

bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

/// Uniform in [0, 1) from a counter.
double unit(uint64_t seed, uint64_t i) { return toUnit(hashCounters(seed, i)); }

/// A phase-like field: plateaus of exact 0 and 1 (flat: eps^2's no-gradient branch), values
/// within rounding of the bounds, and random values.
float phaseValue(uint64_t seed, uint64_t i)
{
    const double u = unit(seed, i), v = unit(seed + 1, i);
    if (u < 0.2) return 0.f;
    if (u < 0.35) return 1.f;
    if (u < 0.4) return float(1.0 - 1e-7 * v);
    if (u < 0.45) return float(1e-7 * v);
    return float(v);
}

KobayashiParams figure7Params()
{
    KobayashiParams k; // the paper's Table 1 with j = 6, theta0 = pi/2
    k.scheme = PhaseFieldScheme::SecondOrder;
    k.dt = 0.0008;
    k.delta = 0.3; // large anisotropy: Peclet-limited taps (a_eff raised) occur too
    return k;
}

} // namespace

TEST_CASE("Hexagonal second-order vector rows equal the plain rows bit for bit", "[fast][lw_cn][vector_rows]")
{
    ::unsetenv("FROSTVDB_NO_VECTOR_ROWS");
    const Stencil stencil = Lattice(LatticeKind::Hexagonal, 3.0 / 64.0).stencil(false);
    const int W = 40, H = 12;
    const FlatStencil st(stencil, W, 0);
    for (int variant = 0; variant < 4; ++variant) {
        KobayashiParams k = figure7Params();
        if (variant & 1) k.noise = 0.02;
        if (variant & 2) k.gamma = 30.0;
        const Anisotropy an(k);
        const SecondOrderRows vec = fastestSecondOrderRows(st, an);
        const SecondOrderRows plain = plainSecondOrderRows();
        if (!vec.vector) {
            WARN("no AVX2 on this machine: only the plain rows ran");
            return;
        }
        const size_t n = size_t(W) * H;
        const uint64_t seed = 77 + uint64_t(variant);
        std::vector<float> p(n), T(n), pe(n), te(n), pf(n), melt(n), aV(n), aP(n);
        std::vector<double> chi(n);
        for (size_t i = 0; i < n; ++i) {
            p[i] = phaseValue(seed, i);
            pe[i] = (unit(seed + 2, i) < 0.5) ? p[i] : phaseValue(seed + 3, i);
            pf[i] = phaseValue(seed + 4, i);
            T[i] = float(-0.5 + 1.5 * unit(seed + 5, i));
            te[i] = (unit(seed + 6, i) < 0.3) ? T[i] : float(-1.0 + 3.0 * unit(seed + 7, i));
            melt[i] = float(unit(seed + 8, i));
            chi[i] = unit(seed + 9, i) - 0.5;
        }
        // eps^2 over every run [i0, i1) of a row (starts and lengths 0..W-2 inside the ring)
        for (int y = 1; y < H - 1; ++y)
            for (int x0 = 1; x0 < W - 1; x0 += 3)
                for (int x1 = x0; x1 < W - 1; x1 += 5) {
                    const size_t i0 = size_t(y) * W + x0, i1 = size_t(y) * W + x1;
                    std::fill(aV.begin(), aV.end(), -7.f);
                    std::fill(aP.begin(), aP.end(), -7.f);
                    vec.epsSquared(pe.data(), i0, i1, st, an, aV.data());
                    plain.epsSquared(pe.data(), i0, i1, st, an, aP.data());
                    REQUIRE(std::memcmp(aV.data(), aP.data(), n * sizeof(float)) == 0);
                }
        // eps^2 on every inner cell, then the rows over runs of every length
        std::vector<float> a(n, 0.f);
        for (int y = 1; y < H - 1; ++y) plain.epsSquared(pe.data(), size_t(y) * W + 1, size_t(y) * W + W - 1, st, an, a.data());
        for (double theta : {0.5, 1.0})
            for (bool withMelt : {false, true}) {
                std::vector<double> outV(10 * n), outP(10 * n);
                auto view = [&](std::vector<double>& o) {
                    SecondOrderRowsOut r{};
                    r.diag = o.data();
                    r.rhs = o.data() + n;
                    r.predictor = o.data() + 2 * n;
                    r.lapT = o.data() + 3 * n;
                    for (int q = 0; q < 6; ++q) r.coef[q] = o.data() + size_t(4 + q) * n;
                    return r;
                };
                const SecondOrderRowsOut rv = view(outV), rp = view(outP);
                for (int y = 2; y < H - 2; ++y)
                    for (int x0 = 2; x0 < W - 2; x0 += 3)
                        for (int x1 = x0; x1 <= W - 2; x1 += 7) {
                            const size_t i0 = size_t(y) * W + x0, i1 = size_t(y) * W + x1;
                            std::fill(outV.begin(), outV.end(), -3.0);
                            std::fill(outP.begin(), outP.end(), -3.0);
                            const float* m = withMelt ? melt.data() : nullptr;
                            const double* c = k.noise != 0 ? chi.data() : nullptr;
                            vec.rows(p.data(), T.data(), pe.data(), te.data(), pf.data(), a.data(), m, c, i0, i1, st, k,
                                     theta, rv);
                            plain.rows(p.data(), T.data(), pe.data(), te.data(), pf.data(), a.data(), m, c, i0, i1, st,
                                       k, theta, rp);
                            INFO("variant " << variant << " theta " << theta << " melt " << withMelt << " run ["
                                            << i0 << ", " << i1 << ")");
                            REQUIRE(std::memcmp(outV.data(), outP.data(), outV.size() * sizeof(double)) == 0);
                        }
            }
    }
    // the switch works: the plain rows when asked
    ::setenv("FROSTVDB_NO_VECTOR_ROWS", "1", 1);
    const KobayashiParams k = figure7Params();
    CHECK(!fastestSecondOrderRows(st, Anisotropy(k)).vector);
    ::unsetenv("FROSTVDB_NO_VECTOR_ROWS");
}

namespace {

/// Ragged topology on the z = 0 plane: a disc with random holes (leaf edges, interior
/// Dirichlet neighbours).
openvdb::FloatGrid::Ptr raggedDisc(int radius, uint64_t seed)
{
    auto g = openvdb::FloatGrid::create(0.f);
    for (int j = -radius; j <= radius; ++j)
        for (int i = -radius; i <= radius; ++i)
            if (i * i + j * j <= radius * radius && unit(seed, uint64_t((j + 500) * 1000 + i + 500)) > 0.05)
                g->tree().setValueOn(openvdb::Coord(i, j, 0), 0.f);
    return g;
}

/// Solves a random system with a fixed number of sweeps; returns x.
std::vector<double> sweep(const SlotLayout& layout, const Stencil& st, bool perRow, bool vector, int threads,
                          SolveReport& rep)
{
    if (vector) ::unsetenv("FROSTVDB_NO_VECTOR_ROWS");
    else ::setenv("FROSTVDB_NO_VECTOR_ROWS", "1", 1);
    ImplicitSystem sys(layout);
    const size_t n = layout.rowCount();
    if (perRow) {
        sys.useCoefficients();
        for (size_t r = 0; r < n; ++r) {
            double sum = 0;
            for (int q = 0; q < layout.taps; ++q) {
                const double c = 0.05 + unit(11, r * 8 + uint64_t(q));
                sys.coef[r * size_t(layout.taps) + size_t(q)] = c;
                sum += c;
            }
            sys.diag[r] = 1.0 + sum * (1.0 + unit(12, r));
        }
    } else {
        sys.setUniform(1.0 + 0.7 * -st.wLapCentre * 1e-4, 0.7e-4);
    }
    for (size_t r = 0; r < n; ++r) {
        sys.rhs[r] = unit(13, r) - 0.3;
        sys.x[r] = unit(14, r);
    }
    sys.setOutside(0.25);
    tbb::task_arena arena(threads);
    arena.execute([&] { rep = sys.solve(LinearSolverKind::GaussSeidel, 0.0, 7); });
    ::unsetenv("FROSTVDB_NO_VECTOR_ROWS");
    return sys.x;
}

} // namespace

TEST_CASE("Vector Gauss-Seidel sweeps equal the plain sweeps bit for bit, 1 and 2 threads", "[fast][lw_cn][vector_rows]")
{
    for (auto kind : {LatticeKind::Hexagonal, LatticeKind::Square}) {
        const Stencil st = Lattice(kind, 3.0 / 64.0).stencil(false);
        auto topo = raggedDisc(45, kind == LatticeKind::Hexagonal ? 3 : 4);
        openvdb::tree::LeafManager<openvdb::FloatTree> leaves(topo->tree());
        const SlotLayout layout(leaves, st, true);
        REQUIRE(layout.rowCount() > 5000);
        for (bool perRow : {true, false}) {
            SolveReport r0, r1, r2;
            const auto plain = sweep(layout, st, perRow, false, 1, r0);
            const auto vec1 = sweep(layout, st, perRow, true, 1, r1);
            const auto vec2 = sweep(layout, st, perRow, true, 2, r2);
            INFO(Lattice::kindName(kind) << (perRow ? " per-row coefficients" : " uniform rows"));
            REQUIRE(plain.size() == vec1.size());
            size_t differ1 = 0, differ2 = 0;
            for (size_t r = 0; r < plain.size(); ++r) {
                differ1 += !sameBits(plain[r], vec1[r]);
                differ2 += !sameBits(plain[r], vec2[r]);
            }
            CHECK(differ1 == 0);
            CHECK(differ2 == 0);
            CHECK(r0.iterations == 7);
            CHECK(sameBits(r0.residual, r1.residual));
            CHECK(sameBits(r0.residual, r2.residual));
        }
    }
}
