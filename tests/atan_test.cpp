// base/Atan.h: Cephes' atan against libm's, and its four-lane version against the scalar one.
#include <frostvdb/base/Atan.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

using namespace frostvdb;

namespace {
/// Arguments over every branch: each side of the branch points (0.66, tan 3pi/8), signed zeros,
/// tiny and huge values, and random ones on a log scale of either sign.
std::vector<double> atanArguments()
{
    std::vector<double> x = {0.0, -0.0, 1e-300, -1e-300, 1e-8, 0.66, -0.66, 1.0, -1.0, 2.41421356237309504880,
                             -2.41421356237309504880, 1e8, -1e8, 1e300, -1e300, std::numeric_limits<double>::max()};
    for (const double edge : {0.66, 2.41421356237309504880})
        for (int k = -3; k <= 3; ++k) x.push_back(edge + k * 1e-16), x.push_back(-(edge + k * 1e-16));
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> e(-12.0, 12.0);
    for (int i = 0; i < 200000; ++i) x.push_back((i % 2 ? -1.0 : 1.0) * std::pow(10.0, e(rng)));
    while (x.size() % 4) x.push_back(0.5);
    return x;
}
} // namespace

TEST_CASE("atanCephes: within 2 ulp of libm's atan, odd, bounded", "[fast]")
{
    double worst = 0;
    size_t oddFailures = 0;
    for (const double x : atanArguments()) {
        const double a = atanCephes(x), ref = std::atan(x);
        const double ulp = std::nextafter(std::fabs(ref), std::numeric_limits<double>::infinity()) - std::fabs(ref);
        worst = std::max(worst, std::fabs(a - ref) / ulp);
        oddFailures += atanCephes(-x) != -a;
        REQUIRE(std::fabs(a) <= M_PI / 2);
    }
    INFO("worst error " << worst << " ulp");
    CHECK(worst <= 2.0);
    CHECK(oddFailures == 0);
    CHECK(std::signbit(atanCephes(-0.0)));
    CHECK(!std::signbit(atanCephes(0.0)));
}

#if defined(__x86_64__) || defined(__i386__)
namespace {
FV_AVX2 void atanFour(const double* x, double* out) { _mm256_storeu_pd(out, lanes::atanCephes4(_mm256_loadu_pd(x))); }
} // namespace

TEST_CASE("atanCephes4: four lanes give the scalar's bits", "[fast]")
{
    if (!lanes::cpuHasAvx2()) return; // nothing to compare on this CPU
    const std::vector<double> x = atanArguments();
    size_t differ = 0;
    for (size_t i = 0; i < x.size(); i += 4) {
        double out[4];
        atanFour(&x[i], out);
        for (size_t k = 0; k < 4; ++k) {
            const double ref = atanCephes(x[i + k]);
            differ += std::memcmp(&ref, &out[k], 8) != 0;
        }
    }
    CHECK(differ == 0);
}
#endif
