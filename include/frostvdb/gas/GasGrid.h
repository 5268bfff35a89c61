#pragma once
/// @file GasGrid.h
/// @brief Turns a procedural gas model into sparse OpenVDB grids. Only leaf nodes whose bounding
/// sphere can hold gas (GasModel::mayHold) are evaluated, in parallel over leaves (tbb), each
/// leaf built privately and added to the tree serially afterwards, so the result is identical
/// whatever the thread count. Voxels at or below the threshold stay inactive.
#include <frostvdb/gas/GasModels.h>

#include <openvdb/openvdb.h>

#include <functional>

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
    /// Called on the building thread with (leaves done, leaves in all) after each of about 100
    /// chunks of the frame (a long frame reports progress); empty: one pass, no calls.
    std::function<void(uint64_t, uint64_t)> progress;
};

struct GasGrids {
    openvdb::FloatGrid::Ptr density;
    openvdb::Vec3SGrid::Ptr vel;
    openvdb::FloatGrid::Ptr flame, temperature;
    openvdb::Vec3SGrid::Ptr colour;
    uint64_t candidateLeaves = 0; ///< leaves whose bounds could hold gas
    uint64_t evaluatedVoxels = 0; ///< voxels evaluated (candidate leaves x 512)
};

/// What building one frame of a gas costs at most: every leaf of the index box of the model's
/// bounds evaluated and kept (an upper bound; mayHold usually skips part of the box).
struct GasBuildEstimate {
    double boxLeaves = 0;     ///< 8^3 leaves in the index box of the bounds
    double bytes = 0;         ///< leaf buffers of every grid built, plus bookkeeping
    V3 lo, hi;                ///< the world bounds counted
};

/// Counts the work of buildGasGrids without doing it. Throws SceneError (scene @a label, @a key)
/// when the bounds do not fit OpenVDB's 32-bit index space at this voxel size (they would wrap).
GasBuildEstimate estimateGasBuild(const GasModel& model, const GasContext& ctx,
                                  const openvdb::math::Transform& xform, const GasBuildOptions& opt,
                                  const std::string& label, const std::string& key);

/// The 8^3 leaves of the index box of the model's bounds whose bounding sphere may hold gas
/// (GasModel::mayHold): what buildGasGrids evaluates, counted without evaluating a voxel.
/// Bounds must have passed estimateGasBuild (they fit the index range).
uint64_t countCandidateLeaves(const GasModel& model, const GasContext& ctx, const openvdb::math::Transform& xform);

/// The share of the candidate leaves (countCandidateLeaves) that hold gas at this frame: every
/// voxel of at most @a sampleLeaves of them, spread over the build's order, is evaluated
/// until one is above the threshold (buildGasGrids keeps exactly such leaves). Returned with a
/// margin of two standard errors plus one sample, so a sample that missed the gas's densest
/// part does not under-estimate (issue 25: a teacup's plume fills 41 % of its candidates, and
/// only evaluating the density tells which). 1 without candidates.
double sampledGasLeafShare(const GasModel& model, const GasContext& ctx, const openvdb::math::Transform& xform,
                           size_t sampleLeaves);

/// The transform gas grids use: the scene's field transform when it is a uniform scale (so gas
/// and ice share it), else a uniform transform with the domain's voxel size.
openvdb::math::Transform::Ptr gasTransform(const World& world);

GasGrids buildGasGrids(const GasModel& model, const GasContext& ctx,
                       const openvdb::math::Transform::Ptr& xform, const GasBuildOptions& opt);

/// Evaluates the model's density at every active voxel of @a grid (topology unchanged, no
/// threshold): the benchmark's like-for-like comparison with vdb_ax.
void evaluateDensityOver(const GasModel& model, const GasContext& ctx, openvdb::FloatGrid& grid);

/// A ray-marched preview of a frame's gas (density, plus `ice` if present, and fire emission from
/// `flame`/`Cd`), viewed horizontally (perpendicular to @a up), lit from above. Not
/// tools::VolumeRender: that renders one scalar density with a single light and cannot draw
/// fire's per-voxel emission colour (`Cd` x `flame`) or the second panel of steam seen from above
/// over the frost's `ice`.
void writeGasPreview(const openvdb::GridPtrVec& grids, const V3& up, const std::string& pngPath,
                     int width = 480);

} // namespace frostvdb::gas
