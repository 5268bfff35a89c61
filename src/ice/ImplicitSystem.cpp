#include <frostvdb/ice/ImplicitSystem.h>

#include <Eigen/Sparse>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace frostvdb {

namespace {
using FloatLeaf = openvdb::FloatTree::LeafNodeType;
inline int nbIndex(int dx, int dy, int dz) { return (dz + 1) * 9 + (dy + 1) * 3 + (dx + 1); }

} // namespace

SlotLayout::SlotLayout(openvdb::tree::LeafManager<openvdb::FloatTree>& topology, const Stencil& stencil,
                       bool isPlane)
    : plane(isPlane), slots(isPlane ? 64 : 512)
{
    const size_t nLeaves = topology.leafCount();
    origins.resize(nLeaves);
    // Leaf origin -> index through a dense table over the leaves' bounding box (in leaf units):
    // a few bytes per leaf of the domain, much faster than hashing 27 look-ups per leaf.
    openvdb::Coord lo(std::numeric_limits<int>::max()), hi(std::numeric_limits<int>::min());
    for (size_t i = 0; i < nLeaves; ++i) {
        origins[i] = topology.leaf(i).origin();
        lo.minComponent(origins[i] >> 3);
        hi.maxComponent(origins[i] >> 3);
    }
    const openvdb::Coord dim = nLeaves ? hi - lo + openvdb::Coord(1) : openvdb::Coord(0);
    std::vector<int32_t> table(size_t(dim.x()) * dim.y() * dim.z(), -1);
    auto cell = [&](const openvdb::Coord& l) {
        return (size_t(l.z() - lo.z()) * dim.y() + size_t(l.y() - lo.y())) * dim.x() + size_t(l.x() - lo.x());
    };
    for (size_t i = 0; i < nLeaves; ++i) table[cell(origins[i] >> 3)] = int32_t(i);

    const size_t n = nLeaves * size_t(slots);
    active.assign(n, 0);
    colour.assign(n, 0);
    neighbourLeaf.assign(nLeaves * 27, -1);
    colours = stencil.hexagonal ? 3 : 2;
    for (const auto& t : stencil.taps) taps.push_back({t.offset.x(), t.offset.y(), t.offset.z(), t.wLap});

    tbb::parallel_for(tbb::blocked_range<size_t>(0, nLeaves, 16), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t li = r.begin(); li != r.end(); ++li) {
            const openvdb::Coord o = origins[li] >> 3;
            for (int dz = -1; dz <= 1; ++dz)
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        const openvdb::Coord l = o + openvdb::Coord(dx, dy, dz);
                        if (l.x() < lo.x() || l.y() < lo.y() || l.z() < lo.z() || l.x() > hi.x() || l.y() > hi.y() ||
                            l.z() > hi.z())
                            continue;
                        neighbourLeaf[li * 27 + nbIndex(dx, dy, dz)] = table[cell(l)];
                    }
            for (auto it = topology.leaf(li).cbeginValueOn(); it; ++it) {
                const openvdb::Coord c = it.getCoord();
                const size_t s = slot(li, c);
                active[s] = 1;
                if (colours == 2) colour[s] = uint8_t((c.x() + c.y() + c.z()) & 1);
                else colour[s] = uint8_t(((c.x() + 2 * c.y() + c.z()) % 3 + 3) % 3);
            }
        }
    });
}

ImplicitSystem::ImplicitSystem(const SlotLayout& layout) : mL(layout)
{
    for (auto* v : {&x, &diag, &scale, &rhs}) v->assign(layout.slotCount(), 0.0);
}

double ImplicitSystem::neighbourSum(size_t leaf, int lx, int ly, int lz) const
{
    double sum = 0;
    for (const SlotLayout::Tap& t : mL.taps) {
        int nx = lx + t.dx, ny = ly + t.dy, nz = lz + t.dz;
        const int ox = nx < 0 ? -1 : (nx > 7 ? 1 : 0);
        const int oy = ny < 0 ? -1 : (ny > 7 ? 1 : 0);
        const int oz = nz < 0 ? -1 : (nz > 7 ? 1 : 0);
        double v = outside;
        const int32_t nl = (ox | oy | oz) ? mL.neighbourLeaf[leaf * 27 + nbIndex(ox, oy, oz)] : int32_t(leaf);
        if (nl >= 0) {
            nx -= ox * 8;
            ny -= oy * 8;
            nz -= oz * 8;
            const size_t s = size_t(nl) * mL.slots + (mL.plane ? size_t(nx * 8 + ny) : size_t((nx << 6) | (ny << 3) | nz));
            if (mL.active[s]) v = x[s];
        }
        sum += t.w * v;
    }
    return sum;
}

double ImplicitSystem::residualMaxNorm() const
{
    return tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, mL.origins.size(), 16), 0.0,
        [&](const tbb::blocked_range<size_t>& r, double m) {
            for (size_t li = r.begin(); li != r.end(); ++li)
                for (int k = 0; k < mL.slots; ++k) {
                    const size_t s = li * mL.slots + k;
                    if (!mL.active[s]) continue;
                    const int lx = mL.plane ? k >> 3 : k >> 6, ly = mL.plane ? k & 7 : (k >> 3) & 7, lz = mL.plane ? 0 : k & 7;
                    const double res = rhs[s] - diag[s] * x[s] + scale[s] * neighbourSum(li, lx, ly, lz);
                    m = std::max(m, std::fabs(res));
                }
            return m;
        },
        [](double a, double b) { return std::max(a, b); });
}

SolveReport ImplicitSystem::solve(LinearSolverKind kind, double tolerance, int maxIterations)
{
    return kind == LinearSolverKind::GaussSeidel ? gaussSeidel(tolerance, maxIterations)
                                                 : bicgstab(tolerance, maxIterations);
}

SolveReport ImplicitSystem::gaussSeidel(double tolerance, int maxIterations)
{
    SolveReport rep;
    for (int it = 0; it < maxIterations; ++it) {
        double worst = 0;
        for (int colour = 0; colour < mL.colours; ++colour) {
            const double m = tbb::parallel_reduce(
                tbb::blocked_range<size_t>(0, mL.origins.size(), 16), 0.0,
                [&](const tbb::blocked_range<size_t>& r, double mx) {
                    for (size_t li = r.begin(); li != r.end(); ++li)
                        for (int k = 0; k < mL.slots; ++k) {
                            const size_t s = li * mL.slots + k;
                            if (!mL.active[s] || mL.colour[s] != colour) continue;
                            const int lx = mL.plane ? k >> 3 : k >> 6, ly = mL.plane ? k & 7 : (k >> 3) & 7,
                                      lz = mL.plane ? 0 : k & 7;
                            const double v = (rhs[s] + scale[s] * neighbourSum(li, lx, ly, lz)) / diag[s];
                            // The residual of this equation just before its update.
                            mx = std::max(mx, std::fabs(v - x[s]) * diag[s]);
                            x[s] = v;
                        }
                    return mx;
                },
                [](double a, double b) { return std::max(a, b); });
            worst = std::max(worst, m);
        }
        rep.iterations = it + 1;
        rep.residual = worst;
        if (worst <= tolerance) {
            rep.converged = true;
            break;
        }
    }
    return rep;
}

SolveReport ImplicitSystem::bicgstab(double tolerance, int maxIterations)
{
    // Rows are the active slots in slot order.
    std::vector<int64_t> row(x.size(), -1);
    int64_t n = 0;
    for (size_t s = 0; s < x.size(); ++s)
        if (mL.active[s]) row[s] = n++;
    SolveReport rep;
    if (n == 0) {
        rep.converged = true;
        return rep;
    }
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(size_t(n) * (mL.taps.size() + 1));
    Eigen::VectorXd b(n), x0(n);
    for (size_t li = 0; li < mL.origins.size(); ++li)
        for (int k = 0; k < mL.slots; ++k) {
            const size_t s = li * mL.slots + k;
            if (!mL.active[s]) continue;
            const int64_t r = row[s];
            const int lx = mL.plane ? k >> 3 : k >> 6, ly = mL.plane ? k & 7 : (k >> 3) & 7, lz = mL.plane ? 0 : k & 7;
            double bi = rhs[s];
            trip.emplace_back(r, r, diag[s]);
            for (const SlotLayout::Tap& t : mL.taps) {
                int nx = lx + t.dx, ny = ly + t.dy, nz = lz + t.dz;
                const int ox = nx < 0 ? -1 : (nx > 7 ? 1 : 0), oy = ny < 0 ? -1 : (ny > 7 ? 1 : 0),
                          oz = nz < 0 ? -1 : (nz > 7 ? 1 : 0);
                const int32_t nl = (ox | oy | oz) ? mL.neighbourLeaf[li * 27 + nbIndex(ox, oy, oz)] : int32_t(li);
                int64_t col = -1;
                if (nl >= 0) {
                    nx -= ox * 8;
                    ny -= oy * 8;
                    nz -= oz * 8;
                    const size_t ns =
                        size_t(nl) * mL.slots + (mL.plane ? size_t(nx * 8 + ny) : size_t((nx << 6) | (ny << 3) | nz));
                    col = row[ns];
                }
                if (col >= 0) trip.emplace_back(r, col, -scale[s] * t.w);
                else bi += scale[s] * t.w * outside; // Dirichlet neighbour moves to the right-hand side
            }
            b[r] = bi;
            x0[r] = x[s];
        }
    Eigen::SparseMatrix<double, Eigen::RowMajor> A(n, n);
    A.setFromTriplets(trip.begin(), trip.end());
    Eigen::BiCGSTAB<Eigen::SparseMatrix<double, Eigen::RowMajor>> solver;
    solver.compute(A);
    // ||r||_2 <= tol implies ||r||_inf <= tol; Eigen's criterion is relative to ||b||_2.
    const double bn = b.norm();
    solver.setTolerance(bn > 0 ? tolerance / bn : tolerance);
    solver.setMaxIterations(maxIterations);
    Eigen::VectorXd sol = solver.solveWithGuess(b, x0);
    for (size_t s = 0; s < x.size(); ++s)
        if (row[s] >= 0) x[s] = sol[row[s]];
    rep.iterations = int(solver.iterations());
    rep.residual = (b - A * sol).lpNorm<Eigen::Infinity>();
    rep.converged = rep.residual <= tolerance;
    return rep;
}

} // namespace frostvdb
