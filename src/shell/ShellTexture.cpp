/// @file ShellTexture.cpp
/// @brief UV texture lookups at a shell band's closest points (see ShellTexture.h).
#include <frostvdb/shell/ShellTexture.h>

#include <frostvdb/io/Png.h>
#include <frostvdb/shell/ShellGrids.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace frostvdb::shell {

using openvdb::Vec3d;

double Texture::sample(double u, double v) const
{
    // texel centres at (i + 1/2) / width; v up, rows down
    const double x = u * width - 0.5, y = (1.0 - v) * height - 0.5;
    const double fx = std::floor(x), fy = std::floor(y);
    const double tx = x - fx, ty = y - fy;
    auto at = [&](long i, long j) {
        i = ((i % width) + width) % width;
        j = ((j % height) + height) % height;
        return double(values[size_t(j) * size_t(width) + size_t(i)]);
    };
    const long i = long(fx), j = long(fy);
    return (1 - ty) * ((1 - tx) * at(i, j) + tx * at(i + 1, j)) + ty * ((1 - tx) * at(i, j + 1) + tx * at(i + 1, j + 1));
}

Texture loadTexture(const std::string& path)
{
    Texture t;
    t.values = readPngGray(path, t.width, t.height);
    if (t.width <= 0 || t.height <= 0 || t.values.empty()) throw std::runtime_error(path + ": empty image");
    return t;
}

std::vector<float> sampleTexture(const ShellBand& band, const TriangleMesh& mesh, const Texture& texture)
{
    if (mesh.uvs.size() != mesh.points.size())
        throw std::runtime_error(mesh.source + ": the mesh has no UV coordinates (a texture needs them)");
    const double h = band.voxelSize();
    std::vector<float> out(band.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, band.size()), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            const auto& f = mesh.triangles[band.triangle(i)];
            const Vec3d a = Vec3d(mesh.points[f[0]]) / h, b = Vec3d(mesh.points[f[1]]) / h,
                        c = Vec3d(mesh.points[f[2]]) / h, p = band.closestPoint(i);
            // barycentric coordinates of the closest point in its triangle
            const Vec3d v0 = b - a, v1 = c - a, v2 = p - a;
            const double d00 = v0.dot(v0), d01 = v0.dot(v1), d11 = v1.dot(v1), d20 = v2.dot(v0), d21 = v2.dot(v1);
            const double den = d00 * d11 - d01 * d01;
            double wb = 1.0 / 3.0, wc = 1.0 / 3.0;
            if (std::fabs(den) > 1e-300) {
                wb = (d11 * d20 - d01 * d21) / den;
                wc = (d00 * d21 - d01 * d20) / den;
            }
            const double wa = 1.0 - wb - wc;
            const auto &ua = mesh.uvs[f[0]], &ub = mesh.uvs[f[1]], &uc = mesh.uvs[f[2]];
            const double u = wa * ua.x() + wb * ub.x() + wc * uc.x(), v = wa * ua.y() + wb * ub.y() + wc * uc.y();
            out[i] = float(std::clamp(texture.sample(u, v), 0.0, 1.0));
        }
    });
    return out;
}

std::vector<float> meltMap(const ShellBand& band, const openvdb::FloatGrid* meltField, const SurfaceTextures* textures)
{
    std::vector<float> m;
    auto multiply = [&](const std::vector<float>& f) {
        if (f.size() != band.size()) return;
        if (m.empty()) m = f;
        else
            for (size_t i = 0; i < m.size(); ++i) m[i] *= f[i];
    };
    if (meltField) fromGrid(band, *meltField, m);
    if (band.colourUse() == BandSettings::ColourUse::Melt) multiply(band.colourLuminance());
    if (textures) multiply(textures->melt);
    return m;
}

} // namespace frostvdb::shell
