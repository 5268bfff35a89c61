#pragma once
/// @file PlotCsv.h
/// @brief Benchmark plots as data: a bench writes each plot as a CSV (series, x, y) with its
/// title, axis labels, log axes and series styles in `#` header lines, and scripts/plot_csv.py
/// (python3-matplotlib) draws the PNG beside it. drawPlots() runs that script when it is found
/// next to the docs folder (a source checkout), so `frostvdb bench accuracy` still leaves the
/// images in docs/images; elsewhere it prints the command.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace frostvdb::bench {

struct PlotSeries {
    std::string label;
    std::vector<double> x, y;        ///< points; non-finite or (on a log axis) non-positive ones are skipped
    float r = 0.f, g = 0.f, b = 0.f; ///< colour in [0,1]; all 0 -> matplotlib's default cycle
    bool lines = true;               ///< join the points in the order given
    bool markers = true;             ///< a marker at each point
};

struct PlotSpec {
    std::string title, xLabel, yLabel;
    bool logX = false, logY = false;
    std::vector<PlotSeries> series;
};

/// Writes @a spec to @a path (CSV with `#` header lines; scripts/plot_csv.py documents the form).
inline void writePlotCsv(const std::string& path, const PlotSpec& spec)
{
    std::ofstream out(path, std::ios::trunc);
    if (!out) throw std::runtime_error("cannot write " + path);
    auto clean = [](std::string s) {
        for (char& c : s)
            if (c == ',' || c == '|' || c == '\n' || c == '"') c = ' ';
        return s;
    };
    out << "# title: " << clean(spec.title) << "\n# xlabel: " << clean(spec.xLabel)
        << "\n# ylabel: " << clean(spec.yLabel) << "\n# log: "
        << (spec.logX && spec.logY ? "xy" : spec.logX ? "x" : spec.logY ? "y" : "none") << "\n";
    for (const auto& s : spec.series) {
        std::string style = s.lines && s.markers ? "lines+markers" : s.lines ? "lines" : "markers";
        char colour[16] = "";
        if (s.r != 0.f || s.g != 0.f || s.b != 0.f)
            std::snprintf(colour, sizeof colour, "#%02x%02x%02x", int(std::lround(255 * s.r)),
                          int(std::lround(255 * s.g)), int(std::lround(255 * s.b)));
        out << "# series: " << clean(s.label) << "|" << style << "|" << colour << "\n";
    }
    out << "series,x,y\n";
    char buf[64];
    for (const auto& s : spec.series)
        for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
            std::snprintf(buf, sizeof buf, "%.9g,%.9g", s.x[i], s.y[i]);
            out << clean(s.label) << "," << buf << "\n";
        }
    if (!out) throw std::runtime_error("cannot write " + path);
}

/// Draws the PNGs of @a csvFiles with scripts/plot_csv.py, found as @a docsDir/../scripts; prints
/// the command instead when the script or python3-matplotlib is missing. Returns true when drawn.
inline bool drawPlots(const std::string& docsDir, const std::vector<std::string>& csvFiles)
{
    if (csvFiles.empty()) return true;
    namespace fs = std::filesystem;
    const fs::path script = fs::absolute(fs::path(docsDir)).parent_path() / "scripts" / "plot_csv.py";
    std::string files;
    for (const auto& f : csvFiles) files += " '" + f + "'";
    const std::string cmd = "python3 '" + script.string() + "'" + files;
    if (fs::exists(script) && std::system((cmd + " > /dev/null").c_str()) == 0) return true;
    std::cerr << "plots: not drawn (needs scripts/plot_csv.py and python3-matplotlib); draw them with\n  "
              << cmd << "\n";
    return false;
}

/// Indices of the Pareto-optimal points (no other point is both faster and more accurate):
/// minimising both @a cost and @a error; returned sorted by increasing cost.
inline std::vector<size_t> paretoFront(const std::vector<double>& cost, const std::vector<double>& error)
{
    std::vector<size_t> idx;
    for (size_t i = 0; i < cost.size() && i < error.size(); ++i)
        if (std::isfinite(cost[i]) && std::isfinite(error[i])) idx.push_back(i);
    std::sort(idx.begin(), idx.end(), [&](size_t a, size_t b) {
        return cost[a] < cost[b] || (cost[a] == cost[b] && error[a] < error[b]);
    });
    std::vector<size_t> front;
    double best = std::numeric_limits<double>::infinity();
    for (size_t i : idx)
        if (error[i] < best) {
            front.push_back(i);
            best = error[i];
        }
    return front;
}

} // namespace frostvdb::bench
