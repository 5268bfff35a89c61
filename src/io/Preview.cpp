#include <frostvdb/io/Preview.h>
#include <frostvdb/io/Png.h>

#include <openvdb/tools/Count.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/RayTracer.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace frostvdb {

namespace {

/// Icy colour ramp: deep navy -> steel blue -> white.
openvdb::Vec3f iceRamp(float v)
{
    v = std::clamp(v, 0.f, 1.f);
    const openvdb::Vec3f a(0.02f, 0.03f, 0.08f), b(0.25f, 0.45f, 0.70f), c(0.95f, 0.98f, 1.0f);
    return v < 0.5f ? a + (b - a) * (v * 2.f) : b + (c - b) * ((v - 0.5f) * 2.f);
}

/// The top view of a flat field: its active index box @a bbox, its largest active value
/// @a vmax (or the options'), and a per-thread sampler by index-space point.
template <typename MakeSampler>
void flatPreview(const openvdb::math::Transform& xf, const MakeSampler& makeSampler, float dataMax,
                 const std::string& path, const PreviewOptions& opt, const openvdb::CoordBBox& bbox)
{
    // World-space xy bounds of the active index box (corners of a possibly sheared box).
    openvdb::Vec3d lo(1e300), hi(-1e300);
    for (int c = 0; c < 4; ++c) {
        const openvdb::Vec3d ip((c & 1) ? bbox.max().x() + 0.5 : bbox.min().x() - 0.5,
                                (c & 2) ? bbox.max().y() + 0.5 : bbox.min().y() - 0.5, bbox.min().z());
        const auto w = xf.indexToWorld(ip);
        lo = openvdb::math::minComponent(lo, w);
        hi = openvdb::math::maxComponent(hi, w);
    }
    const double spanX = std::max(hi.x() - lo.x(), 1e-12), spanY = std::max(hi.y() - lo.y(), 1e-12);
    const int W = opt.width;
    const int H = std::max(1, int(std::lround(W * spanY / spanX)));
    std::vector<float> val(size_t(W) * H);
    const float vmax = opt.valueMax > 0.f ? opt.valueMax : std::max(dataMax, 1e-6f);
    tbb::parallel_for(0, H, [&](int y) {
        const auto sample = makeSampler(); // GridSampler::wsSample: the sampler at worldToIndex
        const double z = xf.indexToWorld(openvdb::Vec3d(0, 0, bbox.min().z())).z();
        for (int x = 0; x < W; ++x) {
            const double wx = lo.x() + (x + 0.5) / W * spanX;
            const double wy = hi.y() - (y + 0.5) / H * spanY; // row 0 at the top
            val[size_t(y) * W + x] = sample(xf.worldToIndex(openvdb::Vec3d(wx, wy, z))) / vmax;
        }
    });
    ImageRGB img(W, H);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const float v = val[size_t(y) * W + x];
            openvdb::Vec3f c = iceRamp(v);
            if (opt.shade) { // hill shading of the value as a height field, light from upper left
                const float vx = val[size_t(y) * W + std::min(x + 1, W - 1)] - val[size_t(y) * W + std::max(x - 1, 0)];
                const float vy = val[size_t(std::min(y + 1, H - 1)) * W + x] - val[size_t(std::max(y - 1, 0)) * W + x];
                const float shade = std::clamp(1.0f + 2.0f * (-vx + vy), 0.55f, 1.35f);
                c *= shade;
            }
            img.set(x, y, c.x(), c.y(), c.z());
        }
    writePngRGB(path, img);
}

void volumePreview(const openvdb::FloatGrid& grid, const std::string& path, const PreviewOptions& opt,
                   const openvdb::CoordBBox& bbox)
{
    using namespace openvdb;
    const auto& xf = grid.transform();
    const Vec3d wmin = xf.indexToWorld(bbox.min().asVec3d() - Vec3d(0.5));
    const Vec3d wmax = xf.indexToWorld(bbox.max().asVec3d() + Vec3d(0.5));
    const Vec3d centre = 0.5 * (wmin + wmax);
    const double radius = 0.5 * (wmax - wmin).length();
    const int W = opt.width, H = opt.width * 3 / 4;
    tools::Film film(W, H);
    // Camera in front (-y looking +y... ) raised a little; up is +z for volumes built on the xy plane.
    const double dist = radius / std::tan(0.5 * 2 * std::atan(41.2136 / (2 * 50.0))) * 1.15;
    const Vec3d eye = centre + Vec3d(0.0, -0.85, 0.5).unit() * dist;
    tools::PerspectiveCamera cam(film, Vec3d(0.0), eye, 50.0, 41.2136, 1e-6, 1e9);
    cam.lookAt(centre, Vec3d(0, 0, 1));
    using Intersector = tools::VolumeRayIntersector<FloatGrid>;
    Intersector inter(grid);
    tools::VolumeRender<Intersector> renderer(inter, cam);
    const double norm =
        opt.valueMax > 0 ? opt.valueMax : std::max(1e-6f, openvdb::tools::minMax(grid.tree()).max());
    // Extinction scaled so the volume's densest part is opaque over ~8 voxels.
    const double k = 1.0 / (norm * 8.0 * xf.voxelSize()[0]);
    renderer.setLightDir(0.3, -0.4, 1.0);
    renderer.setLightColor(1.0, 1.0, 1.0);
    renderer.setPrimaryStep(0.5);
    renderer.setShadowStep(2.0);
    renderer.setScattering(1.4 * k, 1.5 * k, 1.6 * k);
    renderer.setAbsorption(0.1 * k, 0.08 * k, 0.05 * k);
    renderer.setLightGain(0.3);
    renderer.setCutOff(0.005);
    renderer.render(true);
    ImageRGB img(W, H);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const auto& p = film.pixel(x, y);
            // Composite over a dark gradient background.
            const float bg = 0.05f + 0.10f * float(y) / H;
            const float a = std::clamp(p.a, 0.f, 1.f);
            img.set(x, y, p.r + (1 - a) * bg, p.g + (1 - a) * bg, p.b + (1 - a) * (bg * 1.6f));
        }
    writePngRGB(path, img);
}

} // namespace

void writePreview(const openvdb::GridBase& base, const std::string& pngPath, const PreviewOptions& opt)
{
    auto grid = dynamic_cast<const openvdb::FloatGrid*>(&base);
    if (!grid) throw std::runtime_error("preview: grid '" + base.getName() + "' is not a float grid");
    openvdb::CoordBBox bbox = grid->evalActiveVoxelBoundingBox();
    if (bbox.empty()) bbox = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(7, 7, 0));
    if (bbox.dim().z() > 1) return volumePreview(*grid, pngPath, opt, bbox);
    const float dataMax = opt.valueMax > 0.f ? 0.f : openvdb::tools::minMax(grid->tree()).max();
    auto makeSampler = [grid] {
        return [acc = grid->getConstAccessor()](const openvdb::Vec3d& p) {
            float v = 0.f;
            openvdb::tools::BoxSampler::sample(acc, p, v);
            return v;
        };
    };
    flatPreview(grid->transform(), makeSampler, dataMax, pngPath, opt, bbox);
}

void writeFlatPreview(const FlatPreviewSource& src, const std::string& pngPath, const PreviewOptions& opt)
{
    const openvdb::CoordBBox bbox = src.bbox.empty() ? openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(7, 7, 0)) : src.bbox;
    flatPreview(*src.transform, src.makeSampler, src.valueMax, pngPath, opt, bbox);
}

} // namespace frostvdb
