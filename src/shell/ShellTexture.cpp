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

SurfaceTextures::SurfaceTextures(const TriangleMesh& mesh) : triangles(mesh.triangles), uvs(mesh.uvs)
{
    if (mesh.uvs.size() != mesh.points.size())
        throw std::runtime_error(mesh.source + ": the mesh has no UV coordinates (a texture needs them)");
    points.reserve(mesh.points.size());
    for (const auto& q : mesh.points) points.emplace_back(q);
}

float SurfaceTextures::sample(const Texture& texture, const ShellBand& band, size_t i) const
{
    const double h = band.voxelSize();
    const auto& f = triangles[band.triangle(i)];
    const Vec3d a = points[f[0]] / h, b = points[f[1]] / h, c = points[f[2]] / h, p = band.closestPoint(i);
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
    const auto &ua = uvs[f[0]], &ub = uvs[f[1]], &uc = uvs[f[2]];
    const double u = wa * ua.x() + wb * ub.x() + wc * uc.x(), v = wa * ua.y() + wb * ub.y() + wc * uc.y();
    return float(std::clamp(texture.sample(u, v), 0.0, 1.0));
}

std::vector<uint32_t> SurfaceTextures::seedTriangles() const
{
    std::vector<uint32_t> out;
    if (!seed) return out;
    const Texture& t = *seed;
    // a bilinear sample is a convex combination of the texels around it, so the largest texel
    // over the footprint of the triangle's UV box bounds every sample inside the triangle
    // (barycentric UVs stay inside the box of the corners' UVs)
    auto texel = [&](long i, long j) {
        i = ((i % t.width) + t.width) % t.width;
        j = ((j % t.height) + t.height) % t.height;
        return t.values[size_t(j) * size_t(t.width) + size_t(i)];
    };
    for (uint32_t k = 0; k < triangles.size(); ++k) {
        const auto& f = triangles[k];
        double u0 = 1e300, u1 = -1e300, v0 = 1e300, v1 = -1e300;
        for (int c = 0; c < 3; ++c) {
            u0 = std::min(u0, double(uvs[f[c]].x()));
            u1 = std::max(u1, double(uvs[f[c]].x()));
            v0 = std::min(v0, double(uvs[f[c]].y()));
            v1 = std::max(v1, double(uvs[f[c]].y()));
        }
        // texel index ranges as in Texture::sample (x = u w - 1/2, y = (1 - v) h - 1/2)
        const long i0 = long(std::floor(u0 * t.width - 0.5)), i1 = long(std::floor(u1 * t.width - 0.5)) + 1;
        const long j0 = long(std::floor((1.0 - v1) * t.height - 0.5)), j1 = long(std::floor((1.0 - v0) * t.height - 0.5)) + 1;
        const long ni = std::min<long>(i1 - i0 + 1, t.width + 1), nj = std::min<long>(j1 - j0 + 1, t.height + 1);
        bool bright = false;
        for (long j = 0; j < nj && !bright; ++j)
            for (long i = 0; i < ni && !bright; ++i) bright = texel(i0 + i, j0 + j) > 0.5f;
        if (bright) out.push_back(k);
    }
    return out;
}

std::function<float(const ShellBand&, size_t)> meltSource(openvdb::FloatGrid::ConstPtr meltField, const ShellBand& band,
                                                          const SurfaceTextures* textures)
{
    const bool colour = band.colourUse() == BandSettings::ColourUse::Melt; // the domain checked the colours
    const bool texture = textures && textures->melt;
    if (!meltField && !colour && !texture) return nullptr;
    return [meltField, colour, textures, texture](const ShellBand& b, size_t i) {
        double v = meltField ? double(meltField->tree().getValue(b.coord(i))) : 1.0; // thread-safe read
        if (colour && i < b.colourLuminance().size()) v *= b.colourLuminance()[i];
        if (texture) v *= textures->meltAt(b, i);
        return float(v);
    };
}

std::vector<float> meltMap(const ShellBand& band, const openvdb::FloatGrid* meltField, const SurfaceTextures* textures)
{
    std::vector<float> m;
    const bool colour = band.colourUse() == BandSettings::ColourUse::Melt; // the domain checked the colours
    const bool texture = textures && textures->melt;
    if (!meltField && !colour && !texture) return m;
    if (meltField) fromGrid(band, *meltField, m); // leaf by leaf: faster than a lookup per voxel
    else m.assign(band.size(), 1.f);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m.size()), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            double v = m[i];
            if (colour && i < band.colourLuminance().size()) v *= band.colourLuminance()[i];
            if (texture) v *= textures->meltAt(band, i);
            m[i] = float(v);
        }
    });
    return m;
}

} // namespace frostvdb::shell
