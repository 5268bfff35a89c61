#include <frostvdb/base/Budget.h>
#include <frostvdb/base/Error.h>

#include <cstdio>
#include <fstream>
#include <sstream>

namespace frostvdb {

MemoryEstimate perVoxelEstimate(double voxels, double bytesPerVoxel, const std::string& key, const std::string& what)
{
    char buf[200];
    std::snprintf(buf, sizeof buf, "%.4g voxels x %.0f bytes: %s", voxels, bytesPerVoxel, what.c_str());
    return {voxels * bytesPerVoxel, key, buf};
}

uint64_t availableMemoryBytes()
{
    std::ifstream in("/proc/meminfo");
    std::string key;
    uint64_t value = 0;
    std::string unit;
    while (in >> key >> value >> unit)
        if (key == "MemAvailable:") return value * 1024ull;
    return 0;
}

std::string formatBytes(double bytes)
{
    const char* units[] = {"bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
    int u = 0;
    while (bytes >= 1024.0 && u < 6) {
        bytes /= 1024.0;
        ++u;
    }
    char buf[64];
    std::snprintf(buf, sizeof buf, u == 0 ? "%.0f %s" : "%.1f %s", bytes, units[u]);
    return buf;
}

void checkMemoryEstimate(const MemoryEstimate& e, double limitBytes, const std::string& label)
{
    if (limitBytes <= 0 || !(e.bytes > limitBytes)) return;
    throw SceneError(label, 0, e.key,
                     "needs about " + formatBytes(e.bytes) + (e.detail.empty() ? "" : " (" + e.detail + ")") +
                         ", more than run.memory_limit allows (" + formatBytes(limitBytes) + ")");
}

} // namespace frostvdb
