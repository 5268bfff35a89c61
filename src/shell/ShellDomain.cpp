/// @file ShellDomain.cpp
/// @brief `[domain] kind = "shell"`: frost on objects. The support is a narrow band of voxels
/// around a triangle mesh (shell/ShellBand.h): one layer of surface nodes with least-squares
/// surface stencils (`discretisation = "surface"`, the default), or the closest point method's
/// thick band (`"closest_point"`, the reference) (shell/ShellPhaseField.h). The band is built lazily, leaf by leaf, where the ice and its
/// heat need it ([region] tolerance; dense = true builds it whole): memory follows the ice.
#include <frostvdb/shell/ShellDomain.h>
#include <frostvdb/shell/ShellBudget.h>

#include <frostvdb/core/Error.h>
#include <frostvdb/core/Random.h>
#include <frostvdb/io/InputFiles.h>
#include <frostvdb/io/Mesh.h>
#include <frostvdb/shell/ShellTexture.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <tuple>

namespace frostvdb {
namespace {

using openvdb::Vec3d;

class ShellDomain : public DomainImpl {
public:
    ShellDomain(std::shared_ptr<const shell::ShellBand> band, double spacing, const openvdb::CoordBBox& bounds,
                const TriangleMesh& mesh)
        : DomainImpl(Lattice(LatticeKind::Square, spacing), bounds, band->voxelSize(), /*withZ=*/true),
          mBand(std::move(band)), mMesh(mesh)
    {
        mTransform = mBand->transform();
        double sum = 0;
        for (size_t t = 0; t < mMesh.triangles.size(); ++t) mAreaCdf.push_back(sum += mMesh.area(t));
    }

    /// Area-weighted triangles, uniform barycentric points on them (index space), with the
    /// mesh's UVs and vertex-colour luminance there.
    std::vector<SupportSample> sampleSupport(size_t n, uint64_t seed) const override
    {
        std::vector<SupportSample> out(n);
        if (mAreaCdf.empty() || !(mAreaCdf.back() > 0)) return {};
        const double h = mBand->voxelSize();
        for (size_t k = 0; k < n; ++k) {
            const double pick = toUnit(hashCounters(seed, k, 0)) * mAreaCdf.back();
            const size_t t = size_t(std::upper_bound(mAreaCdf.begin(), mAreaCdf.end(), pick) - mAreaCdf.begin());
            const auto& f = mMesh.triangles[std::min(t, mMesh.triangles.size() - 1)];
            double a = toUnit(hashCounters(seed, k, 1)), b = toUnit(hashCounters(seed, k, 2));
            if (a + b > 1.0) { a = 1.0 - a; b = 1.0 - b; }
            const double w[3] = {1.0 - a - b, a, b};
            Vec3d p(0.0);
            openvdb::Vec2d uv(0.0);
            double lum = 0;
            for (int v = 0; v < 3; ++v) {
                p += Vec3d(mMesh.points[f[v]]) * w[v];
                if (!mMesh.uvs.empty()) uv += openvdb::Vec2d(mMesh.uvs[f[v]]) * w[v];
                if (!mMesh.colours.empty()) {
                    const auto& c = mMesh.colours[f[v]];
                    lum += w[v] * (0.2126 * c.x() + 0.7152 * c.y() + 0.0722 * c.z());
                }
            }
            out[k].index = p / h;
            out[k].uv = uv;
            out[k].hasUv = !mMesh.uvs.empty();
            out[k].colour = mMesh.colours.empty() ? -1.f : float(std::clamp(lum, 0.0, 1.0));
        }
        return out;
    }

    const std::shared_ptr<const shell::ShellBand>& band() const { return mBand; }
    const TriangleMesh& mesh() const { return mMesh; }

    std::string kind() const override { return "shell"; }
    /// The phase field and the walkers pick their shell back ends by it (ice/PhaseFieldBackend.h).
    std::string discretisation() const override { return mBand->surfaceNodes() ? "surface" : "closest_point"; }
    /// Band voxels, except the ghost ring beyond an open border (ShellBand::ghost).
    bool contains(const openvdb::Coord& c) const override
    {
        const int32_t i = mBand->indexOf(c);
        return i >= 0 ? !mBand->ghost(size_t(i)) : mBand->contains(c);
    }
    /// The voxels built so far: the whole band, or (sparse region) the band around the ice.
    uint64_t voxelCount() const override { return mBand->size(); }
    void clipToSupport(openvdb::MaskTree& mask) const override { mask.topologyIntersection(mBand->mask().tree()); }
    void fillSupport(openvdb::MaskTree& mask) const override { mask.topologyUnion(mBand->mask().tree()); }
    bool flat() const override { return false; }
    int intrinsicDimension() const override { return 2; }
    std::vector<openvdb::Coord> walkerNeighbours() const override
    {
        return {openvdb::Coord(-1, 0, 0), openvdb::Coord(1, 0, 0), openvdb::Coord(0, -1, 0),
                openvdb::Coord(0, 1, 0),  openvdb::Coord(0, 0, -1), openvdb::Coord(0, 0, 1)};
    }
    bool hasFrame() const override { return true; }
    VoxelFrame frame(const openvdb::Coord& c) const override { return mBand->frameAt(c); }
    /// Fractions of the band's bounds (x, y, z), moved to the closest point on the surface.
    int parameterDimension() const override { return 3; }
    Vec3d parameterToIndex(const std::vector<double>& u) const override
    {
        Vec3d p;
        for (int a = 0; a < 3; ++a) {
            const double f = size_t(a) < u.size() ? u[size_t(a)] : 0.5;
            p[a] = mBounds.min()[a] + f * (mBounds.max()[a] - mBounds.min()[a]);
        }
        return mBand->nearestSurfacePoint(p);
    }
    /// "border": an open mesh's boundary edges (a glass's rim); a closed mesh has none.
    std::vector<std::string> boundaryNames() const override { return {"border"}; }
    void forEachBoundaryVoxel(const std::string& name, int width,
                              const std::function<void(const openvdb::Coord&)>& fn) const override
    {
        if (name != "border") return;
        checkBorderBudget(double(width));
        for (size_t i : mBand->nearBorder(double(width))) fn(mBand->coord(i));
    }
    // Its phase field and walkers are back ends registered for "surface" and "closest_point"
    // (ShellPhaseFieldBackend.cpp, ShellDlaEffect.cpp); they keep their own invariants.

    // UV texture maps (shell/ShellTexture.h)
    const shell::SurfaceTextures* textures() const { return mTextures ? mTextures.get() : nullptr; }
    void setTextures(std::shared_ptr<const shell::SurfaceTextures> t) { mTextures = std::move(t); }

private:
    /// A lazy band builds its leaves along the whole border before the border's voxels are
    /// visited (ShellBand::nearBorder): the leaves within width + the half-width + 1 of each
    /// border edge, on both sides of it (the ghost ring beyond), about (twice that reach + a leaf)
    /// surface cells per voxel of border, at the band's bytes per surface cell (measured: a 1 m
    /// plate at 1 mm builds 53,433 nodes, 13.4 per voxel of border; estimated 17.2). Refused against run.memory_limit before they are built
    /// (issue 25, finding 1: a border seed on a large plate took gigabytes, then bad_alloc).
    void checkBorderBudget(double width) const
    {
        if (mBand->whole()) return;
        double length = 0;
        for (size_t e = 0; e < mBand->borderEdgeCount(); ++e) {
            const auto [a, b] = mBand->borderEdge(e);
            length += (b - a).length();
        }
        const double reach = width + mBand->halfWidth() + 1.0;
        const double cells = length * (2.0 * reach + 8.0);
        char what[200];
        std::snprintf(what, sizeof what, "the band along the mesh's %.4g m border (%.3g surface cells x %.0f bytes)",
                      length * mBand->voxelSize(), cells, mBand->bytesPerSurfaceCell());
        checkInputMemory("edges = \"border\"", cells * mBand->bytesPerSurfaceCell(), what);
    }

    std::shared_ptr<const shell::ShellBand> mBand;
    std::shared_ptr<const shell::SurfaceTextures> mTextures;
    TriangleMesh mMesh;            ///< world metres, for sampleSupport
    std::vector<double> mAreaCdf;  ///< running sum of the triangles' areas
};

Vec3d vec3(const std::vector<double>& v) { return Vec3d(v[0], v[1], v[2]); }

/// A mesh path as written, or relative to the folder of the scene file that names it.
std::string resolveMeshPath(const std::string& file, const ParamOrigin* origin)
{
    namespace fs = std::filesystem;
    if (file.empty() || fs::path(file).is_absolute() || !origin) return file;
    const fs::path beside = fs::path(origin->file).parent_path() / file;
    if (fs::exists(beside)) return beside.string();
    return file;
}

Domain readShell(ParamDict& d, const DomainCommon& c)
{
    const std::string file = d.getString("mesh", "", {},
        "mesh file (OBJ, STL, PLY, ... through Assimp), relative to the scene file; open or closed. Empty: a "
        "built-in icosphere of radius sphere_radius");
    const double radius = d.getFloat("sphere_radius", 0.002, 1e-6, 1e3, "m",
                                     "radius of the built-in icosphere (mesh = \"\")");
    d.onlyWhen(file.empty(), "sphere_radius", "mesh = \"" + file + "\"");
    MeshPlacement m;
    const auto s = d.getFloatArray("mesh_scale", {1.0}, {1, 3}, -1e6, 1e6, "",
                                   "scale of the mesh (one factor or x, y, z), applied first");
    m.scale = s.size() == 1 ? Vec3d(s[0]) : vec3(s);
    m.rotateDegrees = vec3(d.getFloatArray("mesh_rotate", {0, 0, 0}, {3}, -3600, 3600, "deg",
                                           "rotation of the mesh about x, then y, then z"));
    m.translate = vec3(d.getFloatArray("mesh_translate", {0, 0, 0}, {3}, -1e6, 1e6, "m",
                                       "translation of the mesh, applied last"));
    shell::BandSettings bs;
    bs.voxelSize = c.voxelSize;
    const auto axis = d.getFloatArray("crystal_axis", {1, 0, 0}, {3}, -1e6, 1e6, "",
        "world direction of the crystal axis (theta = 0 of the anisotropy), projected on each tangent plane; "
        "where it is within 3 degrees of the normal, the next axis (crystal_axis x normal's dominant axis) is used");
    bs.crystalAxis = vec3(axis);
    if (bs.crystalAxis.length() < 1e-12) d.fail("crystal_axis", "must not be the zero vector");
    bs.crystalAxis.normalize();
    bs.frostThickness = d.getFloat("frost_thickness", 2.0, 0.0, 4.5, "voxels",
        "thickness of the output frost layer (ice, ice_sdf) where the accumulated growth has reached 1; it grows "
        "outward along the mesh's normals (at most 4.5: the band's half-width less one)");
    const std::string colours = d.getString("vertex_colours", "none", {"none", "seed", "melt"},
        "what the mesh's vertex colours (luminance, interpolated across triangles) control: nothing; seed: ice "
        "where the luminance exceeds 1/2; melt: the melt map (T_e scale = luminance; 0 keeps a patch clear)");
    bs.colourUse = colours == "seed"   ? shell::BandSettings::ColourUse::Seed
                   : colours == "melt" ? shell::BandSettings::ColourUse::Melt
                                       : shell::BandSettings::ColourUse::None;
    const std::string seedTexture = d.getString("seed_texture", "", {},
        "PNG texture (luminance through the mesh's UVs at each closest point), relative to the scene file: ice "
        "where it exceeds 1/2 (as vertex_colours = \"seed\"); empty: none");
    const std::string meltTexture = d.getString("melt_texture", "", {},
        "PNG texture through the mesh's UVs: the melt map (T_e scale = luminance, 0 keeps a patch clear; with "
        "[dla] the sticking probability), multiplied with vertex_colours = \"melt\" and the melt field; empty: none");
    const std::string disc = d.getString("discretisation", "surface", {"surface", "closest_point"},
        "how surface operators are discretised (docs/shells.md): surface = one layer of voxels on the surface with "
        "precomputed least-squares surface stencils, about the plane's cost per surface cell; closest_point = a band "
        "5.5 voxels thick with the tricubic closest-point extension, the reference (needed by phase_field.scheme = "
        "\"lw_cn\" and phase_field.wind_model = \"potential\")");
    bs.discretisation = disc == "surface" ? shell::BandSettings::Discretisation::SurfaceNodes
                                          : shell::BandSettings::Discretisation::ClosestPoint;
    // secondary axis: perpendicular to the first, fixed by it alone
    Vec3d sec = std::fabs(bs.crystalAxis.z()) < 0.9 ? Vec3d(0, 0, 1) : Vec3d(0, 1, 0);
    bs.secondaryAxis = sec.cross(bs.crystalAxis).unit();

    TriangleMesh mesh;
    const std::string path = resolveMeshPath(file, d.origin("mesh"));
    try {
        if (file.empty()) {
            mesh = makeIcosphere(radius, 5);
            mesh.transform(m);
        } else {
            mesh = loadMesh(path, m);
        }
        // placed, against the voxel size: smaller than a voxel, or too far out for float positions
        if (const std::string why = mesh.collapseProblem(MeshPlacement{}, c.voxelSize); !why.empty())
            d.fail(file.empty() ? "sphere_radius" : "mesh", (file.empty() ? std::string() : path + ": ") + why);
        if (colours != "none" && mesh.colours.empty())
            d.fail("vertex_colours", path + ": the mesh has no vertex colours (allowed: none)");
        // Leaves are built where the ice needs them ([region] dense = true builds them all).
        auto band = shell::ShellBand::buildLazy(mesh, bs);
        if (bs.colourUse == shell::BandSettings::ColourUse::Seed) { // the bright triangles' leaves
            std::vector<uint32_t> bright;
            auto lum = [&](uint32_t v) {
                const auto& col = mesh.colours[v];
                return 0.2126 * col.x() + 0.7152 * col.y() + 0.0722 * col.z();
            };
            for (uint32_t t = 0; t < mesh.triangles.size(); ++t)
                for (int v = 0; v < 3; ++v)
                    if (lum(mesh.triangles[t][v]) > 0.5) { bright.push_back(t); break; }
            band->materialiseTriangles(bright);
        }
        auto dom = std::make_shared<ShellDomain>(band, c.spacing, band->bounds(), mesh);
        if (!seedTexture.empty() || !meltTexture.empty()) {
            // sampled per voxel on demand (shell/ShellTexture.h): the band grows after this
            std::shared_ptr<shell::SurfaceTextures> maps;
            try {
                maps = std::make_shared<shell::SurfaceTextures>(mesh);
            } catch (const std::exception& e) {
                d.fail(seedTexture.empty() ? "melt_texture" : "seed_texture", e.what());
            }
            for (const auto& [key, file, target] : {std::make_tuple("seed_texture", seedTexture, &maps->seed),
                                                    std::make_tuple("melt_texture", meltTexture, &maps->melt)}) {
                if (file.empty()) continue;
                try {
                    *target = std::make_shared<const shell::Texture>(shell::loadTexture(resolveMeshPath(file, d.origin(key))));
                } catch (const std::exception& e) {
                    d.fail(key, e.what());
                }
            }
            // every leaf that can hold a texture seed is built now, so the seeds are all stamped
            if (maps->seed) band->materialiseTriangles(maps->seedTriangles());
            dom->setTextures(maps);
        }
        return Domain(dom);
    } catch (const SceneError&) {
        throw; // already names its key
    } catch (const std::runtime_error& e) {
        d.fail("mesh", e.what());
    }
}

} // namespace

namespace shell {

std::shared_ptr<const ShellBand> bandOf(const Domain& domain)
{
    if (!domain) return nullptr;
    const auto* s = dynamic_cast<const ShellDomain*>(&domain.impl());
    return s ? s->band() : nullptr;
}

const SurfaceTextures* texturesOf(const Domain& domain)
{
    if (!domain) return nullptr;
    const auto* s = dynamic_cast<const ShellDomain*>(&domain.impl());
    return s ? s->textures() : nullptr;
}

double wholeBandCells(const Domain& domain)
{
    if (!domain) return 0.0;
    const auto* s = dynamic_cast<const ShellDomain*>(&domain.impl());
    if (!s) return 0.0;
    const ShellBand& band = *s->band();
    const TriangleMesh& mesh = s->mesh();
    // A surface-node band keeps the voxels within kLayerReach of the mesh: a slab 2 kLayerReach
    // thick holds that many voxel centres per cell on average, whatever its orientation, except
    // when it lies in a lattice plane: then it holds the whole layers within reach of its offset.
    // (The closest-point band's voxels within its half-width: the same reasoning, 11.5 per cell,
    // already in its bytes per cell.)
    if (!band.surfaceNodes()) return band.surfaceVoxels();
    const double reach = kLayerReach, h = band.voxelSize();
    double area = 0, weighted = 0;
    for (size_t t = 0; t < mesh.triangles.size(); ++t) {
        const auto& f = mesh.triangles[t];
        const Vec3d a(mesh.points[f[0]]), b(mesh.points[f[1]]), c(mesh.points[f[2]]);
        Vec3d n = (b - a).cross(c - a);
        const double twice = n.length();
        if (!(twice > 0)) continue;
        n /= twice;
        double layers = 2.0 * reach;
        for (int k = 0; k < 3; ++k)
            if (std::fabs(n[k]) > 1.0 - 1e-9) {
                const double d = a[k] / h; // the plane's offset in voxels (voxel centres at integers)
                layers = std::floor(d + reach) - std::ceil(d - reach) + 1.0;
            }
        area += 0.5 * twice;
        weighted += 0.5 * twice * layers;
    }
    return area > 0 ? band.surfaceVoxels() * weighted / (area * 2.0 * reach) : band.surfaceVoxels();
}

MemoryEstimate wholeBandEstimate(const Domain& domain)
{
    const auto band = bandOf(domain);
    if (!band) return {};
    return perVoxelEstimate(wholeBandCells(domain), band->bytesPerSurfaceCell(), "domain.voxel_size",
                            "the whole shell band and the arrays stepped on it, per surface cell (mesh area / "
                            "voxel_size^2)");
}

Domain makeShellDomain(const TriangleMesh& mesh, const BandSettings& settings, double spacing)
{
    auto band = ShellBand::build(mesh, settings);
    return Domain(std::make_shared<ShellDomain>(band, spacing, band->bounds(), mesh));
}

} // namespace shell

FROSTVDB_REGISTER_DOMAIN(shell, "shell", "a narrow band of voxels around a mesh: frost on objects", readShell);

} // namespace frostvdb
