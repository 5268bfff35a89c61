/// @file DlaEngine.cpp
/// @brief The DLA walkers: a dense view of the domain (ice flag + capped exact lattice distance
/// to the ice, one byte per cell; an 8-cell block distance for far jumps), release, walk, jump.
///
/// Why dense arrays and not VDB accessors: a walker reads its cell's distance at every step, and
/// 10^9 steps per run make the ~1 ns of a byte array against the ~10-20 ns of a ValueAccessor
/// probe the difference between seconds and minutes. A 1024^2 plane costs 1 MB.
#include <frostvdb/ice/Dla.h>
#include <frostvdb/core/Error.h>

#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace frostvdb {
namespace ice {

int64_t DlaParams::humidityAt(int64_t step) const
{
    int64_t h = humidity;
    for (const auto& s : schedule)
        if (step >= s.first) h = s.second;
    return h;
}

std::vector<openvdb::Coord> walkerNeighbours(const Domain& domain)
{
    return domain.walkerNeighbours();
}

namespace {
constexpr uint16_t kFar = 65535;
}

DlaEngine::DlaEngine(const Domain& domain, const DlaParams& params, uint64_t seed)
    : mDomain(domain), mParams(params), mSeed(hashCounters(seed, 0xD1A)), mNbr(walkerNeighbours(domain))
{
    const auto& bb = domain.bbox();
    if (bb.min() != openvdb::Coord(0)) throw std::logic_error("DlaEngine: the domain must start at 0");
    mNx = bb.dim().x();
    mNy = bb.dim().y();
    mNz = bb.dim().z();
    mDim = domain.dimension();
    for (const auto& o : mNbr) mNbrDelta.push_back(int64_t(o.x()) + mNx * (int64_t(o.y()) + mNy * int64_t(o.z())));
    mCap = mDim == 3 ? 16 : 64;
    mFine.assign(size_t(cellCount()), uint8_t(mCap));
    const int b = 1 << kBlockLog2;
    mBx = (mNx + b - 1) / b;
    mBy = (mNy + b - 1) / b;
    mBz = (mNz + b - 1) / b;
    mBlockIce.assign(size_t(mBx * mBy * mBz), 0);
    mCoarse.assign(mBlockIce.size(), kFar);
    mDigits = std::max(1, int(48.0 / std::log2(double(mNbr.size()))));

    // jump tables: every radius up to 16, then ~20% apart, up to the largest useful one
    if (params.jumps) {
        int rmax = params.jumpMaxRadius > 0 ? params.jumpMaxRadius : (domain.flat() ? 128 : 32);
        int64_t half = std::max(mNx, mNy);
        if (mDim == 3) half = std::max(half, mNz);
        rmax = int(std::min<int64_t>(rmax, (half + 1) / 2));
        std::vector<int> radii;
        for (int r = std::max(2, params.jumpMinRadius); r <= rmax; r = r < 16 ? r + 1 : int(std::ceil(r * 1.2)))
            radii.push_back(r);
        if (!radii.empty() && radii.back() != rmax && rmax >= params.jumpMinRadius) radii.push_back(rmax);
        mTables.resize(radii.size());
        tbb::parallel_for(size_t(0), radii.size(), [&](size_t i) { mTables[i] = shellTable(mNbr, radii[i]); });
        if (!radii.empty()) {
            mTableForRadius.assign(size_t(radii.back()) + 1, -1);
            for (size_t i = 0; i < radii.size(); ++i)
                for (int r = radii[i]; r <= radii.back(); ++r) mTableForRadius[size_t(r)] = int16_t(i);
        }
    }
}

int DlaEngine::outsideDistance(int x, int y, int z) const
{
    int m = std::min(std::min(x, int(mNx) - 1 - x), std::min(y, int(mNy) - 1 - y));
    if (mDim == 3) m = std::min(m, std::min(z, int(mNz) - 1 - z));
    return m + 1;
}

int DlaEngine::iceDistance(const openvdb::Coord& c) const
{
    const int f = mFine[size_t(index(c))];
    if (f < mCap) return f;
    const int64_t b = (c.x() >> kBlockLog2) + mBx * ((c.y() >> kBlockLog2) + mBy * (c.z() >> kBlockLog2));
    const int k = mCoarse[size_t(b)];
    if (k == 0) return mCap;
    const int mask = (1 << kBlockLog2) - 1;
    auto edge = [&](int v) { const int o = v & mask; return std::min(o, mask - o); };
    int m = std::min(edge(c.x()), edge(c.y()));
    if (mDim == 3) m = std::min(m, edge(c.z()));
    // an ice cell lies >= k blocks away along some axis: >= (k-1) B + 1 + m cells (Chebyshev),
    // and a lattice step moves each index by at most 1
    const int64_t bound = int64_t(k - 1) * (1 << kBlockLog2) + 1 + m;
    return int(std::max<int64_t>(mCap, std::min<int64_t>(bound, 1 << 30)));
}

void DlaEngine::relaxFrom(int64_t cell)
{
    mQueue.clear();
    mQueue.push_back(cell);
    relaxQueue();
}

void DlaEngine::relaxQueue()
{
    for (size_t q = 0; q < mQueue.size(); ++q) {
        const int64_t u = mQueue[q];
        const int d = mFine[size_t(u)] + 1;
        if (d >= mCap) continue;
        const openvdb::Coord c = coord(u);
        for (size_t k = 0; k < mNbr.size(); ++k) {
            const openvdb::Coord n = c + mNbr[k];
            if (n.x() < 0 || n.y() < 0 || n.z() < 0 || n.x() >= mNx || n.y() >= mNy || n.z() >= mNz) continue;
            const int64_t v = u + mNbrDelta[k];
            if (mFine[size_t(v)] > d) {
                mFine[size_t(v)] = uint8_t(d);
                mQueue.push_back(v);
            }
        }
    }
}

void DlaEngine::markBlock(int64_t cell)
{
    const openvdb::Coord c = coord(cell);
    const int64_t b = (c.x() >> kBlockLog2) + mBx * ((c.y() >> kBlockLog2) + mBy * (c.z() >> kBlockLog2));
    if (mBlockIce[size_t(b)]++ > 0) return;
    // incremental Chebyshev BFS over the blocks
    mCoarse[size_t(b)] = 0;
    std::vector<int64_t> q{b};
    const int zr = mDim == 3 ? 1 : 0;
    for (size_t h = 0; h < q.size(); ++h) {
        const int64_t u = q[h];
        const int d = mCoarse[size_t(u)] + 1;
        const int64_t ux = u % mBx, uy = (u / mBx) % mBy, uz = u / (mBx * mBy);
        for (int dz = -zr; dz <= zr; ++dz)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) {
                    const int64_t x = ux + dx, y = uy + dy, z = uz + dz;
                    if (x < 0 || y < 0 || z < 0 || x >= mBx || y >= mBy || z >= mBz) continue;
                    const int64_t v = x + mBx * (y + mBy * z);
                    if (mCoarse[size_t(v)] > d) {
                        mCoarse[size_t(v)] = uint16_t(std::min(d, int(kFar) - 1));
                        q.push_back(v);
                    }
                }
    }
}

void DlaEngine::freeze(int64_t cell)
{
    if (mFine[size_t(cell)] == 0) return;
    mFine[size_t(cell)] = 0;
    ++mIceCount;
    markBlock(cell);
    relaxFrom(cell);
}

void DlaEngine::rebuild(const openvdb::FloatGrid& p)
{
    std::fill(mFine.begin(), mFine.end(), uint8_t(mCap));
    std::fill(mBlockIce.begin(), mBlockIce.end(), 0u);
    std::fill(mCoarse.begin(), mCoarse.end(), kFar);
    mIceCount = 0;
    std::vector<int64_t> ice;
    for (auto it = p.cbeginValueOn(); it; ++it) {
        if (!(*it > 0.5f)) continue;
        openvdb::CoordBBox bb = it.getBoundingBox();
        bb.intersect(mDomain.bbox());
        for (auto c = bb.begin(); c; ++c) ice.push_back(index(*c));
    }
    for (int64_t i : ice)
        if (mFine[size_t(i)] != 0) {
            mFine[size_t(i)] = 0;
            ++mIceCount;
            markBlock(i);
        }
    // multi-source BFS
    mQueue.clear();
    for (int64_t i : ice) mQueue.push_back(i);
    relaxQueue();
}

void DlaEngine::sync(const openvdb::FloatGrid& p)
{
    // p > 1/2 cells: counted and the new ones collected leaf by leaf in parallel (the order of
    // freezing does not matter: the capped distances are the unique BFS minimum)
    openvdb::tree::LeafManager<const openvdb::FloatTree> leaves(p.tree());
    const size_t nl = leaves.leafCount();
    std::vector<uint64_t> counts(nl, 0);
    std::vector<std::vector<int64_t>> fresh(nl);
    const openvdb::CoordBBox dom = mDomain.bbox();
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nl, 8), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t l = r.begin(); l != r.end(); ++l) {
            const auto& leaf = leaves.leaf(l);
            for (auto it = leaf.cbeginValueOn(); it; ++it) {
                if (!(*it > 0.5f)) continue;
                const openvdb::Coord c = it.getCoord();
                if (!dom.isInside(c)) continue;
                ++counts[l];
                const int64_t i = index(c);
                if (mFine[size_t(i)] != 0) fresh[l].push_back(i);
            }
        }
    });
    uint64_t count = 0, nfresh = 0;
    for (size_t l = 0; l < nl; ++l) {
        count += counts[l];
        nfresh += fresh[l].size();
    }
    std::vector<int64_t> tiles; // active tiles above 1/2 (rare: a pruned block of ice)
    auto tileIt = p.tree().cbeginValueOn();
    tileIt.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1); // tiles only
    for (auto& it = tileIt; it; ++it) {
        if (!(*it > 0.5f)) continue;
        openvdb::CoordBBox bb = it.getBoundingBox();
        bb.intersect(dom);
        for (auto c = bb.begin(); c; ++c) {
            ++count;
            const int64_t i = index(*c);
            if (mFine[size_t(i)] != 0) tiles.push_back(i);
        }
    }
    nfresh += tiles.size();
    if (count != mIceCount + nfresh) {
        rebuild(p); // some ice melted: start again
        return;
    }
    for (const auto& f : fresh)
        for (int64_t i : f) freeze(i);
    for (int64_t i : tiles) freeze(i);
}

double DlaEngine::stickingProbability(const Inputs& in, int64_t cell) const
{
    if (!in.melt) return 1.0;
    return double(in.melt->tree().getValue(coord(cell)));
}

int64_t DlaEngine::release(int64_t step, uint64_t walker, WalkerRng& rng, const Inputs& in) const
{
    const uint64_t n = uint64_t(cellCount());
    auto below = [&](uint64_t m) { return uint64_t((static_cast<unsigned __int128>(rng.next()) * m) >> 64); };
    for (int tries = 0; tries < 64; ++tries) {
        int64_t cell = -1;
        if (in.steamCdf && walker >= uint64_t(in.baseWalkers) && !in.steamCdf->empty()) {
            const double u = rng.uniform() * in.steamCdf->back();
            const size_t k = size_t(std::upper_bound(in.steamCdf->begin(), in.steamCdf->end(), u) - in.steamCdf->begin());
            cell = (*in.steamCells)[std::min(k, in.steamCells->size() - 1)];
        } else if (mParams.release == DlaRelease::Uniform) {
            cell = int64_t(below(n));
        } else {
            // perimeter: a face (edge) chosen by its cell count, then a cell on it
            const int64_t fx = mNy * mNz, fy = mNx * mNz, fz = mDim == 3 ? mNx * mNy : 0;
            const uint64_t total = uint64_t(2 * (fx + fy + fz));
            int64_t k = int64_t(below(total));
            int64_t x, y, z;
            const int64_t face = k < 2 * fx ? 0 : (k < 2 * (fx + fy) ? 1 : 2);
            if (face == 0) {
                x = (k % 2) ? mNx - 1 : 0;
                k /= 2;
                y = k % mNy;
                z = k / mNy;
            } else if (face == 1) {
                k -= 2 * fx;
                y = (k % 2) ? mNy - 1 : 0;
                k /= 2;
                x = k % mNx;
                z = k / mNx;
            } else {
                k -= 2 * (fx + fy);
                z = (k % 2) ? mNz - 1 : 0;
                k /= 2;
                x = k % mNx;
                y = k / mNx;
            }
            cell = x + mNx * (y + mNy * z);
        }
        if (mFine[size_t(cell)] != 0) return cell;
    }
    return -1;
}

namespace {

/// Per-thread probes of the optional grids.
struct Probes {
    std::unique_ptr<openvdb::FloatGrid::ConstAccessor> melt;
    std::unique_ptr<openvdb::Vec3SGrid::ConstAccessor> vel;
    explicit Probes(const DlaEngine::Inputs& in)
    {
        if (in.melt) melt = std::make_unique<openvdb::FloatGrid::ConstAccessor>(in.melt->getConstAccessor());
        if (in.vel) vel = std::make_unique<openvdb::Vec3SGrid::ConstAccessor>(in.vel->getConstAccessor());
    }
};

} // namespace

// The walk proper; Probes carries the per-thread accessors.
static WalkEnd walkImpl(const DlaEngine& e, const DlaParams& P, const std::vector<uint8_t>& fine,
                        const std::vector<int64_t>& delta, int dim, int digits,
                        const std::vector<std::shared_ptr<const ShellTable>>& tables,
                        const std::vector<int16_t>& tableFor, WalkerRng& rng, int64_t idx,
                        const DlaEngine::Inputs& in, Probes& pr);

WalkEnd DlaEngine::walk(int64_t step, uint64_t walker, uint64_t salt, int64_t start, const Inputs& in) const
{
    WalkerRng rng(mSeed, walker, uint64_t(step), salt);
    const int64_t idx = start >= 0 ? start : release(step, walker, rng, in);
    if (idx < 0) return WalkEnd{};
    Probes pr(in);
    return walkImpl(*this, mParams, mFine, mNbrDelta, mDim, mDigits, mTables, mTableForRadius, rng, idx, in, pr);
}

void DlaEngine::walkBatch(int64_t step, uint64_t first, uint64_t count, const Inputs& in,
                          std::vector<WalkEnd>& out) const
{
    out.assign(size_t(count), WalkEnd{});
    tbb::parallel_for(tbb::blocked_range<uint64_t>(0, count, 16), [&](const tbb::blocked_range<uint64_t>& r) {
        Probes pr(in);
        for (uint64_t w = r.begin(); w != r.end(); ++w) {
            WalkerRng rng(mSeed, first + w, uint64_t(step));
            const int64_t idx = release(step, first + w, rng, in);
            if (idx < 0) continue;
            out[size_t(w)] = walkImpl(*this, mParams, mFine, mNbrDelta, mDim, mDigits, mTables, mTableForRadius,
                                      rng, idx, in, pr);
        }
    });
}

static WalkEnd walkImpl(const DlaEngine& e, const DlaParams& P, const std::vector<uint8_t>& fine,
                        const std::vector<int64_t>& delta, int dim, int digits,
                        const std::vector<std::shared_ptr<const ShellTable>>& tables,
                        const std::vector<int16_t>& tableFor, WalkerRng& rng, int64_t idx,
                        const DlaEngine::Inputs& in, Probes& pr)
{
    WalkEnd end;
    const auto& nbr = e.neighbours();
    const int deg = int(nbr.size());
    const auto& bb = e.domain().bbox();
    const int nx = bb.dim().x(), ny = bb.dim().y(), nz = bb.dim().z();
    openvdb::Coord c = e.coord(idx);
    int x = c.x(), y = c.y(), z = c.z();
    int64_t prev = -1;
    uint64_t bits = 0;
    int left = 0;
    double steps = 0;
    const bool drift = pr.vel != nullptr;
    openvdb::Vec3d acc(0.0);
    const int maxR = tableFor.empty() ? 0 : int(tableFor.size()) - 1;
    const auto xform = e.domain().transform();

    auto velocityAt = [&](int i, int j, int k) {
        openvdb::Vec3d v;
        if (in.velOnDomainTransform) {
            v = pr.vel->getValue(openvdb::Coord(i, j, k));
        } else {
            const openvdb::Vec3d w = xform->indexToWorld(openvdb::Vec3d(i, j, k));
            v = pr.vel->getValue(in.vel->transform().worldToIndexNodeCentered(w));
        }
        const auto& m = in.velToCells;
        openvdb::Vec3d cells(m(0, 0) * v[0] + m(0, 1) * v[1] + m(0, 2) * v[2],
                             m(1, 0) * v[0] + m(1, 1) * v[1] + m(1, 2) * v[2],
                             dim == 3 ? m(2, 0) * v[0] + m(2, 1) * v[1] + m(2, 2) * v[2] : 0.0);
        return cells;
    };
    auto outside = [&](int i, int j, int k) { return i < 0 || j < 0 || k < 0 || i >= nx || j >= ny || k >= nz; };

    for (;;) {
        const int f = fine[size_t(idx)];
        if (f == 1) { // next to ice: the sticking roll
            double s = 1.0;
            if (pr.melt) s = double(pr.melt->getValue(openvdb::Coord(x, y, z)));
            if (s >= 1.0 || (s > 0.0 && rng.uniform() < s)) {
                end.kind = WalkEnd::Stuck;
                end.cell = idx;
                end.prev = prev;
                end.latticeSteps = steps;
                return end;
            }
        }
        if (P.maxSteps > 0 && steps >= double(P.maxSteps)) {
            end.kind = WalkEnd::Exhausted;
            end.latticeSteps = steps;
            return end;
        }
        ++end.moves;
        // empty-space jump
        bool jumped = false;
        if (maxR > 0 && f >= P.jumpMinRadius + 2) {
            const int dIce = e.iceDistance(openvdb::Coord(x, y, z));
            int dOut = 1 + std::min(std::min(x, nx - 1 - x), std::min(y, ny - 1 - y));
            if (dim == 3) dOut = std::min(dOut, 1 + std::min(z, nz - 1 - z));
            // interior of the ball inside the domain (r <= dOut), no cell of it next to ice and the
            // landing cell at least 2 from the ice (r <= dIce - 2): the walk inside is a free walk
            int r = std::min(std::min(dIce - 2, dOut), maxR);
            openvdb::Vec3d v(0.0);
            if (drift) {
                v = velocityAt(x, y, z);
                const double vm = v.length();
                // the drift over the jump's mean time (~r^2 steps) must stay under half a cell
                if (vm > 0) r = std::min(r, int(std::sqrt(0.5 / vm)));
            }
            const int ti = r >= P.jumpMinRadius ? tableFor[size_t(r)] : -1;
            if (ti >= 0) {
                const ShellTable& t = *tables[size_t(ti)];
                uint32_t k = t.sample(rng.next());
                if (P.testJumpBias > 0 && rng.uniform() < P.testJumpBias) {
                    const uint32_t k2 = t.sample(rng.next());
                    if (t.exits[k2].x() > t.exits[k].x()) k = k2;
                }
                const openvdb::Coord& o = t.exits[k];
                x += o.x();
                y += o.y();
                z += o.z();
                steps += t.meanSteps;
                ++end.jumps;
                prev = -1;
                if (outside(x, y, z)) break;
                idx = int64_t(x) + int64_t(nx) * (int64_t(y) + int64_t(ny) * int64_t(z));
                if (!drift) continue;
                acc += v * t.meanSteps;
                jumped = true;
            }
        }
        if (!jumped) {
            // one random lattice step
            if (left == 0) {
                bits = rng.next();
                left = digits;
            }
            const unsigned dir = unsigned((static_cast<unsigned __int128>(bits) * unsigned(deg)) >> 64);
            bits *= uint64_t(deg);
            --left;
            const int i = x + nbr[dir].x(), j = y + nbr[dir].y(), k = z + nbr[dir].z();
            if (outside(i, j, k)) break;
            const int64_t n = idx + delta[dir];
            if (fine[size_t(n)] != 0) { // ice cannot be entered: the walker stays
                prev = idx;
                idx = n;
                x = i;
                y = j;
                z = k;
            }
            steps += 1;
            if (drift) acc += velocityAt(x, y, z);
        }
        if (drift) {
            bool killed = false;
            for (int a = 0; a < dim && !killed; ++a) {
                while (std::fabs(acc[a]) >= 1.0) {
                    const int s = acc[a] > 0 ? 1 : -1;
                    int i = x, j = y, k = z;
                    (a == 0 ? i : a == 1 ? j : k) += s;
                    if (outside(i, j, k)) {
                        killed = true;
                        break;
                    }
                    const int64_t n = int64_t(i) + int64_t(nx) * (int64_t(j) + int64_t(ny) * int64_t(k));
                    if (fine[size_t(n)] == 0) { // pushed against the ice: the drift is spent
                        acc[a] = 0;
                        break;
                    }
                    prev = idx;
                    idx = n;
                    x = i;
                    y = j;
                    z = k;
                    acc[a] -= s;
                }
            }
            if (killed) break;
        }
    }
    end.kind = WalkEnd::Killed;
    end.latticeSteps = steps;
    return end;
}

} // namespace ice
} // namespace frostvdb
