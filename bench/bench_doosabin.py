# SPDX-License-Identifier: GPL-3.0-or-later
"""Two-phase Doo-Sabin interpolation as the paper measures it: stop at
0.01% of the bounding-box diagonal, for the closed meshes in tests/data and
shape parameters 0.4, 0.5, 0.8 and 0.99, with PIA (the paper's) and GS-PIA
(and AUTO).  Prints a Markdown table and writes it to out/doosabin.md.

    /usr/bin/python3 bench/bench_doosabin.py
"""
import os
import sys
import time


sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import ROOT, addon_on_path  # noqa: E402

addon_on_path()
from meshes import scan  # noqa: E402
from subdiv_pia import native  # noqa: E402

MESHES = ["bunny", "mushroom", "double-torus", "dragon_res2"]
PARAMETERS = [0.4, 0.5, 0.8, 0.99]
METHODS = ["PIA", "GS_PIA", "AUTO"]


def main():
    rows = ["| mesh | vertices | faces | w | method | iterations | max error | time s |",
            "|---|---:|---:|---:|---|---:|---:|---:|"]
    print("\n".join(rows), flush=True)
    for name in MESHES:
        P, sizes, fv = scan(name)
        mesh = native.Mesh(P, sizes, fv)
        for w in PARAMETERS:
            for method in METHODS:
                t = time.perf_counter()
                _, report = native.interpolate(mesh, scheme="DOO_SABIN", shape_parameter=w, method=method,
                                               tolerance=1e-4, max_iterations=10000)
                seconds = time.perf_counter() - t
                label = method if method != "AUTO" else f"AUTO ({report.method})"
                row = (f"| {name} | {len(P):,} | {len(sizes):,} | {w} | {label} | {report.iterations} | "
                       f"{report.max_error_relative:.2e} | {seconds:.3f} |")
                rows.append(row)
                print(row, flush=True)
    out = os.path.join(ROOT, "out", "doosabin.md")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    with open(out, "w") as fh:
        fh.write("\n".join(rows) + "\n")
    print(f"\nwritten to {out}; times include building the stencils")


if __name__ == "__main__":
    main()
