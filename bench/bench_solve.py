# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark of the solve alone, every Gauss-Seidel variant beside GS-PIA, in
one run: a 1M-vertex quad sphere with 0.2% radial noise (bench/meshes.py
quad_sphere(408, noise=0.002), Catmull-Clark, quality 3), smooth quad tori
of 1M and 30k vertices (targets AUTO's probe calls smooth) and the shipped
scans, tolerance 1e-6 of the bounding-box diagonal (the default, as in
bench_scale.py), on 1 and 2 threads.

    /usr/bin/python3 bench/bench_solve.py [--quick] [--repeats N] [--out out/bench/solve.md]

Variants (spia_options.method and solve_flags):

    GS_PIA                  the paper's sweep, vertex order, double, one thread
    GS_PIA +MULTICOLOUR     a greedy multicolour order, each colour on all threads
    GS_PIA +FIRST_STEP      one step of the local approximate inverse first
    GS_PIA_FAST +DOUBLE     the sweep layout and pipelined sweeps, in double
    GS_PIA_FAST             the same in float32 (residual and stop in double)
    GS_PIA_FAST +FIRST_STEP and the first step
    CG, CHEBYSHEV, AUTO     for reference

Each mesh runs in its own process: the stencils are built once, then every
variant is solved `--repeats` times at each thread count, the rounds
interleaved so that a busy moment of the machine does not fall on one
variant; the time is the fastest round's spia_solve wall time
(report.solve_seconds).  Solves one after another reuse the memory the
one before gave back; a solve after CG's or Chebyshev's larger arrays
takes page faults instead (some 10,000 at 1M), so those two come last in
a round.  The last section measures the 1M sphere, each variant in a
process of its own through the C API alone (no numpy copy of the table),
as spia_interpolate runs: the stencil build (time and peak), the table's
resident size with its sweep layout, then one solve on two threads, its
time and the growth of the peak resident size (VmHWM, reset before it).
"""
import argparse
import ctypes
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from harness import ROOT, addon_on_path, proc_status, reset_peak  # noqa: E402

VARIANTS = [
    ("GS_PIA", ()),
    ("GS_PIA", ("MULTICOLOUR",)),
    ("GS_PIA", ("FIRST_STEP",)),
    ("GS_PIA_FAST", ("DOUBLE_SWEEPS",)),
    ("GS_PIA_FAST", ()),
    ("GS_PIA_FAST", ("FIRST_STEP",)),
    ("AUTO", ()),
    ("CG", ()),
    ("CHEBYSHEV", ()),
]
SCANS = ("bunny", "elephant-with-holes", "bun_zipper", "dragon_res2")
TOLERANCE = 1e-6


def label(method, flags):
    short = {"DOUBLE_SWEEPS": "DOUBLE"}
    return method + "".join(f" +{short.get(f, f)}" for f in flags)


def load(mesh_name):
    addon_on_path()
    import numpy as np
    from meshes import quad_sphere, scan
    from subdiv_pia import native
    if mesh_name.startswith("sphere"):
        k, noise = {"sphere-1M": (408, 0.002), "sphere-100k": (129, 0.002)}[mesh_name]
        P, fv = quad_sphere(k, noise=noise)
        return native, P, native.Mesh(P, np.full(len(fv), 4, np.int32), fv.ravel())
    if mesh_name.startswith("torus"):
        nu, nv = {"torus-1M smooth": (1000, 1000), "torus-100k smooth": (400, 250),
                  "torus-30k smooth": (200, 150)}[mesh_name]
        P, fv = torus(nu, nv)
        return native, P, native.Mesh(P, np.full(len(fv), 4, np.int32), fv.ravel())
    P, sizes, fv = scan(mesh_name)
    return native, P, native.Mesh(P, sizes, fv)


def torus(nu, nv):
    """A smooth quad torus (radii 2 and 0.7), nu x nv quads: a target that
    AUTO's probe calls smooth."""
    import numpy as np
    i, j = np.meshgrid(np.arange(nu), np.arange(nv))
    u, v = 2 * np.pi * i / nu, 2 * np.pi * j / nv
    P = np.stack([(2 + 0.7 * np.cos(v)) * np.cos(u), (2 + 0.7 * np.cos(v)) * np.sin(u), 0.7 * np.sin(v)], -1)
    quads = np.stack([j * nu + i, j * nu + (i + 1) % nu, (j + 1) % nv * nu + (i + 1) % nu, (j + 1) % nv * nu + i], -1)
    return P.reshape(-1, 3).astype(np.float32), quads.reshape(-1, 4).astype(np.int32)


def child_mesh(spec):
    native, P, mesh = load(spec["mesh"])
    t = time.perf_counter()
    stencils = native.limit_stencils(mesh)
    stencil_s = time.perf_counter() - t
    results = {}
    for rnd in range(spec["repeats"]):
        for threads in (1, 2):
            for method, flags in VARIANTS:
                key = f"{label(method, flags)}|{threads}"
                try:
                    cage, report = stencils.solve(P, method=method, solve_flags=flags, threads=threads,
                                                  tolerance=TOLERANCE, max_iterations=1000)
                except native.PiaError as error:
                    results[key] = dict(refused=f"{error.code}")
                    continue
                r = results.setdefault(key, dict(seconds=[]))
                r["seconds"].append(report.solve_seconds)
                r.update(iterations=report.iterations, method_used=report.method, status=report.status,
                         max_error=report.max_error_relative, unreachable=report.unreachable_count,
                         cage=hash(cage.tobytes()))
    return dict(vertices=len(P), weights=int(stencils.weights.size), stencil_s=stencil_s, results=results)


def child_memory(spec):
    """The 1M sphere through the C API: build, table, one solve of one variant."""
    native, P, mesh = load("sphere-1M")
    lib = native._library()
    n = len(P)
    out = dict(vertices=n)
    opts, _keep = native._options(threads=2, method=spec["method"], solve_flags=tuple(spec["flags"]))
    handle = ctypes.c_void_p()
    st = native._Status()
    rss0 = reset_peak()
    t = time.perf_counter()
    code = lib.spia_limit_stencils_create(ctypes.byref(mesh._c()), ctypes.byref(opts), ctypes.byref(handle),
                                          ctypes.byref(st))
    out["stencil_s"] = time.perf_counter() - t
    if code != 0:
        return dict(failed=st.message.decode())
    out["build_peak"] = (proc_status("VmHWM") - rss0) / n
    out["table"] = (proc_status("VmRSS") - rss0) / n
    import numpy as np
    cage = np.empty_like(P)
    rep = native._Report()
    rss1 = reset_peak()
    code = lib.spia_solve(handle, native._ptr(P, ctypes.c_float), ctypes.byref(opts), native._ptr(cage, ctypes.c_float),
                          ctypes.byref(rep), ctypes.byref(st))
    out["solve"] = (proc_status("VmHWM") - rss1) / n
    out["table_and_solve"] = (proc_status("VmHWM") - rss0) / n
    out["solve_s"] = rep.solve_seconds
    out["method_used"] = native.METHODS[rep.method]
    lib.spia_stencils_free(handle)
    return out


def run_child(spec):
    out = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], capture_output=True, text=True)
    if out.returncode:
        return dict(failed=(out.stderr.strip().splitlines() or ["?"])[-1])
    return json.loads(out.stdout.strip().splitlines()[-1])


def fmt_s(s):
    return f"{s:.5f}" if s < 0.01 else f"{s:.4f}" if s < 1 else f"{s:.2f}"


def mesh_table(name, r):
    lines = [f"### {name}: {r['vertices']:,} vertices, {r['weights']:,} weights, stencils {r['stencil_s']:.2f} s\n",
             "| variant | iterations | solve s, 1 thread | solve s, 2 threads | max error | / GS-PIA, 1 thread | "
             "/ GS-PIA, 2 threads | method used |",
             "|---|---:|---:|---:|---:|---:|---:|---|"]
    res = r["results"]
    base = {t: min(res[f"GS_PIA|{t}"]["seconds"]) for t in (1, 2) if "seconds" in res.get(f"GS_PIA|{t}", {})}
    for method, flags in VARIANTS:
        name_ = label(method, flags)
        one, two = res.get(f"{name_}|1", {}), res.get(f"{name_}|2", {})
        if "refused" in one:
            lines.append(f"| {name_} | refused: {one['refused']} | | | | | | |")
            continue
        s1, s2 = min(one["seconds"]), min(two["seconds"])
        status = "" if one["status"] == "CONVERGED" else f" ({one['status'].lower()}"
        if one["unreachable"]:
            status += f", {one['unreachable']} unreachable"
        if status:
            status += ")"
        same = "" if one["cage"] == two["cage"] else " (cages differ between 1 and 2 threads!)"
        iters = str(one["iterations"]) if one["iterations"] == two["iterations"] else \
            f"{one['iterations']}/{two['iterations']}"
        lines.append(f"| {name_} | {iters} | {fmt_s(s1)} | {fmt_s(s2)} | {one['max_error']:.1e}{status} | "
                     f"{s1 / base[1]:.2f} | {s2 / base[2]:.2f} | {one['method_used']}{same} |")
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the 100k sphere instead of the 1M ones")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "solve.md"))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        spec = json.loads(args.child)
        fn = child_memory if spec.get("task") == "memory" else child_mesh
        print(json.dumps(fn(spec)), flush=True)
        return
    started = time.monotonic()
    meshes = ["sphere-100k", "torus-100k smooth"] if args.quick else ["sphere-1M", "torus-1M smooth"]
    meshes += ["torus-30k smooth"] + list(SCANS)
    md = [f"# The solve, variant by variant\n",
          f"{time.strftime('%Y-%m-%d %H:%M')}; {os.cpu_count()} processors. Tolerance {TOLERANCE:g} x bounding-box "
          f"diagonal; time = fastest of {args.repeats} rounds of spia_solve (report.solve_seconds; the scans "
          f"below 10k vertices {4 * args.repeats} rounds); ratios are to GS_PIA at the same thread count.\n"]
    print("\n".join(md), flush=True)
    for name in meshes:
        small = name in ("bunny", "elephant-with-holes")
        repeats = 4 * args.repeats if small else args.repeats
        r = run_child(dict(mesh=name, repeats=repeats))
        text = f"### {name}: failed: {r['failed']}\n" if "failed" in r else mesh_table(name, r)
        print(text, flush=True)
        md.append(text)
    if not args.quick:
        lines = ["### Memory of the 1M sphere, C API only, a process per variant (bytes per vertex)\n",
                 "| variant | stencil build s | build peak | table (with its layout) | solve s, 2 threads | solve peak | "
                 "table + solve | method used |",
                 "|---|---:|---:|---:|---:|---:|---:|---|"]
        for method, flags in VARIANTS:
            m = run_child(dict(task="memory", method=method, flags=list(flags)))
            if "failed" in m:
                lines.append(f"| {label(method, flags)} | failed: {m['failed']} |")
                continue
            lines.append(f"| {label(method, flags)} | {m['stencil_s']:.2f} | {m['build_peak']:.0f} | "
                         f"{m['table']:.0f} | {fmt_s(m['solve_s'])} | {m['solve']:.0f} | {m['table_and_solve']:.0f} | "
                         f"{m['method_used']} |")
        text = "\n".join(lines) + "\n"
        print(text, flush=True)
        md.append(text)
    md.append(f"Whole run: {time.monotonic() - started:.0f} s.\n")
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as fh:
        fh.write("\n".join(md))
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
