/// @file make_seeds.cpp
/// @brief Writes the seed corpora of the map-reader harnesses: small PNG and VDB maps of every
/// kind the readers accept (8/16-bit grey, RGB; fog, level set, several grids, vectors, half
/// floats). usage: frostvdb_fuzz_seeds PNG_DIR VDB_DIR
#include <frostvdb/io/Png.h>
#include <frostvdb/io/VdbIO.h>

#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <cmath>
#include <filesystem>
#include <iostream>

using namespace frostvdb;

int main(int argc, char** argv)
{
    if (argc != 3) {
        std::cerr << "usage: " << argv[0] << " PNG_DIR VDB_DIR\n";
        return 2;
    }
    openvdb::initialize();
    const std::string png = argv[1], vdb = argv[2];
    std::filesystem::create_directories(png);
    std::filesystem::create_directories(vdb);

    const int w = 12, h = 8;
    std::vector<float> ramp(size_t(w) * h);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) ramp[size_t(j) * w + i] = float(i + j) / float(w + h - 2);
    writePngGray(png + "/gray8.png", w, h, ramp, 8);
    writePngGray(png + "/gray16.png", w, h, ramp, 16);
    writePngGray(png + "/tiny.png", 1, 1, {0.5f}, 8);
    ImageRGB rgb(w, h);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) rgb.set(i, j, float(i) / w, float(j) / h, 0.5f);
    writePngRGB(png + "/rgb.png", rgb);

    openvdb::MetaMap meta;
    meta.insertMeta("creator", openvdb::StringMetadata("frostvdb_fuzz_seeds"));
    auto fog = openvdb::FloatGrid::create(0.f);
    fog->setName("melt");
    fog->setGridClass(openvdb::GRID_FOG_VOLUME);
    fog->setTransform(openvdb::math::Transform::createLinearTransform(1e-3));
    for (int j = 0; j < 6; ++j)
        for (int i = 0; i < 6; ++i) fog->tree().setValue(openvdb::Coord(i, j, 0), 0.1f * float(i + j) / 2.f);
    writeVdbAtomic(vdb + "/fog.vdb", {fog}, meta);
    writeVdbAtomic(vdb + "/fog_half.vdb", {fog->deepCopy()}, meta, true);

    auto sphere = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(4.f, openvdb::Vec3f(6, 6, 0), 1.f, 2.f);
    sphere->setName("seed");
    writeVdbAtomic(vdb + "/levelset.vdb", {sphere}, meta);

    auto tile = openvdb::FloatGrid::create(0.f);
    tile->setName("tile");
    tile->tree().fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(15)), 0.5f, true);
    auto vel = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
    vel->setName("vel");
    vel->tree().setValue(openvdb::Coord(1, 2, 0), openvdb::Vec3s(1.f, 0.f, 0.f));
    writeVdbAtomic(vdb + "/two_grids.vdb", {tile, vel}, meta);
    writeVdbAtomic(vdb + "/vector_only.vdb", {vel->deepCopy()}, meta);
    std::cout << "seeds written to " << png << " and " << vdb << "\n";
    return 0;
}
