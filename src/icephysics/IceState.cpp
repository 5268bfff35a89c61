#include <frostvdb/icephysics/IceState.h>

#include <frostvdb/core/Export.h>
#include <frostvdb/core/PlaneFold.h>

#include <openvdb/tools/Count.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>
#include <openvdb/tools/ValueTransformer.h>

#include <algorithm>
#include <cmath>

namespace frostvdb {
namespace ice {

void stampDisc(World& world, openvdb::FloatGrid& p, const std::vector<double>& f, double radius)
{
    const Domain& dom = world.domain;
    const openvdb::Vec3d centre = dom.parameterToIndex(f);
    // Measured in the lattice's own geometry so that a hexagonal seed is round too; the index
    // window is wide enough for the hex shear (|di| <= r + |dj|/2).
    const openvdb::Vec2d c2 = dom.lattice().planePosition(centre.x(), centre.y());
    const int r = int(std::ceil(radius * 2.0)) + 1;
    auto acc = p.getAccessor();
    const int k0 = std::max(dom.bbox().min().z(), int(std::floor(centre.z())) - r); // a flat domain: its layer
    const int k1 = std::min(dom.bbox().max().z(), int(std::ceil(centre.z())) + r);
    for (int k = k0; k <= k1; ++k)
        for (int j = int(centre.y()) - r; j <= int(centre.y()) + r; ++j)
            for (int i = int(centre.x()) - r; i <= int(centre.x()) + r; ++i) {
                const openvdb::Coord c(i, j, k);
                if (!dom.contains(c)) continue;
                const openvdb::Vec2d q = dom.lattice().planePosition(i, j) - c2;
                const double dz = k - centre.z();
                if (q.lengthSqr() + dz * dz <= radius * radius) acc.setValue(c, 1.f);
            }
}

void requireIceFields(World& world, bool defaultCrystal)
{
    const bool hadPhase = world.fields.has(kPhase);
    auto p = world.fields.require<openvdb::FloatGrid>(kPhase, 0.f);
    world.fields.require<openvdb::FloatGrid>(kTemperature, float(shared(world).farTemperature));
    // The accumulators are written cell by cell and read only by frames: on a plane they are
    // folded (core/PlaneFold.h), 8x denser; frames unfold them.
    const bool fold = plane::foldsPlaneFields(world.domain);
    for (const auto* key : {&kGrowth, &kFreezeTime})
        if (!world.fields.has(*key)) {
            auto g = world.fields.require<openvdb::FloatGrid>(*key, 0.f);
            if (fold) plane::markFolded(*g);
        }
    if (!hadPhase && defaultCrystal) stampDisc(world, *p, {0.5, 0.5, 0.5}, 3.0);
}

void recordPhaseChange(openvdb::FloatGrid::Accessor& growth, openvdb::FloatGrid::Accessor& freeze,
                       const openvdb::Coord& c, float before, float after, double time)
{
    if (after > before) growth.setValue(c, growth.getValue(c) + (after - before));
    if (before <= 0.5f && after > 0.5f && freeze.getValue(c) == 0.f) freeze.setValue(c, float(time));
}

namespace {

/// exportFoldedStreamed in the current ExportScope (exportsFoldedInPlace holds): the writer
/// makes the grid's values as it writes them.
openvdb::GridBase::Ptr exportFoldedNow(const openvdb::FloatGrid::ConstPtr& folded,
                                       const std::function<void(openvdb::FloatGrid&)>& dress)
{
    const ExportScope* s = ExportScope::current();
    return exportFoldedStreamed(folded, s->domain(), s->keepLattice(), dress);
}

/// p as a fog volume (values in [0,1], background 0, nothing stored where there is no ice), in
/// place on @a ice (a copy of p, in either layout).
openvdb::FloatGrid::Ptr toFog(openvdb::FloatGrid::Ptr ice)
{
    // Per leaf: switching voxels off writes the leaf's mask words, which a voxel-parallel
    // foreach raced on (the frame's topology then varied from run to run).
    auto clampToFog = [](auto& it) {
        const float v = std::min(std::max(*it, 0.f), 1.f);
        it.setValue(v);
        if (v <= 0.f) it.setValueOff();
    };
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(ice->tree());
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType& leaf, size_t) {
        for (auto it = leaf.beginValueOn(); it; ++it) clampToFog(it);
    });
    auto tiles = ice->tree().beginValueOn();
    tiles.setMaxDepth(openvdb::FloatTree::ValueOnIter::LEAF_DEPTH - 1);
    for (; tiles; ++tiles) clampToFog(tiles);
    openvdb::tools::pruneInactive(ice->tree());
    ice->setName(out::kIce.name);
    ice->setGridClass(openvdb::GRID_FOG_VOLUME);
    return ice;
}

/// The frame's `ice`: p as a fog volume, in the plane layout.
openvdb::GridBase::Ptr iceFog(const openvdb::FloatGrid& p)
{
    return toFog(plane::isFolded(p) ? plane::unfoldGrid(p) : p.deepCopy()); // frames hold the plane layout
}

/// The frame's `growth`: growth_acc normalised to [0,1] (the paper's displacement map), in the
/// plane layout when growth_acc is folded.
openvdb::GridBase::Ptr normalisedGrowth(const openvdb::FloatGrid& acc)
{
    auto growth = plane::isFolded(acc) ? plane::unfoldGrid(acc) : acc.deepCopy();
    normaliseGrowth(*growth);
    return growth;
}

/// growth_acc normalised (the frame's `growth`) in its own layout.
openvdb::FloatGrid::Ptr normalisedFolded(const openvdb::FloatGrid& acc)
{
    auto growth = acc.deepCopy();
    normaliseGrowth(*growth);
    return growth;
}

} // namespace

void normaliseGrowth(openvdb::FloatGrid& growth)
{
    const float mx = growth.activeVoxelCount() > 0 ? openvdb::tools::minMax(growth.tree()).max() : 0.f;
    const float scale = mx > 0 ? 1.f / mx : 0.f;
    openvdb::tools::foreach(growth.beginValueOn(), [scale](const openvdb::FloatGrid::ValueOnIter& it) {
        it.setValue(std::min(1.f, *it * scale));
    });
    growth.setName(out::kGrowth.name);
}

void addIceOutputs(World& world, Frame& frame)
{
    for (const auto& g : frame.grids)
        if (g->getName() == out::kIce.name) return;
    auto p = world.fields.get<openvdb::FloatGrid>(kPhase);
    if (!p) return;
    // Copies of live fields: the writer may drop them and make them again when it writes them
    // (the fields do not change in between), so a frame being written holds one at a time.
    // Folded p: the copy the PNGs read is folded too (4.5 bytes per voxel against the plane
    // layout's 36; the preview reads it in place), and is made again for the writer.
    frame.addCopy(plane::isFolded(*p) ? toFog(p->deepCopy()) : iceFog(*p), [p]() -> openvdb::GridBase::Ptr {
        // made again for the VDB writer: exported from a folded fog copy, in place (the clamp and
        // the pruning commute with the fold: a plane leaf is pruned when its chunk has no active
        // voxel left)
        if (exportsFoldedInPlace(*p)) return exportFoldedNow(toFog(p->deepCopy()), nullptr);
        return iceFog(*p);
    });
    addIceFieldOutputs(world, frame);
}

void addIceFieldOutputs(World& world, Frame& frame)
{
    if (auto T = world.fields.get<openvdb::FloatGrid>(kTemperature); T && plane::isFolded(*T)) {
        // folded T (core/PlaneFold.h): its plane-layout copy (36 bytes per voxel, the frame's
        // largest grid) is made only when the writer reaches it, and dropped once written
        // (for the VDB writer: exported in place, without that copy)
        frame.addDeferred(out::kIceTemperature, [T]() -> openvdb::GridBase::Ptr {
            auto dress = [](openvdb::FloatGrid& g) {
                g.setGridClass(openvdb::GRID_UNKNOWN);
                g.setName(out::kIceTemperature.name);
            };
            if (exportsFoldedInPlace(*T)) return exportFoldedNow(T, dress);
            auto temperature = plane::unfoldGrid(*T);
            dress(*temperature);
            return temperature;
        });
    } else if (T) {
        // Shares T's tree (the largest grid: the heat's halo): the frame is written before the
        // next step, and an in-place writer copies a shared tree first (ownTree, DlaEffect::step).
        auto temperature = openvdb::gridPtrCast<openvdb::FloatGrid>(T->copyGrid());
        temperature->setName(out::kIceTemperature.name); // dimensionless: not the gas's Kelvin
        temperature->setGridClass(openvdb::GRID_UNKNOWN);
        frame.add(temperature);
    }
    // growth_acc and freeze_time may be folded (core/PlaneFold.h): frames hold the plane layout.
    if (auto acc = world.fields.get<openvdb::FloatGrid>(kGrowth)) {
        // folded: the copy the displacement map reads is folded too (read in place, as ice's)
        frame.addCopy(plane::isFolded(*acc) ? normalisedFolded(*acc) : normalisedGrowth(*acc), [acc]() -> openvdb::GridBase::Ptr {
            if (exportsFoldedInPlace(*acc)) { // normalised folded (the same active values), exported in place
                auto growth = acc->deepCopy();
                normaliseGrowth(*growth);
                return exportFoldedNow(growth, nullptr);
            }
            return normalisedGrowth(*acc);
        });
    }
    if (auto f = world.fields.get<openvdb::FloatGrid>(kFreezeTime)) {
        if (plane::isFolded(*f)) {
            // made when something reads it (the VDB writer: exported in place)
            frame.addDeferred(out::kFreezeTime, [f]() -> openvdb::GridBase::Ptr {
                auto dress = [](openvdb::FloatGrid& g) { g.setName(out::kFreezeTime.name); };
                if (exportsFoldedInPlace(*f)) return exportFoldedNow(f, dress);
                auto freeze = plane::unfoldGrid(*f);
                dress(*freeze);
                return freeze;
            });
        } else {
            // Shares the field's tree, as T does: its writers copy a shared tree first (ownTree).
            auto freeze = openvdb::gridPtrCast<openvdb::FloatGrid>(f->copyGrid());
            freeze->setName(out::kFreezeTime.name);
            frame.add(freeze);
        }
    }
}

} // namespace ice
} // namespace frostvdb
