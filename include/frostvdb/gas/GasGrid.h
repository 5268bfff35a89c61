#pragma once
/// @file GasGrid.h
/// @brief Turns a procedural gas model into sparse OpenVDB grids. Only leaf nodes whose bounding
/// sphere can hold gas (GasModel::mayHold) are evaluated, in parallel over leaves (tbb), each
/// leaf built privately and added to the tree serially afterwards, so the result is identical
/// whatever the thread count. Voxels at or below the threshold stay inactive.
#include <frostvdb/gas/GasModels.h>

#include <openvdb/openvdb.h>

namespace frostvdb {
struct World;
}

namespace frostvdb::gas {

struct GasBuildOptions {
    bool velocity = true;           ///< build `vel` (Vec3s, contravariant-relative, m/s)
    bool fire = false;              ///< build `flame`, `temperature`, `Cd`
    double ambientTemperature = 293.15; ///< K: temperature background
    double peakTemperature = 1700.0;    ///< K at flame = 1
    bool colour = true;             ///< fire: build `Cd`
    size_t grain = 4;               ///< leaves per task; 0: serial
};

struct GasGrids {
    openvdb::FloatGrid::Ptr density;
    openvdb::Vec3SGrid::Ptr vel;
    openvdb::FloatGrid::Ptr flame, temperature;
    openvdb::Vec3SGrid::Ptr colour;
    uint64_t candidateLeaves = 0; ///< leaves whose bounds could hold gas
    uint64_t evaluatedVoxels = 0; ///< voxels evaluated (candidate leaves x 512)
};

/// The transform gas grids use: the scene's field transform when it is a uniform scale (so gas
/// and ice share it), else a uniform transform with the domain's voxel size.
openvdb::math::Transform::Ptr gasTransform(const World& world);

GasGrids buildGasGrids(const GasModel& model, const GasContext& ctx,
                       const openvdb::math::Transform::Ptr& xform, const GasBuildOptions& opt);

/// Evaluates the model's density at every active voxel of @a grid (topology unchanged, no
/// threshold): the benchmark's like-for-like comparison with vdb_ax.
void evaluateDensityOver(const GasModel& model, const GasContext& ctx, openvdb::FloatGrid& grid);

/// A ray-marched preview of a frame's gas (density, plus `ice` if present, and fire emission from
/// `flame`/`Cd`), viewed horizontally (perpendicular to @a up), lit from above.
void writeGasPreview(const openvdb::GridPtrVec& grids, const V3& up, const std::string& pngPath,
                     int width = 480);

} // namespace frostvdb::gas
