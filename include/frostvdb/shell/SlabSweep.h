#pragma once
/// @file SlabSweep.h
/// @brief Three per-leaf stages over a set of band leaves in one sweep along an axis, so that a
/// leaf's data is still in cache when its later stages read it again.
///
/// The surface-node Euler step (ShellPhaseField::stepSurface) reads each node's stencil taps and
/// frame twice (pass 1, then pass 2) and then copies the new values back (stage 3). As three
/// passes over the whole band every one streams the taps from memory; on the 2 mm windshield
/// the kernel moved about 500 bytes per node and step and ran at memory speed. The sweep runs
/// them slab by slab instead (a slab: the leaves with one origin coordinate along the band's
/// longest axis), a few slabs apart, so the second reads come from cache.
///
/// The result is that of three full passes, bit for bit, when (as on a band whose stencils reach
/// kTapReach <= 8 voxels):
///  - stage 2 of a leaf reads stage 1's output of its own and its neighbour leaves only;
///  - stage 3 of a leaf writes what stages 1 and 2 of its own and its neighbour leaves read;
/// and each stage of a leaf writes only that leaf's entries. A neighbour leaf lies in the same
/// slab or the next one on either side, so:
///  - phase A, in parallel over ranges of slabs: stage 1 on each range's first and last slab;
///  - phase B, each range in order: stage 1 of slab s + 1, stage 2 of slab s, stage 3 of s - 1
///    (for the slabs inside the range; its first and last slab border another range's);
///  - phase C, in parallel: stage 3 on each range's first and last slab.
/// The ranges (and so the thread count) change the order of the work, never its values.
#include <frostvdb/shell/ShellBand.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cstddef>
#include <cstdint>
#include <vector>

namespace frostvdb::shell {

class SlabSweep {
public:
    /// The schedule for these leaf slots of @a leaves: slabs along the axis where their origins
    /// spread most, cut into about @a ranges ranges of similar voxel counts (at least 3 slabs
    /// each, so each has an inside).
    void build(const std::vector<ShellBand::Leaf>& leaves, const std::vector<uint32_t>& slots, size_t ranges);
    bool empty() const { return mOrder.empty(); }
    size_t slabs() const { return mSlabBegin.empty() ? 0 : mSlabBegin.size() - 1; }
    size_t ranges() const { return mRangeBegin.empty() ? 0 : mRangeBegin.size() - 1; }
    int axis() const { return mAxis; }

    /// Runs stage1(slot), stage2(slot), stage3(slot) on every leaf slot of the schedule, in the
    /// order the file comment gives; ahead(slot) just before stage 1 of the slot before it in its
    /// slab (its data asked for early: stage 1 is where a leaf's data comes from memory).
    template <class Stage1, class Stage2, class Stage3, class Ahead = void (*)(uint32_t)>
    void run(const Stage1& stage1, const Stage2& stage2, const Stage3& stage3,
             const Ahead& ahead = [](uint32_t) {}) const
    {
        const size_t nr = ranges();
        // stage 1 of a slab's slots, each after asking for the next one's data
        auto firstStage = [&](size_t slab) {
            for (size_t k = mSlabBegin[slab]; k < mSlabBegin[slab + 1]; ++k) {
                if (k + 1 < mSlabBegin[slab + 1]) ahead(mOrder[k + 1]);
                stage1(mOrder[k]);
            }
        };
        auto onSlab = [&](const auto& stage, size_t slab) {
            for (size_t k = mSlabBegin[slab]; k < mSlabBegin[slab + 1]; ++k) stage(mOrder[k]);
        };
        auto onEnds = [&](const auto& onEnd) {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, nr, 1), [&](const tbb::blocked_range<size_t>& r) {
                for (size_t q = r.begin(); q < r.end(); ++q) {
                    const size_t first = mRangeBegin[q], last = mRangeBegin[q + 1] - 1;
                    onEnd(first);
                    if (last != first) onEnd(last);
                }
            }, tbb::simple_partitioner());
        };
        onEnds(firstStage); // phase A
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nr, 1), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t q = r.begin(); q < r.end(); ++q) { // phase B
                const size_t first = mRangeBegin[q], last = mRangeBegin[q + 1] - 1;
                for (size_t s = first; s <= last; ++s) {
                    if (s + 1 < last) firstStage(s + 1);
                    onSlab(stage2, s);
                    if (s > first + 1) onSlab(stage3, s - 1);
                }
            }
        }, tbb::simple_partitioner());
        onEnds([&](size_t slab) { onSlab(stage3, slab); }); // phase C
    }

private:
    int mAxis = 0;
    std::vector<uint32_t> mOrder;     ///< the slots, by (slab, slot)
    std::vector<size_t> mSlabBegin;   ///< per slab: its first index in mOrder (+ the end)
    std::vector<size_t> mRangeBegin;  ///< per range: its first slab (+ the end)
};

} // namespace frostvdb::shell
