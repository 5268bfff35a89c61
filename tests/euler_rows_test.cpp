// The engine's vector row code against the plain rows the dense reference loop runs: the same
// bits for every output, on inputs chosen to reach every branch of the scalar code (flat
// neighbourhoods, where the anisotropy takes its no-gradient value; ties and signed zeros in the
// limiter's min/max; denormals; the melt map and the noise; row lengths that leave a remainder).
#include <catch2/catch.hpp>

#include <frostvdb/core/Lattice.h>
#include <frostvdb/icephysics/EulerRows.h>

#include <cstring>
#include <random>
#include <vector>

using namespace frostvdb;

namespace {

/// A W x H row-major field: smooth values, flat patches of one exact value, signed zeros,
/// denormals and exact 0 / 1 cells, as a phase field's tail and interior have.
std::vector<float> field(int W, int H, std::mt19937& rng, float scale)
{
    std::uniform_real_distribution<float> u(0.f, 1.f);
    std::vector<float> f(size_t(W) * H);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            float v = scale * (0.5f + 0.45f * std::sin(0.3f * x + 0.2f * y)) + 0.01f * u(rng);
            const int kind = int(u(rng) * 10);
            if (kind == 0) v = 0.f;
            else if (kind == 1) v = -0.f;
            else if (kind == 2) v = 1e-41f;     // denormal
            else if (kind == 3) v = 1.f;
            if (x > W / 2 && y > H / 2 && x < W / 2 + 6 && y < H / 2 + 6) v = 0.25f; // flat patch
            f[size_t(y) * W + x] = v;
        }
    return f;
}

} // namespace

TEST_CASE("Vector Euler rows give the plain rows' bits", "[fast][phase_field]")
{
    const int W = 48, H = 12;
    const Lattice lat(LatticeKind::Square, 0.03);
    std::mt19937 rng(7);
    int compared = 0;
    for (double mode : {4.0, 6.0}) {
        for (double theta0 : {M_PI / 2, 0.3}) {
            KobayashiParams k;
            k.anisotropyMode = mode;
            k.theta0 = theta0;
            k.delta = 0.04;
            k.latentHeat = 1.6;
            FlatStencil st(lat.stencil(false), W, 0);
            const Anisotropy an(k);
            useD6Forms(st, an);
            const EulerRows vec = fastestEulerRows(st, an), plain = plainEulerRows();
            if (!vec.vector) {
                WARN("no AVX2 on this CPU: the vector rows are not built here, nothing to compare");
                return;
            }
            for (int withExtras = 0; withExtras < 2; ++withExtras) {
                k.noise = withExtras ? 0.3 : 0.0;
                const auto p = field(W, H, rng, 1.f), T = field(W, H, rng, -0.5f), melt = field(W, H, rng, 1.f);
                std::vector<double> chi(size_t(W) * H);
                std::uniform_real_distribution<double> u(-0.5, 0.5);
                for (double& c : chi) c = u(rng);
                const size_t n = size_t(W) * H;
                std::vector<float> aux[2][6];
                for (auto& set : aux)
                    for (auto& v : set) v.assign(n, 7.f);
                // Pass 1 everywhere but the outer ring; pass 2 on rows of every length 1..40 at
                // a few starts (the vector loop's remainder goes to the plain code).
                for (int s = 0; s < 2; ++s) {
                    const EulerRows& rows = s ? vec : plain;
                    auto& A = aux[s];
                    for (int y = 1; y < H - 1; ++y)
                        rows.aux(p.data(), size_t(y) * W + 1, size_t(y) * W + W - 1, st, an, A[0].data(), A[1].data(),
                                 A[2].data(), A[3].data(), A[4].data(), A[5].data());
                }
                for (int q = 0; q < 6; ++q) CHECK(std::memcmp(aux[0][q].data(), aux[1][q].data(), n * sizeof(float)) == 0);
                const auto& A = aux[0];
                for (int len = 1; len <= 40; ++len)
                    for (int y : {2, 5, H - 3}) {
                        const size_t i0 = size_t(y) * W + 2 + size_t(len % 3), i1 = i0 + size_t(len);
                        std::vector<float> pOut[2], tOut[2];
                        std::vector<double> dp[2];
                        for (int s = 0; s < 2; ++s) {
                            pOut[s].assign(n, 0.f);
                            tOut[s].assign(n, 0.f);
                            dp[s].assign(n, 0.0);
                            (s ? vec : plain)
                                .euler(p.data(), T.data(), A[0].data(), A[1].data(), A[2].data(), A[3].data(),
                                       A[4].data(), A[5].data(), i0, i1, st, k, withExtras ? melt.data() : nullptr,
                                       withExtras ? chi.data() : nullptr, pOut[s].data(), tOut[s].data(), dp[s].data());
                        }
                        INFO("mode " << mode << " theta0 " << theta0 << " extras " << withExtras << " len " << len);
                        CHECK(std::memcmp(pOut[0].data(), pOut[1].data(), n * sizeof(float)) == 0);
                        CHECK(std::memcmp(tOut[0].data(), tOut[1].data(), n * sizeof(float)) == 0);
                        CHECK(std::memcmp(dp[0].data(), dp[1].data(), n * sizeof(double)) == 0);
                        ++compared;
                    }
            }
        }
    }
    CHECK(compared == 2 * 2 * 2 * 40 * 3);
}

TEST_CASE("Hexagonal vector Euler rows give the plain rows' bits", "[fast][phase_field]")
{
    // The D6 forms (j = 6, arms on lattice directions): the hexagonal plane's default, the one
    // `bench scale` runs.
    const int W = 48, H = 12;
    const Lattice lat(LatticeKind::Hexagonal, 0.03);
    std::mt19937 rng(11);
    int compared = 0;
    for (double theta0 : {M_PI / 2, 0.0}) {
        KobayashiParams k;
        k.anisotropyMode = 6;
        k.theta0 = theta0;
        k.delta = 0.04;
        k.latentHeat = 1.6;
        FlatStencil st(lat.stencil(false), W, 0);
        const Anisotropy an(k);
        useD6Forms(st, an);
        REQUIRE(st.d6);
        const EulerRows vec = fastestEulerRows(st, an), plain = plainEulerRows();
        if (!vec.vector) {
            WARN("no AVX2 on this CPU: the vector rows are not built here, nothing to compare");
            return;
        }
        for (int withExtras = 0; withExtras < 2; ++withExtras) {
            k.noise = withExtras ? 0.3 : 0.0;
            const auto p = field(W, H, rng, 1.f), T = field(W, H, rng, -0.5f), melt = field(W, H, rng, 1.f);
            std::vector<double> chi(size_t(W) * H);
            std::uniform_real_distribution<double> u(-0.5, 0.5);
            for (double& c : chi) c = u(rng);
            const size_t n = size_t(W) * H;
            std::vector<float> aux[2][6];
            for (auto& set : aux)
                for (auto& v : set) v.assign(n, 7.f);
            for (int s = 0; s < 2; ++s) {
                const EulerRows& rows = s ? vec : plain;
                auto& A = aux[s];
                for (int y = 1; y < H - 1; ++y)
                    rows.aux(p.data(), size_t(y) * W + 1, size_t(y) * W + W - 1, st, an, A[0].data(), A[1].data(),
                             A[2].data(), A[3].data(), A[4].data(), A[5].data());
            }
            for (int q = 0; q < 6; ++q) CHECK(std::memcmp(aux[0][q].data(), aux[1][q].data(), n * sizeof(float)) == 0);
            const auto& A = aux[0];
            for (int len = 1; len <= 40; ++len)
                for (int y : {2, 5, H - 3}) {
                    const size_t i0 = size_t(y) * W + 2 + size_t(len % 3), i1 = i0 + size_t(len);
                    std::vector<float> pOut[2], tOut[2];
                    std::vector<double> dp[2];
                    for (int s = 0; s < 2; ++s) {
                        pOut[s].assign(n, 0.f);
                        tOut[s].assign(n, 0.f);
                        dp[s].assign(n, 0.0);
                        (s ? vec : plain)
                            .euler(p.data(), T.data(), A[0].data(), A[1].data(), A[2].data(), A[3].data(), A[4].data(),
                                   A[5].data(), i0, i1, st, k, withExtras ? melt.data() : nullptr,
                                   withExtras ? chi.data() : nullptr, pOut[s].data(), tOut[s].data(), dp[s].data());
                    }
                    INFO("theta0 " << theta0 << " extras " << withExtras << " len " << len);
                    CHECK(std::memcmp(pOut[0].data(), pOut[1].data(), n * sizeof(float)) == 0);
                    CHECK(std::memcmp(tOut[0].data(), tOut[1].data(), n * sizeof(float)) == 0);
                    CHECK(std::memcmp(dp[0].data(), dp[1].data(), n * sizeof(double)) == 0);
                    ++compared;
                }
        }
    }
    CHECK(compared == 2 * 2 * 40 * 3);
}

TEST_CASE("Heat rows give kobayashiEulerHeatOnly's bits, and the full rows' T where p is 0", "[fast][phase_field]")
{
    // The engine runs the heat rows on leaves whose p is 0 within two stencil steps (the heat
    // halo) and the full rows elsewhere: both must give the bits of the per-cell functions.
    const int W = 48, H = 12;
    std::mt19937 rng(5);
    int compared = 0;
    for (const LatticeKind kind : {LatticeKind::Square, LatticeKind::Hexagonal}) {
        KobayashiParams k;
        k.anisotropyMode = kind == LatticeKind::Hexagonal ? 6 : 4;
        k.delta = 0.04;
        k.latentHeat = 1.6;
        FlatStencil st(Lattice(kind, 0.03).stencil(false), W, 0);
        const Anisotropy an(k);
        useD6Forms(st, an);
        const EulerRows fast = fastestEulerRows(st, an), plain = plainEulerRows();
        if (!fast.vector) {
            WARN("no AVX2 on this CPU: the vector rows are not built here, nothing to compare");
            return;
        }
        CHECK(fast.heat != plain.heat);
        const auto T = field(W, H, rng, -0.5f);
        const std::vector<float> p(size_t(W) * H, 0.f);
        const size_t n = size_t(W) * H;
        std::vector<float> A[6];
        for (auto& v : A) v.assign(n, 0.f);
        for (int y = 1; y < H - 1; ++y)
            fast.aux(p.data(), size_t(y) * W + 1, size_t(y) * W + W - 1, st, an, A[0].data(), A[1].data(), A[2].data(),
                     A[3].data(), A[4].data(), A[5].data());
        for (int len = 1; len <= 40; ++len)
            for (int y : {2, 5, H - 3}) {
                const size_t i0 = size_t(y) * W + 2 + size_t(len % 3), i1 = i0 + size_t(len);
                std::vector<float> heatOut[2], cellOut(n, 0.f), fullP(n, 0.f), fullT(n, 0.f);
                for (int s = 0; s < 2; ++s) {
                    heatOut[s].assign(n, 0.f);
                    (s ? fast : plain).heat(T.data(), i0, i1, st, k, heatOut[s].data());
                }
                bool pZero = true;
                for (size_t i = i0; i < i1; ++i) {
                    float pn;
                    kobayashiEulerHeatOnly(T.data(), i, st, k, pn, cellOut[i]);
                    pZero = pZero && pn == 0.f;
                }
                fast.euler(p.data(), T.data(), A[0].data(), A[1].data(), A[2].data(), A[3].data(), A[4].data(),
                           A[5].data(), i0, i1, st, k, nullptr, nullptr, fullP.data(), fullT.data(), nullptr);
                INFO((kind == LatticeKind::Square ? "square" : "hexagonal") << " len " << len);
                CHECK(pZero);
                CHECK(std::memcmp(heatOut[0].data(), cellOut.data(), n * sizeof(float)) == 0);
                CHECK(std::memcmp(heatOut[1].data(), cellOut.data(), n * sizeof(float)) == 0);
                CHECK(std::memcmp(fullT.data(), cellOut.data(), n * sizeof(float)) == 0);
                CHECK(std::memcmp(fullP.data(), std::vector<float>(n, 0.f).data(), n * sizeof(float)) == 0);
                ++compared;
            }
    }
    CHECK(compared == 2 * 40 * 3);
}
