# SPDX-License-Identifier: GPL-3.0-or-later
"""Independent Loop limit matrices from the papers' formulas (numpy/scipy).

Interior vertex of valence n: beta_n on itself, (1 - beta_n) / n on each
neighbour.  Boundary vertices, 'SMOOTH' (OpenSubdiv): (1/6, 2/3, 1/6) along
the boundary, a corner (one face) fixed under PRESERVE_CORNERS.  'HOPPE':
the left eigenvector of the boundary subdivision matrices, computed here
numerically from the rules (vertex 1/8 3/4 1/8; edge 1/2 1/2, or 5/8 on the
regular and 3/8 on the extraordinary end).
"""
import numpy as np
import scipy.sparse


def beta(n):
    return 3.0 / (11.0 - 8.0 * (3.0 / 8.0 + (3.0 / 8.0 + np.cos(2 * np.pi / n) / 4.0) ** 2))


def edge_row(neighbour_regular, centre_regular):
    """Weights (on the neighbour, on the centre) of a boundary edge point."""
    if neighbour_regular == centre_regular:
        return 0.5, 0.5
    return (5 / 8, 3 / 8) if neighbour_regular else (3 / 8, 5 / 8)


def hoppe_mask(prev_regular, centre_regular, next_regular):
    """Limit mask on (prev, centre, next): l_t F, l_t the left eigenvector of
    the stationary matrix, F the first step's matrix."""
    def matrix(pr, cr, nr):
        a, b = edge_row(pr, cr)
        c, d = edge_row(nr, cr)
        return np.array([[a, b, 0], [1 / 8, 3 / 4, 1 / 8], [0, d, c]])
    stationary = matrix(True, centre_regular, True)
    w, v = np.linalg.eig(stationary.T)
    left = np.real(v[:, np.argmin(abs(w - 1))])
    left /= left.sum()
    return left @ matrix(prev_regular, centre_regular, next_regular)


def topology(nv, faces):
    nbrs = [dict() for _ in range(nv)]
    for f in faces:
        for k in range(3):
            a, b = f[k], f[(k + 1) % 3]
            nbrs[a][b] = nbrs[a].get(b, 0) + 1
            nbrs[b][a] = nbrs[b].get(a, 0) + 1
    return nbrs


def loop_matrix(nv, faces, rule="SMOOTH", boundary_smooth="ALL"):
    nbrs = topology(nv, faces)
    valence = [len(n) for n in nbrs]
    boundary = [any(c == 1 for c in n.values()) for n in nbrs]
    face_count = np.zeros(nv, int)
    for f in faces:
        face_count[list(f)] += 1
    rows, cols, vals = [], [], []
    for v in range(nv):
        n = nbrs[v]
        if not n:
            rows.append(v), cols.append(v), vals.append(1.0)
            continue
        if not boundary[v]:
            b = beta(len(n))
            rows += [v] * (len(n) + 1)
            cols += [v] + list(n)
            vals += [b] + [(1 - b) / len(n)] * len(n)
            continue
        ends = [w for w, c in n.items() if c == 1]
        assert len(ends) == 2, "non-manifold boundary vertex"
        if rule == "SMOOTH":
            if boundary_smooth == "PRESERVE_CORNERS" and face_count[v] == 1:
                mask = [0, 1, 0]
            else:
                mask = [1 / 6, 2 / 3, 1 / 6]
        else:
            reg = lambda x: valence[x] == 4  # noqa: E731
            mask = hoppe_mask(reg(ends[0]), reg(v), reg(ends[1]))
        rows += [v] * 3
        cols += [ends[0], v, ends[1]]
        vals += list(mask)
    return scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(nv, nv))


def refine_boundary_vertex(prev, centre, nxt, types, levels):
    """Where Hoppe's boundary subdivision takes a boundary vertex: applies
    the rules `levels` times to the vertex and its two boundary neighbours
    (the only points its limit depends on; every new edge point on the
    boundary has valence 4, so it is regular)."""
    p, c, n = (np.asarray(x, float) for x in (prev, centre, nxt))
    pr, cr, nr = types
    for _ in range(levels):
        wp, wc = edge_row(pr, cr)
        wn, wc2 = edge_row(nr, cr)
        p, c, n = wp * p + wc * c, p / 8 + 3 * c / 4 + n / 8, wn * n + wc2 * c
        pr = nr = True
    return c
