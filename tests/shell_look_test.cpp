// The look of frost on a shell against the plane engine (issue 23 item 4): the hero recipe
// (walkers + phase field from the border) on a flat plate mesh and on a plane of the same cells
// and seed layout must frost the same area and the same fractal texture. The walks differ (the
// shell's walkers step on the node graph and jump off-lattice), so the comparison is statistical:
// means over seeds.
#include "test_util.h"
#include "plane_layout_util.h"

#include <frostvdb/shell/ShellDomain.h>

#include <catch2/catch.hpp>

#include <openvdb/openvdb.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <vector>

using namespace frostvdb;

namespace {

/// Cells (x, y) with p > 1/2 in the run's p grid (the plate lies in z = 0: its nodes are the
/// plane's cells).
std::set<std::pair<int, int>> iceCells(Simulation& sim)
{
    std::set<std::pair<int, int>> out;
    auto p = test::planeLayout(sim.world(), "p"); // the plane's p is folded (core/PlaneFold.h)
    for (auto it = p->cbeginValueOn(); it; ++it)
        if (*it > 0.5f) out.insert({it.getCoord().x(), it.getCoord().y()});
    return out;
}

/// Box-counting dimension of a set of cells: the slope of log N(s) against log(1/s) for boxes of
/// 2, 4, 8 and 16 cells (least squares).
double boxDimension(const std::set<std::pair<int, int>>& cells)
{
    std::vector<double> xs, ys;
    for (int s : {2, 4, 8, 16}) {
        std::set<std::pair<int, int>> boxes;
        for (const auto& [x, y] : cells)
            boxes.insert({int(std::floor(double(x) / s)), int(std::floor(double(y) / s))});
        xs.push_back(std::log(1.0 / s));
        ys.push_back(std::log(double(boxes.size())));
    }
    const double n = double(xs.size());
    double sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (size_t k = 0; k < xs.size(); ++k) {
        sx += xs[k];
        sy += ys[k];
        sxx += xs[k] * xs[k];
        sxy += xs[k] * ys[k];
    }
    return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

} // namespace

TEST_CASE("Shell look: a flat plate frosts the plane's area and fractal dimension (hero recipe)", "[fast][shell][dla]")
{
    const int L = 128, steps = 80; // about a third of the plate frozen
    const std::string obj = (std::filesystem::temp_directory_path() / "frostvdb_look_plate.obj").string();
    {
        // cells 0 .. L-1 of 1 mm: nodes lie within half a voxel of the plate, so a plate from
        // -0.25 to L - 0.75 mm holds exactly the plane's L x L cells, and its border the plane's edges
        const double a = -0.25e-3, b = (L - 0.75) * 1e-3;
        std::ofstream f(obj);
        f << "v " << a << " " << a << " 0\nv " << b << " " << a << " 0\nv " << b << " " << b << " 0\nv " << a << " " << b
          << " 0\nf 1 2 3\nf 1 3 4\n";
    }
    const std::string plane = "[domain]\nkind = \"plane\"\nlattice = \"square\"\nsize = [" + std::to_string(L) + ", " +
                              std::to_string(L) + "]\nvoxel_size = 0.001\n"
                              "[[crystal.seed]]\nshape = \"edge\"\nedges = \"all\"\nwidth = 1\n";
    const std::string shell = "[domain]\nkind = \"shell\"\nmesh = \"" + obj + "\"\nvoxel_size = 0.001\n"
                              "[[crystal.seed]]\nshape = \"edge\"\nedges = \"border\"\nwidth = 1\n";
    const std::string walkers = "[dla]\nhumidity = 100\nhits = 2\n";
    const std::string phaseField = "[phase_field]\nanisotropy_mode = 6\ndelta = 0.05\n";
    // mean ice area (cells with p > 1/2) and box-counting dimension over seeds 1 .. seeds
    auto measure = [&](const std::string& effects, int seeds, double area[2], double dim[2]) {
        const std::string common = "[scene]\nframes = 1\nsteps_per_frame = " + std::to_string(steps) + "\n" + effects;
        area[0] = area[1] = dim[0] = dim[1] = 0;
        for (int s = 1; s <= seeds; ++s)
            for (int k = 0; k < 2; ++k) {
                auto sim = test::makeSim(common + (k == 0 ? plane : shell), {"scene.seed=" + std::to_string(s)});
                for (int step = 0; step < steps; ++step) sim.step();
                const auto cells = iceCells(sim);
                area[k] += double(cells.size()) / seeds;
                dim[k] += boxDimension(cells) / seeds;
            }
    };
    double area[2], dim[2];
    measure(walkers + phaseField, 3, area, dim);
    WARN("hybrid: ice area plane " << area[0] << ", shell " << area[1] << " (" << 100.0 * (area[1] / area[0] - 1.0)
                                   << " %); box-counting dimension: plane " << dim[0] << ", shell " << dim[1]);
    // issue 23: the hero recipe's frost within 3 % of the plane's area (measured +0.7 %)
    CHECK(std::fabs(area[1] / area[0] - 1.0) < 0.03);
    CHECK(std::fabs(dim[1] - dim[0]) < 0.05);

    // and each half on its own, so that two errors cannot cancel: the phase field alone (no noise:
    // deterministic) matches the plane's cells, the open border's ghost ring reading the
    // background as the plane's edge does (without it: +19 %) ...
    measure(phaseField, 1, area, dim);
    WARN("phase field alone: plane " << area[0] << ", shell " << area[1]);
    CHECK(std::fabs(area[1] / area[0] - 1.0) < 0.005);
    // ... and the walkers alone (measured -0.7 % over these seeds; the node-graph walk)
    measure(walkers, 3, area, dim);
    WARN("walkers alone: plane " << area[0] << ", shell " << area[1] << " (" << 100.0 * (area[1] / area[0] - 1.0)
                                 << " %)");
    CHECK(std::fabs(area[1] / area[0] - 1.0) < 0.03);
    std::filesystem::remove(obj);
}
