# SPDX-License-Identifier: GPL-3.0-or-later
"""Mesh cleanup on flat arrays (numpy only: no bpy, no scipy).

clean() takes the arrays of a mesh (as api.mesh_arrays gives them) and
returns cleaned copies; the input arrays are never written. In order:

1. vertices closer than ``distance`` x bounding-box diagonal are merged
   (grid hashing: each vertex is compared with the vertices of its own and
   the 26 neighbouring cells; chains merge transitively); a merged vertex
   keeps the position of the lowest-numbered vertex of its group, so the
   cleaned positions are positions of the input;
2. inside each face, a corner repeating the vertex of the next corner is
   dissolved; a face then left with fewer than 3 distinct vertices, or that
   still visits a vertex twice (it folds back on itself), is removed;
3. faces thinner than the merge distance (twice their area over their
   longest edge) are removed as zero-area faces;
4. vertices used by no face are removed, and edges that bound no face;
5. faces are turned to one orientation per connected component (faces
   joined by edges shared by exactly two faces): a face whose shared edge
   runs the same way as its neighbour's is flipped. Per component the
   majority orientation is kept (on a tie the first face's); a component
   that is not orientable (a Moebius strip) is left as it is.

Edge creases follow their vertex pair through the merge (the largest
crease of the edges that become one); vertex creases the largest of the
vertices merged. The result gives vertex_map (input vertex -> output vertex
or -1) and face_map (output face -> input face) so that callers can carry
other per-vertex and per-face data.
"""

import numpy as np

DEFAULT_DISTANCE = 1e-6

# The counts clean() reports, in the order format_stats gives them.
STAT_NAMES = ("merged_vertices", "dissolved_corners", "degenerate_faces", "zero_area_faces",
              "loose_vertices", "loose_edges", "flipped_faces", "non_orientable_parts")


def _diagonal(points):
    if not len(points):
        return 0.0
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def _union(labels, a, b):
    """Connected components of the pairs (a, b): each label becomes the
    smallest index of its component."""
    if not len(a):
        return labels
    while True:
        m = np.minimum(labels[a], labels[b])
        new = labels.copy()
        np.minimum.at(new, a, m)
        np.minimum.at(new, b, m)
        while True:  # pointer jumping
            jumped = new[new]
            if np.array_equal(jumped, new):
                break
            new = jumped
        if np.array_equal(new, labels):
            return labels
        labels = new


def merge_groups(points, tol):
    """For each point, the lowest index of the point group it merges into
    (points within tol of each other, transitively)."""
    n = len(points)
    labels = np.arange(n, dtype=np.int64)
    if n < 2 or not tol > 0.0:
        # Exact duplicates still merge with a zero distance.
        if n >= 2:
            _, first, inverse = np.unique(points, axis=0, return_index=True, return_inverse=True)
            labels = first[inverse.ravel()].astype(np.int64)
        return labels
    p = np.asarray(points, np.float64)
    lo = p.min(axis=0)
    extent = float((p.max(axis=0) - lo).max())
    # Cells at least tol wide, and few enough per axis that a cell number fits in int64.
    cell = max(tol, extent / float(1 << 20))
    c = np.floor((p - lo) / cell).astype(np.int64) + 1
    dims = c.max(axis=0) + 2
    key = (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    pairs_a, pairs_b = [], []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                shifted = sorted_key + (dx * dims[1] + dy) * dims[2] + dz  # sorted: fast lookups
                start = np.searchsorted(sorted_key, shifted, "left")
                count = np.searchsorted(sorted_key, shifted, "right") - start
                total = int(count.sum())
                if not total:
                    continue
                i = np.repeat(order, count)
                offsets = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
                j = order[np.repeat(start, count) + offsets]
                keep = i < j
                i, j = i[keep], j[keep]
                close = np.einsum("ij,ij->i", p[i] - p[j], p[i] - p[j]) <= tol * tol
                pairs_a.append(i[close])
                pairs_b.append(j[close])
    a = np.concatenate(pairs_a) if pairs_a else np.zeros(0, np.int64)
    b = np.concatenate(pairs_b) if pairs_b else np.zeros(0, np.int64)
    return _union(labels, a, b)


def _unique(values):
    """np.unique of an integer array, by sorting."""
    s = np.sort(values)
    if len(s) < 2:
        return s
    return s[np.concatenate(([True], s[1:] != s[:-1]))]


def _face_ids(face_sizes):
    return np.repeat(np.arange(len(face_sizes), dtype=np.int64), face_sizes)


def _starts(face_sizes):
    starts = np.zeros(len(face_sizes), np.int64)
    if len(face_sizes) > 1:
        np.cumsum(face_sizes[:-1], out=starts[1:])
    return starts


def _next_corner(face_sizes):
    """Index of the next corner in the same face (cyclically), per corner."""
    sizes = np.asarray(face_sizes, np.int64)
    starts = _starts(sizes)
    corner = np.arange(int(sizes.sum()), dtype=np.int64)
    local = corner - np.repeat(starts, sizes)
    return np.repeat(starts, sizes) + (local + 1) % np.maximum(np.repeat(sizes, sizes), 1)


def _select_faces(face_sizes, face_vertices, keep):
    """The faces where keep is True."""
    return face_sizes[keep], face_vertices[np.repeat(keep, face_sizes)]


def _edge_keys(u, w, n):
    lo, hi = np.minimum(u, w), np.maximum(u, w)
    return lo * np.int64(n) + hi


def orient(face_sizes, face_vertices, vertex_count):
    """(face_vertices with faces flipped to one orientation per component,
    flipped (bool per face), number of non-orientable components)."""
    sizes = np.asarray(face_sizes, np.int64)
    fv = np.asarray(face_vertices, np.int64)
    f = len(sizes)
    flipped = np.zeros(f, bool)
    if f == 0:
        return fv.copy(), flipped, 0
    face = _face_ids(sizes)
    nxt = _next_corner(sizes)
    u, w = fv, fv[nxt]
    keys = _edge_keys(u, w, vertex_count)
    order = np.argsort(keys, kind="stable")
    k = keys[order]
    boundaries = np.flatnonzero(np.diff(k)) + 1
    group_start = np.concatenate(([0], boundaries))
    group_count = np.diff(np.concatenate((group_start, [len(k)])))
    two = group_start[group_count == 2]
    c1, c2 = order[two], order[two + 1]
    f1, f2 = face[c1], face[c2]
    ok = f1 != f2
    c1, c2, f1, f2 = c1[ok], c2[ok], f1[ok], f2[ok]
    same = u[c1] == u[c2]  # both faces run the edge the same way: one must flip
    # Adjacency (both directions), sorted by source face.
    src = np.concatenate((f1, f2))
    dst = np.concatenate((f2, f1))
    rel = np.concatenate((same, same)).astype(np.int8)
    o = np.argsort(src, kind="stable")
    src, dst, rel = src[o], dst[o], rel[o]
    degree = np.bincount(src, minlength=f)
    first = np.concatenate(([0], np.cumsum(degree)[:-1]))
    parity = np.full(f, -1, np.int8)
    component = np.full(f, -1, np.int64)
    # A face sharing no edge with another is a part of its own, as it is.
    isolated = np.flatnonzero(degree == 0)
    parity[isolated] = 0
    component[isolated] = np.arange(len(isolated))
    comps = list(isolated)
    for seed in np.flatnonzero(degree > 0).tolist():
        if parity[seed] >= 0:
            continue
        cid = len(comps)
        comps.append(seed)
        parity[seed] = 0
        component[seed] = cid
        frontier = np.array([seed], np.int64)
        while len(frontier):
            count = degree[frontier]
            total = int(count.sum())
            if not total:
                break
            idx = np.repeat(first[frontier], count) + (
                np.arange(total) - np.repeat(np.cumsum(count) - count, count))
            nb = dst[idx]
            par = parity[src[idx]] ^ rel[idx]
            fresh = parity[nb] < 0
            nb, par = nb[fresh], par[fresh]
            nb, where = np.unique(nb, return_index=True)
            parity[nb] = par[where]
            component[nb] = cid
            frontier = nb
    # Components where some shared edge disagrees cannot be oriented.
    bad = (parity[f1] ^ parity[f2]) != same.astype(np.int8)
    nonorientable = np.zeros(len(comps), bool)
    nonorientable[component[f1[bad]]] = True
    ones = np.bincount(component, weights=parity.astype(np.float64), minlength=len(comps))
    total = np.bincount(component, minlength=len(comps))
    flip_parity = np.where(ones > total - ones, 0, 1)  # flip the minority (ties: keep the seed's)
    flipped = (parity == flip_parity[component]) & ~nonorientable[component]
    out = fv.copy()
    if flipped.any():
        starts = _starts(sizes)
        local = np.arange(len(fv)) - np.repeat(starts, sizes)
        rep_sizes = np.repeat(sizes, sizes)
        reversed_index = np.repeat(starts, sizes) + (rep_sizes - local) % rep_sizes
        corner_flipped = np.repeat(flipped, sizes)
        out[corner_flipped] = fv[reversed_index[corner_flipped]]
    return out, flipped, int(nonorientable.sum())


def clean(positions, face_sizes, face_vertices, edges=None, edge_creases=None,
          vertex_creases=None, distance=DEFAULT_DISTANCE, orientation=True):
    """Cleaned copies of a mesh's arrays, as a dict:

    positions (M, 3) float32, face_sizes int32, face_vertices int32, edges
    (E, 2) int32 (the faces' edges, each once, smaller vertex first),
    edge_creases (E,) float32 or None, vertex_creases (M,) float32 or None,
    vertex_map (N,) int64 (input vertex -> output vertex, -1 if removed),
    face_map (K,) int64 (output face -> input face), flipped (K,) bool, and
    stats: a dict of the counts in STAT_NAMES.

    distance is relative to the bounding-box diagonal (0: only vertices at
    the same position merge). ValueError on arrays that do not fit together.
    """
    points = np.asarray(positions, np.float32).reshape(-1, 3)
    sizes = np.asarray(face_sizes, np.int64).ravel()
    fv = np.asarray(face_vertices, np.int64).ravel()
    n = len(points)
    distance = float(distance)
    if not (distance >= 0.0 and np.isfinite(distance)):
        raise ValueError("cleanup_distance must be zero or a positive number, not %r" % distance)
    if (sizes < 0).any() or int(sizes.sum()) != len(fv):
        raise ValueError("face sizes add up to %d corners, but %d face vertices are given"
                         % (int(sizes.sum()), len(fv)))
    if len(fv) and (fv.min() < 0 or fv.max() >= n):
        raise ValueError("a face refers to a vertex outside 0..%d" % (n - 1))
    if not np.isfinite(points).all():
        raise ValueError("a vertex has a NaN or infinite coordinate: cleanup needs finite positions")
    stats = dict.fromkeys(STAT_NAMES, 0)

    # 1. Merge by distance.
    tol = distance * _diagonal(points.astype(np.float64))
    rep = merge_groups(points, tol)
    stats["merged_vertices"] = int(n - np.count_nonzero(rep == np.arange(n)))
    fv = rep[fv]

    # 2. Dissolve repeated corners; drop faces that still repeat a vertex.
    f0 = len(sizes)
    face_map = np.arange(f0, dtype=np.int64)
    if len(fv):
        keep_corner = fv != fv[_next_corner(sizes)]
        stats["dissolved_corners"] = int(np.count_nonzero(~keep_corner))
        sizes = np.bincount(_face_ids(sizes)[keep_corner], minlength=f0).astype(np.int64)
        fv = fv[keep_corner]
    face = _face_ids(sizes)
    distinct = np.bincount(_unique(face * np.int64(max(n, 1)) + fv) // max(n, 1),
                           minlength=len(sizes)) if len(fv) else np.zeros(len(sizes), np.int64)
    good = (sizes >= 3) & (distinct == sizes)
    stats["degenerate_faces"] = int(np.count_nonzero(~good))
    sizes, fv = _select_faces(sizes, fv, good)
    face_map = face_map[good]

    # 3. Zero-area faces: thinner than the merge distance.
    if len(sizes):
        p = points.astype(np.float64)
        nxt = _next_corner(sizes)
        a, b = p[fv], p[fv[nxt]]
        face = _face_ids(sizes)
        normal = np.zeros((len(sizes), 3))
        np.add.at(normal, face, np.cross(a, b))
        area2 = np.linalg.norm(normal, axis=1)
        longest = np.zeros(len(sizes))
        np.maximum.at(longest, face, np.linalg.norm(b - a, axis=1))
        flat = area2 <= tol * longest if tol > 0.0 else area2 <= 0.0
        stats["zero_area_faces"] = int(np.count_nonzero(flat))
        sizes, fv = _select_faces(sizes, fv, ~flat)
        face_map = face_map[~flat]

    # 4. Loose vertices (merged-away ones are not counted again) and edges.
    used = np.zeros(n, bool)
    used[fv] = True
    representatives = rep == np.arange(n)
    stats["loose_vertices"] = int(np.count_nonzero(representatives & ~used))
    vertex_of = np.full(n, -1, np.int64)
    vertex_of[used] = np.arange(int(used.sum()))
    vertex_map = vertex_of[rep]
    m = int(used.sum())
    fv = vertex_of[fv]
    new_points = points[used]

    face_keys = np.zeros(0, np.int64)
    if len(fv):
        face_keys = _unique(_edge_keys(fv, fv[_next_corner(sizes)], m))
    new_edges = np.stack((face_keys // max(m, 1), face_keys % max(m, 1)), axis=1) if m else \
        np.zeros((0, 2), np.int64)
    new_creases = None
    if edges is not None and len(edges):
        e = np.asarray(edges, np.int64).reshape(-1, 2)
        if len(e) and (e.min() < 0 or e.max() >= n):
            raise ValueError("an edge refers to a vertex outside 0..%d" % (n - 1))
        ra, rb = rep[e[:, 0]], rep[e[:, 1]]
        ea, eb = vertex_map[e[:, 0]], vertex_map[e[:, 1]]
        live = (ea >= 0) & (eb >= 0) & (ea != eb)
        ekeys = _edge_keys(ea[live], eb[live], m)
        in_face = np.zeros(len(e), bool)
        in_face[live] = np.isin(ekeys, face_keys)
        # An edge is loose when it bounds no face (edges merged into one count once).
        proper = ra != rb
        stats["loose_edges"] = int(len(np.unique(_edge_keys(ra, rb, n)[proper & ~in_face])))
        if edge_creases is not None:
            values = np.asarray(edge_creases, np.float32).ravel()[live]
            where = np.searchsorted(face_keys, ekeys)
            inside = where < len(face_keys)
            inside[inside] = face_keys[where[inside]] == ekeys[inside]
            new_creases = np.zeros(len(face_keys), np.float32)
            np.maximum.at(new_creases, where[inside], values[inside])
            if not new_creases.any():
                new_creases = None
    new_vertex_creases = None
    if vertex_creases is not None:
        values = np.asarray(vertex_creases, np.float32).ravel()
        new_vertex_creases = np.zeros(m, np.float32)
        alive = vertex_map >= 0
        np.maximum.at(new_vertex_creases, vertex_map[alive], values[alive])
        if not new_vertex_creases.any():
            new_vertex_creases = None

    # 5. One orientation per component.
    flipped = np.zeros(len(sizes), bool)
    if orientation:
        fv, flipped, stats["non_orientable_parts"] = orient(sizes, fv, m)
        stats["flipped_faces"] = int(np.count_nonzero(flipped))

    return {
        "positions": np.ascontiguousarray(new_points, np.float32),
        "face_sizes": np.ascontiguousarray(sizes, np.int32),
        "face_vertices": np.ascontiguousarray(fv, np.int32),
        "edges": np.ascontiguousarray(new_edges, np.int32),
        "edge_creases": new_creases,
        "vertex_creases": new_vertex_creases,
        "vertex_map": vertex_map,
        "face_map": face_map,
        "flipped": flipped,
        "stats": stats,
    }


def changed(stats):
    """True if the cleanup changed anything (non-orientable parts left as they are do not count)."""
    return any(stats.get(name, 0) for name in STAT_NAMES if name != "non_orientable_parts")


def format_stats(stats, future=False):
    """The counts in words, e.g. 'merged 3 vertices, flipped 2 faces' ('nothing to clean');
    future=True: what a cleanup would do ('merge 3 vertices, flip 2 faces')."""
    words = (("merged_vertices", "merge", "vertex", "vertices"),
             ("dissolved_corners", "dissolve", "repeated corner", "repeated corners"),
             ("degenerate_faces", "remove", "degenerate face", "degenerate faces"),
             ("zero_area_faces", "remove", "zero-area face", "zero-area faces"),
             ("loose_vertices", "remove", "loose vertex", "loose vertices"),
             ("loose_edges", "remove", "loose edge", "loose edges"),
             ("flipped_faces", "flip", "face", "faces"),
             ("non_orientable_parts", "leave", "non-orientable part as it is",
              "non-orientable parts as they are"))
    past = {"merge": "merged", "dissolve": "dissolved", "remove": "removed", "flip": "flipped",
            "leave": "left"}
    parts = []
    for key, verb, one, many in words:
        count = int(stats.get(key, 0))
        if count:
            parts.append("%s %d %s" % (verb if future else past[verb], count, one if count == 1 else many))
    return ", ".join(parts) if parts else "nothing to clean"
