#include <frostvdb/io/VdbCheck.h>

#include <cstdint>
#include <cstring>
#include <fstream>
#include <sys/stat.h>
#include <sstream>
#include <vector>

namespace frostvdb {

namespace {

/// Reads the file's bytes with bounds checks; fails with a message instead of throwing.
struct Walker {
    std::string bytes;
    size_t pos = 0;
    std::string problem;

    bool need(uint64_t n, const char* what)
    {
        if (!problem.empty()) return false;
        if (n <= bytes.size() - pos) return true;
        std::ostringstream os;
        os << what << " of " << n << " bytes at offset " << pos << ", but the file has " << bytes.size();
        problem = os.str();
        return false;
    }
    template <typename T>
    bool pod(T& v, const char* what)
    {
        if (!need(sizeof(T), what)) return false;
        std::memcpy(&v, bytes.data() + pos, sizeof(T));
        pos += sizeof(T);
        return true;
    }
    bool skipString(const char* what) // uint32 length + bytes (io::readString)
    {
        uint32_t n = 0;
        if (!pod(n, what) || !need(n, what)) return false;
        pos += n;
        return true;
    }
    /// MetaMap::readMeta: count, then (name, type name, uint32 size + value bytes) each.
    bool metaMap()
    {
        uint32_t count = 0;
        if (!pod(count, "metadata count")) return false;
        if (!need(uint64_t(count) * 12, "metadata entries")) return false; // >= 12 bytes each
        for (uint32_t i = 0; i < count; ++i)
            if (!skipString("metadata name") || !skipString("metadata type name") || !skipString("metadata value"))
                return false;
        return true;
    }
};

} // namespace

std::string vdbLengthProblem(const std::string& path)
{
    Walker w;
    {
        struct stat st {};
        if (::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode)) return "not a regular file";
        std::ifstream in(path, std::ios::binary);
        if (!in) return {}; // OpenVDB reports it
        std::stringstream ss;
        ss << in.rdbuf();
        w.bytes = ss.str();
    }
    int64_t magic = 0;
    uint32_t version = 0, major = 0, minor = 0;
    if (!w.pod(magic, "header") || !w.pod(version, "header")) return w.problem;
    if (magic != 0x56444220 || version < 222 || version > 300) return {}; // old or unknown: OpenVDB decides
    char offsets = 0;
    if (!w.pod(major, "header") || !w.pod(minor, "header") || !w.pod(offsets, "header") || !w.need(36, "uuid"))
        return w.problem;
    w.pos += 36;
    if (!w.metaMap()) return "file metadata: " + w.problem;
    if (!offsets) return {};
    int32_t grids = 0;
    if (!w.pod(grids, "grid count")) return w.problem;
    if (grids < 0 || !w.need(uint64_t(grids) * 32, "grid descriptors")) return w.problem.empty() ? "negative grid count" : w.problem;
    std::vector<int64_t> gridPos;
    for (int32_t g = 0; g < grids; ++g) {
        int64_t gp = 0, bp = 0, ep = 0;
        if (!w.skipString("grid name") || !w.skipString("grid type") || !w.skipString("instance parent name") ||
            !w.pod(gp, "grid offsets") || !w.pod(bp, "grid offsets") || !w.pod(ep, "grid offsets"))
            return w.problem;
        const int64_t size = int64_t(w.bytes.size());
        if (gp < 0 || bp < gp || ep < bp || ep > size) {
            std::ostringstream os;
            os << "grid " << g << " spans bytes " << gp << "-" << ep << " of a " << size << "-byte file";
            return os.str();
        }
        gridPos.push_back(gp);
        w.pos = size_t(ep); // the next descriptor follows the grid
    }
    for (size_t g = 0; g < gridPos.size(); ++g) {
        w.pos = size_t(gridPos[g]);
        uint32_t compression = 0;
        if (!w.pod(compression, "grid compression") || !w.metaMap())
            return "grid " + std::to_string(g) + " metadata: " + w.problem;
    }
    return {};
}

} // namespace frostvdb
