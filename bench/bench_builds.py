#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Two builds of the library side by side, for a change that must not alter
speed (a refactoring): the same cases, each in a fresh process per round,
the two builds alternating in order, one thread, CPU time, best of the
rounds; and the outputs' sha256 compared.

    python3 bench/bench_builds.py BEFORE.so AFTER.so [--rounds 3]

A build to compare with: `git worktree add /tmp/base <revision> && make -C
/tmp/base build`, then /tmp/base/build/cmake/libsubdiv_pia.so.  Prints a
Markdown table: case, CPU seconds of each build, their ratio, and whether
the outputs are the same to the bit."""
import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CASES = {
    "interpolate dragon scan (AUTO)": "interpolate:dragon_res2.obj:AUTO",
    "interpolate dragon scan (CHEBYSHEV)": "interpolate:dragon_res2.obj:CHEBYSHEV",
    "interpolate armadillo (CG)": "interpolate:armadillo.obj:CG",
    "interpolate car, quality 6": "interpolate:catmark_car.obj:AUTO:6",
    "GS-PIA solve, armadillo": "solve:armadillo.obj:GS_PIA",
    "scan, armadillo": "scan:armadillo.obj",
    "fit, bunny (Surface)": "fit:bun_zipper_quadriflow_cage.obj:bun_zipper.obj",
    "fit, dragon (Surface)": "fit:dragon_res2_quadriflow_cage.obj:dragon_res2.obj",
}
CHILD = r'''
import hashlib, json, os, sys, time
import numpy as np
sys.path.insert(0, os.path.join(ROOT, "tools"))
import spia
from checksums import load as data  # a tests/data mesh as a spia.Mesh, with its creases
kind, *args = CASE.split(":")
if kind == "interpolate":
    mesh = data(args[0])
    run = lambda: spia.interpolate(mesh, method=args[1], quality=int(args[2]) if len(args) > 2 else 3, threads=1)[0]
elif kind == "solve":
    mesh = data(args[0])
    table = spia.limit_stencils(mesh, threads=1)
    run = lambda: table.solve(mesh.positions, method=args[1], threads=1)[0]
elif kind == "scan":
    mesh = data(args[0])
    run = lambda: spia.Scan(mesh).closest_points(mesh.positions[::7] * 1.01)[2]
else:
    cage, scan = data(args[0]), spia.Scan(data(args[1]))
    run = lambda: spia.fit(cage, scan, threads=1)[0]
t0 = time.process_time()
out = run()
repeat = max(1, int(0.3 / max(time.process_time() - t0, 1e-4)))  # at least about 0.3 s per measure
best = None
for _ in range(ROUNDS):
    t0 = time.process_time()
    for _ in range(repeat):
        out = run()
    t = (time.process_time() - t0) / repeat
    best = t if best is None else min(best, t)
print(json.dumps([best, hashlib.sha256(np.ascontiguousarray(out).tobytes()).hexdigest()]))
'''


def one(library, case, rounds):
    code = "ROOT, CASE, ROUNDS = %r, %r, %d\n" % (ROOT, case, rounds) + CHILD
    env = dict(os.environ, PYTHONPATH=os.path.join(ROOT, "python"), SUBDIV_PIA_LIBRARY=os.path.abspath(library))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit("%s on %s failed:\n%s" % (case, library, out.stderr[-2000:]))
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before")
    parser.add_argument("after")
    parser.add_argument("--rounds", type=int, default=3, help="fresh processes per build and case")
    args = parser.parse_args(argv)
    builds = [args.before, args.after]
    times = {(b, c): [] for b in (0, 1) for c in CASES}
    sums = {}
    for r in range(args.rounds):
        for name, case in CASES.items():
            for b in ((0, 1) if r % 2 == 0 else (1, 0)):
                seconds, digest = one(builds[b], case, 2)
                times[(b, name)].append(seconds)
                sums.setdefault((b, name), set()).add(digest)
    print("| case | before (ms) | after (ms) | after / before | outputs |\n|---|---:|---:|---:|---|")
    for name in CASES:
        before, after = min(times[(0, name)]), min(times[(1, name)])
        same = sums[(0, name)] == sums[(1, name)] and len(sums[(0, name)]) == 1
        print("| %s | %.1f | %.1f | %.3f | %s |" % (name, before * 1e3, after * 1e3, after / before,
                                                   "identical" if same else "DIFFERENT"))
    print("\nCPU time of one thread per call (calls repeated to about 0.3 s), best of %d fresh processes per "
          "build, the builds alternating." % args.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
