/// @file GasGrid.cpp
/// @brief Sparse grid construction for the procedural gases, the VDB vector-field table and the
/// gas preview renderer.
#include <frostvdb/gas/GasGrid.h>

#include <frostvdb/core/Effect.h>
#include <frostvdb/core/Error.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/io/Png.h>
#include <frostvdb/io/VdbIO.h>

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <limits>
#include <string>
#include <cmath>

namespace frostvdb::gas {

using openvdb::Coord;
using openvdb::Vec3d;

openvdb::math::Transform::Ptr gasTransform(const World& world)
{
    auto xf = world.fields.transform();
    if (xf && xf->isLinear() && xf->hasUniformScale()) {
        const auto m = xf->baseMap()->getAffineMap()->getMat4();
        // uniform scale with no rotation/shear: diagonal 3x3 part
        bool diag = true;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                if (i != j && std::fabs(m(i, j)) > 1e-12) diag = false;
        if (diag) return xf;
    }
    auto t = openvdb::math::Transform::createLinearTransform(world.domain.voxelSize());
    return t;
}

namespace {

template <typename LeafT>
LeafT* newLeaf(const Coord& origin, typename LeafT::ValueType bg)
{
    return new LeafT(origin, bg, false);
}

} // namespace

namespace {

/// Origins of the leaves of the index box of the model's bounds that may hold gas, in a fixed
/// order (x, then y, then z), so the build is the same whatever the thread count.
template <typename Visit>
void visitCandidateLeaves(const GasModel& model, const GasContext& ctx, const openvdb::math::Transform& xform,
                          Visit&& visit)
{
    V3 lo, hi;
    model.bounds(ctx, lo, hi);
    // index-space box of the world bounds
    Coord imin(std::numeric_limits<int>::max()), imax(std::numeric_limits<int>::min());
    for (int c = 0; c < 8; ++c) {
        const Vec3d w((c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z);
        const Vec3d i = xform.worldToIndex(w);
        for (int a = 0; a < 3; ++a) {
            imin[a] = std::min(imin[a], int(std::floor(i[a])) - 1);
            imax[a] = std::max(imax[a], int(std::ceil(i[a])) + 1);
        }
    }
    const double dx = xform.voxelSize()[0];
    const double leafRadius = 0.5 * std::sqrt(3.0) * 7.0 * dx + 1e-9;
    for (int i = imin.x() & ~7; i <= imax.x(); i += 8)
        for (int j = imin.y() & ~7; j <= imax.y(); j += 8)
            for (int k = imin.z() & ~7; k <= imax.z(); k += 8) {
                const Vec3d w = xform.indexToWorld(Vec3d(i + 3.5, j + 3.5, k + 3.5));
                if (model.mayHold(V3(w.x(), w.y(), w.z()), leafRadius, ctx)) visit(Coord(i, j, k));
            }
}

std::vector<Coord> candidateLeafOrigins(const GasModel& model, const GasContext& ctx,
                                        const openvdb::math::Transform& xform)
{
    std::vector<Coord> origins;
    visitCandidateLeaves(model, ctx, xform, [&](const Coord& c) { origins.push_back(c); });
    return origins;
}

} // namespace

uint64_t countCandidateLeaves(const GasModel& model, const GasContext& ctx, const openvdb::math::Transform& xform)
{
    uint64_t n = 0;
    visitCandidateLeaves(model, ctx, xform, [&](const Coord&) { ++n; });
    return n;
}

double sampledGasLeafShare(const GasModel& model, const GasContext& ctx, const openvdb::math::Transform& xform,
                           size_t sampleLeaves)
{
    const std::vector<Coord> origins = candidateLeafOrigins(model, ctx, xform);
    if (origins.empty() || sampleLeaves == 0) return 1.0;
    // Every leaf when there are few; else a golden-ratio sequence over the build's order: an
    // even stride would alias with the box's rows (a stride of two rows picked only the bottom
    // layer of a box, below the gas).
    std::vector<size_t> picked;
    if (origins.size() <= sampleLeaves) {
        for (size_t i = 0; i < origins.size(); ++i) picked.push_back(i);
    } else {
        for (size_t k = 0; k < sampleLeaves; ++k) {
            const double u = std::fmod(0.5 + 0.6180339887498949 * double(k), 1.0);
            picked.push_back(std::min(origins.size() - 1, size_t(u * double(origins.size()))));
        }
    }
    const float thr = float(model.common().threshold);
    std::vector<char> holds(picked.size(), 0);
    tbb::parallel_for(size_t(0), picked.size(), [&](size_t k) {
        GasSample s;
        const Coord origin = origins[picked[k]];
        for (int dx = 0; dx < 8 && !holds[k]; ++dx)
            for (int dy = 0; dy < 8 && !holds[k]; ++dy)
                for (int dz = 0; dz < 8 && !holds[k]; ++dz) {
                    const Vec3d w = xform.indexToWorld(origin + Coord(dx, dy, dz));
                    model.evaluate(V3(w.x(), w.y(), w.z()), ctx, s);
                    holds[k] = float(s.density) > thr; // the build's test (a NaN holds nothing)
                }
    });
    const double m = double(picked.size());
    const double share = double(std::count(holds.begin(), holds.end(), char(1))) / m;
    return std::min(1.0, share + 2.0 * std::sqrt(share * (1.0 - share) / m) + 1.0 / m);
}

GasBuildEstimate estimateGasBuild(const GasModel& model, const GasContext& ctx,
                                  const openvdb::math::Transform& xform, const GasBuildOptions& opt,
                                  const std::string& label, const std::string& key)
{
    GasBuildEstimate e;
    model.bounds(ctx, e.lo, e.hi);
    // Index range in double first: OpenVDB coordinates are 32-bit and would wrap silently.
    constexpr double kMaxIndex = double(1 << 30);
    double cells[3] = {1, 1, 1};
    for (int a = 0; a < 3; ++a) {
        double lo = std::numeric_limits<double>::max(), hi = -lo;
        for (int c = 0; c < 8; ++c) {
            const Vec3d w((c & 1) ? e.hi.x : e.lo.x, (c & 2) ? e.hi.y : e.lo.y, (c & 4) ? e.hi.z : e.lo.z);
            const double i = xform.worldToIndex(w)[a];
            lo = std::min(lo, i);
            hi = std::max(hi, i);
        }
        if (!std::isfinite(lo) || !std::isfinite(hi) || std::fabs(lo) > kMaxIndex || std::fabs(hi) > kMaxIndex)
            throw SceneError(label, 0, key,
                             "the gas extends over " + std::to_string(e.hi.x - e.lo.x) + " x " +
                                 std::to_string(e.hi.y - e.lo.y) + " x " + std::to_string(e.hi.z - e.lo.z) +
                                 " m, beyond OpenVDB's index range (+-2^30 voxels) at voxel size " +
                                 std::to_string(xform.voxelSize()[0]) +
                                 " m: shrink the gas or raise domain.voxel_size");
        cells[a] = std::floor(hi / 8.0) - std::floor(lo / 8.0) + 2.0;
    }
    e.boxLeaves = cells[0] * cells[1] * cells[2];
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    using VecLeaf = openvdb::Vec3STree::LeafNodeType;
    double leafBytes = sizeof(FloatLeaf) + FloatLeaf::SIZE * sizeof(float);
    if (opt.velocity) leafBytes += sizeof(VecLeaf) + VecLeaf::SIZE * sizeof(openvdb::Vec3s);
    if (opt.fire) {
        leafBytes += 2 * (sizeof(FloatLeaf) + FloatLeaf::SIZE * sizeof(float));
        if (opt.colour) leafBytes += sizeof(VecLeaf) + VecLeaf::SIZE * sizeof(openvdb::Vec3s);
    }
    e.bytes = e.boxLeaves * (leafBytes + sizeof(Coord) + 5 * sizeof(void*));
    return e;
}

GasGrids buildGasGrids(const GasModel& model, const GasContext& ctx,
                       const openvdb::math::Transform::Ptr& xform, const GasBuildOptions& opt)
{
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    using VecLeaf = openvdb::Vec3STree::LeafNodeType;
    GasGrids out;
    const GasCommon& C = model.common();

    const std::vector<Coord> origins = candidateLeafOrigins(model, ctx, *xform);
    out.candidateLeaves = origins.size();
    out.evaluatedVoxels = origins.size() * 512ull;

    const size_t n = origins.size();
    std::vector<FloatLeaf*> dLeaves(n, nullptr), fLeaves(n, nullptr), tLeaves(n, nullptr);
    std::vector<VecLeaf*> vLeaves(n, nullptr), cLeaves(n, nullptr);
    const float thr = float(C.threshold);
    const bool wantVel = opt.velocity;
    const bool fire = opt.fire;

    // Named at the gas that made it (a guard: the scene keys keep every term finite).
    auto notFinite = [&](const char* grid, const Coord& ijk) {
        throw SimulationError(std::string("gas '") + model.kind() + "': " + grid + " is not finite at voxel " +
                              std::to_string(ijk.x()) + "," + std::to_string(ijk.y()) + "," + std::to_string(ijk.z()) +
                              " frame " + std::to_string(ctx.time.frame));
    };
    auto work = [&](const tbb::blocked_range<size_t>& r) {
        GasSample s;
        for (size_t li = r.begin(); li != r.end(); ++li) {
            std::unique_ptr<FloatLeaf> dl(newLeaf<FloatLeaf>(origins[li], 0.f));
            std::unique_ptr<VecLeaf> vl, cl;
            std::unique_ptr<FloatLeaf> fl, tl;
            bool any = false;
            for (openvdb::Index off = 0; off < FloatLeaf::SIZE; ++off) {
                const Coord ijk = dl->offsetToGlobalCoord(off);
                const Vec3d w = xform->indexToWorld(ijk);
                const V3 x(w.x(), w.y(), w.z());
                model.evaluate(x, ctx, s);
                const float d = float(s.density);
                // finiteness first: a NaN would fail the threshold test and vanish unseen
                if (!std::isfinite(d)) notFinite("density", ijk);
                if (!(d > thr)) continue;
                any = true;
                dl->setValueOn(off, d);
                if (wantVel) {
                    if (!vl) vl.reset(newLeaf<VecLeaf>(origins[li], openvdb::Vec3s(0.f)));
                    const V3 v = model.velocity(x, ctx);
                    const openvdb::Vec3s vs(float(v.x), float(v.y), float(v.z));
                    if (!(std::isfinite(vs.x()) && std::isfinite(vs.y()) && std::isfinite(vs.z())))
                        notFinite("vel", ijk);
                    vl->setValueOn(off, vs);
                }
                if (fire) {
                    if (!fl) fl.reset(newLeaf<FloatLeaf>(origins[li], 0.f));
                    if (!tl) tl.reset(newLeaf<FloatLeaf>(origins[li], float(opt.ambientTemperature)));
                    fl->setValueOn(off, float(s.flame));
                    tl->setValueOn(off, float(opt.ambientTemperature +
                                              s.flame * (opt.peakTemperature - opt.ambientTemperature)));
                    if (opt.colour) {
                        if (!cl) cl.reset(newLeaf<VecLeaf>(origins[li], openvdb::Vec3s(0.f)));
                        cl->setValueOn(off, openvdb::Vec3s(float(s.colour.x), float(s.colour.y), float(s.colour.z)));
                    }
                }
            }
            if (!any) continue;
            dLeaves[li] = dl.release();
            vLeaves[li] = vl.release();
            fLeaves[li] = fl.release();
            tLeaves[li] = tl.release();
            cLeaves[li] = cl.release();
        }
    };
    // A long frame is built in about 100 chunks with a progress call after each; every leaf is
    // built alone, so chunking changes nothing in the result.
    const size_t chunk = opt.progress ? std::max<size_t>(64, n / 100) : std::max<size_t>(n, 1);
    for (size_t b = 0; b < n; b += chunk) {
        const size_t e = std::min(n, b + chunk);
        if (opt.grain == 0) work(tbb::blocked_range<size_t>(b, e));
        else tbb::parallel_for(tbb::blocked_range<size_t>(b, e, opt.grain), work);
        if (opt.progress) opt.progress(e, n);
    }

    auto makeF = [&](const std::string& name, float bg, std::vector<FloatLeaf*>& leaves, bool fog) {
        auto g = openvdb::FloatGrid::create(bg);
        g->setName(name);
        g->setTransform(xform);
        if (fog) g->setGridClass(openvdb::GRID_FOG_VOLUME);
        for (auto* l : leaves)
            if (l) g->tree().addLeaf(l);
        return g;
    };
    auto makeV = [&](const std::string& name, std::vector<VecLeaf*>& leaves, openvdb::VecType vt) {
        auto g = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
        g->setName(name);
        g->setTransform(xform);
        g->setVectorType(vt);
        g->setIsInWorldSpace(true);
        for (auto* l : leaves)
            if (l) g->tree().addLeaf(l);
        return g;
    };
    out.density = makeF(out::kDensity.name, 0.f, dLeaves, true);
    if (wantVel) out.vel = makeV(out::kVel.name, vLeaves, openvdb::VEC_CONTRAVARIANT_RELATIVE);
    if (fire) {
        out.flame = makeF(out::kFlame.name, 0.f, fLeaves, true);
        out.temperature = makeF(out::kTemperature.name, float(opt.ambientTemperature), tLeaves, false);
        if (opt.colour) out.colour = makeV(out::kColour.name, cLeaves, openvdb::VEC_INVARIANT);
    }
    return out;
}

void evaluateDensityOver(const GasModel& model, const GasContext& ctx, openvdb::FloatGrid& grid)
{
    const auto& xform = grid.transform();
    openvdb::tree::LeafManager<openvdb::FloatTree> lm(grid.tree());
    tbb::parallel_for(lm.leafRange(4), [&](const openvdb::tree::LeafManager<openvdb::FloatTree>::LeafRange& r) {
        GasSample s;
        for (auto leaf = r.begin(); leaf; ++leaf)
            for (auto it = leaf->beginValueOn(); it; ++it) {
                const Vec3d w = xform.indexToWorld(it.getCoord());
                model.evaluate(V3(w.x(), w.y(), w.z()), ctx, s);
                it.setValue(float(s.density));
            }
    });
}

// -------------------------------------------------------------------------------------------------
// Vector-field table

struct VectorFieldTable::Impl {
    openvdb::Vec3SGrid::Ptr grid;
    openvdb::BBoxd worldBox; // world bounds of the active voxels
};

VectorFieldTable::VectorFieldTable() : mImpl(std::make_unique<Impl>()) {}
VectorFieldTable::~VectorFieldTable() = default;

namespace {
void finishTable(VectorFieldTable::Impl& impl)
{
    const openvdb::CoordBBox ib = impl.grid->evalActiveVoxelBoundingBox();
    const openvdb::BBoxd ibd(ib.min().asVec3d(), ib.max().asVec3d());
    impl.worldBox = impl.grid->transform().indexToWorld(ibd);
}
} // namespace

std::shared_ptr<VectorFieldTable> VectorFieldTable::load(const std::string& path, const std::string& gridName)
{
    openvdb::GridPtrVecPtr grids;
    try {
        grids = readVdb(path);
    } catch (const std::exception& e) {
        throw SceneError(path, 0, "vector_field.file", std::string("cannot read: ") + e.what());
    }
    for (auto& g : *grids) {
        if (g->getName() != gridName) continue;
        std::shared_ptr<VectorFieldTable> t(new VectorFieldTable());
        if (auto v = openvdb::gridPtrCast<openvdb::Vec3SGrid>(g)) t->mImpl->grid = v;
        else if (auto vd = openvdb::gridPtrCast<openvdb::Vec3DGrid>(g)) {
            auto v3 = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
            v3->setTransform(vd->transform().copy());
            auto acc = v3->getAccessor();
            for (auto it = vd->cbeginValueOn(); it; ++it)
                acc.setValue(it.getCoord(), openvdb::Vec3s(*it));
            t->mImpl->grid = v3;
        } else
            throw SceneError(path, 0, "vector_field.grid", "grid '" + gridName + "' is not a vector grid");
        if (t->mImpl->grid->activeVoxelCount() == 0)
            throw SceneError(path, 0, "vector_field.grid", "grid '" + gridName + "' has no active voxels");
        // a NaN or inf in the table would reach every gas's `vel` (and stop the run at output)
        for (auto it = t->mImpl->grid->cbeginValueAll(); it; ++it) {
            const openvdb::Vec3s v = *it;
            if (std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z())) continue;
            const Coord c = it.getCoord();
            throw SceneError(path, 0, "vector_field.file",
                             "grid '" + gridName + "' holds a non-finite velocity at voxel " + std::to_string(c.x()) +
                                 "," + std::to_string(c.y()) + "," + std::to_string(c.z()));
        }
        finishTable(*t->mImpl);
        return t;
    }
    throw SceneError(path, 0, "vector_field.grid", "no grid named '" + gridName + "' in the file");
}

std::shared_ptr<VectorFieldTable> VectorFieldTable::fromLattice(const V3& origin, double spacing, int nx, int ny,
                                                                int nz, const std::vector<V3>& values)
{
    std::shared_ptr<VectorFieldTable> t(new VectorFieldTable());
    auto g = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
    auto xf = openvdb::math::Transform::createLinearTransform(spacing);
    xf->postTranslate(Vec3d(origin.x, origin.y, origin.z));
    g->setTransform(xf);
    auto acc = g->getAccessor();
    for (int k = 0; k < nz; ++k)
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const V3& v = values.at(size_t(i + nx * (j + ny * k)));
                acc.setValue(Coord(i, j, k), openvdb::Vec3s(float(v.x), float(v.y), float(v.z)));
            }
    t->mImpl->grid = g;
    finishTable(*t->mImpl);
    return t;
}

double VectorFieldTable::maxSpeed() const
{
    double m = 0;
    for (auto it = mImpl->grid->cbeginValueOn(); it; ++it) m = std::max(m, double((*it).length()));
    return m;
}

V3 VectorFieldTable::sample(const V3& x) const
{
    // thread-safe: a fresh (cheap) accessor per call keeps the table const and shareable
    const openvdb::Vec3s v = openvdb::tools::BoxSampler::sample(
        mImpl->grid->tree(), mImpl->grid->transform().worldToIndex(Vec3d(x.x, x.y, x.z)));
    return {v.x(), v.y(), v.z()};
}

double VectorFieldTable::percent(const V3& x, const FlowTime& t) const
{
    const auto& b = mImpl->worldBox;
    double f = 1.0;
    for (int a = 0; a < 3; ++a) {
        const double p = a == 0 ? x.x : (a == 1 ? x.y : x.z);
        const double d = std::min(p - b.min()[a], b.max()[a] - p);
        if (d < 0) return 0.0;
        if (edge > 0 && d < edge) f *= 1.0 - cosineRamp(d / edge);
    }
    return f * maxPercent * std::clamp(strength(t.frame), 0.0, 1.0);
}

// -------------------------------------------------------------------------------------------------
// Preview

namespace {

template <typename GridT>
typename GridT::Ptr findGrid(const openvdb::GridPtrVec& grids, const std::string& name)
{
    for (auto& g : grids)
        if (g && g->getName() == name)
            if (auto t = openvdb::gridPtrCast<GridT>(g)) return t;
    return nullptr;
}

} // namespace

namespace {

/// The frame's gas grids sampled every s voxels over their active box, with the view's axes:
/// U the dominant axis of `up` (image vertical), H the image's horizontal axis, D the depth.
struct PreviewVolume {
    int U = 2, H = 0, D = 1;
    bool flipUp = false;
    int n[3] = {1, 1, 1};
    double dx = 1;                 ///< world size of one sample
    std::vector<float> rho, fl;    ///< density, flame (empty without flame)
    std::vector<openvdb::Vec3s> cd; ///< colour (empty without Cd)
    std::vector<float> iceTop;     ///< max ice per (H, D) column (with ice)
    bool fire = false, colour = false, ice = false;
    size_t idx(int i, int j, int k) const { return size_t(i) + size_t(n[0]) * (size_t(j) + size_t(n[1]) * k); }
    size_t at(int h, int u, int d) const
    {
        int ijk[3];
        ijk[H] = h;
        ijk[U] = u;
        ijk[D] = d;
        return idx(ijk[0], ijk[1], ijk[2]);
    }
};

PreviewVolume samplePreview(const openvdb::FloatGrid::Ptr& density, openvdb::FloatGrid::Ptr ice,
                            const openvdb::Vec3SGrid::Ptr& colour, const openvdb::FloatGrid::Ptr& flame, const V3& up,
                            int width)
{
    PreviewVolume v;
    openvdb::CoordBBox bb = density->evalActiveVoxelBoundingBox();
    if (ice && ice->activeVoxelCount() > 0 && ice->transform() == density->transform())
        bb.expand(ice->evalActiveVoxelBoundingBox());
    else
        ice.reset();
    if (bb.empty()) bb = openvdb::CoordBBox(Coord(0), Coord(7));

    const double uc[3] = {up.x, up.y, up.z};
    int U = 0;
    for (int a = 1; a < 3; ++a)
        if (std::fabs(uc[a]) > std::fabs(uc[U])) U = a;
    v.flipUp = uc[U] < 0;
    v.U = U;
    v.H = U == 0 ? 1 : 0;
    v.D = 3 - U - v.H;

    const int ext[3] = {bb.dim().x(), bb.dim().y(), bb.dim().z()};
    int s = std::max(1, int(std::ceil(double(std::max(ext[v.H], ext[U])) / width)));
    auto cells = [&](int step) {
        return double((ext[0] + step - 1) / step) * ((ext[1] + step - 1) / step) * ((ext[2] + step - 1) / step);
    };
    while (cells(s) > 12e6) ++s;
    for (int a = 0; a < 3; ++a) v.n[a] = (ext[a] + s - 1) / s;
    const size_t total = size_t(v.n[0]) * v.n[1] * v.n[2];
    v.rho.assign(total, 0.f);
    v.fl.assign(flame ? total : 0, 0.f);
    v.cd.resize(colour ? total : 0);
    v.iceTop.assign(size_t(v.n[v.H]) * v.n[v.D], 0.f);
    v.fire = flame != nullptr;
    v.colour = colour != nullptr;
    v.ice = ice != nullptr;
    v.dx = density->voxelSize()[0] * s;
    auto acc = density->getConstAccessor();
    std::unique_ptr<openvdb::FloatGrid::ConstAccessor> facc;
    std::unique_ptr<openvdb::Vec3SGrid::ConstAccessor> cacc;
    std::unique_ptr<openvdb::FloatGrid::ConstAccessor> iacc;
    if (flame) facc = std::make_unique<openvdb::FloatGrid::ConstAccessor>(flame->getConstAccessor());
    if (colour) cacc = std::make_unique<openvdb::Vec3SGrid::ConstAccessor>(colour->getConstAccessor());
    if (ice) iacc = std::make_unique<openvdb::FloatGrid::ConstAccessor>(ice->getConstAccessor());
    for (int k = 0; k < v.n[2]; ++k)
        for (int j = 0; j < v.n[1]; ++j)
            for (int i = 0; i < v.n[0]; ++i) {
                const Coord c = bb.min() + Coord(i * s, j * s, k * s);
                const size_t id = v.idx(i, j, k);
                v.rho[id] = std::max(0.f, acc.getValue(c));
                if (facc) v.fl[id] = facc->getValue(c);
                if (cacc) v.cd[id] = cacc->getValue(c);
                if (iacc) {
                    const int ijk[3] = {i, j, k};
                    float& t = v.iceTop[size_t(ijk[v.H]) + size_t(v.n[v.H]) * ijk[v.D]];
                    t = std::max(t, iacc->getValue(c));
                }
            }
    return v;
}

/// Extinction scale: the 99th percentile of view-column optical depth maps to ~2.5.
double extinctionScale(const PreviewVolume& v)
{
    std::vector<float> cols;
    cols.reserve(size_t(v.n[v.H]) * v.n[v.U]);
    for (int u = 0; u < v.n[v.U]; ++u)
        for (int h = 0; h < v.n[v.H]; ++h) {
            double sum = 0;
            for (int d = 0; d < v.n[v.D]; ++d) sum += v.rho[v.at(h, u, d)];
            if (sum > 0) cols.push_back(float(sum * v.dx));
        }
    if (cols.empty()) return 1.0;
    const size_t p = std::min(cols.size() - 1, size_t(cols.size() * 0.99));
    std::nth_element(cols.begin(), cols.begin() + long(p), cols.end());
    return 2.5 / std::max(1e-12, double(cols[p]));
}

/// Light from above: transmittance along -up from the top of the box.
std::vector<float> lightFromAbove(const PreviewVolume& v, double k)
{
    std::vector<float> light(v.rho.size(), 1.f);
    for (int d = 0; d < v.n[v.D]; ++d)
        for (int h = 0; h < v.n[v.H]; ++h) {
            double tau = 0;
            for (int q = 0; q < v.n[v.U]; ++q) {
                const int u = v.flipUp ? q : v.n[v.U] - 1 - q;
                const size_t id = v.at(h, u, d);
                light[id] = float(std::exp(-tau));
                tau += 0.6 * k * v.rho[id] * v.dx;
            }
        }
    return light;
}

/// Both panels: the side view along D and, with ice, the top view along -up over the frost.
ImageRGB renderPreview(const PreviewVolume& v, double k, const std::vector<float>& light)
{
    auto shade = [&](size_t id, double a, double T, double& r, double& g, double& b) {
        if (v.fire) {
            const openvdb::Vec3s c = v.colour ? v.cd[id] : openvdb::Vec3s(1.f, 0.6f, 0.2f);
            const double e = 0.4 + 1.6 * (v.fl.empty() ? 1.0 : v.fl[id]);
            r += T * a * c.x() * e;
            g += T * a * c.y() * e;
            b += T * a * c.z() * e;
        } else {
            const double l = 0.22 + 0.9 * light[id];
            r += T * a * l * 0.97;
            g += T * a * l * 0.98;
            b += T * a * l * 1.0;
        }
    };
    const int W = v.n[v.H], Hh = v.n[v.U];
    const int panels = v.ice ? 2 : 1;
    const int topH = v.ice ? v.n[v.D] : 0;
    ImageRGB img(W * panels + (panels - 1) * 4, std::max(Hh, topH));
    for (int py = 0; py < Hh; ++py)
        for (int px = 0; px < W; ++px) {
            const int u = v.flipUp ? py : Hh - 1 - py;
            double r = 0, g = 0, b = 0, T = 1;
            for (int d = 0; d < v.n[v.D] && T > 1e-3; ++d) {
                const size_t id = v.at(px, u, d);
                if (v.rho[id] <= 0) continue;
                const double a = 1.0 - std::exp(-k * v.rho[id] * v.dx);
                shade(id, a, T, r, g, b);
                T *= 1.0 - a;
            }
            const double fy = double(py) / std::max(1, Hh - 1);
            const double bgR = v.fire ? 0.02 : 0.10 + 0.08 * fy, bgG = v.fire ? 0.02 : 0.12 + 0.08 * fy,
                         bgB = v.fire ? 0.03 : 0.16 + 0.08 * fy;
            img.set(px, py, float(r + T * bgR), float(g + T * bgG), float(b + T * bgB));
        }
    if (!v.ice) return img;
    const int x0 = W + 4;
    for (int py = 0; py < topH; ++py)
        for (int px = 0; px < W; ++px) {
            const int d = topH - 1 - py;
            double r = 0, g = 0, b = 0, T = 1;
            for (int q = 0; q < v.n[v.U] && T > 1e-3; ++q) {
                const int u = v.flipUp ? q : v.n[v.U] - 1 - q;
                const size_t id = v.at(px, u, d);
                if (v.rho[id] <= 0) continue;
                const double a = 1.0 - std::exp(-k * v.rho[id] * v.dx);
                shade(id, a, T, r, g, b);
                T *= 1.0 - a;
            }
            const double p = std::clamp(double(v.iceTop[size_t(px) + size_t(W) * d]), 0.0, 1.0);
            const double bgR = 0.08 + 0.75 * p, bgG = 0.10 + 0.82 * p, bgB = 0.16 + 0.84 * p;
            img.set(x0 + px, py, float(r + T * bgR), float(g + T * bgG), float(b + T * bgB));
        }
    return img;
}

/// Small volumes: bilinear upscale by an integer factor f.
ImageRGB upscale(const ImageRGB& img, int f)
{
    ImageRGB big(img.width * f, img.height * f);
    for (int y = 0; y < big.height; ++y)
        for (int x = 0; x < big.width; ++x) {
            const double sx = std::clamp((x + 0.5) / f - 0.5, 0.0, img.width - 1.0);
            const double sy = std::clamp((y + 0.5) / f - 0.5, 0.0, img.height - 1.0);
            const int x0 = int(sx), y0 = int(sy);
            const int x1 = std::min(x0 + 1, img.width - 1), y1 = std::min(y0 + 1, img.height - 1);
            const double ax = sx - x0, ay = sy - y0;
            float c[3];
            for (int ch = 0; ch < 3; ++ch) {
                auto px = [&](int xx, int yy) { return img.rgb[(size_t(yy) * img.width + xx) * 3 + ch] / 255.0; };
                c[ch] = float((1 - ay) * ((1 - ax) * px(x0, y0) + ax * px(x1, y0)) +
                              ay * ((1 - ax) * px(x0, y1) + ax * px(x1, y1)));
            }
            big.set(x, y, c[0], c[1], c[2]);
        }
    return big;
}

} // namespace

void writeGasPreview(const openvdb::GridPtrVec& grids, const V3& up, const std::string& pngPath, int width)
{
    auto density = findGrid<openvdb::FloatGrid>(grids, out::kDensity.name);
    if (!density) throw SimulationError("gas preview: the frame has no density grid");
    auto ice = findGrid<openvdb::FloatGrid>(grids, out::kIce.name);
    if (ice && plane::isFolded(*ice)) ice = plane::unfoldGrid(*ice); // a frame's PNG copy may be folded
    const PreviewVolume v = samplePreview(density, ice,
                                          findGrid<openvdb::Vec3SGrid>(grids, out::kColour.name),
                                          findGrid<openvdb::FloatGrid>(grids, out::kFlame.name), up, width);
    const double k = extinctionScale(v);
    ImageRGB img = renderPreview(v, k, lightFromAbove(v, k));
    const int f = std::max(1, width / std::max(1, img.width));
    if (f > 1) img = upscale(img, f);
    writePngRGB(pngPath, img);
}

} // namespace frostvdb::gas
