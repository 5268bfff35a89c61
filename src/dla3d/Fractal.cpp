/// @file Fractal.cpp
#include <frostvdb/dla3d/Fractal.h>

#include <algorithm>
#include <cmath>

namespace frostvdb::dla3d {

namespace {
FractalFit fit(const std::vector<double>& x, const std::vector<double>& y)
{
    FractalFit f;
    const size_t n = x.size();
    f.samples = int(n);
    if (n < 2) return f;
    double sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0;
    for (size_t i = 0; i < n; ++i) {
        sx += x[i]; sy += y[i]; sxx += x[i] * x[i]; sxy += x[i] * y[i]; syy += y[i] * y[i];
    }
    const double cov = sxy - sx * sy / n, vx = sxx - sx * sx / n, vy = syy - sy * sy / n;
    f.dimension = cov / vx;
    f.r2 = vy > 0 ? cov * cov / (vx * vy) : 1.0;
    return f;
}
} // namespace

FractalFit massRadiusDimension(const std::vector<openvdb::Vec3d>& positions, const openvdb::Vec3d& centre,
                               double rMin, double rMax, int samples)
{
    std::vector<double> d(positions.size());
    for (size_t i = 0; i < positions.size(); ++i) d[i] = (positions[i] - centre).length();
    std::sort(d.begin(), d.end());
    std::vector<double> x, y;
    for (int s = 0; s < samples; ++s) {
        const double r = rMin * std::pow(rMax / rMin, double(s) / (samples - 1));
        const double n = double(std::upper_bound(d.begin(), d.end(), r) - d.begin());
        if (n < 1) continue;
        x.push_back(std::log(r));
        y.push_back(std::log(n));
    }
    return fit(x, y);
}

FractalFit gyrationDimension(const std::vector<openvdb::Vec3d>& positions, size_t nMin, int samples)
{
    const size_t n = positions.size();
    std::vector<double> x, y;
    if (n < nMin || nMin < 2) return {};
    std::vector<size_t> marks;
    for (int s = 0; s < samples; ++s)
        marks.push_back(size_t(std::llround(double(nMin) * std::pow(double(n) / nMin, double(s) / (samples - 1)))));
    openvdb::Vec3d sum(0.0);
    double sum2 = 0;
    size_t next = 0;
    for (size_t i = 0; i < n && next < marks.size(); ++i) {
        sum += positions[i];
        sum2 += positions[i].lengthSqr();
        const size_t m = i + 1;
        while (next < marks.size() && marks[next] == m) {
            const openvdb::Vec3d c = sum / double(m);
            const double rg2 = sum2 / double(m) - c.lengthSqr();
            x.push_back(0.5 * std::log(std::max(rg2, 1e-300)));
            y.push_back(std::log(double(m)));
            ++next;
        }
    }
    return fit(x, y);
}

} // namespace frostvdb::dla3d
