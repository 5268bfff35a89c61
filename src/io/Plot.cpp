#include <frostvdb/io/Plot.h>
#include <frostvdb/io/Png.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

namespace frostvdb {

namespace {

/// 5x7 glyphs, 7 rows of 5 columns, '#' = ink.
struct Glyph {
    char c;
    const char* rows; // 35 characters
};

// clang-format off
const Glyph kFont[] = {
    {'0', " ### #   ##  ### # ###  ##   # ### "},
    {'1', "  #   ##    #    #    #    #   ### "},
    {'2', " ### #   #    #   #   #   #   #####"},
    {'3', "#####   #   #     #     ##   # ### "},
    {'4', "   #   ##  # # #  # #####   #    # "},
    {'5', "######    ####     #    ##   # ### "},
    {'6', "  ##  #   #    #### #   ##   # ### "},
    {'7', "#####    #   #   #   #    #    #   "},
    {'8', " ### #   ##   # ### #   ##   # ### "},
    {'9', " ### #   ##   # ####    #   #  ##  "},
    {'A', " ### #   ##   #######   ##   ##   #"},
    {'B', "#### #   ##   ##### #   ##   ##### "},
    {'C', " ### #   ##    #    #    #   # ### "},
    {'D', "###  #  # #   ##   ##   ##  # ###  "},
    {'E', "######    #    #### #    #    #####"},
    {'F', "######    #    #### #    #    #    "},
    {'G', " ### #   ##    # ####   ##   # ####"},
    {'H', "#   ##   ##   #######   ##   ##   #"},
    {'I', " ###   #    #    #    #    #   ### "},
    {'J', "  ###   #    #    #    # #  #  ##  "},
    {'K', "#   ##  # # #  ##   # #  #  # #   #"},
    {'L', "#    #    #    #    #    #    #####"},
    {'M', "#   ### ### # ## # ##   ##   ##   #"},
    {'N', "#   ##   ###  ## # ##  ###   ##   #"},
    {'O', " ### #   ##   ##   ##   ##   # ### "},
    {'P', "#### #   ##   ##### #    #    #    "},
    {'Q', " ### #   ##   ##   ## # ##  #  ## #"},
    {'R', "#### #   ##   ##### # #  #  # #   #"},
    {'S', " #####    #     ###     #    ##### "},
    {'T', "#####  #    #    #    #    #    #  "},
    {'U', "#   ##   ##   ##   ##   ##   # ### "},
    {'V', "#   ##   ##   ##   ##   # # #   #  "},
    {'W', "#   ##   ##   ## # ## # ## # # # # "},
    {'X', "#   ##   # # #   #   # # #   ##   #"},
    {'Y', "#   ##   # # #   #    #    #    #  "},
    {'Z', "#####    #   #   #   #   #    #####"},
    {'.', "                         ##   ##   "},
    {',', "                    ##   ##  #     "},
    {'-', "               ###                 "},
    {'+', "       #    #  #####  #    #       "},
    {'=', "          #####     #####          "},
    {'/', "    #    #   #   #   #    #        "},
    {'(', "   #   #   #    #    #     #     # "},
    {')', " #     #     #    #    #   #   #   "},
    {'[', " ###  #    #    #    #    #    ### "},
    {']', " ###    #    #    #    #    #  ### "},
    {':', "      ##   ##        ##   ##       "},
    {'%', "##   ##  #   #   #   #   #  ##   ##"},
    {'^', "  #   # # #   #                    "},
    {'_', "                              #####"},
    {'*', "       # # # ### ##### ### # # #   "},
    {'<', "   #   #   #   #     #     #     # "},
    {'>', " #     #     #     #   #   #   #   "},
    {'\'', "  #    #   #                       "},
    {'"', " # #  # #                          "},
    {'|', "  #    #    #    #    #    #    #  "},
    {'~', "      #   # # #   #                "},
};
// clang-format on

const char* glyphRows(char c)
{
    if (c >= 'a' && c <= 'z') c = char(c - 'a' + 'A');
    for (const auto& g : kFont)
        if (g.c == c) return g.rows;
    return nullptr;
}

struct Canvas {
    ImageRGB img;
    explicit Canvas(int w, int h) : img(w, h)
    {
        std::fill(img.rgb.begin(), img.rgb.end(), uint8_t(255));
    }
    void px(int x, int y, float r, float g, float b)
    {
        if (x < 0 || y < 0 || x >= img.width || y >= img.height) return;
        img.set(x, y, r, g, b);
    }
    void rect(int x0, int y0, int x1, int y1, float r, float g, float b)
    {
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) px(x, y, r, g, b);
    }
    void line(double x0, double y0, double x1, double y1, int w, float r, float g, float b)
    {
        const double len = std::max(std::fabs(x1 - x0), std::fabs(y1 - y0));
        const int n = std::max(1, int(std::ceil(len)));
        for (int i = 0; i <= n; ++i) {
            const double t = double(i) / n;
            const int x = int(std::lround(x0 + t * (x1 - x0))), y = int(std::lround(y0 + t * (y1 - y0)));
            rect(x - (w - 1) / 2, y - (w - 1) / 2, x + w / 2, y + w / 2, r, g, b);
        }
    }
    /// Text at scale @a s; (x, y) is the top-left corner. Returns the width drawn.
    int text(int x, int y, const std::string& s, int scale, float r = 0.f, float g = 0.f, float b = 0.f)
    {
        int cx = x;
        for (char c : s) {
            if (const char* rows = glyphRows(c))
                for (int row = 0; row < 7; ++row)
                    for (int col = 0; col < 5; ++col)
                        if (rows[row * 5 + col] == '#')
                            rect(cx + col * scale, y + row * scale, cx + col * scale + scale - 1,
                                 y + row * scale + scale - 1, r, g, b);
            cx += 6 * scale;
        }
        return cx - x;
    }
    /// Text rotated 90 degrees counter-clockwise (reads bottom to top); (x, y) bottom-left.
    void textUp(int x, int y, const std::string& s, int scale)
    {
        int cy = y;
        for (char c : s) {
            if (const char* rows = glyphRows(c))
                for (int row = 0; row < 7; ++row)
                    for (int col = 0; col < 5; ++col)
                        if (rows[row * 5 + col] == '#') {
                            const int X = x + row * scale, Y = cy - col * scale;
                            rect(X, Y - scale + 1, X + scale - 1, Y, 0.f, 0.f, 0.f);
                        }
            cy -= 6 * scale;
        }
    }
};

int textWidth(const std::string& s, int scale) { return int(s.size()) * 6 * scale; }

const float kCycle[][3] = {{0.12f, 0.47f, 0.71f}, {1.00f, 0.50f, 0.05f}, {0.17f, 0.63f, 0.17f},
                           {0.84f, 0.15f, 0.16f}, {0.58f, 0.40f, 0.74f}, {0.55f, 0.34f, 0.29f},
                           {0.89f, 0.47f, 0.76f}, {0.50f, 0.50f, 0.50f}, {0.74f, 0.74f, 0.13f},
                           {0.09f, 0.75f, 0.81f}};

struct Axis {
    bool log = false;
    double lo = 0, hi = 1; // in transformed units (log10 when log)
    double tf(double v) const { return log ? std::log10(v) : v; }
    bool valid(double v) const { return std::isfinite(v) && (!log || v > 0); }
};

std::string fmtTick(double v, bool log)
{
    char buf[32];
    if (log) {
        const int e = int(std::lround(v));
        if (e >= -2 && e <= 3) {
            std::snprintf(buf, sizeof buf, "%g", std::pow(10.0, e));
        } else {
            std::snprintf(buf, sizeof buf, "1E%d", e);
        }
        return buf;
    }
    if (std::fabs(v) < 1e-12) return "0";
    std::snprintf(buf, sizeof buf, "%g", v);
    return buf;
}

/// Linear ticks: a 1-2-5 step giving about @a n ticks.
std::vector<double> linearTicks(double lo, double hi, int n)
{
    const double span = hi - lo;
    const double raw = span / n;
    const double mag = std::pow(10.0, std::floor(std::log10(raw)));
    double step = mag;
    for (double m : {1.0, 2.0, 5.0, 10.0})
        if (m * mag >= raw) { step = m * mag; break; }
    std::vector<double> t;
    for (double v = std::ceil(lo / step - 1e-9) * step; v <= hi + 1e-9 * step; v += step) t.push_back(v);
    return t;
}

} // namespace

void writePlotPng(const std::string& path, const PlotSpec& spec)
{
    Canvas cv(spec.width, spec.height);
    Axis ax, ay;
    ax.log = spec.logX;
    ay.log = spec.logY;
    double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin, ymin = xmin, ymax = -xmin;
    for (const auto& s : spec.series)
        for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
            if (!ax.valid(s.x[i]) || !ay.valid(s.y[i])) continue;
            xmin = std::min(xmin, ax.tf(s.x[i]));
            xmax = std::max(xmax, ax.tf(s.x[i]));
            ymin = std::min(ymin, ay.tf(s.y[i]));
            ymax = std::max(ymax, ay.tf(s.y[i]));
        }
    if (!(xmin <= xmax)) { xmin = 0; xmax = 1; }
    if (!(ymin <= ymax)) { ymin = 0; ymax = 1; }
    auto range = [](Axis& a, double mn, double mx) {
        if (a.log) {
            a.lo = std::floor(mn + 1e-9);
            a.hi = std::ceil(mx - 1e-9);
            if (a.hi <= a.lo) a.hi = a.lo + 1;
        } else {
            const double pad = mx > mn ? 0.05 * (mx - mn) : std::max(1e-12, 0.5 * std::fabs(mx) + 0.5);
            a.lo = mn - pad;
            a.hi = mx + pad;
            if (mn >= 0 && a.lo < 0) a.lo = 0;
        }
    };
    range(ax, xmin, xmax);
    range(ay, ymin, ymax);

    const int S = 2; // font scale
    const int left = 110, right = 30, top = 50, bottom = 80;
    // The legend goes in a column to the right when there are labels.
    int legendW = 0;
    for (const auto& s : spec.series) legendW = std::max(legendW, textWidth(s.label, S) + 50);
    legendW = std::min(legendW, spec.width / 3);
    const int x0 = left, x1 = spec.width - right - legendW, y0 = top, y1 = spec.height - bottom;
    auto X = [&](double v) { return x0 + (ax.tf(v) - ax.lo) / (ax.hi - ax.lo) * (x1 - x0); };
    auto Y = [&](double v) { return y1 - (ay.tf(v) - ay.lo) / (ay.hi - ay.lo) * (y1 - y0); };

    // Grid and ticks.
    auto ticks = [](const Axis& a) {
        std::vector<double> t;
        if (a.log) {
            const int step = std::max(1, int(std::ceil((a.hi - a.lo) / 8.0)));
            for (double e = a.lo; e <= a.hi + 1e-9; e += step) t.push_back(e);
        } else {
            t = linearTicks(a.lo, a.hi, 6);
        }
        return t;
    };
    for (double t : ticks(ax)) {
        const int px = int(std::lround(x0 + (t - ax.lo) / (ax.hi - ax.lo) * (x1 - x0)));
        cv.line(px, y0, px, y1, 1, 0.88f, 0.88f, 0.88f);
        cv.line(px, y1, px, y1 + 6, 1, 0, 0, 0);
        const std::string s = fmtTick(t, ax.log);
        cv.text(px - textWidth(s, S) / 2, y1 + 12, s, S);
    }
    if (ax.log) // minor ticks at 2..9 x 10^e
        for (double e = ax.lo; e < ax.hi; e += 1)
            for (int m = 2; m <= 9; ++m) {
                const double t = e + std::log10(double(m));
                const int px = int(std::lround(x0 + (t - ax.lo) / (ax.hi - ax.lo) * (x1 - x0)));
                cv.line(px, y1, px, y1 + 3, 1, 0, 0, 0);
            }
    for (double t : ticks(ay)) {
        const int py = int(std::lround(y1 - (t - ay.lo) / (ay.hi - ay.lo) * (y1 - y0)));
        cv.line(x0, py, x1, py, 1, 0.88f, 0.88f, 0.88f);
        cv.line(x0 - 6, py, x0, py, 1, 0, 0, 0);
        const std::string s = fmtTick(t, ay.log);
        cv.text(x0 - 10 - textWidth(s, S), py - 7, s, S);
    }
    if (ay.log)
        for (double e = ay.lo; e < ay.hi; e += 1)
            for (int m = 2; m <= 9; ++m) {
                const double t = e + std::log10(double(m));
                const int py = int(std::lround(y1 - (t - ay.lo) / (ay.hi - ay.lo) * (y1 - y0)));
                cv.line(x0 - 3, py, x0, py, 1, 0, 0, 0);
            }
    // Frame.
    cv.line(x0, y0, x1, y0, 1, 0, 0, 0);
    cv.line(x0, y1, x1, y1, 1, 0, 0, 0);
    cv.line(x0, y0, x0, y1, 1, 0, 0, 0);
    cv.line(x1, y0, x1, y1, 1, 0, 0, 0);

    // Series (clipped to the frame).
    int ci = 0;
    int legendY = y0 + 4;
    for (const auto& s : spec.series) {
        float r = s.r, g = s.g, b = s.b;
        if (r == 0 && g == 0 && b == 0) {
            r = kCycle[ci % 10][0];
            g = kCycle[ci % 10][1];
            b = kCycle[ci % 10][2];
        }
        ++ci;
        bool havePrev = false;
        double px = 0, py = 0;
        for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
            if (!ax.valid(s.x[i]) || !ay.valid(s.y[i])) { havePrev = false; continue; }
            const double qx = X(s.x[i]), qy = Y(s.y[i]);
            if (s.lines && havePrev) cv.line(px, py, qx, qy, s.lineWidth, r, g, b);
            if (s.markers) cv.rect(int(qx) - 3, int(qy) - 3, int(qx) + 3, int(qy) + 3, r, g, b);
            px = qx;
            py = qy;
            havePrev = true;
        }
        if (!s.label.empty()) {
            const int lx = x1 + 12;
            if (s.lines) cv.line(lx, legendY + 7, lx + 24, legendY + 7, s.lineWidth, r, g, b);
            if (s.markers) cv.rect(lx + 9, legendY + 4, lx + 15, legendY + 10, r, g, b);
            cv.text(lx + 30, legendY, s.label, S);
            legendY += 22;
        }
    }

    // Labels.
    cv.text((x0 + x1 - textWidth(spec.title, S)) / 2, 14, spec.title, S);
    cv.text((x0 + x1 - textWidth(spec.xLabel, S)) / 2, y1 + 44, spec.xLabel, S);
    cv.textUp(14, (y0 + y1 + textWidth(spec.yLabel, S)) / 2, spec.yLabel, S);
    writePngRGB(path, cv.img);
}

std::vector<size_t> paretoFront(const std::vector<double>& cost, const std::vector<double>& error)
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

} // namespace frostvdb
