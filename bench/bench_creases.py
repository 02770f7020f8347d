# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: time and peak memory of the library on closed triangle meshes
whose creased edges all carry one crease value (tests/python/crease_cases.py:
an octahedron with every edge creased, icospheres of 42 and 642 vertices
with their upper cap creased), each cell in a child process limited to
LIMIT bytes of address space, as `ulimit -v` would; and the peak resident
size per face of the refinements, from which the library's estimates
(csrc/src/interpolate.c) are taken.

    /usr/bin/python3 bench/bench_creases.py [--limit-gb 2] [--scheme LOOP] [--quality 3]

Prints Markdown tables: per mesh and crease, the call's wall time and the
child's peak resident size, or the refusal's message, or how the child died.
"""
import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "tests", "python"))

from crease_cases import CREASES, MESHES, run_limited  # noqa: E402


def cell(out):
    if out["killed"] is not None:
        return "killed (%s)" % out["killed"]
    call = out["calls"][0]
    if call["outcome"] == "refused":
        return "refused: %s" % call["message"]
    return "%.3f s, %.0f MB" % (call["seconds"], out["peak_mb"])


def crease_table(limit, scheme, quality):
    print("### %s, quality %d, under %.1f GB of address space\n" % (scheme, quality, limit / 2.0 ** 30))
    print("| mesh | " + " | ".join("crease %g" % c for c in CREASES) + " |")
    print("|---|" + "---|" * len(CREASES))
    for mesh in MESHES:
        row = [cell(run_limited(mesh, c, [{"scheme": scheme, "quality": quality}], limit)) for c in CREASES]
        print("| %s | %s |" % (mesh, " | ".join(row)))
    print()


def refine_table(limit):
    """Peak resident size per face of the last level at two levels, the
    difference taken so that the interpreter's own memory drops out."""
    print("### Peak memory per refined face (the difference of two levels)\n")
    print("| scheme | levels | faces | peak MB | bytes per face |")
    print("|---|---|---|---|---|")
    for scheme, levels in (("LOOP", (5, 6)), ("DOO_SABIN", (4, 5))):
        runs = []
        for level in levels:
            out = run_limited("icosphere-642", 0.9, [{"call": "refine", "levels": level, "scheme": scheme,
                                                      "memory_budget": -1}], limit)
            call = out["calls"][0] if out["calls"] else {"outcome": "killed"}
            if call["outcome"] != "done":
                print("| %s | %d | %s | | |" % (scheme, level, cell(out)))
                break
            runs.append((call["result"]["faces"], out["peak_mb"]))
            print("| %s | %d | %d | %.0f | |" % (scheme, level, runs[-1][0], runs[-1][1]))
        if len(runs) == 2:
            per = (runs[1][1] - runs[0][1]) * 2 ** 20 / (runs[1][0] - runs[0][0])
            print("| %s | %d to %d | | | %.0f |" % (scheme, levels[0], levels[1], per))
    print()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--limit-gb", type=float, default=2.0)
    parser.add_argument("--scheme", default=None, help="one scheme (default: LOOP, CATMULL_CLARK, DOO_SABIN)")
    parser.add_argument("--quality", type=int, default=3)
    args = parser.parse_args()
    limit = int(args.limit_gb * 2 ** 30)
    for scheme in [args.scheme] if args.scheme else ["LOOP", "CATMULL_CLARK", "DOO_SABIN"]:
        qualities = [args.quality] if scheme != "CATMULL_CLARK" or args.scheme else [1, 10]
        for quality in qualities:
            crease_table(limit, scheme, quality)
    refine_table(max(limit, 8 << 30))


if __name__ == "__main__":
    main()
