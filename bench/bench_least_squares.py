# SPDX-License-Identifier: GPL-3.0-or-later
"""Meshes whose limit matrices no cage satisfies: OpenSubdiv's valence-2
regression shapes (singular limit matrices, one with a negative
eigenvalue) and the Stanford dragon scan (double-sided triangles), each
interpolated (Catmull-Clark, AUTO) from the stencils to the cage.  For each:
the status, the solver that gave the cage, iterations, the unreachable
vertices, the worst error of the others and of all (relative to the
diagonal), and the solve's time.  With --compare LIBRARY the same cases run
on another build of the library too, alternating, in this process, and its
figures stand beside these.  Prints a Markdown table.

    /usr/bin/python3 bench/bench_least_squares.py [--compare path/to/libsubdiv_pia.so] [--repeat 3]
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import DATA, ROOT, addon_on_path  # noqa: E402

addon_on_path()
sys.path.insert(0, os.path.join(ROOT, "tools"))
from subdiv_pia import native  # noqa: E402
import osd_shapes  # noqa: E402
from bench_refine import libraries, use  # noqa: E402

CASES = [("catmark_val2_interior", dict(use_creases=False, quality=1)),
         ("catmark_val2_interior", dict(use_creases=True, quality=3)),
         ("catmark_val2_foldover", dict(quality=3)),
         ("catmark_val2_back2back", dict(quality=3)),
         ("catmark_val2_nonman", dict(quality=3)),
         ("dragon_res2", dict(quality=1))]


def load(name):
    if name == "dragon_res2":
        path = os.path.join(DATA, "dragon_res2.obj")
        points, faces = [], []
        with open(path) as f:
            for line in f:
                if line.startswith("v "):
                    points.append([float(x) for x in line.split()[1:4]])
                elif line.startswith("f "):
                    faces.append([int(w.split("/")[0]) - 1 for w in line.split()[1:]])
        sizes = np.array([len(f) for f in faces], np.int32)
        return native.Mesh(np.array(points, np.float32), sizes, np.concatenate(faces).astype(np.int32))
    return native.Mesh(**osd_shapes.load(name).mesh_arrays())


def one_run(mesh, settings):
    """(report, cage, solve seconds, stencils) or the library's error."""
    stencil_settings = {k: v for k, v in settings.items() if k in ("use_creases", "quality")}
    stencils = native.limit_stencils(mesh, **stencil_settings)
    start = time.perf_counter()
    try:
        cage, report = stencils.solve(mesh.positions)
    except native.PiaError as error:
        return error, None, time.perf_counter() - start, stencils
    return report, cage, time.perf_counter() - start, stencils


def describe(run):
    report, _cage, seconds, _ = run
    if isinstance(report, native.PiaError):
        return "%s (nothing made) | | | | | %.3f s" % (report.code, seconds)
    return "%s | %s | %d | %d | %.2g | %.2g | %.3f s" % (
        report.status, report.method, report.iterations, report.unreachable_count,
        report.reachable_max_error_relative if report.unreachable_count else report.max_error_relative,
        report.max_error_relative, seconds)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--compare", help="another build of the library, run beside this one")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each case (the fastest is shown)")
    args = parser.parse_args()
    loaded = libraries(args.compare)
    this = loaded[0][1]
    columns = "status | solver | iterations | unreachable | worst of the others | worst | solve time"
    head = "| mesh | settings | vertices | " + columns + " |"
    if args.compare:
        head += " other: " + " | other: ".join(columns.split(" | ")) + " |"
    print(head)
    print("|---|---|---:|" + "---|---|---:|---:|---:|---:|---:|" * len(loaded))
    for name, settings in CASES:
        mesh = load(name)
        best = {}
        for _ in range(args.repeat):
            for label, library in loaded:  # alternating, so that both see the same machine
                use(library)
                run = one_run(mesh, settings)
                if label not in best or run[2] < best[label][2]:
                    best[label] = run
        use(this)
        row = "| %s | %s | %d | %s |" % (name, ", ".join("%s=%s" % kv for kv in settings.items()),
                                         mesh.vertex_count, describe(best["this"]))
        if args.compare:
            row += " %s |" % describe(best["other"])
        print(row, flush=True)


if __name__ == "__main__":
    main()
