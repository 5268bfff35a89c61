#pragma once
/// @file HexLattice.h
/// @brief The snowflake automata's array layout on the one hexagonal lattice
/// (geometry/HexLattice.h: axial coordinates, neighbours, D6 images): a hexagon of radius R in
/// axial coordinates (q, r) centred on (0, 0), stored in a (2(R+pad)+1)^2 square array whose
/// cells outside the hexagon form a fixed border. No OpenVDB here, to keep compile times low.
///
/// Neighbour ring offsets follow hex::kNeighbours (counter-clockwise); second ring
/// (Coxe-Reiter): points P_k = 2 N_k, edges E_k = N_k + N_{k+1}. The fundamental wedge is
/// { 0 <= r <= q, q + r <= R }.
#include <frostvdb/geometry/HexLattice.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include <cmath>

namespace frostvdb {
namespace automata {

using hex::Axial;
using hex::canonical;
using hex::cellAt;
using hex::hexDistance;
using hex::kNeighbours;
using hex::roundAxial;

/// Sum of six values v[0..5] given in cyclic order, computed so that the result is bit-identical
/// for every D6 permutation of the inputs: opposite pairs are summed first (addition is
/// commutative in IEEE arithmetic), then the three pair sums are sorted and added in order.
inline double symSum6(double v0, double v1, double v2, double v3, double v4, double v5)
{
    double a = v0 + v3, b = v1 + v4, c = v2 + v5;
    if (a > b) std::swap(a, b);
    if (b > c) std::swap(b, c);
    if (a > b) std::swap(a, b);
    return (a + b) + c;
}

/// One row of cells to update: layer, row r and the inclusive q range.
struct Row {
    int layer, r, q0, q1;
};

/// Index bookkeeping for a hexagon of radius R with a fixed border of width pad.
class HexLayout {
public:
    HexLayout() = default;
    HexLayout(int radius, int pad) : mR(radius), mPad(pad), mOff(radius + pad), mW(2 * (radius + pad) + 1)
    {
        for (int k = 0; k < 6; ++k) {
            mN[k] = offset(kNeighbours[k].q, kNeighbours[k].r);
            mP[k] = 2 * mN[k];
            const Axial& a = kNeighbours[k];
            const Axial& b = kNeighbours[(k + 1) % 6];
            mE[k] = offset(a.q + b.q, a.r + b.r);
        }
    }

    int radius() const { return mR; }
    int pad() const { return mPad; }
    int width() const { return mW; }
    size_t size() const { return size_t(mW) * mW; }
    int64_t offset(int dq, int dr) const { return int64_t(dr) * mW + dq; }
    size_t index(int q, int r) const { return size_t(r + mOff) * mW + size_t(q + mOff); }
    Axial axial(size_t idx) const { return {int(idx % mW) - mOff, int(idx / mW) - mOff}; }
    bool inside(int q, int r) const { return hexDistance(q, r) <= mR; }
    bool inArray(int q, int r) const
    {
        return q >= -mOff && q <= mOff && r >= -mOff && r <= mOff;
    }
    /// Index offsets of the neighbour rings, cyclic order.
    const std::array<int64_t, 6>& n() const { return mN; }
    const std::array<int64_t, 6>& p() const { return mP; }
    const std::array<int64_t, 6>& e() const { return mE; }

    /// Rows of the whole hexagon, for one layer.
    std::vector<Row> fullRows(int layer = 0) const
    {
        std::vector<Row> rows;
        for (int r = -mR; r <= mR; ++r)
            rows.push_back({layer, r, std::max(-mR, -mR - r), std::min(mR, mR - r)});
        return rows;
    }
    /// Rows of the fundamental wedge { 0 <= r <= q, q + r <= R }.
    std::vector<Row> wedgeRows(int layer = 0) const
    {
        std::vector<Row> rows;
        for (int r = 0; 2 * r <= mR; ++r) rows.push_back({layer, r, r, mR - r});
        return rows;
    }
    static bool inWedge(int q, int r) { return r >= 0 && q >= r; }

    /// Cells of the hexagon outside the wedge that lie within @a reach (hex distance) of a wedge
    /// cell, each paired with the index of its canonical image: the mirrored border the wedge
    /// computation reads.
    std::vector<std::pair<uint32_t, uint32_t>> ghosts(int reach) const
    {
        std::vector<uint8_t> seen(size(), 0);
        std::vector<std::pair<uint32_t, uint32_t>> out;
        for (const Row& row : wedgeRows())
            for (int q = row.q0; q <= row.q1; ++q)
                for (int dr = -reach; dr <= reach; ++dr)
                    for (int dq = -reach; dq <= reach; ++dq) {
                        if (hexDistance(dq, dr) > reach) continue;
                        const int qq = q + dq, rr = row.r + dr;
                        if (!inside(qq, rr) || inWedge(qq, rr)) continue;
                        const size_t i = index(qq, rr);
                        if (seen[i]) continue;
                        seen[i] = 1;
                        const Axial c = canonical(qq, rr);
                        out.emplace_back(uint32_t(i), uint32_t(index(c.q, c.r)));
                    }
        std::sort(out.begin(), out.end());
        return out;
    }

    /// For every cell of the hexagon, (index, index of its canonical image).
    std::vector<std::pair<uint32_t, uint32_t>> images() const
    {
        std::vector<std::pair<uint32_t, uint32_t>> out;
        for (const Row& row : fullRows())
            for (int q = row.q0; q <= row.q1; ++q) {
                const Axial c = canonical(q, row.r);
                out.emplace_back(uint32_t(index(q, row.r)), uint32_t(index(c.q, c.r)));
            }
        return out;
    }

private:
    int mR = 0, mPad = 0, mOff = 0, mW = 1;
    std::array<int64_t, 6> mN{}, mP{}, mE{};
};

} // namespace automata
} // namespace frostvdb
