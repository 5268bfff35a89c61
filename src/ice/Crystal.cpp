#include <frostvdb/io/InputFiles.h>
#include <frostvdb/ice/Crystal.h>
#include <frostvdb/io/VdbIO.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/icephysics/IceState.h>
#include <frostvdb/io/Png.h>
#include <frostvdb/io/VdbCheck.h>

#include <openvdb/tools/Count.h>
#include <openvdb/io/File.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tools/ValueTransformer.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <sstream>

namespace frostvdb {
namespace ice {

FROSTVDB_REGISTER_EFFECT(CrystalEffect, "crystal",
    "User controls (ice paper 4.4): seed crystal map and melting temperature map, from PNG or VDB maps "
    "and shapes ([[crystal.seed]], [[crystal.melt]]: point, disc, line, edge).");

namespace {

using openvdb::Coord;
using openvdb::Vec3d;

/// Index position of a shape point: fractions of the domain's parameterisation, or metres.
Vec3d indexOf(const Domain& dom, const std::vector<double>& f, bool world)
{
    if (!world) return dom.parameterToIndex(f);
    Vec3d w(f[0], f[1], 0.0);
    if (f.size() > 2) w.z() = f[2];
    else w.z() = dom.transform()->indexToWorld(dom.centre()).z(); // on the domain's middle layer
    Vec3d idx = dom.worldToIndex(w);
    if (dom.flat()) idx.z() = dom.bbox().min().z(); // a flat domain's own layer
    return idx;
}

/// Position in the lattice's own geometry, in cells (hexagonal cells are unit apart too).
Vec3d geo(const Domain& dom, const Vec3d& idx)
{
    const openvdb::Vec2d p = dom.lattice().planePosition(idx.x(), idx.y());
    return Vec3d(p.x(), p.y(), idx.z());
}

/// Index window around [lo, hi] widened by @a r cells (with room for the hexagonal shear).
openvdb::CoordBBox window(const Domain& dom, Vec3d lo, Vec3d hi, double r)
{
    const double rr = 2.0 * r + 2.0;
    const Coord a(int(std::floor(lo.x() - rr)), int(std::floor(lo.y() - rr)), int(std::floor(lo.z() - r - 2.0)));
    const Coord b(int(std::ceil(hi.x() + rr)), int(std::ceil(hi.y() + rr)), int(std::ceil(hi.z() + r + 2.0)));
    openvdb::CoordBBox box(a, b);
    box.intersect(dom.bbox());
    return box;
}

/// Splits "left, top" into boundary part names the domain knows ("all": every part).
std::vector<std::string> parseEdges(ParamDict& d, const std::string& text, const Domain& dom)
{
    const std::vector<std::string> known = dom.boundaryNames();
    std::vector<std::string> out;
    std::string word;
    auto flush = [&]() {
        if (word.empty()) return;
        if (word == "all") out.insert(out.end(), known.begin(), known.end());
        else if (std::find(known.begin(), known.end(), word) != known.end()) out.push_back(word);
        else {
            std::string list = "all";
            for (const auto& k : known) list += ", " + k;
            d.fail("edges", "unknown edge '" + word + "' (allowed: " + list + ")");
        }
        word.clear();
    };
    for (char c : text) {
        if (c == ',' || c == '+' || std::isspace(static_cast<unsigned char>(c))) flush();
        else word += char(std::tolower(static_cast<unsigned char>(c)));
    }
    flush();
    if (out.empty()) d.fail("edges", "names no edge");
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
}

bool endsWith(const std::string& s, const std::string& suffix)
{
    if (s.size() < suffix.size()) return false;
    return std::equal(suffix.rbegin(), suffix.rend(), s.rbegin(),
                      [](char a, char b) { return std::tolower(static_cast<unsigned char>(a)) == b; });
}

[[noreturn]] void mapFail(const MapSource& src, const std::string& what)
{
    throw SceneError(src.origin.file, src.origin.line, src.key, what);
}

/// World rectangle [x0, x1] x [y0, y1] the domain's cells cover (centres +- half a cell).
void domainWorldRect(const Domain& dom, double& x0, double& x1, double& y0, double& y1)
{
    const auto& bb = dom.bbox();
    x0 = y0 = 1e300;
    x1 = y1 = -1e300;
    for (int c = 0; c < 4; ++c) {
        const Vec3d ip((c & 1) ? bb.max().x() : bb.min().x(), (c & 2) ? bb.max().y() : bb.min().y(), bb.min().z());
        const Vec3d w = dom.transform()->indexToWorld(ip);
        x0 = std::min(x0, w.x());
        x1 = std::max(x1, w.x());
        y0 = std::min(y0, w.y());
        y1 = std::max(y1, w.y());
    }
    const double h = dom.voxelSize();
    x0 -= 0.5 * h;
    x1 += 0.5 * h;
    y0 -= 0.5 * h;
    y1 += 0.5 * h;
}

/// Runs @a value(cell) over every domain cell in parallel (one z layer at a time), then hands the
/// values to @a fn serially.
template <typename ValueFn>
void sampleDomain(const Domain& dom, const ValueFn& value, const std::function<void(const Coord&, float)>& fn)
{
    const auto& bb = dom.bbox();
    const int nx = bb.dim().x(), ny = bb.dim().y();
    std::vector<float> layer(size_t(nx) * ny);
    for (int k = bb.min().z(); k <= bb.max().z(); ++k) {
        tbb::parallel_for(tbb::blocked_range<int>(0, ny), [&](const tbb::blocked_range<int>& r) {
            auto sampler = value.make(); // one accessor per task
            for (int j = r.begin(); j < r.end(); ++j)
                for (int i = 0; i < nx; ++i)
                    layer[size_t(j) * nx + i] = sampler(Coord(bb.min().x() + i, bb.min().y() + j, k));
        });
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i)
            {
                const Coord c(bb.min().x() + i, bb.min().y() + j, k);
                if (dom.contains(c)) fn(c, layer[size_t(j) * nx + i]); // the support, not its bounds
            }
    }
}

struct PngSampler {
    const Domain* dom;
    const std::vector<float>* img;
    int W, H;
    double x0, x1, y0, y1;
    struct Fn {
        const PngSampler* s;
        float operator()(const Coord& c) const
        {
            const Vec3d w = s->dom->transform()->indexToWorld(Vec3d(c.x(), c.y(), c.z()));
            const double u = (w.x() - s->x0) / (s->x1 - s->x0), v = (w.y() - s->y0) / (s->y1 - s->y0);
            const double px = std::clamp(u * s->W - 0.5, 0.0, double(s->W - 1));
            const double py = std::clamp((1.0 - v) * s->H - 0.5, 0.0, double(s->H - 1)); // row 0 = top
            const int ix = std::min(int(px), s->W - 2 < 0 ? 0 : s->W - 2);
            const int iy = std::min(int(py), s->H - 2 < 0 ? 0 : s->H - 2);
            const int ix1 = std::min(ix + 1, s->W - 1), iy1 = std::min(iy + 1, s->H - 1);
            const double fx = px - ix, fy = py - iy;
            auto at = [&](int x, int y) { return double((*s->img)[size_t(y) * s->W + x]); };
            return float((1 - fy) * ((1 - fx) * at(ix, iy) + fx * at(ix1, iy)) +
                         fy * ((1 - fx) * at(ix, iy1) + fx * at(ix1, iy1)));
        }
    };
    Fn make() const { return Fn{this}; }
};

struct VdbSampler {
    const Domain* dom;
    const openvdb::FloatGrid* grid;
    bool indexSpace;
    struct Fn {
        const VdbSampler* s;
        openvdb::FloatGrid::ConstAccessor acc;
        float operator()(const Coord& c)
        {
            if (s->indexSpace) return acc.getValue(c);
            const Vec3d w = s->dom->transform()->indexToWorld(c);
            const Vec3d ip = s->grid->transform().worldToIndex(w);
            return openvdb::tools::BoxSampler::sample(acc, ip);
        }
    };
    Fn make() const { return Fn{this, grid->getConstAccessor()}; }
};

} // namespace

bool MapSource::isPng() const { return endsWith(path, ".png"); }

std::string resolveScenePath(const std::string& path, const std::string& sceneLabel, const ParamOrigin* origin)
{
    namespace fs = std::filesystem;
    const fs::path p(path);
    if (p.is_absolute()) return path;
    if (origin && origin->file == "--set") return path;
    if (sceneLabel.empty() || sceneLabel[0] == '<') return path;
    const fs::path dir = fs::path(sceneLabel).parent_path();
    return dir.empty() ? path : (dir / p).string();
}

CrystalShape readCrystalShape(ParamDict& d, const Domain& dom, bool withValue)
{
    CrystalShape s;
    s.key = d.section();
    for (const char* k : {"shape", "edges"})
        if (const ParamOrigin* o = d.origin(k)) s.origin = *o;
    const std::string kind = d.getString("shape", "point", {"point", "disc", "line", "edge", "scatter"},
        "point: disc of `radius` cells; disc: radius as a fraction of the domain; line: segment of `width` cells; "
        "edge: band of `width` cells along domain edges (a box: balls, capsules and slabs); scatter: `count` "
        "discs of `radius` cells spread over the domain by area (a shell: over the mesh), `min_distance` apart");
    const std::vector<size_t> dims = dom.parameterDimension() == 2 ? std::vector<size_t>{2} : std::vector<size_t>{2, 3};
    s.world = d.getString("space", "fraction", {"fraction", "world"},
        "how position, from and to are given: fractions of the domain's parameterisation, or world metres "
        "[x, y(, z)] (a missing z: the domain's middle layer)") == "world";
    const double lo = s.world ? -1e6 : 0.0, hi = s.world ? 1e6 : 1.0;
    const std::vector<size_t> worldDims{2, 3};
    s.position = d.getFloatArray("position", {0.5, 0.5}, s.world ? worldDims : dims, lo, hi, "fraction or m",
        "centre of a point or disc as fractions of the domain [x, y] (box: [x, y, z], z defaults to 0.5)");
    s.radius = d.getFloat("radius", 3.0, 0.0, 1e6, "cells", "radius of a point, or of each scatter site");
    s.count = d.getInt("count", 100, 1, 1000000, "sites", "scatter: number of sites");
    s.minDistance = d.getFloat("min_distance", 0.0, 0.0, 1e6, "cells",
        "scatter: no two sites closer than this (fewer than count are placed when the domain is full)");
    const std::string weight = d.getString("weight", "none", {},
        "scatter: where sites are likelier: none; vertex_colours (a shell mesh's colour luminance: 0 never, 1 "
        "always); or a greyscale PNG, relative to the scene file (a plane: stretched over it, row 0 = +y; a shell: "
        "through the mesh's UVs)");
    s.seed = uint64_t(d.getInt("seed", 1, 0, 1000000000, "", "scatter: the sites' random stream (another value, "
                                                                  "another layout; independent of the run's seed)"));
    const double rf = d.getFloat("radius_fraction", 0.1, 0.0, 1.0, "fraction",
        "radius of a disc as a fraction of the domain's smaller side");
    s.from = d.getFloatArray("from", {}, s.world ? worldDims : dims, lo, hi, "fraction or m",
        "start of a line as fractions of the domain");
    s.to = d.getFloatArray("to", {}, s.world ? worldDims : dims, lo, hi, "fraction or m",
        "end of a line as fractions of the domain");
    s.width = d.getFloat("width", 2.0, 0.0, 1e6, "cells",
        "thickness of a line (cells within width/2 of it) or of an edge band (ceil(width) cells)");
    const std::string edges = d.getString("edges", "all", {},
        "edge shape: all, or a comma list of left, right, bottom, top (box also front = z min, back = z max)");
    if (withValue)
        s.value = float(d.getFloat("value", 0.0, 0.0, 1.0, "",
            "melt value inside the shape: 0 suppresses growth, 1 fully promotes it"));

    auto only = [&](const char* key, std::initializer_list<const char*> shapes) {
        if (!d.has(key)) return;
        for (const char* k : shapes)
            if (kind == k) return;
        std::string list;
        for (const char* k : shapes) list += (list.empty() ? "" : " or ") + std::string("\"") + k + "\"";
        d.fail(key, std::string("applies to shape = ") + list + " only (this entry is \"" + kind + "\")");
    };
    only("position", {"point", "disc"});
    only("radius", {"point", "scatter"});
    only("count", {"scatter"});
    only("min_distance", {"scatter"});
    only("weight", {"scatter"});
    only("seed", {"scatter"});
    only("radius_fraction", {"disc"});
    only("from", {"line"});
    only("to", {"line"});
    only("width", {"line", "edge"});
    only("edges", {"edge"});
    only("space", {"point", "disc", "line"});

    const auto& bb = dom.bbox();
    if (kind == "point") {
        s.kind = CrystalShape::Kind::Point;
    } else if (kind == "disc") {
        s.kind = CrystalShape::Kind::Disc;
        s.radius = rf * std::min(bb.dim().x(), bb.dim().y());
    } else if (kind == "scatter") {
        s.kind = CrystalShape::Kind::Scatter;
        if (weight == "none") {
            s.weight = CrystalShape::Weight::None;
        } else if (weight == "vertex_colours") {
            if (dom.sampleSupport(1, 0).front().colour < 0.f)
                d.fail("weight", "vertex_colours needs a mesh with vertex colours (this domain has none; allowed: "
                                 "none or a PNG file)");
            s.weight = CrystalShape::Weight::VertexColours;
        } else {
            if (!endsWith(weight, ".png")) d.fail("weight", "'" + weight + "': expected none, vertex_colours or a .png file");
            if (!dom.sampleSupport(1, 0).front().hasUv)
                d.fail("weight", "a PNG weight needs texture coordinates: this mesh has no UVs (allowed: none, vertex_colours)");
            s.weight = CrystalShape::Weight::Texture;
            s.weightPath = weight; // resolved against the scene file by the caller
        }
    } else if (kind == "line") {
        s.kind = CrystalShape::Kind::Line;
        if (!d.has("from") || !d.has("to"))
            d.fail(d.has("from") ? "to" : "from", "a line needs both `from` and `to`");
    } else {
        s.kind = CrystalShape::Kind::Edge;
        s.edges = parseEdges(d, edges, dom);
        if (s.width < 1.0) d.fail("width", "an edge band is at least 1 cell wide");
    }
    return s;
}

namespace {
/// A greyscale PNG sampled bilinearly at texture coordinates (u, v) (v = 0 at the bottom row).
struct PngWeight {
    std::vector<float> img;
    int w = 0, h = 0;
    explicit PngWeight(const std::string& path) { img = readPngGray(path, w, h); }
    double operator()(const openvdb::Vec2d& uv) const
    {
        const double x = std::clamp(uv.x() * w - 0.5, 0.0, w - 1.0), y = std::clamp((1.0 - uv.y()) * h - 0.5, 0.0, h - 1.0);
        const int i = std::min(int(x), w - 2 < 0 ? 0 : w - 2), j = std::min(int(y), h - 2 < 0 ? 0 : h - 2);
        const double fx = w > 1 ? x - i : 0, fy = h > 1 ? y - j : 0;
        auto at = [&](int a, int b) { return double(img[size_t(std::min(b, h - 1)) * w + std::min(a, w - 1)]); };
        return (1 - fy) * ((1 - fx) * at(i, j) + fx * at(i + 1, j)) + fy * ((1 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1));
    }
};
} // namespace

std::vector<Vec3d> scatterSites(const Domain& dom, const CrystalShape& s)
{
    std::unique_ptr<PngWeight> png;
    if (s.weight == CrystalShape::Weight::Texture) png = std::make_unique<PngWeight>(s.weightPath);
    const uint64_t stream = hashCounters(s.seed, 0x5CA77E55ull);
    const size_t tries = size_t(std::min<int64_t>(s.count * 30, 30000000));
    const std::vector<SupportSample> cand = dom.sampleSupport(tries, stream);
    // kept sites bucketed by cells of min_distance (index space, 3D distance: on a surface the
    // chord, within a few percent of the geodesic at these distances)
    const double cell = std::max(1.0, s.minDistance), d2 = s.minDistance * s.minDistance;
    auto key = [&](const Vec3d& p) { return Coord::floor(p / cell); };
    std::map<Coord, std::vector<Vec3d>> buckets;
    std::vector<Vec3d> out;
    for (size_t k = 0; k < cand.size() && int64_t(out.size()) < s.count; ++k) {
        double w = 1.0;
        if (s.weight == CrystalShape::Weight::VertexColours) w = std::max(0.f, cand[k].colour);
        else if (png) w = (*png)(cand[k].uv);
        if (toUnit(hashCounters(stream, k, 7)) >= w) continue;
        const Vec3d p = cand[k].index;
        bool near = false;
        if (d2 > 0) {
            const Coord c = key(p);
            for (int dz = -1; dz <= 1 && !near; ++dz)
                for (int dy = -1; dy <= 1 && !near; ++dy)
                    for (int dx = -1; dx <= 1 && !near; ++dx) {
                        const auto it = buckets.find(c + Coord(dx, dy, dz));
                        if (it == buckets.end()) continue;
                        for (const Vec3d& q : it->second)
                            if ((q - p).lengthSqr() < d2) { near = true; break; }
                    }
        }
        if (near) continue;
        buckets[key(p)].push_back(p);
        out.push_back(p);
    }
    return out;
}

void forEachShapeCell(const Domain& dom, const CrystalShape& s, const std::function<void(const Coord&)>& fn)
{
    switch (s.kind) {
    case CrystalShape::Kind::Scatter: {
        const double r2 = s.radius * s.radius;
        for (const Vec3d& c : scatterSites(dom, s)) {
            const Vec3d g = geo(dom, c);
            const auto box = window(dom, c, c, s.radius);
            for (auto it = box.begin(); it; ++it)
                if ((geo(dom, (*it).asVec3d()) - g).lengthSqr() <= r2) fn(*it);
        }
        break;
    }
    case CrystalShape::Kind::Point:
    case CrystalShape::Kind::Disc: {
        const Vec3d c = indexOf(dom, s.position, s.world);
        const Vec3d g = geo(dom, c);
        const double r2 = s.radius * s.radius;
        const auto box = window(dom, c, c, s.radius);
        for (auto it = box.begin(); it; ++it)
            if ((geo(dom, (*it).asVec3d()) - g).lengthSqr() <= r2) fn(*it);
        break;
    }
    case CrystalShape::Kind::Line: {
        const Vec3d a = indexOf(dom, s.from, s.world), b = indexOf(dom, s.to, s.world);
        const Vec3d ga = geo(dom, a), gb = geo(dom, b), ab = gb - ga;
        const double len2 = ab.lengthSqr(), hw = 0.5 * s.width;
        const auto box = window(dom, openvdb::math::minComponent(a, b), openvdb::math::maxComponent(a, b), hw);
        for (auto it = box.begin(); it; ++it) {
            const Vec3d q = geo(dom, (*it).asVec3d()) - ga;
            const double t = len2 > 0 ? std::clamp(q.dot(ab) / len2, 0.0, 1.0) : 0.0;
            if ((q - ab * t).lengthSqr() <= hw * hw) fn(*it);
        }
        break;
    }
    case CrystalShape::Kind::Edge: {
        const int n = std::max(1, int(std::ceil(s.width - 1e-9)));
        for (const auto& e : s.edges) dom.forEachBoundaryVoxel(e, n, fn);
        break;
    }
    }
}

void stampShape(const Domain& dom, openvdb::FloatGrid& grid, const CrystalShape& s, float value)
{
    auto acc = grid.getAccessor();
    forEachShapeCell(dom, s, [&](const Coord& c) { acc.setValue(c, value); });
}

void sampleMap(const Domain& dom, const MapSource& src, bool requireUnit,
               const std::function<void(const Coord&, float)>& fn)
{
    namespace fs = std::filesystem;
    if (!fs::exists(src.path)) mapFail(src, "cannot find '" + src.path + "'");
    try {
        requireRegularFile(src.path); // a FIFO would block the read forever
    } catch (const std::exception& e) {
        mapFail(src, e.what());
    }
    if (src.isPng()) {
        int W = 0, H = 0;
        std::vector<float> img;
        try {
            img = readPngGray(src.path, W, H);
        } catch (const std::exception& e) {
            mapFail(src, e.what());
        }
        double x0, x1, y0, y1;
        domainWorldRect(dom, x0, x1, y0, y1);
        const double aspect = (x1 - x0) / (y1 - y0);
        if (!src.stretch && std::fabs(W - aspect * H) > std::max(1.5, 0.02 * W)) {
            std::ostringstream os;
            os.precision(4);
            os << "'" << src.path << "' is " << W << "x" << H << " pixels, but the domain's aspect ratio is " << aspect
               << " (e.g. " << dom.bbox().dim().x() << "x" << int(std::lround(dom.bbox().dim().x() / aspect))
               << "); resize the image or set crystal.map_stretch = true";
            mapFail(src, os.str());
        }
        PngSampler s{&dom, &img, W, H, x0, x1, y0, y1};
        sampleDomain(dom, s, fn);
        return;
    }
    if (!endsWith(src.path, ".vdb")) mapFail(src, "'" + src.path + "': expected a .png or .vdb file");
    // OpenVDB allocates the lengths a damaged file states before reading them: check them first
    if (const std::string why = vdbLengthProblem(src.path); !why.empty())
        mapFail(src, "'" + src.path + "' is damaged: " + why);
    openvdb::GridBase::Ptr base;
    std::string names;
    try {
        // readVdb validates the file against its length first (a damaged map is refused cheaply).
        const auto grids = readVdb(src.path, nullptr, /*requireGrids=*/true);
        std::vector<openvdb::GridBase::Ptr> floats;
        for (auto& g : *grids) {
            names += (names.empty() ? "" : ", ") + g->getName();
            if (g->isType<openvdb::FloatGrid>()) floats.push_back(g);
            if (!src.grid.empty() && g->getName() == src.grid && !base) base = g;
        }
        if (src.grid.empty()) {
            if (floats.size() != 1)
                mapFail(src, "'" + src.path + "' holds " + std::to_string(floats.size()) +
                                 " float grids (" + names + "): name one with the *_map_grid key");
            base = floats[0];
        } else if (!base) {
            mapFail(src, "'" + src.path + "' has no grid '" + src.grid + "' (grids: " + names + ")");
        }
    } catch (const SceneError&) {
        throw;
    } catch (const std::exception& e) {
        mapFail(src, shortMessage(e.what(), 240));
    }
    auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
    if (!grid) mapFail(src, "grid '" + base->getName() + "' in '" + src.path + "' is " + base->type() + ", expected a float grid");
    const bool ls = grid->getGridClass() == openvdb::GRID_LEVEL_SET;
    if (requireUnit && !ls) {
        float mn = grid->background(), mx = grid->background();
        if (grid->activeVoxelCount() > 0) {
            const auto range = openvdb::tools::minMax(grid->tree());
            mn = std::min(mn, range.min());
            mx = std::max(mx, range.max());
        }
        if (!(mn >= 0.f && mx <= 1.f)) {
            std::ostringstream os;
            os << "grid '" << grid->getName() << "' in '" << src.path << "' has values in [" << mn << ", " << mx
               << "], expected [0, 1]";
            mapFail(src, os.str());
        }
    }
    VdbSampler s{&dom, grid.get(), src.indexSpace};
    if (!ls) {
        sampleDomain(dom, s, fn);
        return;
    }
    sampleDomain(dom, s, [&](const Coord& c, float v) { fn(c, v <= 0.f ? 1.f : 0.f); }); // inside = 1
}

std::unique_ptr<Effect> CrystalEffect::create(ParamDict& d, const World& world)
{
    auto fx = std::make_unique<CrystalEffect>();
    const Domain& dom = world.domain;
    ParamDict seedSchema("crystal.seed"), meltSchema("crystal.melt");
    readCrystalShape(seedSchema, dom, false);
    readCrystalShape(meltSchema, dom, true);
    // a scatter's PNG weight: relative to the scene file, and readable now (one line naming it)
    auto resolveWeight = [&](ParamDict& t, CrystalShape& s) {
        if (s.weight != CrystalShape::Weight::Texture) return;
        s.weightPath = resolveScenePath(s.weightPath, world.sceneLabel, t.origin("weight"));
        try {
            PngWeight check(s.weightPath);
        } catch (const std::exception& e) {
            t.fail("weight", "'" + s.weightPath + "': " + e.what());
        }
    };
    for (auto& t : d.getTables("seed", "seed shapes (p = 1): [[crystal.seed]] tables, see seed[].*", seedSchema)) {
        fx->mSeeds.push_back(readCrystalShape(t, dom, false));
        resolveWeight(t, fx->mSeeds.back());
    }
    for (auto& t : d.getTables("melt", "melt-map shapes: [[crystal.melt]] tables with a value, see melt[].*", meltSchema)) {
        fx->mMelt.push_back(readCrystalShape(t, dom, true));
        resolveWeight(t, fx->mMelt.back());
    }

    auto readMap = [&](const std::string& prefix, Map& m, const std::string& what) {
        std::string path = d.getString(prefix + "_map", "", {},
            what + ": a greyscale PNG (8/16-bit, stretched over the domain, row 0 = +y; per column in a box) "
                   "or a .vdb file (\"file.vdb:grid\" names the grid); relative to the scene file");
        std::string grid = d.getString(prefix + "_map_grid", "", {},
            "grid of a .vdb " + prefix + "_map (default: its only float grid)");
        const std::string space = d.getString(prefix + "_map_space", "world", {"world", "index"},
            "VDB " + prefix + " map: sample at world positions, or at our cell indices");
        if (const auto colon = path.rfind(".vdb:"); colon != std::string::npos) { // "file.vdb:grid"
            if (d.has(prefix + "_map_grid"))
                d.fail(prefix + "_map_grid", "the grid is already named in " + prefix + "_map (\"" + path + "\")");
            grid = path.substr(colon + 5);
            path = path.substr(0, colon + 4);
        }
        if (path.empty()) {
            if (d.has(prefix + "_map_grid")) d.fail(prefix + "_map_grid", "needs " + prefix + "_map");
            return;
        }
        m.has = true;
        m.src.path = resolveScenePath(path, world.sceneLabel, d.origin(prefix + "_map"));
        m.src.grid = grid;
        m.src.indexSpace = space == "index";
        m.src.key = "crystal." + prefix + "_map";
        if (auto o = d.origin(prefix + "_map")) m.src.origin = *o;
        if (!std::filesystem::exists(m.src.path))
            d.fail(prefix + "_map", "cannot find '" + m.src.path + "'");
        if (!endsWith(m.src.path, ".png") && !endsWith(m.src.path, ".vdb"))
            d.fail(prefix + "_map", "'" + m.src.path + "': expected a .png or .vdb file");
        if (m.src.isPng() && !grid.empty()) d.fail(prefix + "_map_grid", "applies to .vdb maps only");
    };
    readMap("seed", fx->mSeedMap, "seed crystal map: ice where the map >= seed_map_threshold (a VDB level set: inside)");
    fx->mSeedThreshold = d.getFloat("seed_map_threshold", 0.5, 0.0, 1.0, "",
                                    "seed map value from which a cell starts as ice");
    d.onlyWhen(fx->mSeedMap.has, "seed_map_threshold", "no seed_map");
    readMap("melt", fx->mMeltMap, "melting temperature map in [0,1]: 1 promotes growth, 0 suppresses it");
    fx->mMeltValue = d.getFloat("melt_value", 1.0, 0.0, 1.0, "",
                                "melt value wherever no melt map or melt shape says otherwise");
    const bool stretch = d.getBool("map_stretch", false,
                                   "stretch PNG maps whose aspect ratio differs from the domain's instead of refusing them");
    fx->mSeedMap.src.stretch = fx->mMeltMap.src.stretch = stretch;
    return fx;
}

FieldDeclaration CrystalEffect::declaration() const
{
    FieldDeclaration d;
    d.stage = Stage::Sources;
    if (hasSeeds()) d.use(kPhase, kInitialises);
    if (hasMelt()) d.use(kMelt, kInitialises);
    return d;
}

namespace {
/// Cells of a ball of radius @a r (cells) about @a c, clipped to @a box: per z layer, the
/// smaller of the layer's disc and the box's layer.
double ballCellsInBox(const Vec3d& c, double r, const openvdb::CoordBBox& box)
{
    if (box.empty()) return 0.0;
    const double rect = double(box.dim().x()) * double(box.dim().y());
    double n = 0;
    const double z0 = std::max(double(box.min().z()), std::floor(c.z() - r)),
                 z1 = std::min(double(box.max().z()), std::ceil(c.z() + r));
    for (double z = z0; z <= z1; z += 1.0) {
        const double dz = z - c.z(), rz2 = r * r - dz * dz;
        n += std::min(rect, 3.14159265358979 * std::max(rz2, 0.0) + 1.0);
    }
    return n;
}

/// Bytes a sparse float grid spends per stamped cell: 8^3 leaves of floats (2 KiB and their
/// masks), full where the stamp is thicker than a leaf, one layer of 64 cells on a flat domain.
double gridBytesPerCell(const openvdb::CoordBBox& box)
{
    const double layers = std::clamp(double(box.dim().z()), 1.0, 8.0);
    return 2200.0 / (64.0 * layers);
}
} // namespace

namespace {
/// stampShape, with what the domain refuses while it lays out the entry's cells (a shell builds
/// its band along the border for an edge band, held to run.memory_limit: ShellDomain) named at
/// the entry's key in one line, not at [crystal] (issue 25, finding 1).
void stampEntry(const Domain& dom, openvdb::FloatGrid& grid, const CrystalShape& s, float value)
{
    try {
        stampShape(dom, grid, s, value);
    } catch (const SceneError&) {
        throw;
    } catch (const std::runtime_error& e) {
        if (s.kind != CrystalShape::Kind::Edge || s.key.empty()) throw;
        std::string what = e.what();
        // the domain's message starts with the value it refuses (edges = "border": ...)
        if (what.rfind("edges = ", 0) == 0 && what.find(": ") != std::string::npos)
            what = what.substr(what.find(": ") + 2);
        std::string edges;
        for (const auto& n : s.edges) edges += (edges.empty() ? "" : ", ") + n;
        throw SceneError(s.origin.file, s.origin.line, s.key + ".edges",
                         "an edge band along \"" + edges + "\" " + std::to_string(int(std::ceil(s.width - 1e-9))) +
                             " cells wide: " + what + "; raise run.memory_limit or seed a smaller part");
    }
}
} // namespace

MemoryEstimate CrystalEffect::memoryEstimate(const World& world) const
{
    // Each shape is stamped cell by cell into a sparse grid (p or melt) before any effect runs.
    // A disc's radius is a fraction of the domain's bounds, so on a large shell its ball (clipped
    // to the bounds) can hold far more cells than any memory; so can a line or a scatter of
    // large discs. (A shell's border band is checked by the shell domain, which knows its border.)
    const Domain& dom = world.domain;
    const openvdb::CoordBBox& bb = dom.bbox();
    const double perCell = gridBytesPerCell(bb);
    double bytes = 0, biggest = -1, cells = 0;
    std::string key = "crystal.seed";
    auto add = [&](const CrystalShape& s, const std::string& table) {
        double n = 0;
        std::string k = table;
        switch (s.kind) {
        case CrystalShape::Kind::Point:
        case CrystalShape::Kind::Disc: {
            const Vec3d c = indexOf(dom, s.position, s.world);
            n = ballCellsInBox(c, s.radius, window(dom, c, c, s.radius));
            k += s.kind == CrystalShape::Kind::Disc ? ".radius_fraction" : ".radius";
            break;
        }
        case CrystalShape::Kind::Scatter: {
            const Vec3d c = bb.getCenter();
            n = double(s.count) * ballCellsInBox(c, s.radius, window(dom, c, c, s.radius));
            k += ".count";
            break;
        }
        case CrystalShape::Kind::Line: {
            const Vec3d a = indexOf(dom, s.from, s.world), b = indexOf(dom, s.to, s.world);
            const double hw = 0.5 * s.width;
            const Vec3d m = 0.5 * (a + b);
            n = ((geo(dom, b) - geo(dom, a)).length() + 1.0) * ballCellsInBox(m, hw, window(dom, m, m, hw)) /
                std::max(1.0, 2.0 * hw);
            k += ".width";
            break;
        }
        case CrystalShape::Kind::Edge: {
            const double w = std::max(1.0, std::ceil(s.width - 1e-9));
            const double x = bb.dim().x(), y = bb.dim().y(), z = bb.dim().z();
            if (dom.flat()) n = 2.0 * (x + y) * w;
            else if (dom.intrinsicDimension() == 3) n = 2.0 * (x * y + y * z + x * z) * w;
            k += ".width";
            break;
        }
        }
        cells += n;
        bytes += n * perCell;
        if (n > biggest) biggest = n, key = k;
    };
    for (const auto& s : mSeeds) add(s, s.key.empty() ? "crystal.seed" : s.key);
    for (const auto& s : mMelt) add(s, s.key.empty() ? "crystal.melt" : s.key);
    char detail[200];
    std::snprintf(detail, sizeof detail, "%.4g cells stamped by the seed and melt shapes x %.1f bytes in their sparse grids",
                  cells, perCell);
    return {bytes, key, detail};
}

void CrystalEffect::initialize(World& world)
{
    const Domain& dom = world.domain;
    if (hasSeeds()) {
        auto p = world.fields.require<openvdb::FloatGrid>(kPhase, 0.f);
        auto acc = p->getAccessor();
        if (mSeedMap.has)
            sampleMap(dom, mSeedMap.src, true, [&](const Coord& c, float v) {
                if (v >= float(mSeedThreshold)) acc.setValue(c, 1.f);
            });
        for (const auto& s : mSeeds) stampEntry(dom, *p, s, 1.f);
    }
    if (hasMelt()) {
        auto m = world.fields.require<openvdb::FloatGrid>(kMelt, 1.f);
        if (mMeltValue != 1.0) { // the value over the domain's support
            openvdb::MaskTree support;
            dom.fillSupport(support);
            m->setTree(std::make_shared<openvdb::FloatTree>(support, 1.f, float(mMeltValue), openvdb::TopologyCopy()));
        }
        if (mMeltMap.has) {
            auto acc = m->getAccessor();
            sampleMap(dom, mMeltMap.src, true, [&](const Coord& c, float v) {
                if (v != 1.f || acc.getValue(c) != 1.f) acc.setValue(c, v);
            });
        }
        for (const auto& s : mMelt) stampEntry(dom, *m, s, s.value);
        // Store only what differs from the background 1.
        // (serially: switching voxels off in parallel races on the leaves' mask words)
        openvdb::tools::foreach(m->beginValueOn(), [](const openvdb::FloatGrid::ValueOnIter& it) {
            if (*it == 1.f) it.setValueOff();
        }, /*threaded=*/false);
        openvdb::tools::pruneInactive(m->tree());
    }
}

} // namespace ice
} // namespace frostvdb
