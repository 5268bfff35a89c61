#pragma once
/// @file base/Budget.h
/// @brief The run's resource budget: effects estimate the memory their scene keys ask for before
/// allocating it, and the driver refuses, naming the key and the estimate, what exceeds
/// `[run] memory_limit` (default: the memory the machine has available when the run starts).
#include <cstdint>
#include <string>

namespace frostvdb {

/// What an effect expects to allocate, and the scene key that drives it.
struct MemoryEstimate {
    double bytes = 0;    ///< peak bytes the effect will hold
    std::string key;     ///< "section.key" that drives the estimate
    std::string detail;  ///< how it was counted, e.g. "512 x 512 x 64 voxels x 12 bytes"
};

/// @a voxels x @a bytesPerVoxel, driven by @a key (e.g. "domain.size"); @a what says which arrays.
MemoryEstimate perVoxelEstimate(double voxels, double bytesPerVoxel, const std::string& key, const std::string& what);

/// MemAvailable from /proc/meminfo (bytes), or 0 when it cannot be read.
uint64_t availableMemoryBytes();

/// "3.2 GiB", "512 MiB", "12 KiB".
std::string formatBytes(double bytes);

/// Throws SceneError naming @a e.key, the estimate and the limit when e.bytes > limitBytes.
/// @a label is the scene file for the message.
void checkMemoryEstimate(const MemoryEstimate& e, double limitBytes, const std::string& label);

} // namespace frostvdb
