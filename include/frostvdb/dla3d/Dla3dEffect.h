#pragma once
/// @file Dla3dEffect.h
/// @brief The [dla3d] scene section: Bourke's constrained off-lattice DLA (dla3d/Aggregate.h)
/// grown over the frames of a run, written as `points` (PointDataGrid with radius, parent,
/// generation, attach_time, id), `ice_sdf` (sphere-swept tapering branches) and `ice` (fog
/// volume), plus an optional OBJ/PLY mesh beside the preview.
#include <frostvdb/core/Effect.h>
#include <frostvdb/dla3d/Aggregate.h>
#include <frostvdb/dla3d/Branches.h>

#include <memory>

namespace frostvdb::dla3d {

class Dla3dEffect : public Effect {
public:
    static std::unique_ptr<Effect> create(ParamDict& d, const World& world);

    std::string name() const override { return "dla3d"; }
    FieldDeclaration declaration() const override
    {
        FieldDeclaration d; // its own particles: no fields shared with other effects
        d.stage = Stage::Sources;
        d.output(out::kPoints).output(out::kIceSdf).output(out::kAggregateIce);
        return d;
    }
    void initialize(World& world) override;
    void step(World& world, const StepInfo& info) override;
    void addToFrame(World& world, Frame& frame) override;
    bool writePreview(World& world, const Frame& frame, const std::string& pngPath) override;
    std::vector<std::pair<std::string, double>> timings() const override;
    /// The level set's leaves at the last frame (before its interior was pruned).
    std::vector<std::pair<std::string, double>> counters() const override;
    /// The particle arrays and the hash of `particles` particles (capacity doubling included),
    /// the points grid, and the last frame's level set and fog from a model of the branches the
    /// keys grow (Dla3dEffect.cpp); each frame checks its level set's leaves again before
    /// rasterising.
    MemoryEstimate memoryEstimate(const World& world) const override;

    const Aggregate& aggregate() const { return *mAggregate; }

    struct Options {
        std::string constraintFile, launchFile;
        MeshPlacement constraintPlacement, launchPlacement;
        std::string side = "front";
        int64_t seedsOnMesh = 0;
        double constraintVoxel = 0;
        int64_t particles = 20000;
        double voxelSize = 0;
        BranchStyle style;
        double halfWidth = 3;
        double maxVoxels = 2e9; ///< refuse a frame whose branches would visit more voxels (max_voxels)
        bool progress = false;  ///< the run reports progress: long rasterisations report theirs
        bool points = true, sdf = true, fog = true;
        std::string mesh = "none";
        std::string sceneLabel;
    };

private:
    void checkOutputKeys(ParamDict& d) const;
    void checkFrameBudget(const World& world, int64_t frame, const std::vector<float>& radii);
    double modelledLeaves(double reach) const;
    double modelledSdfLeaves() const;
    double pointsBytes() const;
    DlaSettings mSettings;
    Options mOptions;
    std::unique_ptr<Aggregate> mAggregate;
    std::vector<float> mAttach; ///< attach time per particle (0..1 of the run's particles)
    int64_t mTotalSteps = 1;
    double mGrowSeconds = 0, mOutputSeconds = 0;
    double mSdfLeaves = 0; ///< the last frame's level set, before pruning
    openvdb::FloatGrid::Ptr mSdf; ///< of the last frame (for the mesh)
};

} // namespace frostvdb::dla3d
