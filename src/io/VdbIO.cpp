#include <frostvdb/io/VdbIO.h>
#include <frostvdb/core/Error.h>

#include <openvdb/io/File.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iomanip>
#include <sstream>
#include <unistd.h>

namespace frostvdb {

std::string framePath(const std::string& dir, const std::string& name, int64_t frame, const std::string& ext)
{
    std::ostringstream os;
    os << dir << (dir.empty() || dir.back() == '/' ? "" : "/") << name << "." << std::setw(4)
       << std::setfill('0') << frame << "." << ext;
    return os.str();
}

std::string temporaryPathFor(const std::string& path)
{
    static std::atomic<int> counter{0};
    std::filesystem::path p(path);
    return (p.parent_path() / ("." + p.filename().string() + ".tmp" + std::to_string(::getpid()) + "_" +
                               std::to_string(counter++)))
        .string();
}

void commitTemporary(const std::string& tmp, const std::string& path)
{
    if (std::rename(tmp.c_str(), path.c_str()) != 0) {
        std::remove(tmp.c_str());
        throw std::runtime_error(path + ": cannot rename temporary file into place");
    }
}

namespace {
template <typename GridT>
bool checkGrid(const openvdb::GridBase& base)
{
    auto grid = dynamic_cast<const GridT*>(&base);
    if (!grid) return false;
    auto finite = [](const auto& v) {
        using V = std::decay_t<decltype(v)>;
        if constexpr (std::is_floating_point_v<V>) return std::isfinite(v);
        else return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
    };
    if (!finite(grid->background()))
        throw SimulationError("grid '" + grid->getName() + "': non-finite background value");
    for (auto it = grid->cbeginValueOn(); it; ++it) {
        if (!finite(*it)) {
            std::ostringstream os;
            os << "grid '" << grid->getName() << "' holds a non-finite value at voxel " << it.getCoord()
               << "; refusing to write it";
            throw SimulationError(os.str());
        }
    }
    return true;
}
} // namespace

void checkFinite(const openvdb::GridBase& grid)
{
    checkGrid<openvdb::FloatGrid>(grid) || checkGrid<openvdb::DoubleGrid>(grid) ||
        checkGrid<openvdb::Vec3SGrid>(grid);
}

void makeDirectories(const std::string& dir)
{
    std::error_code ec;
    if (!dir.empty()) std::filesystem::create_directories(dir, ec);
    if (ec) throw std::runtime_error(dir + ": cannot create directory (" + ec.message() + ")");
}

void writeVdbAtomic(const std::string& path, const openvdb::GridPtrVec& grids,
                    const openvdb::MetaMap& fileMeta, bool halfFloat)
{
    for (auto& g : grids) {
        checkFinite(*g);
        g->setSaveFloatAsHalf(halfFloat);
    }
    const std::string tmp = temporaryPathFor(path);
    try {
        openvdb::io::File file(tmp);
        file.write(grids, fileMeta);
        file.close();
    } catch (...) {
        std::remove(tmp.c_str());
        throw;
    }
    commitTemporary(tmp, path);
}

openvdb::GridPtrVecPtr readVdb(const std::string& path, openvdb::MetaMap::Ptr* fileMeta)
{
    openvdb::io::File file(path);
    file.open();
    auto grids = file.getGrids();
    if (fileMeta) *fileMeta = file.getMetadata();
    file.close();
    return grids;
}

} // namespace frostvdb
