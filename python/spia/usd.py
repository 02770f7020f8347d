# SPDX-License-Identifier: GPL-3.0-or-later
"""A cage as a USDA layer, written as text without any USD library
(:func:`usd_text`, :func:`write_usd`), and the creases as the sharpness
the library hands OpenSubdiv (:func:`sharpness`)."""

import ctypes
import re

import numpy as np

from .errors import PiaError, _raise
from .header import _Status
from .interpolation import validate
from .library import _library
from .mesh import BOUNDARY_RULES, BOUNDARY_SMOOTH, SCHEMES, Mesh, _enum, _options, _ptr

_USD_SCHEMES = {"CATMULL_CLARK": "catmullClark", "LOOP": "loop"}
# OpenSubdiv's VTX_BOUNDARY_EDGE_ONLY / EDGE_AND_CORNER, as Blender's modifier sets them.
_USD_BOUNDARY = {"ALL": "edgeOnly", "PRESERVE_CORNERS": "edgeAndCorner"}
_USD_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_USD_SHARPNESS_INFINITE = np.float32(10.0)  # Sdc::Crease::SHARPNESS_INFINITE, USD's too
_USD_PER_LINE = 8


def _usd_cage(mesh, cage):
    try:
        array = np.asarray(cage)
    except Exception as exc:  # ragged lists and the like
        raise PiaError("INVALID_ARGUMENT", f"cage must be an (N, 3) array of numbers: {exc}") from None
    if array.dtype.kind not in "biuf":
        raise PiaError("INVALID_ARGUMENT", f"cage must be an (N, 3) array of numbers, not of {array.dtype}")
    if array.shape != (mesh.vertex_count, 3):
        raise PiaError("INVALID_ARGUMENT",
                       f"cage must have shape ({mesh.vertex_count}, 3), one point per mesh vertex, not {array.shape}")
    with np.errstate(over="ignore", invalid="ignore"):
        points = np.ascontiguousarray(array, dtype=np.float32)
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        raise PiaError("NONFINITE", f"{len(bad)} cage points are NaN, infinite or beyond float32's range "
                       f"(first: point {bad[0]})", int(bad[0]))
    return points


def sharpness(mesh, scheme="CATMULL_CLARK", use_creases=True, two_edge_rule=True):
    """The sharpness the library hands OpenSubdiv for ``mesh``: ``(pairs (K, 2)
    int32, crease sharpness (K,) float32, vertex sharpness (N,) float32)``.

    Creases c in [0, 1] become c*c*10 (float32); face edges below 1e-6 are
    left out and an edge listed more than once takes its largest; pairs are
    each creased face edge's (smaller, larger) vertex index, sorted.  With
    Catmull-Clark, Blender's rules: the ends of edges in no face are
    infinitely sharp (10) and, with ``two_edge_rule``, a vertex with exactly
    two face edges gets the smaller of their sharpnesses added to its own,
    capped at 10."""
    lib = _library()
    opts, _keep = _options(scheme=scheme, use_creases=use_creases)
    cm = mesh._c()
    status = _Status()
    flags = 0 if two_edge_rule else 1
    count = ctypes.c_int32(0)
    code = lib.spia_sharpness(ctypes.byref(cm), ctypes.byref(opts), flags, ctypes.byref(count), None, None, None,
                              ctypes.byref(status))
    if code < 0:
        _raise(code, status)
    pairs = np.zeros((count.value, 2), np.int32)
    creases = np.zeros(count.value, np.float32)
    vertices = np.zeros(mesh.vertex_count, np.float32)
    code = lib.spia_sharpness(ctypes.byref(cm), ctypes.byref(opts), flags, ctypes.byref(count),
                              _ptr(pairs, ctypes.c_int32), _ptr(creases, ctypes.c_float),
                              _ptr(vertices, ctypes.c_float), ctypes.byref(status))
    if code < 0:
        _raise(code, status)
    return pairs, creases, vertices


def _usd_sharpness(mesh, scheme, use_creases, two_edge_rule=True):
    """(crease pairs (K, 2), their sharpness (K,), corner vertices (C,), their
    sharpness (C,)): the library's own (:func:`sharpness`)."""
    pairs, creases, vertices = sharpness(mesh, scheme=scheme, use_creases=use_creases, two_edge_rule=two_edge_rule)
    corners = np.flatnonzero(vertices > 0)
    return pairs, creases, corners, vertices[corners]


def _usd_loose_points(mesh, points):
    """points with the vertices that no face uses where Blender's modifier
    shows them: one between exactly two loose edges at (prev + 4 V + next)
    / 6 of the cage (as the library's limit stencils have it), any other at
    its own position.  USD meshes have no loose edges to smooth them."""
    if mesh.edges is None or not len(mesh.edges):
        return points
    n = mesh.vertex_count
    used = np.zeros(n, bool)
    used[mesh.face_vertices] = True
    ends, others = mesh.edges.ravel(), mesh.edges[:, ::-1].ravel()
    loose = ~used[ends]
    degree = np.bincount(ends[loose], minlength=n)
    chosen = loose & (degree[ends] == 2)
    if not chosen.any():
        return points
    order = np.argsort(ends[chosen], kind="stable")
    vertices, neighbours = ends[chosen][order][0::2], others[chosen][order].reshape(-1, 2)
    cage = points.astype(np.float64)
    out = points.copy()
    out[vertices] = ((cage[neighbours[:, 0]] + 4.0 * cage[vertices] + cage[neighbours[:, 1]]) / 6.0).astype(np.float32)
    return out


def _usd_floats(values):
    """float32 values as decimals that give the same float32 back, whether a
    reader parses them as float or (as USD's text reader does) as double
    and then rounds to float: numpy's shortest float32 form, checked
    through double, else the double's own shortest form (exact)."""
    x = np.ascontiguousarray(values, np.float32).ravel()
    text = [str(v) for v in x]
    if not text:
        return text
    back = np.array(text).astype(np.float64).astype(np.float32)
    for i in np.flatnonzero(back.view(np.uint32) != x.view(np.uint32)).tolist():
        text[i] = repr(float(x[i]))
    return text


def _usd_array(kind, name, items, indent="    "):
    if not len(items):
        return f"{indent}{kind} {name} = []\n"
    lines = [", ".join(items[i:i + _USD_PER_LINE]) for i in range(0, len(items), _USD_PER_LINE)]
    if len(lines) == 1:
        return f"{indent}{kind} {name} = [{lines[0]}]\n"
    body = (",\n" + indent + "    ").join(lines)
    return f"{indent}{kind} {name} = [\n{indent}    {body}\n{indent}]\n"


def _usd_tuples(points):
    xyz = _usd_floats(points)
    return ["(%s, %s, %s)" % tuple(xyz[i:i + 3]) for i in range(0, len(xyz), 3)]


def usd_text(mesh, cage=None, *, scheme="CATMULL_CLARK", boundary_smooth="ALL", boundary_rule="SMOOTH",
             use_creases=True, name="cage", up_axis="Z", meters_per_unit=1.0, two_edge_rule=True):
    """The USDA text of a layer with one subdivision ``Mesh`` prim: the
    topology and creases of ``mesh`` (a :class:`Mesh`), the points of
    ``cage`` ((N, 3), default: the mesh's own positions), float32 exactly
    (points no face uses: see :func:`write_usd`)."""
    if not isinstance(mesh, Mesh):
        raise PiaError("INVALID_ARGUMENT", f"mesh must be a spia.Mesh, not {type(mesh).__name__}")
    _enum(scheme, SCHEMES, "scheme")
    _enum(boundary_smooth, BOUNDARY_SMOOTH, "boundary_smooth")
    _enum(boundary_rule, BOUNDARY_RULES, "boundary_rule")
    if scheme == "DOO_SABIN":
        raise PiaError("INVALID_ARGUMENT", "USD has no Doo-Sabin subdivision scheme (only catmullClark, loop and "
                       "bilinear): a Doo-Sabin cage cannot be written as a USD subdivision mesh")
    if scheme == "LOOP" and boundary_rule == "HOPPE":
        raise PiaError("INVALID_ARGUMENT", "USD's loop scheme follows OpenSubdiv's boundary rules "
                       "(boundary_rule 'SMOOTH'); a cage made for boundary_rule 'HOPPE' would not interpolate there")
    if not (isinstance(name, str) and _USD_NAME.match(name)):
        raise PiaError("INVALID_ARGUMENT", f"name must be a USD prim name (letters, digits and _, not starting "
                       f"with a digit), not {name!r}")
    if up_axis not in ("Y", "Z"):
        raise PiaError("INVALID_ARGUMENT", f"up_axis must be 'Y' or 'Z', not {up_axis!r}")
    try:
        unit = float(meters_per_unit)
    except (TypeError, ValueError):
        unit = float("nan")
    if not (unit > 0 and np.isfinite(unit)):
        raise PiaError("INVALID_ARGUMENT", f"meters_per_unit must be a positive number, not {meters_per_unit!r}")
    validate(mesh)  # the library refuses what it would refuse to subdivide
    points = _usd_cage(mesh, mesh.positions if cage is None else cage)
    if scheme == "LOOP":
        other = np.flatnonzero(mesh.face_sizes != 3)
        if len(other):
            raise PiaError("FACE_SIZE", f"USD's loop scheme takes triangles only; {len(other)} faces are not "
                           f"(first: face {other[0]})", int(other[0]))
    if scheme == "CATMULL_CLARK":
        points = _usd_loose_points(mesh, points)
    pairs, edge_sharpness, corners, corner_sharpness = _usd_sharpness(
        mesh, scheme="CATMULL_CLARK" if scheme == "CATMULL_CLARK" else "LOOP", use_creases=bool(use_creases),
        two_edge_rule=bool(two_edge_rule))

    out = ["#usda 1.0\n(\n",
           '    defaultPrim = "%s"\n' % name,
           "    metersPerUnit = %s\n" % repr(unit),
           '    upAxis = "%s"\n' % up_axis,
           ")\n\n",
           'def Mesh "%s"\n{\n' % name]
    out.append(_usd_array("float3[]", "extent", _usd_tuples(np.stack([points.min(axis=0), points.max(axis=0)]))))
    out.append(_usd_array("int[]", "faceVertexCounts", [str(v) for v in mesh.face_sizes.tolist()]))
    out.append(_usd_array("int[]", "faceVertexIndices", [str(v) for v in mesh.face_vertices.tolist()]))
    out.append(_usd_array("point3f[]", "points", _usd_tuples(points)))
    out.append('    uniform token subdivisionScheme = "%s"\n' % _USD_SCHEMES[scheme])
    out.append('    token interpolateBoundary = "%s"\n' % _USD_BOUNDARY[boundary_smooth])
    out.append('    token triangleSubdivisionRule = "catmullClark"\n')
    out.append('    token faceVaryingLinearInterpolation = "all"\n')
    out.append('    uniform token orientation = "rightHanded"\n')
    if len(pairs):
        out.append(_usd_array("int[]", "creaseIndices", [str(v) for v in pairs.ravel().tolist()]))
        out.append(_usd_array("int[]", "creaseLengths", ["2"] * len(pairs)))
        out.append(_usd_array("float[]", "creaseSharpnesses", _usd_floats(edge_sharpness)))
    if len(corners):
        out.append(_usd_array("int[]", "cornerIndices", [str(v) for v in corners.tolist()]))
        out.append(_usd_array("float[]", "cornerSharpnesses", _usd_floats(corner_sharpness)))
    out.append("}\n")
    return "".join(out)


def write_usd(path, mesh, cage=None, *, scheme="CATMULL_CLARK", boundary_smooth="ALL", boundary_rule="SMOOTH",
              use_creases=True, name="cage", up_axis="Z", meters_per_unit=1.0, two_edge_rule=True):
    """Writes a cage to ``path`` as a USDA layer (text: .usda, or .usd,
    which USD reads as text too) with one subdivision ``Mesh`` prim,
    ``name``, its default prim.  Returns the path.

    ``mesh`` (a :class:`Mesh`) gives the faces and creases, ``cage`` the
    points (default: the mesh's positions); scheme, boundary_smooth,
    boundary_rule and use_creases as given to :func:`interpolate`.
    Catmull-Clark is written as Blender's modifier builds it for
    OpenSubdiv: boundary_smooth 'ALL' / 'PRESERVE_CORNERS' as
    interpolateBoundary "edgeOnly" / "edgeAndCorner", creases c as
    sharpness c*c*10, and Blender's own rules made explicit as corner
    sharpness: the end points of loose edges (which USD meshes do not have)
    are infinitely sharp (10, with use_creases False too, as in Blender),
    and a vertex with exactly two face edges gets the smaller of their
    sharpnesses added (capped at 10).  A point that no face uses is
    written where Blender's modifier shows it: the cage's point, but for
    one between exactly two loose edges, (prev + 4 V + next) / 6.  Loop
    (triangles only) is USD's "loop", with OpenSubdiv's rules.  Doo-Sabin,
    and Loop with boundary_rule 'HOPPE', have no USD counterpart: PiaError.

    Blender's own USD import (option ``import_subdiv``, from 5.0
    ``import_subdivision``) reads, from 4.4 on, the creases back as
    c = sqrt(sharpness / 10) and then applies the two-edge rule itself, once
    more: where a vertex has two face edges whose smaller sharpness is
    between 0 and 10, its surface differs there.  ``two_edge_rule=False``
    leaves the rule to the reader: a file for Blender alone.  Blender 4.2
    and 4.3 read neither creases nor interpolateBoundary, and no Blender
    gives a "loop" mesh a modifier.  No USD attribute holds the modifier's
    ``quality``: set it on the imported modifier.
    """
    text = usd_text(mesh, cage, scheme=scheme, boundary_smooth=boundary_smooth, boundary_rule=boundary_rule,
                    use_creases=use_creases, name=name, up_axis=up_axis, meters_per_unit=meters_per_unit,
                    two_edge_rule=two_edge_rule)
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
    return path
