# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender's numbering of a Multires modifier's finest level, computed from
the library's levels.

Blender numbers the vertices of a mesh subdivided `levels` times (a
Subdivision Surface's result, a Multires level) in one pass over the base
mesh at resolution R = 2^levels + 1 points along each base edge: the base
vertices first, as numbered; then R - 2 points on each base edge, from its
first vertex to its second, edge by edge; then each face's inner points,
face by face.  A quad's inner points are its (R - 2)^2 grid points away
from its edges, row after row, a row along the edge from its first corner
to its second.  Any other face is split into a quad per corner (its ptex
faces, P = 2^(levels-1) + 1 points along each side, running from the
corner to the middle of the edge after it and of the edge before it):
its inner points are its centre, then corner after corner that quad's
points off the base edges and off the side toward the middle of the edge
before it, row after row.

The library subdivides one level at a time and numbers each level anew (a
vertex's child keeps its number; the children of a face follow the faces
before them).  Its levels are walked down here ptex grid by ptex grid: a
face's children are found from the corner each holds, and each grid's
points are given Blender's numbers.  No bpy: the add-on's detail.py calls
it with the meshes' arrays.
"""

import numpy as np


class OrderMismatch(ValueError):
    """The library's levels do not have the shape Blender's numbering
    assumes (loose edges, a level not refined from the one above, ...)."""


def _children(faces, first_child, count, cells, corners, n_above):
    """For each cell (a face of the level above, `cells`, its corners
    (..., k) in order), its `count` children (rows of `faces` from
    first_child[cell]) each rotated to start at the corner it holds, and
    which of the cell's corners that is."""
    child = first_child[cells][..., None] + np.arange(count)
    quads = faces[child]                                  # (..., count, 4)
    corner_at = np.argmax(quads < n_above, axis=-1)       # the one vertex of the level above
    if not np.all(np.count_nonzero(quads < n_above, axis=-1) == 1):
        raise OrderMismatch("a child face does not hold exactly one vertex of the level above")
    turn = (corner_at[..., None] + np.arange(4)) % 4
    quads = np.take_along_axis(quads, turn, axis=-1)
    where = np.argmax(quads[..., :1] == corners[..., None, :], axis=-1)
    if not np.all(np.take_along_axis(corners, where, axis=-1) == quads[..., 0]):
        raise OrderMismatch("a child face's corner is not a corner of its parent")
    return child, quads, where


# A cell's corners (0,0), (1,0), (1,1), (0,1) in grid steps.
_CORNER_X = np.array([0, 1, 1, 0])
_CORNER_Y = np.array([0, 0, 1, 1])


def _refine(grids, cells, faces, n_above, first=None):
    """Grids of the level below: grids (G, m+1, m+1) of vertex numbers
    indexed [x, y], cells (G, m, m) the level's faces (quads) in them;
    faces: the level below's, 4 a face, a face's children after the
    children of the faces before it (from first[face], or 4 face).  Returns ((G, 2m+1, 2m+1),
    (G, 2m, 2m)).  A child quad (a, b, c, d) starts at its parent's corner
    a; b and d are the middles of the parent's edges after and before a, c
    its centre."""
    G, m = cells.shape[0], cells.shape[1]
    faces = faces.reshape(-1, 4)
    if first is None:
        first = 4 * np.arange(len(faces) // 4)
    x, y = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    corners = np.stack([grids[:, x + _CORNER_X[k], y + _CORNER_Y[k]] for k in range(4)], axis=-1)  # (G, m, m, 4)
    child, quads, q = _children(faces, first, 4, cells, corners, n_above)
    g = np.arange(G)[:, None, None, None]
    X, Y = (2 * x)[None, :, :, None], (2 * y)[None, :, :, None]
    nxt, prv = (q + 1) % 4, (q + 3) % 4
    where = [(X + 2 * _CORNER_X[q], Y + 2 * _CORNER_Y[q]),                          # a
             (X + _CORNER_X[q] + _CORNER_X[nxt], Y + _CORNER_Y[q] + _CORNER_Y[nxt]),  # b
             (np.broadcast_to(X + 1, q.shape), np.broadcast_to(Y + 1, q.shape)),    # c
             (X + _CORNER_X[q] + _CORNER_X[prv], Y + _CORNER_Y[q] + _CORNER_Y[prv])]  # d
    out = np.full((G, 2 * m + 1, 2 * m + 1), -1, np.int64)
    for k, (px, py) in enumerate(where):
        out[g, px, py] = quads[..., k]
    # Where two children (of one face or of two) give one point, they agree.
    for k, (px, py) in enumerate(where):
        if not np.array_equal(out[g, px, py], quads[..., k]):
            raise OrderMismatch("two child faces put different vertices at one point of the grid")
    out_cells = np.full((G, 2 * m, 2 * m), -1, np.int64)
    out_cells[g, X + _CORNER_X[q], Y + _CORNER_Y[q]] = child
    if np.any(out < 0) or np.any(out_cells < 0):
        raise OrderMismatch("a level's grid was not covered by its children")
    return out, out_cells


def _edge_steps(edges, edge, start, t, R):
    """Blender's number, among edge's R - 2 points, of the point t steps
    from its end vertex `start`."""
    return np.where(edges[edge, 0] == start, t - 1, R - 2 - t)


def blender_order(face_sizes, face_vertices, edges, vertex_count, levels):
    """Blender's numbering of the finest of the library's levels.
    face_sizes, face_vertices, vertex_count: the base mesh as the library
    took it, its faces and their corners in Blender's order; edges (E, 2):
    Blender's edges of it, in order; levels: (vertex_count, face_vertices)
    of each level the library made, 1 to L.  Returns order: Blender's
    vertex b is the finest level's vertex order[b].  Raises OrderMismatch
    where the levels do not fit Blender's numbering.  Working memory: about
    170 bytes a vertex of the finest level (537 MB for 3.2M), less than the
    fit of that level held (check_detail_memory's estimate), which has
    freed it by then."""
    L = len(levels)
    if L < 1:
        raise OrderMismatch("no levels")
    R, P = (1 << L) + 1, (1 << (L - 1)) + 1
    sizes = np.asarray(face_sizes, np.int64)
    corners_all = np.asarray(face_vertices, np.int64)
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    n0, E, F = int(vertex_count), len(edges), len(sizes)
    starts = np.zeros(F, np.int64)
    np.cumsum(sizes[:-1], out=starts[1:])
    face_of = np.repeat(np.arange(F), sizes)
    corner_in_face = np.arange(len(corners_all)) - starts[face_of]
    after = corners_all[starts[face_of] + (corner_in_face + 1) % sizes[face_of]]
    # Each corner's edge (to the next corner), found among Blender's edges.
    key = np.minimum(edges[:, 0], edges[:, 1]) * n0 + np.maximum(edges[:, 0], edges[:, 1])
    by_key = np.argsort(key)
    want = np.minimum(corners_all, after) * n0 + np.maximum(corners_all, after)
    at = np.minimum(np.searchsorted(key[by_key], want), max(E - 1, 0))
    if E == 0 or not np.array_equal(key[by_key][at], want):
        raise OrderMismatch("a face's side is not among the mesh's edges")
    corner_edge = by_key[at]
    inner = np.where(sizes == 4, (R - 2) ** 2, 1 + sizes * (P - 2) * (P - 1))
    voff = n0 + E * (R - 2) + np.concatenate(([0], np.cumsum(inner)[:-1]))
    total = n0 + E * (R - 2) + int(inner.sum())
    if total != int(levels[-1][0]):
        raise OrderMismatch("Blender's level %d has %d vertices, the library's %d" % (L, total, int(levels[-1][0])))
    # Each level a quad for each corner of the level above (which also
    # keeps the children's rows within each level's faces).
    corner_counts = [int(sizes.sum())] + [len(faces) for _count, faces in levels[:-1]]
    if any(len(faces) != 4 * count for (_n, faces), count in zip(levels, corner_counts)):
        raise OrderMismatch("a level does not have a quad for each corner of the level above")
    above = [n0] + [int(count) for count, _faces in levels[:-1]]
    theirs, ours = [np.arange(n0)], [np.arange(n0)]

    def put(b, o):
        theirs.append(np.asarray(b).reshape(-1))
        ours.append(np.asarray(o).reshape(-1))

    # Quads: one grid each, [0, 0] at the first corner, x toward the second.
    quads = np.flatnonzero(sizes == 4)
    if len(quads):
        c = corners_all[starts[quads][:, None] + np.arange(4)]
        grids = np.stack([np.stack([c[:, 0], c[:, 3]], 1), np.stack([c[:, 1], c[:, 2]], 1)], 1)
        cells = quads[:, None, None]
        for k in range(L):
            grids, cells = _refine(grids, cells, np.asarray(levels[k][1]), above[k], starts if k == 0 else None)
        t = np.arange(1, R - 1)
        xi, yi = np.meshgrid(t, t, indexing="ij")
        put(voff[quads][:, None, None] + (yi - 1) * (R - 2) + (xi - 1), grids[:, xi, yi])
        sides = [(t, 0 * t), (0 * t + R - 1, t), (R - 1 - t, 0 * t + R - 1), (0 * t, R - 1 - t)]
        for s, (sx, sy) in enumerate(sides):
            corner = starts[quads] + s
            e = corner_edge[corner][:, None]
            put(n0 + e * (R - 2) + _edge_steps(edges, e, corners_all[corner][:, None], t[None, :], R),
                grids[:, sx, sy])
    # Other faces: a grid per corner (its ptex face), [0, 0] at the corner,
    # x toward the middle of the edge after it, y of the edge before it.
    for n in np.unique(sizes[sizes != 4]):
        faces = np.flatnonzero(sizes == n)
        c = corners_all[starts[faces][:, None] + np.arange(n)]
        level1 = np.asarray(levels[0][1]).reshape(-1, 4)
        child, quads1, which = _children(level1, starts, int(n), faces, c, n0)
        order_in = np.argsort(which, axis=1, kind="stable")
        if not np.array_equal(np.sort(which, axis=1), np.broadcast_to(np.arange(n), which.shape)):
            raise OrderMismatch("a face's children do not start at its corners one each")
        quads1 = np.take_along_axis(quads1, order_in[..., None], axis=1)      # (G, n, 4), corner by corner
        child = np.take_along_axis(child, order_in, axis=1)
        a, b, cc, d = (quads1[..., k].reshape(-1) for k in range(4))
        grids = np.stack([np.stack([a, d], 1), np.stack([b, cc], 1)], 1)
        cells = child.reshape(-1)[:, None, None]
        for k in range(1, L):
            grids, cells = _refine(grids, cells, np.asarray(levels[k][1]), above[k])
        G = len(faces)
        grids = grids.reshape(G, int(n), P, P)
        base = voff[faces][:, None]
        i = np.arange(n)[None, :]
        put(base, grids[:, :, P - 1, P - 1][:, :1])  # the centre, once
        tx, ty = np.arange(1, P), np.arange(1, P - 1)
        xi, yi = np.meshgrid(tx, ty, indexing="ij")
        put(base[..., None, None] + 1 + i[..., None, None] * (P - 2) * (P - 1) + (yi - 1) * (P - 1) + (xi - 1),
            grids[:, :, xi, yi])
        # The side toward the edge before's middle is the corner before's x = P - 1 column.
        t = np.arange(1, P - 1)
        before = (i - 1) % n
        put(base[..., None] + 1 + before[..., None] * (P - 2) * (P - 1) + (t - 1) * (P - 1) + (P - 2),
            grids[:, :, t, P - 1])
        t = np.arange(1, P)
        here = corners_all[starts[faces][:, None] + i]
        e = corner_edge[starts[faces][:, None] + i]
        put(n0 + e[..., None] * (R - 2) + _edge_steps(edges, e[..., None], here[..., None], t, R), grids[:, :, t, 0])
        e = corner_edge[starts[faces][:, None] + before]
        put(n0 + e[..., None] * (R - 2) + _edge_steps(edges, e[..., None], here[..., None], t, R), grids[:, :, 0, t])
    b = np.concatenate(theirs)
    o = np.concatenate(ours)
    order = np.full(total, -1, np.int64)
    order[b] = o
    if not np.array_equal(order[b], o):
        raise OrderMismatch("one of Blender's vertices falls on two of the library's")
    if np.any(order < 0) or np.any(np.bincount(order, minlength=total) != 1):
        raise OrderMismatch("Blender's numbering and the library's levels are not one to one")
    return order
