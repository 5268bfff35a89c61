#pragma once
/// @file Fields.h
/// @brief The named fields of a run: OpenVDB grids sharing one transform, allocated only when an
/// effect asks for them. A field's background value is its far-field value (p = 0, T = T_inf),
/// so only voxels that differ from the far field are stored.
#include <openvdb/openvdb.h>

#include <map>
#include <memory>
#include <string>
#include <vector>

namespace frostvdb {

/// Call before writing a field's grid in place: gives it a tree of its own when another grid
/// shares it (a frame shares the trees of T and freeze_time instead of copying them; it is
/// written before the next step, but a caller may keep it longer).
template <typename GridT>
void ownTree(GridT& grid)
{
    if (grid.treePtr().use_count() > 2) // the grid's own reference and this call's copy
        grid.setTree(std::make_shared<typename GridT::TreeType>(grid.tree()));
}

class FieldSet {
public:
    explicit FieldSet(openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform())
        : mTransform(std::move(xform)) {}

    /// Returns the field, creating it with @a background on first request.
    template <typename GridT>
    typename GridT::Ptr require(const std::string& name, const typename GridT::ValueType& background)
    {
        auto it = mGrids.find(name);
        if (it != mGrids.end()) {
            auto g = openvdb::gridPtrCast<GridT>(it->second);
            if (!g) throw std::logic_error("field '" + name + "' requested with a different type");
            return g;
        }
        auto g = GridT::create(background);
        g->setName(name);
        g->setTransform(mTransform);
        mGrids[name] = g;
        mOrder.push_back(name);
        return g;
    }

    /// The field if allocated, else nullptr.
    template <typename GridT>
    typename GridT::Ptr get(const std::string& name) const
    {
        auto it = mGrids.find(name);
        return it == mGrids.end() ? nullptr : openvdb::gridPtrCast<GridT>(it->second);
    }

    /// The field of any type if allocated, else nullptr.
    openvdb::GridBase::Ptr base(const std::string& name) const
    {
        auto it = mGrids.find(name);
        return it == mGrids.end() ? nullptr : it->second;
    }

    /// Replaces a field's grid (e.g. after a solver swapped buffers); keeps name and transform.
    void replace(const std::string& name, openvdb::GridBase::Ptr grid)
    {
        grid->setName(name);
        grid->setTransform(mTransform);
        if (!mGrids.count(name)) mOrder.push_back(name);
        mGrids[name] = std::move(grid);
    }

    /// The field of any type if allocated, else nullptr.
    openvdb::GridBase::Ptr grid(const std::string& name) const
    {
        auto it = mGrids.find(name);
        return it == mGrids.end() ? nullptr : it->second;
    }

    bool has(const std::string& name) const { return mGrids.count(name) > 0; }
    const std::vector<std::string>& names() const { return mOrder; }
    openvdb::math::Transform::Ptr transform() const { return mTransform; }
    /// Bytes held by all fields' trees.
    uint64_t memoryUsage() const;
    /// Active voxels over all fields.
    uint64_t activeVoxels() const;

private:
    openvdb::math::Transform::Ptr mTransform;
    std::map<std::string, openvdb::GridBase::Ptr> mGrids;
    std::vector<std::string> mOrder;
};

} // namespace frostvdb
