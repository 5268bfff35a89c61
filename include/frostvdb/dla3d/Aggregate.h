#pragma once
/// @file Aggregate.h
/// @brief Off-lattice (continuum) diffusion-limited aggregation in 2D and 3D after Bourke:
/// particles of one radius, walkers that stick within a stick distance of the aggregate with a
/// probability (stickiness) and attach at the contact point, launch distributions (sphere, axis,
/// plane, surface), a bias force, slow rotation, several seeds and mesh constraints.
///
/// Walkers move by walk-on-spheres: each step is a uniform random jump whose length is a lower
/// bound on the distance to the nearest particle minus the contact distance (ParticleHash), so
/// they cross empty space in a few steps and never pass through a particle. With the sphere
/// launch and no bias the outside of the launch sphere is handled exactly: a walker beyond it
/// escapes with probability 1 - R/r (3D; never in 2D) or returns to the sphere at a point drawn
/// from the harmonic measure.
///
/// Parallel and deterministic: walkers run in speculative batches against the frozen aggregate,
/// walker i of the run drawing only from CounterRng(seed, i). Results are committed in walker
/// order; a candidate closer than the conflict distance to one accepted earlier in the same batch
/// is dropped (its walker is spent). The batch size depends only on the particle count, so the
/// aggregate is bit-identical whatever the thread count.
#include <frostvdb/core/Random.h>
#include <frostvdb/dla3d/MeshConstraint.h>
#include <frostvdb/dla3d/ParticleHash.h>

#include <openvdb/openvdb.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

namespace frostvdb::dla3d {

enum class Launch { Sphere, Axis, Plane, Surface };

struct DlaSettings {
    int dimension = 3;
    double radius = 0.5;          ///< particle radius; joined particles sit 2 radius apart
    double stickDistance = 0.5;   ///< a walker touches when within 2 radius + this of a particle
    double stickiness = 1.0;      ///< probability to attach per touch
    Launch launch = Launch::Sphere;
    openvdb::Vec3d centre{0, 0, 0};   ///< sphere launch / rotation / kill centre ("" -> seed centroid)
    bool centreGiven = false;
    double launchMargin = 0;          ///< sphere: launch radius = aggregate radius + this (0: 2 contact)
    openvdb::Vec3d axisA{0, 0, 0}, axisB{0, 0, 1}; ///< axis launch: points on the segment A-B
    double axisSpread = 0;            ///< axis launch: plus a uniform disc of this radius around it
    openvdb::Vec3d planeOrigin{0, 0, 0}, planeU{1, 0, 0}, planeV{0, 1, 0}; ///< plane: O + s U + t V
    std::shared_ptr<const TriangleMesh> launchMesh; ///< surface launch: area-uniform on this mesh
    double launchOffset = 0;          ///< surface launch: along the triangle normal
    openvdb::Vec3d bias{0, 0, 0};     ///< drift added to every unit step direction (gravity, wind)
    openvdb::Vec3d rotationAxis{0, 0, 1};
    double rotationPerParticle = 0;   ///< radians the aggregate turns per attached particle
    double killFactor = 3.0;          ///< walkers farther than this x the growth radius relaunch
    std::vector<openvdb::Vec3d> seeds{openvdb::Vec3d(0, 0, 0)};
    uint64_t seed = 1;
    int maxBatch = 256;               ///< speculative walkers per batch (at large sizes)
    double batchFraction = 0.0005;     ///< batch = clamp(particles x this, 1, maxBatch)
    double conflictFactor = 3.0;      ///< conflict distance = this x (contact + stick)
    int64_t maxStepsPerWalker = 5000000;
    double cellFactor = 4.0;          ///< level-0 hash cell = this x (contact + stick)
    std::shared_ptr<const MeshConstraint> constraint;

    double contact() const { return 2.0 * radius; }
};

struct DlaStats {
    uint64_t walkers = 0, steps = 0, touches = 0, refusedStickiness = 0, refusedConstraint = 0;
    uint64_t conflicts = 0, escapes = 0, returns = 0, relaunches = 0, exhausted = 0, batches = 0;
    double walkSeconds = 0, commitSeconds = 0;
};

class Aggregate {
public:
    explicit Aggregate(DlaSettings settings);

    /// Grows until the aggregate holds @a total particles (seeds included). Returns false when
    /// no walker could attach within the step budget for a whole batch (a blocked constraint).
    /// @a onBatch, when given, is called after each batch with the aggregate's size (progress of
    /// a long step; it never changes the growth).
    bool growTo(size_t total, const std::function<void(size_t)>& onBatch = {});

    size_t size() const { return mPos.size(); }
    const std::vector<openvdb::Vec3d>& positions() const { return mPos; }
    const std::vector<int32_t>& parents() const { return mParent; }     ///< -1 for seeds
    const std::vector<int32_t>& generations() const { return mGeneration; }
    const DlaSettings& settings() const { return mSettings; }
    const DlaStats& stats() const { return mStats; }
    /// Distance of the farthest particle surface from the centre.
    double radius() const { return mRadius; }
    openvdb::Vec3d centre() const { return mCentre; }
    size_t memoryBytes() const;

private:
    struct Candidate {
        openvdb::Vec3d pos;
        int32_t parent = -1;
        uint64_t steps = 0, touches = 0, refusedStick = 0, refusedConstraint = 0;
        uint64_t escapes = 0, returns = 0, relaunches = 0;
        bool ok = false;
    };
    struct Environment; // the per-batch launch frame (rotation, growth radius)
    Candidate walk(uint64_t walkerId, const Environment& env) const;
    openvdb::Vec3d launchPoint(CounterRng& rng, const Environment& env) const;
    openvdb::Vec3d randomDirection(CounterRng& rng) const;
    void add(const openvdb::Vec3d& p, int32_t parent);

    DlaSettings mSettings;
    std::vector<openvdb::Vec3d> mPos;
    std::vector<int32_t> mParent, mGeneration;
    ParticleHash mHash;
    openvdb::Vec3d mCentre;
    double mRadius = 0;
    openvdb::BBoxd mBox;
    uint64_t mNextWalker = 0;
    std::vector<double> mLaunchCdf; ///< surface launch: cumulative triangle areas
    DlaStats mStats;
};

} // namespace frostvdb::dla3d
