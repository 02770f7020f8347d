# SPDX-License-Identifier: GPL-3.0-or-later
"""The Loop and Doo-Sabin previews' refinement (spia_refine_size, then
spia_refine, as native.refine calls them): time, the longest wait between
progress calls, and how soon a cancel stops it, on closed triangle spheres
(an octahedron split 5 to 7 times: 8k to 131k triangles) refined 1 to 3
levels.  With --compare LIBRARY the same cases run on another build of the
library too, alternating, in this process.  Prints a Markdown table.

    /usr/bin/python3 bench/bench_refine.py [--compare path/to/libsubdiv_pia.so] [--repeat 2]
"""
import argparse
import ctypes
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import addon_on_path  # noqa: E402

addon_on_path()
from subdiv_pia import native  # noqa: E402

SCHEMES = [("Loop", dict(scheme="LOOP")), ("Loop, Hoppe", dict(scheme="LOOP", boundary_rule="HOPPE")),
           ("Doo-Sabin", dict(scheme="DOO_SABIN", use_creases=False))]


def octahedron_sphere(splits):
    """A closed unit sphere of triangles: the octahedron, each triangle
    split in four `splits` times, the new vertices pushed onto the sphere."""
    points = [np.array(p, float) for p in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))]
    faces = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]
    for _ in range(splits):
        middle = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in middle:
                p = points[a] + points[b]
                points.append(p / np.linalg.norm(p))
                middle[key] = len(points) - 1
            return middle[key]
        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    faces = np.array(faces, np.int32)
    return native.Mesh(np.array(points, np.float32), np.full(len(faces), 3, np.int32), faces.ravel())


def use(library):
    """Makes native's functions call `library` (a loaded, declared CDLL):
    the loader's own state, which they read (spia/library.py)."""
    native.library._lib = library


def libraries(compare):
    """[("this", this build's library)] and, with `compare` (a path),
    ("other", that build's), loaded and declared for native."""
    found = [("this", native._library())]
    if compare:
        other = ctypes.CDLL(os.path.abspath(compare))
        native._declare(other)
        found.append(("other", other))
    return found


def one_run(mesh, levels, settings, cancel_after=None):
    """(seconds, faces made, longest wait between progress calls (from the
    start and to the end too), calls, seconds from the cancel to the return
    or None)."""
    marks = []
    start = time.perf_counter()
    cancelled_at = []

    def progress(_level, _share):
        now = time.perf_counter()
        marks.append(now)
        if cancel_after is not None and now - start >= cancel_after:
            cancelled_at.append(now)
            return True
        return False
    try:
        _, sizes, _ = native.refine(mesh, levels, progress=progress, **settings)
        faces = len(sizes)
    except native.PiaCancelled:
        faces = None
    end = time.perf_counter()
    gaps = np.diff([start] + marks + [end])
    stop = end - cancelled_at[0] if cancelled_at else None
    return end - start, faces, float(gaps.max()), len(marks), stop


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--compare", help="another build of the library, run beside this one")
    parser.add_argument("--repeat", type=int, default=2, help="runs of each case (the fastest is shown)")
    parser.add_argument("--splits", type=int, nargs="+", default=[5, 6, 7])
    args = parser.parse_args()
    loaded = libraries(args.compare)
    this = loaded[0][1]
    head = ("| scheme | cage triangles | levels | faces made | time | longest wait between progress calls | "
            "cancel half-way: stopped after |")
    if args.compare:
        head += " other library's time |"
    rows = [head, "|---|" + "---:|" * (head.count("|") - 2)]
    print("\n".join(rows), flush=True)
    for splits in args.splits:
        mesh = octahedron_sphere(splits)
        for label, settings in SCHEMES:
            for levels in (1, 2, 3):
                best = {}
                for _ in range(args.repeat):
                    for name, library in loaded:  # alternating, so that both see the same machine
                        use(library)
                        run = one_run(mesh, levels, settings)
                        if name not in best or run[0] < best[name][0]:
                            best[name] = run
                use(this)
                seconds, faces, gap, _calls, _ = best["this"]
                _, _, _, _, stop = one_run(mesh, levels, settings, cancel_after=seconds / 2)
                row = "| %s | %d | %d | %d | %.3f s | %.3f s | %s |" % (
                    label, len(mesh.face_sizes), levels, faces, seconds, gap,
                    "%.3f s" % stop if stop is not None else "(ended first)")
                if args.compare:
                    row += " %.3f s (%.2fx) |" % (best["other"][0], best["other"][0] / seconds)
                print(row, flush=True)
    use(this)


if __name__ == "__main__":
    main()
