# SPDX-License-Identifier: GPL-3.0-or-later
"""Checksums of what the library computes: interpolation (every scheme,
every solver method, several qualities and solver options), refinement,
surface stencils, closest points and fits (both modes) on the meshes of
tests/data.  One line per case: its name and the sha256 of its outputs
(arrays and reports, timings left out), so that two builds of the library
can be compared line by line:

    PYTHONPATH=python SUBDIV_PIA_LIBRARY=build/cmake/libsubdiv_pia.so \\
        /usr/bin/python3 tools/checksums.py [--quick] > sums.txt

A case the library refuses is summed over its result code and message."""
import argparse
import dataclasses
import hashlib
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "python"))
import spia  # noqa: E402
from meshio import read_obj  # noqa: E402

DATA = os.path.join(os.path.dirname(__file__), "..", "tests", "data")
TIMINGS = {"stencil_seconds", "solve_seconds", "query_seconds"}


def load(name):
    positions, faces, creases = read_obj(os.path.join(DATA, name))
    kwargs = {}
    if creases:
        edges = np.array(list(creases.keys()), np.int32)
        kwargs = dict(edges=edges, edge_creases=np.array([min(s / 10.0, 1.0) for s in creases.values()], np.float32))
    return spia.Mesh.from_faces(positions, faces, **kwargs)


def creased_grid(k, triangles):
    """A wavy k x k grid (open: corners of two edges), every third row of
    edges semi-sharp, and quads or triangles."""
    i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    z = 0.1 * np.sin(i * 0.7) * np.cos(j * 0.5)
    positions = np.stack([i.ravel(), j.ravel(), z.ravel()], 1).astype(np.float32)
    at = lambda a, b: a * (k + 1) + b  # noqa: E731
    faces = []
    for a in range(k):
        for b in range(k):
            q = [at(a, b), at(a + 1, b), at(a + 1, b + 1), at(a, b + 1)]
            faces += [q[:3], [q[0], q[2], q[3]]] if triangles else [q]
    edges = [(at(a, b), at(a, b + 1)) for a in range(0, k + 1, 3) for b in range(k)]
    sharpness = [0.3 + 0.1 * (n % 5) for n in range(len(edges))]
    return spia.Mesh.from_faces(positions, faces, edges=np.array(edges, np.int32),
                                edge_creases=np.array(sharpness, np.float32))


def feed(h, value):
    if isinstance(value, np.ndarray):
        h.update(str(value.dtype).encode() + str(value.shape).encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif dataclasses.is_dataclass(value):
        for f in dataclasses.fields(value):
            if f.name not in TIMINGS:
                h.update(f.name.encode())
                feed(h, getattr(value, f.name))
    elif isinstance(value, (tuple, list)):
        for v in value:
            feed(h, v)
    elif isinstance(value, float):
        h.update(np.float64(value).tobytes())
    else:
        h.update(repr(value).encode())


def case(name, fn):
    h = hashlib.sha256()
    try:
        feed(h, fn())
    except spia.PiaError as e:
        feed(h, ("error", getattr(e, "code", None), str(e)))
    print(f"{name} {h.hexdigest()}", flush=True)


class Calls:
    """A progress callback that keeps the calls past iteration 0, each once
    in a row (the calls made on a timer repeat the last figures), and
    cancels at iteration `stop`."""

    def __init__(self, stop=None):
        self.calls, self.stop = [], stop

    def __call__(self, iteration, value):
        if iteration > 0 and (not self.calls or self.calls[-1] != (iteration, value)):
            self.calls.append((iteration, value))
        return self.stop is not None and iteration >= self.stop


def with_calls(fn, stop=None):
    calls = Calls(stop)
    try:
        out = fn(calls)
    except spia.PiaError as e:
        out = ("error", getattr(e, "code", None), str(e))
    return out, calls.calls


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="leave out the largest meshes")
    args = ap.parse_args()
    small = ["catmark_car.obj", "catmark_nonman_edges.obj", "double-torus.obj", "mushroom.obj", "teapot.obj",
             "bunny.obj", "elephant-with-holes.obj", "bun_zipper_quadriflow_cage.obj"]
    meshes = {n: load(n) for n in small}
    for triangles, scheme in ((False, "CATMULL_CLARK"), (True, "LOOP")):
        grid = creased_grid(40, triangles)
        for quality in (2, 4):
            case(f"interpolate grid {scheme} q{quality}", lambda: spia.interpolate(grid, scheme=scheme,
                                                                                  quality=quality, threads=2))
            case(f"stencils grid {scheme} q{quality}", lambda: (lambda s: (s.offsets, s.indices, s.weights))(
                spia.limit_stencils(grid, scheme=scheme, quality=quality, threads=2)))
    methods = spia.METHODS
    for n, m in meshes.items():
        for scheme in spia.SCHEMES:
            for quality in (1, 3):
                case(f"interpolate {n} {scheme} q{quality}",
                     lambda: spia.interpolate(m, scheme=scheme, quality=quality))
            case(f"stencils {n} {scheme}", lambda: (lambda s: (s.offsets, s.indices, s.weights))(
                spia.limit_stencils(m, scheme=scheme)))
        case(f"interpolate {n} LOOP HOPPE", lambda: spia.interpolate(m, scheme="LOOP", boundary_rule="HOPPE"))
        case(f"interpolate {n} CC corners", lambda: spia.interpolate(m, boundary_smooth="PRESERVE_CORNERS",
                                                                      use_creases=False, quality=5))
        for method in methods:
            case(f"interpolate {n} {method}", lambda: spia.interpolate(m, method=method))
            case(f"interpolate {n} {method} staged", lambda: spia.interpolate(m, method=method, staged=True))
            case(f"interpolate {n} {method} it7", lambda: spia.interpolate(m, method=method, max_iterations=7,
                                                                           tolerance=1e-9))
            case(f"interpolate {n} {method} tol1e-3", lambda: spia.interpolate(m, method=method, tolerance=1e-3))
        case(f"interpolate {n} WPIA w0.7", lambda: spia.interpolate(m, method="WPIA", weight=0.7))
        for flags in (("FIRST_STEP",), ("MULTICOLOUR",), ("DOUBLE_SWEEPS",), ("NO_AVX",),
                      ("FIRST_STEP", "MULTICOLOUR")):
            for method in ("GS_PIA", "GS_PIA_FAST", "AUTO"):
                case(f"interpolate {n} {method} {'+'.join(flags)}",
                     lambda: spia.interpolate(m, method=method, solve_flags=flags))
        try:
            L = spia.limit_stencils(m)
        except spia.PiaError:
            L = None
        initial = m.positions * np.float32(1.01)
        for method in methods if L is not None else ():
            case(f"solve {n} {method} initial", lambda: L.solve(m.positions, initial=initial, method=method))
        for levels in (0, 1, 2):
            for scheme, rule in (("LOOP", "SMOOTH"), ("LOOP", "HOPPE"), ("DOO_SABIN", "SMOOTH")):
                case(f"refine {n} {scheme} {rule} {levels}",
                     lambda: spia.refine(m, levels, scheme=scheme, boundary_rule=rule))
        for k in (1, 3):
            case(f"surface_stencils {n} {k}", lambda: (lambda s: (s.offsets, s.indices, s.weights))(
                spia.surface_stencils(m, samples_per_edge=k)))
        if n == "catmark_car.obj":
            case(f"interpolate {n} DOO_SABIN shape0.3", lambda: spia.interpolate(m, scheme="DOO_SABIN",
                                                                                  shape_parameter=0.3))
    pairs = [("bun_zipper_quadriflow_cage.obj", "bun_zipper.obj"),
             ("armadillo_quadriflow_cage.obj", "armadillo.obj"),
             ("ChineseDragon-10kv_quadriflow_cage.obj", "ChineseDragon-10kv.obj")]
    if not args.quick:
        pairs.append(("dragon_res2_quadriflow_cage.obj", "dragon_res2.obj"))
    scans = {}
    for cage_name, scan_name in pairs:
        cage = meshes.get(cage_name) or load(cage_name)
        scan_mesh = load(scan_name)
        scan = spia.Scan(scan_mesh)
        scans[scan_name] = (scan_mesh, scan)
        rng = np.random.default_rng(1)
        lo, hi = scan_mesh.positions.min(0), scan_mesh.positions.max(0)
        pts = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (5000, 3)).astype(np.float32)
        case(f"closest {scan_name}", lambda: (scan.diagonal, scan.closest_points(pts, with_boundary=True)))
        case(f"closest {scan_name} vertices", lambda: scan.closest_points(scan_mesh.positions, with_boundary=True))
        case(f"fit {cage_name} SURFACE", lambda: spia.fit(cage, scan, max_rounds=6))
        case(f"fit {cage_name} SURFACE k2 allow_folds hard", lambda: spia.fit(
            cage, scan, samples_per_edge=2, max_rounds=3, allow_folds=True, hard_cutoff=True, slide_weight=0.3))
        case(f"fit {cage_name} SURFACE k1 no scan", lambda: spia.fit(cage, scan, samples_per_edge=1, max_rounds=3,
                                                                    measure_scan=False))
        case(f"fit {cage_name} SURFACE r1", lambda: spia.fit(cage, scan, max_rounds=1, round_tolerance=0.5))
        case(f"fit {cage_name} VERTICES", lambda: spia.fit(cage, scan, mode="VERTICES"))
        case(f"fit {cage_name} VERTICES GS_PIA", lambda: spia.fit(cage, scan, mode="VERTICES", method="GS_PIA"))
        case(f"fit {cage_name} VERTICES DOO_SABIN", lambda: spia.fit(cage, scan, mode="VERTICES",
                                                                     scheme="DOO_SABIN"))
        case(f"fit {cage_name} cutoff tiny", lambda: spia.fit(cage, scan, cutoff=1e-9))
    bunny_scan = scans["bun_zipper.obj"][1]
    for mode in ("VERTICES", "SURFACE"):
        case(f"fit bunny.obj LOOP {mode}", lambda: spia.fit(meshes["bunny.obj"], bunny_scan, mode=mode,
                                                             scheme="LOOP"))
    case("fit bunny.obj LOOP HOPPE VERTICES", lambda: spia.fit(meshes["bunny.obj"], bunny_scan, mode="VERTICES",
                                                               scheme="LOOP", boundary_rule="HOPPE"))
    cage = meshes["bun_zipper_quadriflow_cage.obj"]
    for stop in (None, 3):
        for mode in ("SURFACE", "VERTICES"):
            case(f"fit {mode} progress {stop}", lambda: with_calls(
                lambda p: spia.fit(cage, bunny_scan, mode=mode, progress=p), stop))
        for method in methods:
            case(f"interpolate teapot.obj {method} progress {stop}", lambda: with_calls(
                lambda p: spia.interpolate(meshes["teapot.obj"], method=method, progress=p), stop))
            case(f"interpolate teapot.obj {method} staged progress {stop}", lambda: with_calls(
                lambda p: spia.interpolate(meshes["teapot.obj"], method=method, staged=True, progress=p), stop))
    for n in ("elephant-with-holes.obj", "teapot.obj", "mushroom.obj", "catmark_nonman_edges.obj"):
        s = spia.Scan(meshes[n])
        case(f"closest {n}", lambda: s.closest_points(meshes[n].positions * np.float32(1.05), with_boundary=True))
    if not args.quick:
        big = load("dragon_res2.obj")
        for method in ("AUTO", "GS_PIA_FAST", "GS_PIA", "CG", "LEAST_SQUARES"):
            case(f"interpolate dragon_res2.obj {method}", lambda: spia.interpolate(big, method=method, threads=2))
        case("interpolate dragon_res2.obj LOOP", lambda: spia.interpolate(big, scheme="LOOP", threads=2))


if __name__ == "__main__":
    main()
