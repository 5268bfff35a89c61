#pragma once
/// @file Crystal.h
/// @brief The ice paper's user controls (section 4.4, after Kim and Lin): the seed crystal map
/// and the melting temperature map, as the scene section [crystal]. It initialises p and melt, so
/// the driver initialises it before the effects that read them (core/StepOrder.h); it writes the initial phase p = 1 where the user seeds ice and
/// the field `melt` in [0,1], and does nothing during steps.
///
/// Sources, combined in this order (later wins for `melt`, seeds are a union):
///   - a map: a PNG (greyscale, 8 or 16 bit, stretched over the domain's world rectangle, row 0
///     at the top = +y; in a box it applies to every z layer of a column) or a VDB grid
///     (`*_map_grid`, sampled in world space or, with `*_map_space = "index"`, at our cell indices);
///   - shapes, as TOML arrays of tables:
///     @code
///       [[crystal.seed]]
///       shape = "point"           # disc of `radius` cells (ball in a box)
///       position = [0.5, 0.5]     # fractions of the domain, [x, y] or [x, y, z] in a box
///       space = "fraction"        # or "world": position/from/to in metres
///       radius = 3
///       [[crystal.seed]]
///       shape = "line"            # segment of `width` cells (capsule in a box)
///       from = [0.1, 0.2]
///       to = [0.9, 0.2]
///       width = 2
///       [[crystal.melt]]          # melt shapes take a `value` in [0,1]
///       shape = "edge"            # band of `width` cells along the domain's edges
///       edges = "left, bottom"    # all | left | right | bottom | top (| front | back in a box)
///       value = 0.3
///     @endcode
///     `disc` is a point whose radius is a fraction of the domain (`radius_fraction`), so it keeps
///     its size when the resolution changes.
/// Without any seed the default crystal of ice::requireIceFields (disc r = 3 at the centre) is used.
/// Distances are measured in the lattice's own geometry (a hexagonal disc is round in world space).
///
/// The melt map's meaning: for the phase field T_e(x) = T_inf + melt(x) (T_e - T_inf); for DLA the
/// sticking probability. Its background is 1 (fully promoted growth); only values != 1 are stored.
#include <frostvdb/core/Effect.h>

#include <openvdb/openvdb.h>

#include <functional>
#include <string>
#include <vector>

namespace frostvdb {
namespace ice {

/// One element of [[crystal.seed]] or [[crystal.melt]].
struct CrystalShape {
    enum class Kind { Point, Disc, Line, Edge, Scatter };
    Kind kind = Kind::Point;
    std::vector<double> position{0.5, 0.5}; ///< centre (point, disc), fractions of the domain
    std::vector<double> from, to;           ///< line end points, fractions of the domain
    double radius = 3.0;                    ///< cells (point); disc: set from radius_fraction
    double width = 2.0;                     ///< cells: line thickness, edge band width
    std::vector<std::string> edges;         ///< boundary parts of the domain (Domain::boundaryNames)
    bool world = false;                     ///< position/from/to in world metres, not fractions
    float value = 1.f;                      ///< melt value ([[crystal.melt]] only)
    // scatter: `count` sites of `radius` cells, spread by area at least `minDistance` cells apart,
    // each kept with the probability `weight` gives at it (see scatterSites)
    int64_t count = 100;
    double minDistance = 0;
    enum class Weight { None, VertexColours, Texture } weight = Weight::None;
    std::string weightPath; ///< Texture: a greyscale PNG (a plane: stretched over it; a mesh: through its UVs)
    uint64_t seed = 1;      ///< the sites' random stream
    std::string key;        ///< the entry as messages name it, e.g. "crystal.seed#2" (its keys follow a dot)
    ParamOrigin origin;     ///< where the entry's `edges` (else its `shape`) was given
};

/// The scatter shape's site centres (index space): candidates drawn uniformly by area
/// (Domain::sampleSupport), each kept when a uniform draw is below its weight and no kept site
/// lies within minDistance (dart throwing, in draw order), until `count` are kept or 30 x count
/// candidates are spent. Same sites whatever the thread count.
std::vector<openvdb::Vec3d> scatterSites(const Domain& domain, const CrystalShape& shape);

/// Reads one shape table (an empty table gives the default point). @a withValue: read `value`.
/// Throws SceneError naming the entry and key on bad input (checks against @a domain).
CrystalShape readCrystalShape(ParamDict& d, const Domain& domain, bool withValue);

/// Calls @a fn for every domain cell the shape covers.
void forEachShapeCell(const Domain& domain, const CrystalShape& shape,
                      const std::function<void(const openvdb::Coord&)>& fn);

/// Sets every cell the shape covers to @a value (edges are filled densely, no tiles).
void stampShape(const Domain& domain, openvdb::FloatGrid& grid, const CrystalShape& shape, float value);

/// Where a map comes from, as the scene gave it.
struct MapSource {
    std::string path;        ///< resolved file path (.png or .vdb)
    std::string grid;        ///< VDB grid name ("" -> the file's only float grid)
    bool indexSpace = false; ///< VDB: sample at our cell indices instead of world positions
    bool stretch = false;    ///< PNG: accept an image whose aspect ratio differs from the domain's
    std::string key;         ///< qualified scene key, for messages
    ParamOrigin origin;      ///< where the key was given
    bool isPng() const;
};

/// Samples a map at every domain cell (in parallel) and calls @a fn(cell, value) serially for each.
/// A VDB level set gives 1 inside (distance <= 0) and 0 outside. Throws SceneError (file and key) on a
/// missing or unreadable file, an unknown grid, a wrong aspect ratio or (when @a requireUnit and
/// the grid is not a level set) values outside [0,1].
void sampleMap(const Domain& domain, const MapSource& src, bool requireUnit,
               const std::function<void(const openvdb::Coord&, float)>& fn);

/// Resolves a path from a scene: absolute paths as they are, --set values relative to the current
/// folder, others relative to the scene file's folder.
std::string resolveScenePath(const std::string& path, const std::string& sceneLabel, const ParamOrigin* origin);

/// [crystal]: seed crystal map and melting temperature map.
class CrystalEffect : public Effect {
public:
    static std::unique_ptr<Effect> create(ParamDict& d, const World& world);

    std::string name() const override { return "crystal"; }
    FieldDeclaration declaration() const override;
    void initialize(World& world) override;
    void step(World&, const StepInfo&) override {}
    void addToFrame(World&, Frame&) override {}
    /// Seeds and melt map live in the fields p and melt: nothing of its own to save.
    bool supportsCheckpoint() const override { return true; }
    void saveState(const World&, StateWriter&) const override {}
    void loadState(World&, const StateReader&) override {}
    /// The cells the seed and melt shapes stamp into their sparse grids (a disc's ball clipped to
    /// the domain's bounds, a line's capsule, the scatter discs, the edge bands of a plane or a
    /// box), refused by the shape's key before anything is stamped (issue 25, finding 1).
    MemoryEstimate memoryEstimate(const World& world) const override;

    bool hasSeeds() const { return !mSeeds.empty() || mSeedMap.has; }
    bool hasMelt() const { return !mMelt.empty() || mMeltMap.has || mMeltValue != 1.0; }

private:
    struct Map {
        bool has = false;
        MapSource src;
    };
    std::vector<CrystalShape> mSeeds, mMelt;
    Map mSeedMap, mMeltMap;
    double mSeedThreshold = 0.5;
    double mMeltValue = 1.0;
};

} // namespace ice
} // namespace frostvdb
