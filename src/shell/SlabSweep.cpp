/// @file SlabSweep.cpp
/// @brief The sweep's schedule (see SlabSweep.h).
#include <frostvdb/shell/SlabSweep.h>

#include <algorithm>
#include <limits>

namespace frostvdb::shell {

void SlabSweep::build(const std::vector<ShellBand::Leaf>& leaves, const std::vector<uint32_t>& slots, size_t ranges)
{
    mOrder.clear();
    mSlabBegin.clear();
    mRangeBegin.clear();
    if (slots.empty()) return;
    // the axis along which the leaves spread most: the most slabs, so the thinnest ones
    openvdb::Coord lo(std::numeric_limits<int>::max()), hi(std::numeric_limits<int>::min());
    for (uint32_t s : slots) {
        lo.minComponent(leaves[s].origin);
        hi.maxComponent(leaves[s].origin);
    }
    const openvdb::Coord extent = hi - lo;
    mAxis = extent.x() >= extent.y() && extent.x() >= extent.z() ? 0 : (extent.y() >= extent.z() ? 1 : 2);
    mOrder = slots;
    const int a = mAxis;
    std::sort(mOrder.begin(), mOrder.end(), [&](uint32_t u, uint32_t v) {
        const int ou = leaves[u].origin[a], ov = leaves[v].origin[a];
        return ou != ov ? ou < ov : u < v;
    });
    std::vector<size_t> slabVoxels;
    for (size_t k = 0; k < mOrder.size(); ++k) {
        const ShellBand::Leaf& l = leaves[mOrder[k]];
        if (k == 0 || l.origin[a] != leaves[mOrder[k - 1]].origin[a]) {
            mSlabBegin.push_back(k);
            slabVoxels.push_back(0);
        }
        slabVoxels.back() += l.end - l.begin;
    }
    mSlabBegin.push_back(mOrder.size());
    // ranges of similar voxel counts, each of at least 3 slabs (the last takes what is left)
    size_t total = 0;
    for (size_t v : slabVoxels) total += v;
    const size_t nSlabs = slabVoxels.size();
    ranges = std::max<size_t>(1, std::min(ranges, nSlabs / 3));
    const size_t target = (total + ranges - 1) / ranges;
    size_t acc = 0, count = 0;
    mRangeBegin.push_back(0);
    for (size_t s = 0; s < nSlabs; ++s) {
        acc += slabVoxels[s];
        ++count;
        const bool roomForNext = nSlabs - (s + 1) >= 3;
        if (acc >= target && count >= 3 && roomForNext && mRangeBegin.size() < ranges) {
            mRangeBegin.push_back(s + 1);
            acc = count = 0;
        }
    }
    mRangeBegin.push_back(nSlabs);
}

} // namespace frostvdb::shell
