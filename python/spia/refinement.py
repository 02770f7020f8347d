# SPDX-License-Identifier: GPL-3.0-or-later
"""Refined surfaces of a cage: the Loop and Doo-Sabin refinements Blender
cannot show (:func:`refine`), Catmull-Clark subdivision into the control
mesh of the same limit surface (:func:`subdivide`), and the positions that
put a quad mesh's flat faces on its limit surface (:func:`flat_positions`)."""

import ctypes

import numpy as np

from .errors import _raise
from .header import _Status
from .library import _library
from .mesh import Mesh, _options, _ptr


def refine(mesh, levels, scheme="LOOP", boundary_rule="SMOOTH", boundary_smooth="ALL", use_creases=True,
           shape_parameter=0.5, face_shape_parameters=None, progress=None, memory_budget=0):
    """The surface of ``mesh`` (a cage) refined ``levels`` times, for the
    schemes Blender cannot show: ``(positions (M, 3) float32, face_sizes
    (K,) int32, face_vertices int32)``.  LOOP: triangles, every vertex at its
    limit position, rows 0..N-1 the limit points of the N control vertices.
    DOO_SABIN: the refined control mesh (its face centroids lie on the
    limit surface).  ``progress(level, share_done) -> bool`` is called at
    the end of each level and about every 0.1 s in between, but for steps
    that are single calls (spia_refine in subdiv_pia.h lists them); True
    cancels (:class:`PiaCancelled`)."""
    lib = _library()
    opts, _keep = _options(scheme=scheme, boundary_smooth=boundary_smooth, use_creases=use_creases,
                           boundary_rule=boundary_rule, shape_parameter=shape_parameter,
                           face_shape_parameters=face_shape_parameters, progress=progress,
                           memory_budget=memory_budget)
    cm = mesh._c()
    status = _Status()
    nv, nf, nc = ctypes.c_int32(), ctypes.c_int32(), ctypes.c_int64()
    code = lib.spia_refine_size(ctypes.byref(cm), ctypes.byref(opts), int(levels), ctypes.byref(nv),
                                ctypes.byref(nf), ctypes.byref(nc), ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    positions = np.empty((nv.value, 3), np.float32)
    sizes = np.empty(nf.value, np.int32)
    face_vertices = np.empty(nc.value, np.int32)
    code = lib.spia_refine(ctypes.byref(cm), ctypes.byref(opts), int(levels), _ptr(positions, ctypes.c_float),
                           _ptr(sizes, ctypes.c_int32), _ptr(face_vertices, ctypes.c_int32), ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    return positions, sizes, face_vertices


def subdivide(mesh, levels=1, boundary_smooth="ALL", use_creases=True, quality=3, opensubdiv_version=None,
              progress=None, memory_budget=0):
    """The cage ``mesh`` subdivided ``levels`` times (1 to 6) by Catmull-Clark,
    as a :class:`Mesh`: the control mesh of the same limit surface, all
    quads, with every edge and its crease and every vertex's crease (the
    cage's sharpness one step softer a level, in Blender's terms).  Vertex i
    is the child of the cage's vertex i.  ``progress(level, share_done) ->
    bool`` is called at the end of each level; True cancels."""
    lib = _library()
    opts, _keep = _options(boundary_smooth=boundary_smooth, use_creases=use_creases, quality=quality,
                           opensubdiv_version=opensubdiv_version, progress=progress, memory_budget=memory_budget)
    cm = mesh._c()
    status = _Status()
    nv, nf, ne = ctypes.c_int32(), ctypes.c_int32(), ctypes.c_int32()
    code = lib.spia_subdivide_size(ctypes.byref(cm), ctypes.byref(opts), int(levels), ctypes.byref(nv),
                                   ctypes.byref(nf), ctypes.byref(ne), ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    positions = np.empty((nv.value, 3), np.float32)
    face_vertices = np.empty(4 * nf.value, np.int32)
    edges = np.empty((ne.value, 2), np.int32)
    edge_creases = np.empty(ne.value, np.float32)
    vertex_creases = np.empty(nv.value, np.float32)
    code = lib.spia_subdivide(ctypes.byref(cm), ctypes.byref(opts), int(levels), _ptr(positions, ctypes.c_float),
                              _ptr(face_vertices, ctypes.c_int32), _ptr(edges, ctypes.c_int32),
                              _ptr(edge_creases, ctypes.c_float), _ptr(vertex_creases, ctypes.c_float),
                              ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    return Mesh(positions, np.full(nf.value, 4, np.int32), face_vertices, edges=edges, edge_creases=edge_creases,
                vertex_creases=vertex_creases)


def flat_positions(mesh, boundary_smooth="ALL", use_creases=True, quality=3, opensubdiv_version=None, threads=0,
                   progress=None, memory_budget=0):
    """Positions (N, 3) float32 for the vertices of a quad mesh whose faces,
    drawn flat (a Multires modifier's finest level), lie closest to its
    Catmull-Clark limit surface (spia_flat_positions)."""
    lib = _library()
    opts, _keep = _options(boundary_smooth=boundary_smooth, use_creases=use_creases, quality=quality,
                           opensubdiv_version=opensubdiv_version, threads=threads, progress=progress,
                           memory_budget=memory_budget)
    cm = mesh._c()
    out = np.empty_like(mesh.positions)
    status = _Status()
    code = lib.spia_flat_positions(ctypes.byref(cm), ctypes.byref(opts), _ptr(out, ctypes.c_float),
                                   ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    return out
