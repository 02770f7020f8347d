# SPDX-License-Identifier: GPL-3.0-or-later
"""The log-log plot of bench/bench_fit_scale.py's figures.

    python3 bench/plot_fit_scale.py [out/bench/fit_scale.json] [out/bench/fit_scale.png]
           [--before out/bench/fit_scale_before.json]

Left: seconds against the cage's vertex count (the runs on one scan),
right: against the scan's triangle count (the runs under one cage); the
total and each phase, with the fitted slope in the legend.  --before adds
another run's totals dashed (the same cases measured with an earlier
build)."""
import argparse
import json
import os

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PHASES = [("total", "total"), ("read_scan", "read scan"), ("scan_create", "scan create"),
          ("stencil", "stencils"), ("query", "queries"), ("solve", "solve"), ("write", "write object")]


def groups(rows):
    by_scan, by_cage = {}, {}
    for r in rows:
        by_scan.setdefault(r["scan"], []).append(r)
        by_cage.setdefault(r["cage"], []).append(r)
    cage_sweep = max(by_scan.values(), key=len)
    scan_sweep = max(by_cage.values(), key=len)
    return (sorted(cage_sweep, key=lambda r: r["cage_vertices"]),
            sorted(scan_sweep, key=lambda r: r["scan_triangles"]))


def slope(xs, ys):
    return np.polyfit(np.log(xs), np.log(ys), 1)[0] if len(xs) > 1 else float("nan")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("json", nargs="?", default=os.path.join(ROOT, "out", "bench", "fit_scale.json"))
    parser.add_argument("png", nargs="?", default=os.path.join(ROOT, "out", "bench", "fit_scale.png"))
    parser.add_argument("--before", default=None)
    args = parser.parse_args()
    with open(args.json) as f:
        rows = json.load(f)["rows"]
    before = None
    if args.before:
        with open(args.before) as f:
            before = groups(json.load(f)["rows"])
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, sweep, key, label, i in ((axes[0], groups(rows)[0], "cage_vertices", "cage vertices", 0),
                                     (axes[1], groups(rows)[1], "scan_triangles", "scan triangles", 1)):
        xs = [r[key] for r in sweep]
        for phase, name in PHASES:
            ys = [max(r[phase], 1e-3) for r in sweep]
            ax.loglog(xs, ys, "o-", label="%s (slope %.2f)" % (name, slope(xs, ys)),
                      linewidth=2.5 if phase == "total" else 1)
        if before:
            bx = [r[key] for r in before[i]]
            by = [r["total"] for r in before[i]]
            ax.loglog(bx, by, "k--", label="total before (slope %.2f)" % slope(bx, by))
        ax.loglog(xs, [xs[-1] and sweep[-1]["total"] * x / xs[-1] for x in xs], ":", color="grey",
                  label="linear")
        fixed = ("scan %.2fM triangles" % (sweep[0]["scan_triangles"] / 1e6) if i == 0
                 else "cage %d vertices" % sweep[0]["cage_vertices"])
        ax.set_title("surface fit, %s" % fixed)
        ax.set_xlabel(label)
        ax.set_ylabel("seconds")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.png, dpi=110)
    print("wrote %s" % os.path.relpath(args.png, ROOT))


if __name__ == "__main__":
    main()
