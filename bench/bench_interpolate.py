# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: stencils and solve for generated quad spheres of about 10k,
100k and 1M vertices and for the shipped scans, with AUTO, PIA and GS-PIA.

    /usr/bin/python3 bench/bench_interpolate.py [--quick] [--out out/bench.md]

Each case runs in its own process so that its peak memory (VmHWM, reset
before the library call) is the library's: stencils, solver and cage.
Times are wall-clock on this machine, one thread.
"""
import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from harness import ROOT, addon_on_path, proc_status, reset_peak  # noqa: E402


def child(spec):
    import numpy as np
    addon_on_path()
    from meshes import quad_sphere, scan
    from subdiv_pia import native
    if spec["mesh"].startswith("sphere"):
        P, fv = quad_sphere(spec["k"], noise=spec.get("noise", 0.0))
        mesh = native.Mesh(P, np.full(len(fv), 4, np.int32), fv.ravel())
    else:
        P, sizes, fv = scan(spec["mesh"])
        mesh = native.Mesh(P, sizes, fv)

    rss0 = reset_peak()
    t = time.perf_counter()
    stencils = native.limit_stencils(mesh)
    t_stencils = time.perf_counter() - t
    t = time.perf_counter()
    cage, report = stencils.solve(P, method=spec["method"], max_iterations=2000)
    t_solve = time.perf_counter() - t
    peak = proc_status("VmHWM") - rss0
    print(json.dumps(dict(vertices=len(P), weights=int(stencils.weights.size), stencil_s=t_stencils,
                          solve_s=t_solve, iterations=report.iterations, status=report.status,
                          max_error=report.max_error_relative, unreachable=report.unreachable_count,
                          reachable=report.reachable_max_error_relative, peak_bytes=peak)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="skip the 1M-vertex sphere")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench.md"))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(json.loads(args.child))
        return
    cases = [("sphere-10k", dict(k=41)), ("sphere-100k", dict(k=129))]
    if not args.quick:
        cases.append(("sphere-1M", dict(k=408)))
    cases.append(("sphere-100k rough", dict(k=129, noise=0.002)))
    cases += [(name, {}) for name in ("bunny", "elephant-with-holes", "bun_zipper", "dragon_res2")]
    rows = ["| mesh | vertices | weights | method | stencils s | solve s | iterations | status | max error | peak MB | bytes/vertex |",
            "|---|---:|---:|---|---:|---:|---:|---|---:|---:|---:|"]
    print("\n".join(rows), flush=True)
    for label, extra in cases:
        for method in ("AUTO", "PIA", "GS_PIA"):
            spec = dict(mesh=label.split()[0].replace("-10k", "").replace("-100k", "").replace("-1M", "")
                        if not label.startswith("sphere") else "sphere", method=method, **extra)
            if not label.startswith("sphere"):
                spec["mesh"] = label
            out = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)],
                                 capture_output=True, text=True)
            if out.returncode:
                row = f"| {label} | | | {method} | failed: {out.stderr.strip().splitlines()[-1]} |"
            else:
                r = json.loads(out.stdout)
                status = r["status"].lower()
                if r["unreachable"]:
                    status += f" ({r['unreachable']} unreachable, rest {r['reachable']:.1e})"
                row = (f"| {label} | {r['vertices']:,} | {r['weights']:,} | {method} | {r['stencil_s']:.3f} | "
                       f"{r['solve_s']:.3f} | {r['iterations']} | {status} | {r['max_error']:.1e} | "
                       f"{r['peak_bytes'] / 2**20:.0f} | {r['peak_bytes'] / r['vertices']:.0f} |")
            rows.append(row)
            print(row, flush=True)
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as fh:
        fh.write("\n".join(rows) + "\n")
    print(f"\nwritten to {args.out}")


if __name__ == "__main__":
    main()
