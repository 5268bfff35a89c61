/// @file Mesh.cpp
/// @brief Assimp-backed mesh loading and small OBJ/PLY writers.
#include <frostvdb/io/Mesh.h>
#include <frostvdb/io/InputFiles.h>

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace frostvdb {

openvdb::Mat4d MeshPlacement::matrix() const
{
    // row vectors: p' = p * S * Rx * Ry * Rz * T
    openvdb::Mat4d m = openvdb::Mat4d::identity();
    m.setToScale(scale);
    const double k = M_PI / 180.0;
    m.postRotate(openvdb::math::X_AXIS, rotateDegrees.x() * k);
    m.postRotate(openvdb::math::Y_AXIS, rotateDegrees.y() * k);
    m.postRotate(openvdb::math::Z_AXIS, rotateDegrees.z() * k);
    m.postTranslate(translate);
    return m;
}

openvdb::BBoxd TriangleMesh::bbox() const
{
    openvdb::BBoxd b;
    for (const auto& p : points) b.expand(openvdb::Vec3d(p));
    return b;
}

double TriangleMesh::area(size_t t) const
{
    const auto& f = triangles[t];
    const openvdb::Vec3d a(points[f[0]]), b(points[f[1]]), c(points[f[2]]);
    return 0.5 * (b - a).cross(c - a).length();
}

openvdb::Vec3d TriangleMesh::normal(size_t t) const
{
    const auto& f = triangles[t];
    const openvdb::Vec3d a(points[f[0]]), b(points[f[1]]), c(points[f[2]]);
    openvdb::Vec3d n = (b - a).cross(c - a);
    const double l = n.length();
    return l > 0 ? n / l : openvdb::Vec3d(0, 0, 1);
}

double TriangleMesh::totalArea() const
{
    double s = 0;
    for (size_t t = 0; t < triangles.size(); ++t) s += area(t);
    return s;
}

void TriangleMesh::transform(const MeshPlacement& placement)
{
    const openvdb::Mat4d m = placement.matrix();
    for (auto& p : points) p = openvdb::Vec3s(m.transform(openvdb::Vec3d(p)));
    // a mirroring scale flips the winding: keep normals pointing the way the file meant
    const auto& s = placement.scale;
    if (s.x() * s.y() * s.z() < 0)
        for (auto& f : triangles) std::swap(f[1], f[2]);
}

std::vector<openvdb::Vec3d> TriangleMesh::vertexNormals() const
{
    std::vector<openvdb::Vec3d> n(points.size(), openvdb::Vec3d(0.0));
    for (size_t t = 0; t < triangles.size(); ++t) {
        const auto& f = triangles[t];
        const openvdb::Vec3d a(points[f[0]]), b(points[f[1]]), c(points[f[2]]);
        const openvdb::Vec3d w = (b - a).cross(c - a); // length = 2 area: area weighting
        for (int v = 0; v < 3; ++v) n[f[v]] += w;
    }
    for (auto& v : n) {
        const double l = v.length();
        v = l > 0 ? v / l : openvdb::Vec3d(0, 0, 1);
    }
    return n;
}

std::vector<std::pair<uint32_t, uint32_t>> TriangleMesh::boundaryEdges() const
{
    std::vector<std::pair<uint32_t, uint32_t>> edges;
    edges.reserve(triangles.size() * 3);
    for (const auto& f : triangles)
        for (int e = 0; e < 3; ++e) {
            const uint32_t a = f[e], b = f[(e + 1) % 3];
            edges.emplace_back(std::min(a, b), std::max(a, b));
        }
    std::sort(edges.begin(), edges.end());
    std::vector<std::pair<uint32_t, uint32_t>> border;
    for (size_t i = 0; i < edges.size();) {
        size_t j = i;
        while (j < edges.size() && edges[j] == edges[i]) ++j;
        if (j - i == 1) border.push_back(edges[i]);
        i = j;
    }
    return border;
}

std::vector<std::vector<uint32_t>> TriangleMesh::vertexTriangles() const
{
    std::vector<std::vector<uint32_t>> vt(points.size());
    for (uint32_t t = 0; t < triangles.size(); ++t)
        for (int v = 0; v < 3; ++v) vt[triangles[t][v]].push_back(t);
    return vt;
}

TriangleMesh makeIcosphere(double radius, int subdivisions)
{
    using V = openvdb::Vec3d;
    const double g = (1.0 + std::sqrt(5.0)) / 2.0;
    std::vector<V> p = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0}, {0, -1, g}, {0, 1, g},
                        {0, -1, -g}, {0, 1, -g}, {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
    std::vector<openvdb::Vec3I> f = {{0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                                     {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
                                     {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
    for (auto& v : p) v.normalize();
    for (int s = 0; s < subdivisions; ++s) {
        std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
        auto midpoint = [&](uint32_t a, uint32_t b) {
            const auto key = std::make_pair(std::min(a, b), std::max(a, b));
            auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            V m = p[a] + p[b];
            m.normalize();
            p.push_back(m);
            return mid[key] = uint32_t(p.size() - 1);
        };
        std::vector<openvdb::Vec3I> next;
        for (const auto& t : f) {
            const uint32_t a = midpoint(t[0], t[1]), b = midpoint(t[1], t[2]), c = midpoint(t[2], t[0]);
            next.insert(next.end(), {{t[0], a, c}, {t[1], b, a}, {t[2], c, b}, {a, b, c}});
        }
        f.swap(next);
    }
    TriangleMesh mesh;
    mesh.source = "icosphere";
    for (const auto& v : p) mesh.points.emplace_back(v * radius);
    mesh.triangles = f;
    return mesh;
}

TriangleMesh makePlate(double size, int n)
{
    TriangleMesh mesh;
    mesh.source = "plate";
    for (int j = 0; j <= n; ++j)
        for (int i = 0; i <= n; ++i)
            mesh.points.emplace_back(float(size * (double(i) / n - 0.5)), float(size * (double(j) / n - 0.5)), 0.f);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const uint32_t a = uint32_t(j * (n + 1) + i), b = a + 1, c = a + uint32_t(n + 1), d = c + 1;
            mesh.triangles.emplace_back(a, b, d);
            mesh.triangles.emplace_back(a, d, c);
        }
    return mesh;
}

TriangleMesh loadMesh(const std::string& path, const MeshPlacement& placement)
{
    requireRegularFile(path); // "mesh file not found", or a directory / FIFO refused before it is opened
    checkPlyHeader(path);
    noteInputFile(path);
    Assimp::Importer importer;
    const aiScene* scene = importer.ReadFile(
        path, aiProcess_Triangulate | aiProcess_JoinIdenticalVertices | aiProcess_SortByPType |
                  aiProcess_PreTransformVertices);
    if (!scene || !scene->mRootNode)
        throw std::runtime_error(path + ": cannot read mesh (" + importer.GetErrorString() + ")");
    TriangleMesh mesh;
    mesh.source = path;
    bool anyColour = false, anyUv = false;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh* am = scene->mMeshes[m];
        anyColour |= am->HasVertexColors(0);
        anyUv |= am->HasTextureCoords(0);
    }
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh* am = scene->mMeshes[m];
        if (!(am->mPrimitiveTypes & aiPrimitiveType_TRIANGLE)) continue;
        const uint32_t base = uint32_t(mesh.points.size());
        for (unsigned v = 0; v < am->mNumVertices; ++v) {
            const aiVector3D& p = am->mVertices[v];
            mesh.points.emplace_back(p.x, p.y, p.z);
            if (anyColour) {
                if (am->HasVertexColors(0)) {
                    const aiColor4D& c = am->mColors[0][v];
                    mesh.colours.emplace_back(c.r, c.g, c.b);
                } else mesh.colours.emplace_back(1.f, 1.f, 1.f);
            }
            if (anyUv) {
                if (am->HasTextureCoords(0)) mesh.uvs.emplace_back(am->mTextureCoords[0][v].x, am->mTextureCoords[0][v].y);
                else mesh.uvs.emplace_back(0.f, 0.f);
            }
        }
        for (unsigned f = 0; f < am->mNumFaces; ++f) {
            const aiFace& face = am->mFaces[f];
            if (face.mNumIndices != 3) continue;
            mesh.triangles.emplace_back(base + face.mIndices[0], base + face.mIndices[1], base + face.mIndices[2]);
        }
    }
    if (mesh.triangles.empty()) throw std::runtime_error(path + ": mesh has no triangles");
    for (const auto& p : mesh.points)
        if (!std::isfinite(p.x()) || !std::isfinite(p.y()) || !std::isfinite(p.z()))
            throw std::runtime_error(path + ": mesh has non-finite vertex coordinates");
    mesh.transform(placement);
    const std::string why = mesh.collapseProblem(placement);
    if (!why.empty()) throw std::runtime_error(path + ": " + why);
    return mesh;
}

namespace {
std::string fmt(double v)
{
    char b[32];
    std::snprintf(b, sizeof b, "%.3g", v);
    return b;
}
} // namespace

std::string TriangleMesh::collapseProblem(const MeshPlacement& placement, double voxelSize) const
{
    if (triangles.empty()) return "mesh has no triangles";
    const auto& s = placement.scale;
    if (s.x() == 0.0 || s.y() == 0.0 || s.z() == 0.0)
        return "the placement scale (" + fmt(s.x()) + ", " + fmt(s.y()) + ", " + fmt(s.z()) +
               ") has a zero factor: the mesh collapses (allowed: non-zero factors)";
    for (const auto& p : points)
        if (!std::isfinite(p.x()) || !std::isfinite(p.y()) || !std::isfinite(p.z()))
            return "the placed mesh has non-finite vertex coordinates (scale or translate too large)";
    const openvdb::BBoxd box = bbox();
    const double extent = box.extents().length();
    const double area = totalArea();
    // Vertices are single-precision floats: far from the origin their spacing is coarse and the
    // mesh loses its shape (a 0.3 m plate moved 1e6 m is quantised to 12 cm steps, or to a point).
    const double far = std::max({std::fabs(box.min().x()), std::fabs(box.min().y()), std::fabs(box.min().z()),
                                 std::fabs(box.max().x()), std::fabs(box.max().y()), std::fabs(box.max().z())});
    const double ulp = far * std::ldexp(1.0, -23); // float spacing at the farthest coordinate
    if (far > 0.0 && ulp > 1e-3 * extent)
        return "placed " + fmt(far) + " m from the origin, the mesh's single-precision vertices are " + fmt(ulp) +
               " m apart, too coarse for its size of " + fmt(extent) +
               " m (allowed: a spacing below 1/1000 of the size; move the mesh nearer the origin)";
    if (!(area > 0.0) || !(extent > 0.0))
        return "the placed mesh has zero area (every triangle is degenerate, or the scale collapses it: extent " +
               fmt(extent) + " m)";
    if (voxelSize > 0.0) {
        if (extent < voxelSize)
            return "the placed mesh (" + fmt(extent) + " m across) is smaller than one voxel (" + fmt(voxelSize) +
                   " m): nothing can grow on it";
        if (far / voxelSize > double(1 << 24))
            return "placed " + fmt(far) + " m from the origin, the mesh is " + fmt(far / voxelSize) +
                   " voxels out, where single-precision voxel positions are no longer exact (allowed: up to 1.7e7 "
                   "voxels from the origin)";
        if (ulp > 0.125 * voxelSize)
            return "placed " + fmt(far) + " m from the origin, the mesh's single-precision vertices are " + fmt(ulp) +
                   " m apart, more than 1/8 of a voxel (" + fmt(voxelSize) + " m)";
    }
    return {};
}

/// A PLY header states its element counts; a damaged one can claim a billion vertices that
/// Assimp would try to allocate. Each element needs at least one byte per property (binary) or
/// two characters per property (ASCII: a digit and a separator), so a count the file cannot
/// hold is refused before Assimp reads it.
void checkPlyHeader(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    std::string magic;
    if (!std::getline(in, magic) || magic.rfind("ply", 0) != 0) return;
    std::error_code ec;
    const double size = double(std::filesystem::file_size(path, ec));
    if (ec) return;
    bool ascii = false;
    double need = 0, count = 0;
    std::string element;
    std::string line;
    int lines = 0;
    auto close = [&](double props) { need += count * props * (ascii ? 2.0 : 1.0); };
    double props = 0;
    while (std::getline(in, line) && ++lines < 10000) {
        std::istringstream ls(line);
        std::string word;
        ls >> word;
        if (word == "format") {
            std::string f;
            ls >> f;
            ascii = f == "ascii";
        } else if (word == "element") {
            close(props);
            props = 0;
            std::string n;
            ls >> element >> n;
            count = std::strtod(n.c_str(), nullptr);
            if (!(count >= 0) || !std::isfinite(count)) count = 0;
            if (count > 0 && count > size)
                throw std::runtime_error(path + ": the PLY header declares " + fmt(count) + " " + element +
                                         " elements, but the file holds only " + fmt(size) +
                                         " bytes (damaged or truncated)");
        } else if (word == "property") {
            props += 1;
        } else if (word == "end_header") {
            close(props);
            if (need > size)
                throw std::runtime_error(path + ": the PLY header declares elements needing at least " + fmt(need) +
                                         " bytes, but the file holds only " + fmt(size) + " (damaged or truncated)");
            return;
        }
    }
}

namespace {
/// Writes through a temporary name and renames, so a crash never leaves half a file.
template <typename Fn>
void writeAtomically(const std::string& path, bool binary, Fn fn)
{
    const std::string tmp = path + ".tmp";
    {
        std::ofstream out(tmp, binary ? std::ios::binary : std::ios::out);
        if (!out) throw std::runtime_error(path + ": cannot open for writing");
        fn(out);
        if (!out) throw std::runtime_error(path + ": write failed");
    }
    std::filesystem::rename(tmp, path);
}
} // namespace

void writeObj(const std::string& path, const std::vector<openvdb::Vec3s>& points,
              const std::vector<openvdb::Vec3I>& triangles, const std::vector<openvdb::Vec4I>& quads)
{
    writeAtomically(path, false, [&](std::ofstream& out) {
        out << "# frostvdb\n";
        char buf[96];
        for (const auto& p : points) {
            std::snprintf(buf, sizeof buf, "v %.7g %.7g %.7g\n", p.x(), p.y(), p.z());
            out << buf;
        }
        for (const auto& t : triangles) out << "f " << t[0] + 1 << ' ' << t[1] + 1 << ' ' << t[2] + 1 << '\n';
        for (const auto& q : quads)
            out << "f " << q[0] + 1 << ' ' << q[1] + 1 << ' ' << q[2] + 1 << ' ' << q[3] + 1 << '\n';
    });
}

void writePly(const std::string& path, const std::vector<openvdb::Vec3s>& points,
              const std::vector<openvdb::Vec3I>& triangles, const std::vector<openvdb::Vec4I>& quads)
{
    writeAtomically(path, true, [&](std::ofstream& out) {
        out << "ply\nformat binary_little_endian 1.0\ncomment frostvdb\nelement vertex " << points.size()
            << "\nproperty float x\nproperty float y\nproperty float z\nelement face "
            << triangles.size() + quads.size() << "\nproperty list uchar int vertex_indices\nend_header\n";
        for (const auto& p : points) out.write(reinterpret_cast<const char*>(p.asPointer()), 12);
        for (const auto& t : triangles) {
            const unsigned char n = 3;
            const int32_t v[3] = {int32_t(t[0]), int32_t(t[1]), int32_t(t[2])};
            out.write(reinterpret_cast<const char*>(&n), 1);
            out.write(reinterpret_cast<const char*>(v), 12);
        }
        for (const auto& q : quads) {
            const unsigned char n = 4;
            const int32_t v[4] = {int32_t(q[0]), int32_t(q[1]), int32_t(q[2]), int32_t(q[3])};
            out.write(reinterpret_cast<const char*>(&n), 1);
            out.write(reinterpret_cast<const char*>(v), 16);
        }
    });
}

} // namespace frostvdb
