#include <frostvdb/core/Fields.h>

namespace frostvdb {

uint64_t FieldSet::memoryUsage() const
{
    uint64_t bytes = 0;
    for (auto& [n, g] : mGrids) bytes += g->memUsage();
    return bytes;
}

uint64_t FieldSet::activeVoxels() const
{
    uint64_t n = 0;
    for (auto& [name, g] : mGrids) n += g->activeVoxelCount();
    return n;
}

} // namespace frostvdb
