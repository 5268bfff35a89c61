#pragma once
/// @file Plot.h
/// @brief A small PNG line/scatter plot writer for benchmark reports (there is no plotting
/// library on the build machines): axes with ticks, linear or log10 scales, a title, axis
/// labels and a legend, drawn with a built-in 5x7 bitmap font (upper-case letters, digits and
/// the usual punctuation; lower case is drawn as upper case). Written through writePngRGB, so a
/// crash never leaves half a file.
#include <string>
#include <vector>

namespace frostvdb {

struct PlotSeries {
    std::string label;
    std::vector<double> x, y;    ///< points; non-finite or (on a log axis) non-positive ones are skipped
    float r = 0.f, g = 0.f, b = 0.f; ///< colour in [0,1]; all 0 -> a colour from the default cycle
    bool lines = true;           ///< join the points in the order given
    bool markers = true;         ///< draw a square marker at each point
    int lineWidth = 2;
};

struct PlotSpec {
    std::string title, xLabel, yLabel;
    bool logX = false, logY = false;
    int width = 900, height = 600;
    std::vector<PlotSeries> series;
};

/// Renders @a spec to an RGB PNG at @a path. Axis ranges cover every finite point (log axes
/// snap to decades). Throws std::runtime_error if the file cannot be written.
void writePlotPng(const std::string& path, const PlotSpec& spec);

/// Indices of the Pareto-optimal points (no other point is both faster and more accurate):
/// minimising both @a cost and @a error; returned sorted by increasing cost.
std::vector<size_t> paretoFront(const std::vector<double>& cost, const std::vector<double>& error);

} // namespace frostvdb
