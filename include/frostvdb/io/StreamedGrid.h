#pragma once
/// @file StreamedGrid.h
/// @brief A FloatGrid whose voxel values are made only while it is written to a VDB stream.
#include <openvdb/openvdb.h>
#include <openvdb/io/DelayedLoadMetadata.h>

#include <functional>
#include <memory>

namespace frostvdb {

/// A FloatGrid that holds its topology only (leaves made with openvdb::PartialCreate: masks, no
/// value buffers) and makes its leaves' values while it is written (writeBuffers), a batch of
/// leaves at a time. A large exported plane field (a plane-layout grid, ~2 KiB per leaf of 64
/// voxels) so costs its topology, ~100 bytes per leaf, while a frame is written. The file's bytes
/// are those of the grid with its values: OpenVDB writes a tree's buffers leaf by leaf in the
/// leaf iterator's order, each as LeafNode::writeBuffers, which is what is called here; its
/// memUsage (written as `file_mem_bytes`) counts the buffers it would hold.
///
/// Only the writer may read its values (a leaf's getValue reads 0): OpenVDB's Archive::writeGrid
/// would compute the grid's `file_delayed_load` metadata from the leaf buffers, so the VDB writer
/// (writeVdbStreamed) writes such a grid through its own copy of that function, with
/// delayedLoadMetadata. checkFinite leaves it to writeBuffers, which throws SimulationError on
/// the first non-finite active value.
class StreamedFloatGrid : public openvdb::FloatGrid {
public:
    using LeafT = openvdb::FloatTree::LeafNodeType;
    /// Sets values[i * LeafT::SIZE + n] for every active voxel n of leaves[i], i < count (the
    /// others are preset to the background); a pure function of the leaves, so it may run them
    /// in parallel.
    using Fill = std::function<void(const LeafT* const* leaves, size_t count, float* values)>;

    /// @a topology: the grid's tree (no active tiles), its leaves without buffers; @a like: the
    /// grid whose metadata and transform it takes.
    StreamedFloatGrid(openvdb::FloatTree::Ptr topology, const openvdb::GridBase& like, Fill fill);
    /// Shares the tree and the fill (as Grid's shallow copy).
    StreamedFloatGrid(StreamedFloatGrid& other, openvdb::ShallowCopy);

    openvdb::GridBase::Ptr copyGrid() override;
    openvdb::GridBase::ConstPtr copyGrid() const override;
    openvdb::Index64 memUsage() const override;
    void writeBuffers(std::ostream& os) const override;
    /// What OpenVDB's writer stores as `file_delayed_load` for this grid with its values, under
    /// the archive's @a compression flags: per leaf the mask compression code and, with Blosc or
    /// zip, the compressed size.
    openvdb::io::DelayedLoadMetadata delayedLoadMetadata(uint32_t compression) const;

private:
    /// Calls f(index, leaf, values) for every leaf in the leaf iterator's order (the order OpenVDB
    /// writes buffers in), its values made by the fill a batch at a time.
    template <typename F>
    void forEachFilledLeaf(const F& f) const;

    std::shared_ptr<const Fill> mFill;
};

} // namespace frostvdb
