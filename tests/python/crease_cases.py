# SPDX-License-Identifier: GPL-3.0-or-later
"""Closed triangle meshes whose creased edges all carry one Blender crease
value, and a way to run the library on one of them in a child process
under an address-space limit, timing it and reading its peak resident
size (tests/python/test_memory_budget.py, bench/bench_creases.py).

The meshes: an octahedron with every edge creased, and icospheres (42 and
642 vertices) with the edges of their upper cap creased (both ends above
z = 0.3 on the unit sphere)."""
import json
import os
import subprocess
import sys

import numpy as np

from spheres import icosphere

HERE = os.path.dirname(os.path.abspath(__file__))

CREASES = (0.7, 0.9, 0.95, 0.99)
MESHES = ("octahedron", "icosphere-42", "icosphere-642")
CAP_HEIGHT = 0.3


def octahedron():
    p = np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)], np.float64)
    f = np.array([(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)], np.int64)
    return p, f


def edges_of(faces):
    """The unique edges of a face array, (E, 2), smaller index first."""
    faces = np.asarray(faces)
    k = faces.shape[1]
    e = np.concatenate([faces[:, [i, (i + 1) % k]] for i in range(k)])
    return np.unique(np.sort(e, axis=1), axis=0)


def creased_mesh(name, crease):
    """(positions, faces, edges, edge_creases) of one of MESHES."""
    if name == "octahedron":
        p, f = octahedron()
        e = edges_of(f)
        creased = np.ones(len(e), bool)
    else:
        p, f = icosphere({"icosphere-42": 1, "icosphere-642": 3}[name])
        e = edges_of(f)
        creased = (p[e[:, 0], 2] > CAP_HEIGHT) & (p[e[:, 1], 2] > CAP_HEIGHT)
    return p, f, e, np.where(creased, crease, 0.0).astype(np.float32)


def run_limited(mesh, crease, calls, limit_bytes=2 << 30, timeout=120.0):
    """Runs ``calls`` (dicts: crease_child.one's keyword arguments) on one
    mesh in a child process limited to ``limit_bytes`` of address space.
    Returns a dict: ``killed`` (None, or how the child ended without
    reporting: a signal number, an exit code or 'timeout'), ``calls`` (per
    call: ``outcome`` 'done' or 'refused', ``seconds``, and ``result`` or
    ``code`` and ``message``), ``peak_mb`` (the child's peak resident size)
    and ``stderr``."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))
    argument = json.dumps({"mesh": mesh, "crease": crease, "calls": calls})
    proc = subprocess.Popen([sys.executable, os.path.join(HERE, "crease_child.py"), argument],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=limit)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        return {"killed": "timeout", "calls": [], "peak_mb": float("nan"), "stderr": err.decode(errors="replace")}
    lines = out.decode(errors="replace").strip().splitlines()
    if proc.returncode != 0 or not lines:
        return {"killed": proc.returncode, "calls": [], "peak_mb": float("nan"),
                "stderr": err.decode(errors="replace")[-4000:]}
    report = json.loads(lines[-1])
    report["killed"] = None
    report["stderr"] = err.decode(errors="replace")[-4000:]
    return report
