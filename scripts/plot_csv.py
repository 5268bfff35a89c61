#!/usr/bin/python3
"""Draws the benchmark plots (docs/images/*.png) from the CSV files the benchmarks write.

    python3 scripts/plot_csv.py docs/images/accuracy_*.csv     # each X.csv -> X.png beside it

A plot CSV (written by `frostvdb bench accuracy`, vdb_tools/bench/PlotCsv.h) is:

    # title: dt sweep
    # xlabel: time (s)
    # ylabel: L1 error of p
    # log: xy                      (x, y, xy or none)
    # series: <label>|<lines, markers or lines+markers>|<#rrggbb or empty>   (one line per series)
    series,x,y
    euler,0.53,0.0123
    ...

Needs python3-matplotlib (scripts/install-packages.sh python3-matplotlib).
"""
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read_plot(path):
    meta, styles, series, order = {}, {}, {}, []
    with open(path, newline="") as f:
        lines = f.read().splitlines()
    body = []
    for line in lines:
        if line.startswith("#"):
            key, _, value = line[1:].strip().partition(":")
            value = value.strip()
            if key == "series":
                label, style, colour = (value.split("|") + ["", ""])[:3]
                styles[label] = (style or "lines+markers", colour)
            else:
                meta[key] = value
        elif line.strip():
            body.append(line)
    for row in csv.DictReader(body):
        label = row["series"]
        if label not in series:
            series[label] = ([], [])
            order.append(label)
        x, y = float(row["x"]), float(row["y"])
        series[label][0].append(x)
        series[label][1].append(y)
    return meta, styles, [(label, series[label]) for label in order]


def draw(path):
    meta, styles, series = read_plot(path)
    log = meta.get("log", "none")
    fig, ax = plt.subplots(figsize=(9, 6), dpi=100)
    for label, (xs, ys) in series:
        pts = [(x, y) for x, y in zip(xs, ys) if math.isfinite(x) and math.isfinite(y)
               and (x > 0 or "x" not in log) and (y > 0 or "y" not in log)]
        if not pts:
            continue
        style, colour = styles.get(label, ("lines+markers", ""))
        kw = {"label": label}
        if colour:
            kw["color"] = colour
        kw["linestyle"] = "-" if "lines" in style else "none"
        kw["marker"] = "s" if "markers" in style else None
        kw["markersize"] = 4
        ax.plot([p[0] for p in pts], [p[1] for p in pts], **kw)
    if "x" in log:
        ax.set_xscale("log")
    if "y" in log:
        ax.set_yscale("log")
    ax.set_title(meta.get("title", ""))
    ax.set_xlabel(meta.get("xlabel", ""))
    ax.set_ylabel(meta.get("ylabel", ""))
    ax.grid(True, which="both", alpha=0.3)
    if series:
        ax.legend()
    fig.tight_layout()
    out = os.path.splitext(path)[0] + ".png"
    fig.savefig(out)
    plt.close(fig)
    return out


def main():
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        sys.exit(0 if len(sys.argv) > 1 else 2)
    for path in sys.argv[1:]:
        print(draw(path))


if __name__ == "__main__":
    main()
