#pragma once
/// @file Fractal.h
/// @brief Fractal dimension of an aggregate, two ways:
/// - mass-radius: N(r), the particles within r of the centre, fitted as log N = D log r + c over
///   r in [rMin, rMax] (geometric samples);
/// - radius of gyration over the growth history: Rg(n) of the first n particles, fitted as
///   log n = D log Rg + c for n from nMin to the full size (geometric samples).
/// Both are least-squares slopes; the docs report both for every measurement.
#include <openvdb/openvdb.h>

#include <vector>

namespace frostvdb::dla3d {

struct FractalFit {
    double dimension = 0;
    double r2 = 0; ///< coefficient of determination of the fit
    int samples = 0;
};

FractalFit massRadiusDimension(const std::vector<openvdb::Vec3d>& positions, const openvdb::Vec3d& centre,
                               double rMin, double rMax, int samples = 24);

FractalFit gyrationDimension(const std::vector<openvdb::Vec3d>& positions, size_t nMin, int samples = 24);

} // namespace frostvdb::dla3d
