/// @file DlaTables.cpp
/// @brief Exact first-passage tables for the empty-space jumps of the DLA walkers.
///
/// For a lattice (its neighbour offsets) and a graph radius r, the ball B_r is every cell within r
/// lattice steps of the origin (a diamond on the square lattice, a hexagon on the hexagonal one,
/// an octahedron on the cubic one); its sphere is the cells at distance exactly r. A walk started
/// at the origin reaches the sphere first at a cell s with probability
///     P(s) = sum over interior neighbours y of s of G(y) / deg,
/// where G is the Green's function of the walk killed on the sphere: (I - P_int) G = e_origin,
/// P_int the transition matrix restricted to the interior (symmetric, since every cell has deg
/// neighbours). G is solved with conjugate gradients in double precision to a relative residual
/// of 1e-13; sum(G) is the mean number of steps to reach the sphere. The tables depend only on
/// the neighbour set and r, so they are computed once per process and shared.
#include <frostvdb/ice/Dla.h>
#include <frostvdb/solver/ConjugateGradient.h>

#include <cmath>
#include <map>
#include <mutex>
#include <sstream>

namespace frostvdb {
namespace ice {

namespace {

/// I - P_int on the interior cells: y_i = x_i - w * sum of x over i's interior neighbours.
class WalkOperator final : public solver::LinearOperator {
public:
    WalkOperator(const std::vector<int>& adj, size_t n, size_t deg, double w) : mAdj(adj), mN(n), mDeg(deg), mW(w) {}
    size_t size() const override { return mN; }
    void apply(const std::vector<double>& x, std::vector<double>& y) const override
    {
        for (size_t i = 0; i < mN; ++i) {
            double s = 0;
            for (size_t k = 0; k < mDeg; ++k) {
                const int a = mAdj[i * mDeg + k];
                if (a >= 0) s += x[size_t(a)];
            }
            y[i] = x[i] - mW * s;
        }
    }

private:
    const std::vector<int>& mAdj;
    size_t mN, mDeg;
    double mW;
};

std::shared_ptr<SphereTable> computeLatticeSphere(const std::vector<openvdb::Coord>& nbr, int r)
{
    bool hasZ = false;
    for (const auto& o : nbr) hasZ = hasZ || o.z() != 0;
    const int side = 2 * r + 1, sideZ = hasZ ? side : 1, rz = hasZ ? r : 0;
    auto key = [&](const openvdb::Coord& c) -> int64_t {
        return int64_t(c.x() + r) + int64_t(side) * (int64_t(c.y() + r) + int64_t(side) * int64_t(c.z() + rz));
    };
    auto inBox = [&](const openvdb::Coord& c) {
        return std::abs(c.x()) <= r && std::abs(c.y()) <= r && std::abs(c.z()) <= rz;
    };
    std::vector<int> dist(size_t(side) * side * sideZ, -1);
    std::vector<openvdb::Coord> order{openvdb::Coord(0)};
    dist[size_t(key(openvdb::Coord(0)))] = 0;
    for (size_t q = 0; q < order.size(); ++q) {
        const int d = dist[size_t(key(order[q]))];
        if (d == r) continue;
        for (const auto& o : nbr) {
            const openvdb::Coord c = order[q] + o;
            if (!inBox(c)) continue; // graph distance >= Chebyshev distance: never needed
            int& dc = dist[size_t(key(c))];
            if (dc < 0) {
                dc = d + 1;
                order.push_back(c);
            }
        }
    }
    // compact numbering: interior (d < r) first, then sphere
    std::vector<int> id(dist.size(), -1);
    std::vector<openvdb::Coord> interior, sphere;
    for (const auto& c : order) {
        if (dist[size_t(key(c))] < r) {
            id[size_t(key(c))] = int(interior.size());
            interior.push_back(c);
        }
    }
    for (const auto& c : order) {
        if (dist[size_t(key(c))] == r) {
            id[size_t(key(c))] = int(sphere.size());
            sphere.push_back(c);
        }
    }
    const size_t n = interior.size(), deg = nbr.size();
    // interior adjacency: index of the interior neighbour, or -1 - sphereIndex for a sphere one
    std::vector<int> adj(n * deg);
    for (size_t i = 0; i < n; ++i)
        for (size_t k = 0; k < deg; ++k) {
            const openvdb::Coord c = interior[i] + nbr[k];
            const int64_t kk = key(c);
            adj[i * deg + k] = dist[size_t(kk)] < r ? id[size_t(kk)] : -1 - id[size_t(kk)];
        }
    const double w = 1.0 / double(deg);
    // (I - P_int) G = e_origin by the shared CG, serial reductions (one block), unpreconditioned
    const WalkOperator A(adj, n, deg, w);
    std::vector<double> b(n, 0.0), x(n, 0.0);
    b[0] = 1.0; // origin is interior index 0 (first in BFS order)
    const solver::CgStats cg = solver::conjugateGradient(A, solver::IdentityPreconditioner(), b, x,
                                                         solver::Blocks::serial(n), 100000,
                                                         [](const solver::Residual& r) { return !(r.sumSquares > 1e-26); });
    const double rs = cg.residual.sumSquares;
    auto t = std::make_shared<SphereTable>();
    t->radius = r;
    t->exits = sphere;
    t->prob.assign(sphere.size(), 0.0);
    t->solverResidual = std::sqrt(rs);
    for (size_t i = 0; i < n; ++i) {
        t->meanSteps += x[i];
        for (size_t k = 0; k < deg; ++k) {
            const int a = adj[i * deg + k];
            if (a < 0) t->prob[size_t(-1 - a)] += x[i] * w;
        }
    }
    double total = 0;
    for (double q : t->prob) total += q;
    for (double& q : t->prob) q /= total; // total is 1 to the solver's accuracy
    // Vose's alias method (deterministic: fixed processing order)
    const size_t m = sphere.size();
    std::vector<double> aliasProb(m, 1.0);
    t->alias.resize(m);
    std::vector<double> scaled(m);
    std::vector<uint32_t> small, large;
    for (size_t i = 0; i < m; ++i) {
        scaled[i] = t->prob[i] * double(m);
        t->alias[i] = uint32_t(i);
        (scaled[i] < 1.0 ? small : large).push_back(uint32_t(i));
    }
    while (!small.empty() && !large.empty()) {
        const uint32_t s = small.back(), l = large.back();
        small.pop_back();
        aliasProb[s] = scaled[s];
        t->alias[s] = l;
        scaled[l] = (scaled[l] + scaled[s]) - 1.0;
        if (scaled[l] < 1.0) {
            large.pop_back();
            small.push_back(l);
        }
    }
    for (uint32_t i : large) aliasProb[i] = 1.0;
    for (uint32_t i : small) aliasProb[i] = 1.0;
    t->aliasThreshold.resize(m);
    for (size_t i = 0; i < m; ++i)
        t->aliasThreshold[i] = aliasProb[i] >= 1.0 ? 0xFFFFFFFFu : uint32_t(std::ldexp(aliasProb[i], 32));
    t->slots.resize(m);
    for (size_t i = 0; i < m; ++i) {
        SphereTable::Slot& s = t->slots[i];
        s.threshold = t->aliasThreshold[i];
        const openvdb::Coord& a = t->exits[i];
        const openvdb::Coord& b = t->exits[t->alias[i]];
        for (int c = 0; c < 3; ++c) {
            s.keep[c] = int16_t(a[c]);
            s.other[c] = int16_t(b[c]);
        }
    }
    return t;
}

} // namespace

std::shared_ptr<const SphereTable> sphereTable(const std::vector<openvdb::Coord>& neighbours, int radius)
{
    static std::mutex mutex;
    static std::map<std::string, std::shared_ptr<const SphereTable>> cache;
    std::ostringstream os;
    os << radius;
    for (const auto& o : neighbours) os << ' ' << o.x() << ',' << o.y() << ',' << o.z();
    const std::string key = os.str();
    {
        std::lock_guard<std::mutex> lock(mutex);
        auto it = cache.find(key);
        if (it != cache.end()) return it->second;
    }
    auto t = computeLatticeSphere(neighbours, radius); // outside the lock; a duplicate is identical
    std::lock_guard<std::mutex> lock(mutex);
    auto& slot = cache[key];
    if (!slot) slot = t;
    return slot;
}

} // namespace ice
} // namespace frostvdb
