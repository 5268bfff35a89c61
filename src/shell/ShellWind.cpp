/// @file ShellWind.cpp
/// @brief Tangential wind on a shell band: uniform, or the potential flow around the object
/// (OpenVDB tools::PotentialFlow), see ShellWind.h.
///
/// The potential flow's tangential velocity on the surface is the surface gradient of the total
/// potential Phi = U . x + phi' (phi' the solved disturbance). Because dPhi/dn = 0 at the wall,
/// Phi sampled one flow voxel off the surface is second-order accurate there, and its surface
/// gradient is taken the closest-point way: Phi at each band voxel's closest point, central
/// differences in 3D, projected on the tangent plane (no differencing of the staircase Neumann
/// velocities the tool writes on its boundary voxels).
#include <frostvdb/shell/ShellWind.h>

#include <openvdb/tools/GridOperators.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/LevelSetRebuild.h>
#include <openvdb/tools/SignedFloodFill.h>

// libopenvdb (built with gcc) exports createPotentialFlowNeumannVelocities<Vec3f> under gcc's
// mangling of its dependent ConstPtr parameter; clang (the fuzz build) mangles that parameter
// differently and cannot link against the extern template. This file instantiates the
// potential-flow templates itself instead (the cost is compile time here only).
#undef OPENVDB_USE_EXPLICIT_INSTANTIATION
#include <openvdb/tools/PotentialFlow.h>
#define OPENVDB_USE_EXPLICIT_INSTANTIATION

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

namespace frostvdb::shell {

using openvdb::Coord;
using openvdb::Vec3d;
using openvdb::Vec3f;

std::vector<Vec3f> uniformWind(const ShellBand& band, const Vec3d& wind)
{
    std::vector<Vec3f> out;
    if (wind.lengthSqr() == 0.0) return out;
    out.resize(band.size());
    for (size_t i = 0; i < band.size(); ++i) {
        const Vec3d n = band.normal(i);
        out[i] = Vec3f(wind - n * wind.dot(n));
    }
    return out;
}

namespace {

/// The object as a level set on a grid of @a c band voxels per flow voxel (index units of the
/// band: voxel size c): the band's signed normal offset at the band voxels that are flow voxel
/// centres, flood-filled (so the inside is solid), then rebuilt to a clean narrow band.
openvdb::FloatGrid::Ptr objectLevelSet(const ShellBand& band, int c)
{
    auto xf = openvdb::math::Transform::createLinearTransform(double(c));
    auto sdf = openvdb::FloatGrid::create(float(3 * c));
    sdf->setTransform(xf);
    sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    {
        auto acc = sdf->getAccessor();
        for (size_t i = 0; i < band.size(); ++i) {
            const Coord& f = band.coord(i);
            if (f.x() % c || f.y() % c || f.z() % c) continue;
            if (band.lateralOffset(i) > 0.25f) continue; // beyond an open border: no side
            acc.setValue(Coord(f.x() / c, f.y() / c, f.z() / c),
                         std::clamp(band.normalOffset(i), -float(3 * c), float(3 * c)));
        }
    }
    openvdb::tools::signedFloodFill(sdf->tree());
    return openvdb::tools::levelSetRebuild(*sdf, 0.f, 3.f, 3.f);
}

} // namespace

std::vector<Vec3f> potentialFlowWind(const ShellBand& band, const Vec3d& freeStream, int padding,
                                     PotentialFlowStats* stats, std::vector<Vec3f>* full)
{
    namespace vt = openvdb::tools;
    std::vector<Vec3f> out;
    if (freeStream.lengthSqr() == 0.0) return out;
    const auto t0 = std::chrono::steady_clock::now();
    // the flow grid: about 24 flow voxels across the object's half-size, at most 4 band voxels each
    openvdb::CoordBBox bb;
    for (const auto& c : band.coords()) bb.expand(c);
    const int half = std::max({bb.dim().x(), bb.dim().y(), bb.dim().z()}) / 2;
    const int c = std::clamp(half / 24, 1, 4);
    auto sdf = objectLevelSet(band, c);
    const Vec3f U(freeStream);
    if (padding <= 0) padding = half; // the flow domain reaches about 2x the object's half size out
    auto mask = vt::createPotentialFlowMask(*sdf, std::max(4, padding / c));
    auto neumann = vt::createPotentialFlowNeumannVelocities(*sdf, *mask, openvdb::Vec3SGrid::ConstPtr(), U);
    openvdb::math::pcg::State state = openvdb::math::pcg::terminationDefaults<float>();
    state.iterations = 5000;
    state.relativeError = 1e-7;
    state.absoluteError = 1e-7 * double(U.length());
    auto potential = vt::computeScalarPotential(*mask, *neumann, state);
    if (stats) {
        stats->iterations = state.iterations;
        stats->absoluteError = state.absoluteError;
        stats->domainVoxels = size_t(mask->activeVoxelCount());
    }
    // the disturbance potential of the tool is -phi' (its Neumann data is +U . n): Phi = U . x - phi
    const size_t n = band.size();
    std::vector<float> Phi(n);
    const double off = double(c); // one flow voxel outward
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& r) {
        auto acc = potential->getConstAccessor();
        vt::GridSampler<openvdb::FloatGrid::ConstAccessor, vt::BoxSampler> s(acc, potential->transform());
        for (size_t i = r.begin(); i < r.end(); ++i) {
            const Vec3d x = band.closestPoint(i) + band.normal(i) * off;
            Phi[i] = float(freeStream.dot(x) - double(s.wsSample(x)));
        }
    });
    // surface gradient: central differences of the closest-point data, projected
    out.assign(n, Vec3f(0.f));
    if (full) full->assign(n, Vec3f(0.f));
    std::vector<float> comp[3];
    for (auto& v : comp) v.assign(n, 0.f);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            if (!band.inUpdateSet(i)) continue;
            Vec3d g;
            for (int a = 0; a < 3; ++a)
                g[a] = 0.5 * (double(Phi[size_t(band.neighbour(i, 2 * a + 1))]) - double(Phi[size_t(band.neighbour(i, 2 * a))]));
            const Vec3d nn = band.normal(i);
            g -= nn * g.dot(nn);
            for (int a = 0; a < 3; ++a) comp[a][i] = float(g[a]);
        }
    });
    // re-extension: every band voxel gets the value at its closest point (tricubic over the update set)
    std::vector<float> ext[3];
    for (int a = 0; a < 3; ++a) band.extend(comp[a], ext[a], false);
    for (size_t i = 0; i < n; ++i) {
        const Vec3d nn = band.normal(i);
        Vec3d v(ext[0][i], ext[1][i], ext[2][i]);
        v -= nn * v.dot(nn);
        out[i] = Vec3f(v);
    }
    if (full) { // grad Phi in 3D, 1.5 flow voxels off the surface (central differences of half a voxel)
        auto acc = potential->getConstAccessor();
        vt::GridSampler<openvdb::FloatGrid::ConstAccessor, vt::BoxSampler> s(acc, potential->transform());
        auto total = [&](const Vec3d& x) { return freeStream.dot(x) - double(s.wsSample(x)); };
        for (size_t i = 0; i < n; ++i) {
            const Vec3d x = band.closestPoint(i) + band.normal(i) * (1.5 * off);
            Vec3d g;
            for (int a = 0; a < 3; ++a) {
                Vec3d e(0.0);
                e[a] = 0.5 * off;
                g[a] = (total(x + e) - total(x - e)) / off;
            }
            (*full)[i] = Vec3f(g);
        }
    }
    if (stats) stats->solveSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return out;
}

} // namespace frostvdb::shell
