#include <frostvdb/io/StreamedGrid.h>
#include <frostvdb/base/Error.h>

#include <openvdb/io/Compression.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <vector>

namespace frostvdb {

namespace {
/// Leaves made and written together: 8 MiB of values, enough to fill them in parallel.
constexpr size_t kBatchLeaves = 4096;

void throwNonFinite(const openvdb::GridBase& grid, const openvdb::Coord& c)
{
    std::ostringstream os;
    os << "grid '" << grid.getName() << "' holds a non-finite value at voxel " << c << "; refusing to write it";
    throw SimulationError(os.str());
}
} // namespace

StreamedFloatGrid::StreamedFloatGrid(openvdb::FloatTree::Ptr topology, const openvdb::GridBase& like, Fill fill)
    : openvdb::FloatGrid(topology), mFill(std::make_shared<const Fill>(std::move(fill)))
{
    for (auto it = like.beginMeta(); it != like.endMeta(); ++it) insertMeta(it->first, *it->second);
    setTransform(like.transform().copy());
}

StreamedFloatGrid::StreamedFloatGrid(StreamedFloatGrid& other, openvdb::ShallowCopy)
    : openvdb::FloatGrid(other, openvdb::ShallowCopy()), mFill(other.mFill)
{
}

openvdb::GridBase::Ptr StreamedFloatGrid::copyGrid()
{
    return std::make_shared<StreamedFloatGrid>(*this, openvdb::ShallowCopy());
}

openvdb::GridBase::ConstPtr StreamedFloatGrid::copyGrid() const
{
    return std::make_shared<StreamedFloatGrid>(const_cast<StreamedFloatGrid&>(*this), openvdb::ShallowCopy());
}

openvdb::Index64 StreamedFloatGrid::memUsage() const
{
    openvdb::Index64 missing = 0; // the buffers the written grid holds
    for (auto it = tree().cbeginLeaf(); it; ++it)
        if (it->buffer().empty()) missing += LeafT::SIZE * sizeof(float);
    return openvdb::FloatGrid::memUsage() + missing;
}

template <typename F>
void StreamedFloatGrid::forEachFilledLeaf(const F& f) const
{
    std::vector<const LeafT*> leaves;
    leaves.reserve(kBatchLeaves);
    std::vector<float> values;
    size_t index = 0;
    auto flush = [&] {
        values.assign(leaves.size() * LeafT::SIZE, background());
        (*mFill)(leaves.data(), leaves.size(), values.data());
        for (size_t i = 0; i < leaves.size(); ++i) f(index++, *leaves[i], values.data() + i * LeafT::SIZE);
        leaves.clear();
    };
    for (auto it = tree().cbeginLeaf(); it; ++it) {
        leaves.push_back(&*it);
        if (leaves.size() == kBatchLeaves) flush();
    }
    if (!leaves.empty()) flush();
}

void StreamedFloatGrid::writeBuffers(std::ostream& os) const
{
    // Tree::writeBuffers' order (root table, then each internal node's children, depth first) is
    // the leaf iterator's; each leaf as LeafNode::writeBuffers writes it.
    LeafT scratch(openvdb::Coord(0), background());
    const bool half = saveFloatAsHalf();
    forEachFilledLeaf([&](size_t, const LeafT& leaf, const float* v) {
        for (auto on = leaf.cbeginValueOn(); on; ++on)
            if (!std::isfinite(v[on.pos()])) throwNonFinite(*this, on.getCoord());
        scratch.setOrigin(leaf.origin());
        scratch.setValueMask(leaf.getValueMask());
        std::copy_n(v, LeafT::SIZE, scratch.buffer().data());
        scratch.writeBuffers(os, half);
    });
}

openvdb::io::DelayedLoadMetadata StreamedFloatGrid::delayedLoadMetadata(uint32_t compression) const
{
    // OpenVDB's populateDelayedLoadMetadata (io/Archive.cc) on the leaves with their values
    using MaskT = LeafT::NodeMaskType;
    openvdb::io::DelayedLoadMetadata meta;
    const size_t count = tree().leafCount();
    if (count == 0) return meta;
    const bool sized = compression & (openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ZIP);
    meta.resizeMask(count);
    if (sized) meta.resizeCompressedSize(count);
    const float bg = background();
    const bool half = saveFloatAsHalf();
    forEachFilledLeaf([&](size_t i, const LeafT& leaf, const float* v) {
        const openvdb::io::MaskCompress<float, MaskT> mc(leaf.valueMask(), MaskT(), v, bg);
        meta.setMask(i, mc.metadata);
        if (sized)
            meta.setCompressedSize(i, openvdb::io::writeCompressedValuesSize(v, LeafT::SIZE, leaf.valueMask(), mc.metadata,
                                                                            half, compression) + 8);
    });
    return meta;
}

} // namespace frostvdb
