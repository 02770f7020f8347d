# SPDX-License-Identifier: GPL-3.0-or-later
"""Meshes for the benchmarks: generated quad spheres and the shipped scans."""
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests", "python"))
from meshio import read_obj  # noqa: E402


def quad_sphere(k, noise=0.0, seed=1):
    """A cube with k x k quads per side pushed onto a sphere: 6 k^2 + 2
    vertices, eight valence-3 vertices, all others valence 4.  `noise`
    displaces the vertices radially (a rough, scan-like target)."""
    t = np.arange(k + 1)
    a, b = np.meshgrid(t, t, indexing="ij")
    a, b = a.ravel(), b.ravel()
    lattice, quads = [], []
    faces_idx = (np.arange(k)[:, None] * (k + 1) + np.arange(k)[None, :]).ravel()
    quad = np.stack([faces_idx, faces_idx + k + 1, faces_idx + k + 2, faces_idx + 1], 1)
    for axis in range(3):
        for side in (0, k):
            p = np.empty((len(a), 3), np.int64)
            p[:, axis] = side
            p[:, (axis + 1) % 3] = a
            p[:, (axis + 2) % 3] = b
            q = quad if side == k else quad[:, ::-1]
            quads.append(q + sum(len(x) for x in lattice))
            lattice.append(p)
    lattice = np.concatenate(lattice)
    keys, inverse = np.unique(lattice, axis=0, return_inverse=True)
    faces = inverse.ravel()[np.concatenate(quads)]
    p = keys / k * 2.0 - 1.0
    p /= np.linalg.norm(p, axis=1)[:, None]
    if noise:
        p *= 1.0 + noise * np.random.default_rng(seed).standard_normal(len(p))[:, None]
    return p.astype(np.float32), faces.astype(np.int32)


def scan(name):
    P, faces, _ = read_obj(os.path.join(ROOT, "tests", "data", name + ".obj"))
    faces = [f for f in faces if len(set(f)) == len(f)]
    sizes = np.fromiter((len(f) for f in faces), np.int32, len(faces))
    return P, sizes, np.fromiter((v for f in faces for v in f), np.int32, int(sizes.sum()))
