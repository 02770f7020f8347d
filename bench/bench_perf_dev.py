"""Quick timing of the library at scan sizes, for development.

    /usr/bin/python3 bench/bench_perf_dev.py [case ...] [--threads N] [--method M]

Cases: cc1m (1M-vertex quad sphere), cc1m-crease (the same with 10% of its
edges creased: random edges, fixed seed, creases 0.3 / 0.5 / 0.7 / 1.0),
loop1m (the sphere's quads split in two), and the names of meshes in
/work/shared/meshes or tests/data (e.g. bunny, dragon_res2).  Each case runs
spia_interpolate in its own process; peak is VmHWM over the call (reset
before it), so it is the library's: stencils, solver, cage.  The machine is
shared: single runs are noisy.
"""
import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SHARED = "/work/shared/meshes"


def sphere_edges(fv):
    import numpy as np
    e = np.stack([fv, np.roll(fv, -1, axis=1)], 2).reshape(-1, 2)
    e.sort(axis=1)
    return np.unique(e, axis=0).astype(np.int32)


def load(case):
    import numpy as np
    sys.path.insert(0, HERE)
    from meshes import quad_sphere
    from meshio import read_obj
    kw = {}
    if case.startswith("cc1m") or case.startswith("loop1m") or case.startswith("cc100k"):
        k = 129 if case.startswith("cc100k") else 408
        P, fv = quad_sphere(k)
        if case.startswith("loop"):
            fv = np.concatenate([fv[:, [0, 1, 2]], fv[:, [0, 2, 3]]])
            return P, np.full(len(fv), 3, np.int32), fv.ravel(), dict(scheme="LOOP")
        if case.endswith("crease"):
            edges = sphere_edges(fv)
            rng = np.random.default_rng(7)
            creases = np.zeros(len(edges), np.float32)
            pick = rng.random(len(edges)) < 0.1
            creases[pick] = rng.choice(np.array([0.3, 0.5, 0.7, 1.0], np.float32), int(pick.sum()))
            kw = dict(edges=edges, edge_creases=creases)
        return P, np.full(len(fv), 4, np.int32), fv.ravel(), dict(mesh_kw=kw)
    name, _, scheme = case.partition(":")
    path = os.path.join(SHARED, name + ".obj")
    if not os.path.exists(path):
        path = os.path.join(ROOT, "tests", "data", name + ".obj")
    P, faces, _ = read_obj(path)
    faces = [f for f in faces if len(set(f)) == len(f)]
    sizes = np.fromiter((len(f) for f in faces), np.int32, len(faces))
    fv = np.fromiter((v for f in faces for v in f), np.int32, int(sizes.sum()))
    return P, sizes, fv, dict(scheme=scheme or "CATMULL_CLARK")


def child(spec):
    import numpy as np
    sys.path.insert(0, os.path.join(ROOT, "tests", "python"))
    sys.path.insert(0, os.path.join(ROOT, "build", "addon"))
    from subdiv_pia import native
    P, sizes, fv, extra = load(spec["case"])
    mesh = native.Mesh(P, sizes, fv, **extra.get("mesh_kw", {}))
    opts = dict(scheme=extra.get("scheme", "CATMULL_CLARK"), method=spec["method"], tolerance=spec["tol"],
                max_iterations=2000)
    if spec.get("threads") is not None and "threads" in native.interpolate.__code__.co_varnames:
        opts["threads"] = spec["threads"]

    def status(field):
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field):
                    return int(line.split()[1]) * 1024
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")
    rss0 = status("VmRSS")
    t, c = time.perf_counter(), time.process_time()
    cage, rep = native.interpolate(mesh, **opts)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    peak = status("VmHWM") - rss0
    print(json.dumps(dict(n=len(P), st=rep.stencil_seconds, so=rep.solve_seconds, wall=wall, cpu=cpu, it=rep.iterations,
                          method=rep.method, status=rep.status, err=rep.max_error_relative,
                          bpv=peak / len(P))))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="*", default=["cc1m", "cc1m-crease", "loop1m"])
    ap.add_argument("--method", default="AUTO")
    ap.add_argument("--threads", type=int)
    ap.add_argument("--tol", type=float, default=1e-6)
    ap.add_argument("--child")
    args = ap.parse_args()
    if args.child:
        child(json.loads(args.child))
        return
    print("| case | method | threads | vertices | stencils s | solve s | total s | cpu s | iterations | status | max err | B/vertex |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|")
    for case in args.cases:
        for method in args.method.split(","):
            spec = dict(case=case, method=method, threads=args.threads, tol=args.tol)
            out = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], capture_output=True, text=True)
            if out.returncode:
                print(f"| {case} | {method} | failed: {out.stderr.strip().splitlines()[-1]} |", flush=True)
                continue
            r = json.loads(out.stdout)
            print(f"| {case} | {method}->{r['method']} | {args.threads if args.threads is not None else '-'} | "
                  f"{r['n']:,} | {r['st']:.3f} | {r['so']:.3f} | {r['st'] + r['so']:.3f} | {r['cpu']:.2f} | {r['it']} | "
                  f"{r['status'].lower()} | {r['err']:.1e} | {r['bpv']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
