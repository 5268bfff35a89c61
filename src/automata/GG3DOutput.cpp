/// @file GG3DOutput.cpp
/// @brief The OpenVDB side of [gravner_griffeath_3d]: `cells` / `freeze_time` on the prism
/// lattice, `automaton_ice` (prisms resampled to cubic voxels), `ice_sdf` (tools::topologyToLevelSet),
/// mesh files (tools::volumeToMesh), a ray-marched preview of the level set, and the effect's
/// addToFrame and registration.
#include <frostvdb/automata/GG3DEffect.h>
#include <frostvdb/geometry/HexTransform.h>
#include <frostvdb/io/Png.h>

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/TopologyToLevelSet.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <tbb/parallel_for.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <stdexcept>

namespace frostvdb {
namespace automata {

namespace {


/// `automaton_ice`: each voxel takes the state of the prism containing its centre. Slabs of voxel rows
/// in parallel, each into its own tree, merged in slab order (deterministic).
openvdb::FloatGrid::Ptr resampleIce(const GG3D& a, const GG3DOutput& out, double h)
{
    auto ice = openvdb::FloatGrid::create(0.0f);
    const double vs = h / out.voxelsPerCell;
    ice->setTransform(openvdb::math::Transform::createLinearTransform(vs));
    const int R = a.crystalRadius();
    if (R < 0) return ice;
    const double layerH = out.prismHeight * h;
    const int m = a.mirror();
    const int lz0 = a.crystalZMin(), lz1 = a.crystalZMax();
    const int X = int(std::ceil((R + 1.0) * h / vs)) + 1;
    const int Z0 = int(std::floor(((lz0 - 0.5 * m) - 0.5) * layerH / vs)) - 1;
    const int Z1 = int(std::ceil(((lz1 - 0.5 * m) + 0.5) * layerH / vs)) + 1;
    const int nRows = 2 * X + 1, slab = 32, nSlabs = (nRows + slab - 1) / slab;
    std::vector<openvdb::FloatTree::Ptr> trees(static_cast<size_t>(nSlabs));
    tbb::parallel_for(0, nSlabs, [&](int si) {
        auto tree = std::make_shared<openvdb::FloatTree>(0.0f);
        openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(*tree);
        std::vector<uint8_t> column(size_t(lz1 - lz0 + 1));
        for (int yi = si * slab; yi < std::min(nRows, (si + 1) * slab); ++yi) {
            const int y = yi - X;
            for (int x = -X; x <= X; ++x) {
                const Axial c = cellAt(x * vs / h, y * vs / h);
                if (hexDistance(c.q, c.r) > R) continue;
                bool any = false;
                for (int l = lz0; l <= lz1; ++l) any |= (column[size_t(l - lz0)] = a.attached(c.q, c.r, l)) != 0;
                if (!any) continue;
                for (int z = Z0; z <= Z1; ++z) {
                    const int l = int(std::floor(z * vs / layerH + 0.5 * m + 0.5));
                    if (l >= lz0 && l <= lz1 && column[size_t(l - lz0)])
                        acc.setValue(openvdb::Coord(x, y, z), 1.0f);
                }
            }
        }
        trees[size_t(si)] = tree;
    });
    for (auto& t : trees) ice->tree().merge(*t, openvdb::MERGE_ACTIVE_STATES_AND_NODES);
    return ice;
}

/// Sphere-traced, Lambert + rim shaded picture of a level set, seen obliquely from above.
void renderLevelSet(const openvdb::FloatGrid& sdf, const std::string& path, int width)
{
    const auto bb = sdf.evalActiveVoxelBoundingBox();
    const auto& xf = sdf.transform();
    const openvdb::Vec3d lo = xf.indexToWorld(bb.min()), hi = xf.indexToWorld(bb.max());
    const openvdb::Vec3d centre = 0.5 * (lo + hi);
    const double radius = 0.5 * (hi - lo).length() * 1.02;
    const double vs = xf.voxelSize()[0];
    const double elev = 40.0 * M_PI / 180.0, azim = -25.0 * M_PI / 180.0;
    const openvdb::Vec3d dir(-std::cos(elev) * std::sin(azim), std::cos(elev) * std::cos(azim), -std::sin(elev));
    const openvdb::Vec3d fwd = -dir; // camera looks along -fwd... keep explicit below
    openvdb::Vec3d right = openvdb::Vec3d(0, 0, 1).cross(dir);
    right.normalize();
    openvdb::Vec3d up = dir.cross(right);
    up.normalize();
    const openvdb::Vec3d light = openvdb::Vec3d(0.4, -0.3, 0.85).unitSafe();
    const int W = width, H = width;
    ImageRGB img(W, H);
    tbb::parallel_for(0, H, [&](int py) {
        openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> s(
            sdf.getConstAccessor(), xf);
        for (int px = 0; px < W; ++px) {
            const double u = (2.0 * (px + 0.5) / W - 1.0) * radius, v = (1.0 - 2.0 * (py + 0.5) / H) * radius;
            const openvdb::Vec3d o = centre + right * u + up * v - dir * radius * 1.5;
            // March only inside the level set's bounding box (slab test).
            double t = 0.0, tEnd = 1e300;
            for (int a = 0; a < 3; ++a) {
                const double lo2 = lo[a] - 4 * vs, hi2 = hi[a] + 4 * vs;
                if (std::abs(dir[a]) < 1e-12) {
                    if (o[a] < lo2 || o[a] > hi2) tEnd = -1.0;
                    continue;
                }
                double t0 = (lo2 - o[a]) / dir[a], t1 = (hi2 - o[a]) / dir[a];
                if (t0 > t1) std::swap(t0, t1);
                t = std::max(t, t0);
                tEnd = std::min(tEnd, t1);
            }
            bool hit = false;
            openvdb::Vec3d p;
            for (int it = 0; it < 4000 && t < tEnd; ++it) {
                p = o + dir * t;
                const double dist = s.wsSample(p);
                if (dist < 0.05 * vs) { hit = true; break; }
                t += std::max(0.5 * dist, 0.2 * vs);
            }
            const float bgc = float(0.05 + 0.08 * (py / double(H)));
            if (!hit) { img.set(px, py, bgc, bgc * 1.1f, bgc * 1.6f); continue; }
            const double e = vs;
            openvdb::Vec3d n(s.wsSample(p + openvdb::Vec3d(e, 0, 0)) - s.wsSample(p - openvdb::Vec3d(e, 0, 0)),
                             s.wsSample(p + openvdb::Vec3d(0, e, 0)) - s.wsSample(p - openvdb::Vec3d(0, e, 0)),
                             s.wsSample(p + openvdb::Vec3d(0, 0, e)) - s.wsSample(p - openvdb::Vec3d(0, 0, e)));
            n = n.unitSafe();
            const double diff = std::max(0.0, n.dot(light));
            const double rim = std::pow(1.0 - std::abs(n.dot(dir)), 3.0);
            const openvdb::Vec3d hv = (light - dir).unitSafe();
            const double spec = std::pow(std::max(0.0, n.dot(hv)), 40.0);
            const double k = 0.18 + 0.62 * diff;
            img.set(px, py, float(0.70 * k + 0.35 * rim + 0.5 * spec), float(0.82 * k + 0.40 * rim + 0.5 * spec),
                    float(0.95 * k + 0.50 * rim + 0.5 * spec));
        }
    });
    (void)fwd;
    writePngRGB(path, img);
}
} // namespace

GG3DGrids buildGG3DGrids(const GG3D& a, const GG3DOutput& out, double h)
{
    GG3DGrids g;
    auto xf = hex::prismTransform(h, out.prismHeight * h, -0.5 * a.mirror() * (out.prismHeight * h)); // layer m/2 at z = 0
    g.cells = openvdb::FloatGrid::create(0.0f);
    g.cells->setTransform(xf->copy());
    g.freeze = openvdb::FloatGrid::create(-1.0f);
    g.freeze->setTransform(xf->copy());
    auto cacc = g.cells->getAccessor();
    auto facc = g.freeze->getAccessor();
    const int R = a.crystalRadius();
    for (int z = a.crystalZMin(); R >= 0 && z <= a.crystalZMax(); ++z)
        for (int r = -R; r <= R; ++r)
            for (int q = -R; q <= R; ++q) {
                if (hexDistance(q, r) > R || !a.attached(q, r, z)) continue;
                cacc.setValue(openvdb::Coord(q, r, z), float(a.boundaryMass(q, r, z)));
                facc.setValue(openvdb::Coord(q, r, z), float(a.attachStep(q, r, z)));
            }
    g.ice = resampleIce(a, out, h);
    g.ice->setGridClass(openvdb::GRID_FOG_VOLUME);
    if (out.sdf) {
        if (g.ice->activeVoxelCount() > 0) {
            g.sdf = openvdb::tools::topologyToLevelSet(*g.ice, 3, 0, 0, out.sdfSmoothing);
        } else {
            g.sdf = openvdb::FloatGrid::create(float(3 * g.ice->voxelSize()[0]));
            g.sdf->setTransform(g.ice->transform().copy());
        }
        g.sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    }
    return g;
}

void writeGG3DMesh(const openvdb::FloatGrid& sdf, const std::string& path, double adaptivity)
{
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> tris;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(sdf, points, tris, quads, 0.0, adaptivity);
    const bool ply = path.size() > 4 && path.substr(path.size() - 4) == ".ply";
    const std::string tmp = path + ".tmp";
    {
        std::ofstream f(tmp);
        if (!f) throw std::runtime_error("cannot write " + path);
        // VolumeToMesh winds faces inward for a level set (negative inside): reverse them.
        if (ply) {
            f << "ply\nformat ascii 1.0\nelement vertex " << points.size()
              << "\nproperty float x\nproperty float y\nproperty float z\nelement face " << tris.size() + quads.size()
              << "\nproperty list uchar int vertex_indices\nend_header\n";
            for (const auto& p : points) f << p[0] << ' ' << p[1] << ' ' << p[2] << '\n';
            for (const auto& t : tris) f << "3 " << t[2] << ' ' << t[1] << ' ' << t[0] << '\n';
            for (const auto& q : quads) f << "4 " << q[3] << ' ' << q[2] << ' ' << q[1] << ' ' << q[0] << '\n';
        } else {
            f << "# frostvdb gravner_griffeath_3d crystal surface\n";
            for (const auto& p : points) f << "v " << p[0] << ' ' << p[1] << ' ' << p[2] << '\n';
            for (const auto& t : tris) f << "f " << t[2] + 1 << ' ' << t[1] + 1 << ' ' << t[0] + 1 << '\n';
            for (const auto& q : quads)
                f << "f " << q[3] + 1 << ' ' << q[2] + 1 << ' ' << q[1] + 1 << ' ' << q[0] + 1 << '\n';
        }
    }
    std::rename(tmp.c_str(), path.c_str());
}

namespace {
/// Attached cells of a flake (what its frame grids are made of).
double attachedCells(const GG3D& a)
{
    double n = 0;
    const int R = a.crystalRadius();
    for (int z = a.crystalZMin(); R >= 0 && z <= a.crystalZMax(); ++z)
        for (int r = -R; r <= R; ++r)
            for (int q = -R; q <= R; ++q) n += hexDistance(q, r) <= R && a.attached(q, r, z) ? 1.0 : 0.0;
    return n;
}

/// Refuses a frame whose grids would not fit run.memory_limit, from the crystal's attached cells
/// counted before a grid is built: the keys cannot bound how far a crystal grows (the scene's
/// estimate counts its seed's grids). At the output's peak, measured with voxels_per_cell 3:
/// 1,000-1,300 bytes per attached cell (automaton_ice, ice_sdf and the mask and filter trees
/// topologyToLevelSet makes), 13 MiB of top nodes per flake, and the solver's arrays.
void checkFrameBudget(const std::vector<std::unique_ptr<GG3D>>& flakes, const GG3DOutput& out, const World& world,
                      int64_t frame)
{
    constexpr double kBytesPerCellVoxel = 50.0, kTopNodesPerFlake = 13.5 * 1048576.0, kSolverBytesPerCell = 38.0;
    double cells = 0, solver = 0;
    for (const auto& f : flakes) {
        cells += attachedCells(*f);
        solver += double(f->storageSize()) * kSolverBytesPerCell;
    }
    const double perCell = kBytesPerCellVoxel * std::pow(double(out.voxelsPerCell), 3.0) * out.prismHeight;
    const double flakeGrids = double(flakes.size()) + (flakes.size() > 1 ? 1.0 : 0.0);
    char what[240];
    std::snprintf(what, sizeof what,
                  "frame %lld: the grids of %.4g attached cells at voxels_per_cell %d, and the solver's arrays",
                  static_cast<long long>(frame), cells, out.voxelsPerCell);
    checkMemoryEstimate({cells * perCell + flakeGrids * kTopNodesPerFlake + solver,
                         "gravner_griffeath_3d.voxels_per_cell", what},
                        world.memoryLimitBytes, world.sceneLabel);
}
} // namespace

void GG3DEffect::addToFrame(World& world, Frame& frame)
{
    const auto t0 = std::chrono::steady_clock::now();
    checkFrameBudget(mFlakes, mOut, world, frame.frame);
    const double h = mCellSize;
    const int K = int(mFlakes.size());
    GG3DGrids all;
    for (int k = 0; k < K; ++k) {
        const GG3D& a = *mFlakes[size_t(k)];
        GG3DGrids one = buildGG3DGrids(a, mOut, h);
        one.cells->insertMeta("rule", openvdb::StringMetadata("gravner_griffeath_3d"));
        one.cells->insertMeta("preset", openvdb::StringMetadata(mPreset));
        one.cells->insertMeta("lattice", openvdb::StringMetadata(
            "hexagonal prisms, index (q, r, layer), world = h*(q + r/2, r*sqrt(3)/2, (layer - m/2)*prism_height)"));
        one.cells->insertMeta("unit", openvdb::StringMetadata("mass b of attached cells"));
        one.freeze->insertMeta("unit", openvdb::StringMetadata("steps"));
        if (K == 1) {
            all = one;
            break;
        }
        for (auto* g : {&one.cells, &one.freeze, &one.ice, &one.sdf})
            if (*g)
                frame.add(*g == one.cells    ? out::kCells
                          : *g == one.freeze ? out::kFreezeStep
                          : *g == one.ice    ? out::kAutomatonIce
                                             : out::kIceSdf,
                          *g, "_" + std::to_string(k));
        // Side by side along x, 2R + 4 cells apart (R = domain radius).
        const int shift = k * (2 * mCfg.domainRadius + 4);
        auto place = [&](openvdb::FloatGrid::Ptr& dst, const openvdb::FloatGrid::Ptr& src, int dx) {
            if (!src) return;
            if (!dst) {
                dst = openvdb::FloatGrid::create(src->background());
                dst->setTransform(src->transform().copy());
                dst->setGridClass(src->getGridClass());
                dst->insertMeta(*src);
            }
            auto acc = dst->getAccessor();
            for (auto it = src->cbeginValueOn(); it; ++it) {
                openvdb::CoordBBox b;
                it.getBoundingBox(b);
                for (auto c = b.begin(); c; ++c) acc.setValue(*c + openvdb::Coord(dx, 0, 0), *it);
            }
        };
        place(all.cells, one.cells, shift);
        place(all.freeze, one.freeze, shift);
        place(all.ice, one.ice, shift * mOut.voxelsPerCell);
        if (mOut.sdf && one.sdf) {
            // The combined level set is rebuilt from the combined fog below.
        }
    }
    if (K > 1 && mOut.sdf && all.ice && all.ice->activeVoxelCount() > 0)
        all.sdf = openvdb::tools::topologyToLevelSet(*all.ice, 3, 0, 0, mOut.sdfSmoothing);
    frame.add(out::kCells, all.cells);
    frame.add(out::kFreezeStep, all.freeze);
    all.ice->pruneGrid();
    frame.add(out::kAutomatonIce, all.ice);
    if (mOut.sdf && all.sdf) {
        all.sdf->setGridClass(openvdb::GRID_LEVEL_SET);
        frame.add(out::kIceSdf, all.sdf);
        if (mOut.mesh != "none" && all.sdf->activeVoxelCount() > 0) {
            std::string path = mOut.meshPath.empty() ? world.sceneName + "_gg3d." + mOut.mesh : mOut.meshPath;
            const auto dot = path.rfind('.');
            const std::string stem = dot == std::string::npos ? path : path.substr(0, dot);
            path = stem + "." + std::to_string(frame.frame) + "." + mOut.mesh;
            openvdb::FloatGrid::Ptr m = all.sdf;
            const double worldScale = world.worldScale;
            if (worldScale != 1.0) {
                m = all.sdf->deepCopy();
                auto x = m->transform().copy();
                x->postScale(worldScale);
                m->setTransform(x);
            }
            writeGG3DMesh(*m, path, mOut.meshAdaptivity);
        }
    }
    mOutputSeconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void renderGG3DPreview(const openvdb::FloatGrid& sdf, const std::string& path, int width)
{
    renderLevelSet(sdf, path, width);
}

FROSTVDB_REGISTER_EFFECT(GG3DEffect, "gravner_griffeath_3d",
    "Gravner-Griffeath (2009) 3D snow crystal as published: hexagonal prisms, 7 neighbour configurations, "
    "the paper's cases as presets");

} // namespace automata
} // namespace frostvdb
