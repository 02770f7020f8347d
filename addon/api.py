# SPDX-License-Identifier: GPL-3.0-or-later
"""Script API and the one implementation shared by the operator and cli.py.

Data makes one trip: Blender mesh -> flat numpy arrays (foreach_get) ->
native.interpolate -> cage positions -> foreach_set on a copy of the mesh ->
new object with a Subdivision Surface modifier (use_limit_surface=True).

Blender has no Loop subdivision modifier: for scheme 'LOOP' the new object
is the cage without a modifier, and a child object ``<cage>_limit`` holds
the library's Loop limit surface of the cage (native.refine), which
refresh_limit recomputes after the cage was edited.

The two-phase Doo-Sabin scheme ('DOO_SABIN', closed meshes) has no modifier
either: the cage's child ``<cage>_limit`` holds the refined control mesh
(native.refine; its face centroids lie on the limit surface). The first
step uses a shape parameter per face: the float FACE attribute named by
shape_attribute where the mesh has it (read again from the cage on refresh,
so it can be repainted there), else shape_parameter.

Fitting to a scan: with a ``target`` (the name of a mesh object, usually a
dense scan), the cage is not interpolated through its own vertices but
fitted to the target's evaluated surface (native.fit): 'SURFACE' moves the
whole Catmull-Clark limit surface onto it, 'VERTICES' moves each limit
point of a control vertex to its closest scan point and interpolates those.
The target is read in the cage's object space, so the two objects may have
any transforms. The new object carries the distances as a point attribute
(``pia_distance``) and a heat-map colour attribute (``pia_distance_color``).
"""

import ctypes
import os
import sys
import threading

import bmesh
import numpy as np
import bpy

from . import cleanup, native

# Names follow the Subdivision Surface modifier where one exists.
DEFAULT_SETTINGS = {
    "scheme": 'CATMULL_CLARK',
    "boundary_rule": 'SMOOTH',
    "triangulate": False,
    "staged": False,
    "levels": 1,  # as a new Subdivision Surface modifier: Levels Viewport 1, Render 2
    "render_levels": 2,
    "quality": 3,
    "boundary_smooth": 'ALL',
    "use_creases": True,
    "method": 'AUTO',
    "tolerance": 1e-6,
    "max_iterations": 1000,
    "shape_parameter": 0.5,
    "shape_attribute": "pia_shape",
    # Fitting to a scan (target empty: interpolate the cage's own vertices).
    "target": "",
    "fit": 'SURFACE',
    "fit_cutoff": 0.02,
    "fit_smoothing": 1e-5,
    "fit_samples": 4,
    # Write each scan vertex's distance to the fitted surface onto the scan.
    "fit_paint_scan": False,
    # Catmull-Clark: the OpenSubdiv version whose rules the modifier follows,
    # e.g. "3.7.0" or (3, 7, 0); empty: this Blender's (bpy.app.opensubdiv).
    "opensubdiv_version": "",
    # Interpolate a cleaned copy of the mesh (cleanup.clean); distance relative to the diagonal.
    "cleanup": False,
    "cleanup_distance": cleanup.DEFAULT_DISTANCE,
}

FIT_MODES = tuple(native.FIT_MODES)
FIT_NAMES = {'SURFACE': "Surface", 'VERTICES': "Vertices"}
# The heat map is red at this distance (relative to the scan's diagonal) and beyond.
HEAT_SCALE = 1e-3
DISTANCE_ATTRIBUTE = "pia_distance"
COLOR_ATTRIBUTE = "pia_distance_color"
# On the scan (fit_paint_scan): its vertices' distances to the fitted surface.
SCAN_DISTANCE_ATTRIBUTE = "pia_scan_distance"
SCAN_COLOR_ATTRIBUTE = "pia_scan_distance_color"
# The heat map's colour of scan vertices no face uses (not measured).
UNMEASURED_COLOR = (0.5, 0.5, 0.5, 1.0)

SCHEMES = ('CATMULL_CLARK', 'LOOP', 'DOO_SABIN')
# Schemes Blender's modifier cannot show: a `_limit` child shows the surface.
LIMIT_SCHEMES = ('LOOP', 'DOO_SABIN')
BOUNDARY_SMOOTH = ('ALL', 'PRESERVE_CORNERS')
BOUNDARY_RULES = ('SMOOTH', 'HOPPE')
# The library decides where CG (conjugate gradients) applies: it needs a
# symmetrizable limit matrix (closed meshes) and says so otherwise.
METHODS = tuple(native.METHODS)
LOOP_MAX_LEVELS = 8  # native.refine's limit
SCHEME_NAMES = {'CATMULL_CLARK': "Catmull-Clark", 'LOOP': "Loop", 'DOO_SABIN': "Doo-Sabin"}

# Custom properties of a Loop or Doo-Sabin cage: what refresh_limit needs to remake its
# limit surface, and what a re-run needs to repeat it.
LIMIT_SUFFIX = "_limit"
LIMIT_MARK = "pia_limit_surface"   # on the child that holds the limit surface
STORED_SETTINGS = ("scheme", "boundary_rule", "boundary_smooth", "use_creases", "triangulate", "staged",
                   "levels", "render_levels", "quality", "method", "tolerance", "max_iterations",
                   "shape_parameter", "shape_attribute", "cleanup", "cleanup_distance")
# A live cage follows its source's vertices one to one, which a cleaned copy's are not.
LIVE_CLEANUP_MESSAGE = ("A cage made with cleanup cannot be live: its vertices are those of a cleaned copy "
                        "of '%s', not the source's own; clean the source mesh itself, then make a live cage "
                        "without cleanup")
# What the cleanup did, stored on the cage as pia_cleanup_<name> (cleanup.STAT_NAMES).
CLEANUP_PREFIX = "pia_cleanup_"
# The vertex group of a cage's vertices that no cage can put on their targets
# (their limit points are tied to other vertices'), so that they can be
# selected in Edit Mode; the custom property with their count.
UNREACHABLE_GROUP = "pia_unreachable"
UNREACHABLE_COUNT = "pia_unreachable_count"
REACHABLE_MAX_ERROR = "pia_reachable_max_error"  # max error over the other vertices, while there are any

# Settings that a source Subdivision Surface modifier provides.
MODIFIER_SETTINGS = ("levels", "render_levels", "quality", "boundary_smooth", "use_creases")


def blender_opensubdiv_version():
    """The OpenSubdiv version this Blender evaluates the modifier with, as a
    tuple (bpy.app.opensubdiv.version), or None where it does not say."""
    info = getattr(bpy.app, "opensubdiv", None)
    version = tuple(getattr(info, "version", ()) or ())
    if not version or not any(version):
        return None
    return version


def opensubdiv_version_of(settings):
    """The OpenSubdiv version the settings ask for, as the library takes it
    (major * 10000 + minor * 100 + patch): the setting, else this Blender's."""
    version = settings.get("opensubdiv_version") or blender_opensubdiv_version()
    return native.opensubdiv_version_number(version)


def opensubdiv_version_string(number):
    return "%d.%d.%d" % (number // 10000, number // 100 % 100, number % 100) if number else ""


def find_subsurf(obj):
    """The last Subdivision Surface modifier of obj, or None."""
    if obj is None:
        return None
    found = None
    for mod in obj.modifiers:
        if mod.type == 'SUBSURF':
            found = mod
    return found


def settings_from_modifier(obj):
    """Settings taken from obj's Subdivision Surface modifier (empty dict if none).

    The modifier's use_limit_surface is deliberately ignored: the result is
    always a cage for the limit surface.
    """
    mod = find_subsurf(obj)
    if mod is None:
        return {}
    settings = {name: getattr(mod, name) for name in MODIFIER_SETTINGS}
    if mod.subdivision_type == 'CATMULL_CLARK':
        settings["scheme"] = 'CATMULL_CLARK'
    return settings


def check_settings(settings):
    """Complete settings with defaults and check names and ranges (ValueError)."""
    unknown = set(settings) - set(DEFAULT_SETTINGS)
    if unknown:
        raise ValueError("Unknown setting(s): %s" % ", ".join(sorted(unknown)))
    s = dict(DEFAULT_SETTINGS)
    s.update(settings)
    if s["scheme"] not in SCHEMES:
        raise ValueError("scheme must be one of %s, not %r" % (SCHEMES, s["scheme"]))
    if s["boundary_smooth"] not in BOUNDARY_SMOOTH:
        raise ValueError("boundary_smooth must be one of %s, not %r"
                         % (BOUNDARY_SMOOTH, s["boundary_smooth"]))
    if s["boundary_rule"] not in BOUNDARY_RULES:
        raise ValueError("boundary_rule must be one of %s, not %r"
                         % (BOUNDARY_RULES, s["boundary_rule"]))
    if s["method"] not in METHODS:
        raise ValueError("method must be one of %s, not %r" % (METHODS, s["method"]))
    s["triangulate"] = bool(s["triangulate"])
    s["staged"] = bool(s["staged"])
    s["levels"] = int(s["levels"])
    s["render_levels"] = int(s["render_levels"])
    s["quality"] = int(s["quality"])
    s["max_iterations"] = int(s["max_iterations"])
    s["tolerance"] = float(s["tolerance"])
    s["use_creases"] = bool(s["use_creases"])
    s["cleanup"] = bool(s["cleanup"])
    s["fit_paint_scan"] = bool(s["fit_paint_scan"])
    try:
        s["cleanup_distance"] = float(s["cleanup_distance"])
    except (TypeError, ValueError):
        s["cleanup_distance"] = float("nan")
    if not (s["cleanup_distance"] >= 0.0 and np.isfinite(s["cleanup_distance"])):
        raise ValueError("cleanup_distance must be zero or a positive number (a fraction of the "
                         "bounding-box diagonal), not %r" % (settings.get("cleanup_distance"),))
    if not 0 <= s["levels"] <= 11 or not 0 <= s["render_levels"] <= 11:
        raise ValueError("levels and render_levels must be in 0..11")
    if s["scheme"] in LIMIT_SCHEMES and s["levels"] > LOOP_MAX_LEVELS:
        raise ValueError("levels must be in 0..%d for the %s limit surface, not %d"
                         % (LOOP_MAX_LEVELS, SCHEME_NAMES[s["scheme"]], s["levels"]))
    try:
        s["shape_parameter"] = float(s["shape_parameter"])
    except (TypeError, ValueError):
        raise ValueError("shape_parameter must be a number in (0, 1), not %r"
                         % (s["shape_parameter"],)) from None
    if s["scheme"] == 'DOO_SABIN' and not 0.0 < s["shape_parameter"] < 1.0:
        raise ValueError("shape_parameter must be in (0, 1) (exclusive), not %g"
                         % s["shape_parameter"])
    if not isinstance(s["shape_attribute"], str):
        raise ValueError("shape_attribute must be an attribute name (a string), not %r"
                         % (s["shape_attribute"],))
    if not 1 <= s["quality"] <= 10:
        raise ValueError("quality must be in 1..10, not %d" % s["quality"])
    if s["max_iterations"] < 1:
        raise ValueError("max_iterations must be at least 1")
    if not (s["tolerance"] > 0.0 and np.isfinite(s["tolerance"])):
        raise ValueError("tolerance must be a positive number")
    target = s["target"]
    if target is None:
        target = ""
    elif isinstance(target, bpy.types.Object):
        target = target.name
    if not isinstance(target, str):
        raise ValueError("target must be the name of a mesh object (or the object), not %r" % (target,))
    s["target"] = target
    if s["fit"] not in FIT_MODES:
        raise ValueError("fit must be one of %s, not %r" % (FIT_MODES, s["fit"]))
    s["fit_cutoff"] = float(s["fit_cutoff"])
    s["fit_smoothing"] = float(s["fit_smoothing"])
    s["fit_samples"] = int(s["fit_samples"])
    if not (s["fit_cutoff"] > 0.0 and np.isfinite(s["fit_cutoff"])):
        raise ValueError("fit_cutoff must be a positive number (a fraction of the scan's diagonal)")
    if not (s["fit_smoothing"] >= 0.0 and np.isfinite(s["fit_smoothing"])):
        raise ValueError("fit_smoothing must be zero or a positive number")
    if not 1 <= s["fit_samples"] <= 64:
        raise ValueError("fit_samples must be in 1..64, not %d" % s["fit_samples"])
    version = s["opensubdiv_version"]
    if version is None:
        version = ""
    if isinstance(version, str):
        version = version.strip()
    try:
        native.opensubdiv_version_number(version)
    except native.PiaError:
        raise ValueError("opensubdiv_version must be a version such as '3.7.0' or (3, 7, 0), or empty "
                         "for this Blender's, not %r" % (version,)) from None
    s["opensubdiv_version"] = version
    if target and s["fit"] == 'SURFACE' and s["scheme"] != 'CATMULL_CLARK':
        raise ValueError("The Surface fit works on the Catmull-Clark limit surface only: use "
                         "Fit 'Vertices' for %s" % SCHEME_NAMES[s["scheme"]])
    return s


# ---------------------------------------------------------------------------
# Blender mesh -> flat arrays

def _float_attribute(mesh, name, domain):
    attributes = getattr(mesh, "attributes", None)
    if attributes is None:
        return None
    attr = attributes.get(name)
    if attr is None or attr.data_type != 'FLOAT' or attr.domain != domain:
        return None
    values = np.empty(len(attr.data), np.float32)
    attr.data.foreach_get("value", values)
    return values


def face_shape_parameters(mesh, settings):
    """The Doo-Sabin shape parameters of mesh's faces: a float32 array, one
    value per face, from the float FACE attribute settings["shape_attribute"],
    or None when the mesh has no such attribute (shape_parameter applies).

    ValueError if an attribute of that name exists on another domain or with
    another type. The values are not checked here: the library names the
    faces outside (0, 1).
    """
    name = settings.get("shape_attribute") or ""
    attributes = getattr(mesh, "attributes", None)
    if not name or attributes is None:
        return None
    attr = attributes.get(name)
    if attr is None:
        return None
    if attr.domain != 'FACE' or attr.data_type != 'FLOAT':
        raise ValueError("Attribute '%s' of mesh '%s' is a %s attribute on the %s domain: the "
                         "shape attribute must be a Float attribute on the Face domain"
                         % (name, mesh.name, attr.data_type, attr.domain))
    values = np.empty(len(mesh.polygons), np.float32)
    if len(attr.data) != len(values):
        raise ValueError("Attribute '%s' of mesh '%s' has %d values for %d faces"
                         % (name, mesh.name, len(attr.data), len(values)))
    if len(values):
        attr.data.foreach_get("value", values)
    return values


def _shape_error(error, values, settings):
    """The library's refusal of shape parameters, with the attribute named."""
    if (values is not None and error.code == 'INVALID_ARGUMENT'
            and "shape parameter" in error.message):
        return type(error)(error.code, "%s (face attribute '%s')"
                           % (error.message, settings["shape_attribute"]), error.index)
    return None


def _crease_layer(mesh, name):
    """Blender 3.x crease layers: a collection of layers (3.4) or one layer (3.5+)."""
    layers = getattr(mesh, name, None)
    if layers is None:
        return None
    try:
        count = len(layers)  # a collection of layers (3.4)
    except TypeError:
        return layers        # a single layer (3.5, 3.6)
    return layers[0] if count else None


def read_creases(mesh):
    """(edge_creases (E,) or None, vertex_creases (N,) or None), Blender 0..1."""
    edge = _float_attribute(mesh, "crease_edge", 'EDGE')          # Blender 4.x
    if edge is None:
        layer = _crease_layer(mesh, "edge_creases")
        if layer is not None and len(layer.data) == len(mesh.edges):
            edge = np.empty(len(mesh.edges), np.float32)
            layer.data.foreach_get("value", edge)
        elif layer is None and hasattr(mesh, "edge_creases"):
            pass  # 3.4 to 3.6 without a crease layer: MeshEdge.crease is 0 on every edge
        elif len(mesh.edges) and hasattr(mesh.edges[0], "crease"):
            edge = np.empty(len(mesh.edges), np.float32)
            mesh.edges.foreach_get("crease", edge)
    vertex = _float_attribute(mesh, "crease_vert", 'POINT')       # Blender 4.x
    if vertex is None:
        layer = _crease_layer(mesh, "vertex_creases")              # Blender 3.x
        if layer is not None and len(layer.data) == len(mesh.vertices):
            vertex = np.empty(len(mesh.vertices), np.float32)
            layer.data.foreach_get("value", vertex)
    if edge is not None and not edge.any():
        edge = None
    if vertex is not None and not vertex.any():
        vertex = None
    return edge, vertex


# Where Blender keeps a mesh's arrays as attributes (3.5: vertex positions in
# "position"; 3.6: corner and edge vertices in ".corner_vert" and
# ".edge_verts"), foreach_get on the attribute copies the whole array at once,
# while vertices' co, loops' vertex_index and edges' vertices go element by
# element, 15 to 200 times slower (a million-vertex sphere in 5.2: 0.01 s
# against 0.9 s).
_BUILTIN_ATTRIBUTES = {
    "position": ((3, 5, 0), 'FLOAT_VECTOR', 'POINT'),
    ".corner_vert": ((3, 6, 0), 'INT', 'CORNER'),
    ".edge_verts": ((3, 6, 0), 'INT32_2D', 'EDGE'),
}
# From 4.0 the corners of face i are those from its loop_start to face i+1's
# (loop_total is derived from them): loop_start alone gives the faces.
_FACE_OFFSETS = bpy.types.MeshPolygon.bl_rna.properties["loop_total"].is_readonly


def _builtin_attribute(mesh, name, count):
    """Blender's own storage of mesh's vertex positions, corner vertices or
    edge vertices as an attribute with count values, or None (older Blenders,
    objects that stand in for a mesh)."""
    since, data_type, domain = _BUILTIN_ATTRIBUTES[name]
    if bpy.app.version < since or not isinstance(mesh, bpy.types.Mesh):
        return None
    attr = mesh.attributes.get(name)
    if attr is None or attr.data_type != data_type or attr.domain != domain or len(attr.data) != count:
        return None
    return attr


def position_attribute(mesh):
    """The attribute that holds mesh's vertex positions (Blender 3.5+), or None."""
    return _builtin_attribute(mesh, "position", len(mesh.vertices))


def read_positions(mesh):
    """(N, 3) float32 vertex positions of mesh."""
    n = len(mesh.vertices)
    out = np.empty(n * 3, np.float32)
    attr = position_attribute(mesh)
    if attr is not None:
        attr.data.foreach_get("vector", out)
    else:
        mesh.vertices.foreach_get("co", out)
    return out.reshape(n, 3)


def write_positions(mesh, points):
    """Set mesh's vertex positions (and its reference shape key's) to points (N, 3)."""
    flat = np.ascontiguousarray(points, np.float32).reshape(-1)
    attr = position_attribute(mesh)
    if attr is not None:
        attr.data.foreach_set("vector", flat)
    else:
        mesh.vertices.foreach_set("co", flat)
    keys = mesh.shape_keys
    if keys is not None and keys.reference_key is not None:
        keys.reference_key.data.foreach_set("co", flat)
    mesh.update()


# Some of the arrays have no attribute to read them through: the faces from
# 4.0 (Blender's face offsets, which loop_start reads one by one), and in 3.4
# and 3.5 the loops, edges and faces (arrays of MLoop, MEdge and MPoly).
# Their items' as_pointer() shows where Blender keeps them: where the first,
# second, middle and last items lie in one array of items of the expected
# size, and items spread over it read through RNA as in that array, the array
# is copied at once (a million faces: 0.002 s against 0.05 to 0.1 s; 3.4's
# four million loops: 0.01 s against 0.35 s).  Anything else is read item by
# item, as before.
_LEGACY_STRUCTS = bpy.app.version < (3, 6, 0)  # loops and edges as MLoop and MEdge
_MLOOP = np.dtype({"names": ["v"], "formats": ["<i4"], "offsets": [0], "itemsize": 8})  # then e
# v1 and v2 as one 8-byte field (copied five times faster than two 4-byte
# ones), then the flags.
_MEDGE = np.dtype({"names": ["v"], "formats": ["<i8"], "offsets": [0], "itemsize": 12})
_MPOLY = np.dtype({"names": ["loopstart", "totloop"], "formats": ["<i4", "<i4"], "offsets": [0, 4],
                   "itemsize": 12})  # then mat_nr, flag
_FACE_OFFSET = np.dtype({"names": ["loop_start"], "formats": ["<i4"], "offsets": [0], "itemsize": 4})
_SAMPLES = 17


def _items_array(collection, count, dtype, rna_values):
    """The fields of dtype of a Blender collection's count items, in dtype's
    order, copied at once from the array of dtype items that Blender keeps
    them in: int32 arrays, (count, 2) for an 8-byte field; None where the
    items' addresses make no such array, or where on a sample of items the
    fields read there differ from rna_values(item) (the same through RNA)."""
    if count < 2 or not isinstance(collection, bpy.types.bpy_prop_collection):
        return None
    size = dtype.itemsize
    first = collection[0].as_pointer()
    if not first or any(collection[i].as_pointer() - first != i * size for i in (1, count // 2, count - 1)):
        return None
    items = np.frombuffer((ctypes.c_char * (count * size)).from_address(first), dtype, count)
    fields = [np.array(items[name]) for name in dtype.names]
    del items  # no view of Blender's memory outlives the copy
    fields = [a.view(np.int32).reshape(count, 2) if a.dtype.itemsize == 8 else a.view(np.int32) for a in fields]
    for i in sorted(set(np.linspace(0, count - 1, _SAMPLES).astype(int).tolist())):
        if tuple(rna_values(collection[i])) != tuple(a[i].tolist() for a in fields):
            return None
    return fields


def _corner_vertices(mesh):
    count = len(mesh.loops)
    attr = _builtin_attribute(mesh, ".corner_vert", count)
    if attr is None and _LEGACY_STRUCTS:
        fields = _items_array(mesh.loops, count, _MLOOP, lambda loop: (loop.vertex_index,))
        if fields is not None:
            return fields[0]
    out = np.empty(count, np.int32)
    if attr is not None:
        attr.data.foreach_get("value", out)
    else:
        mesh.loops.foreach_get("vertex_index", out)
    return out


def _edge_vertices(mesh):
    count = len(mesh.edges)
    attr = _builtin_attribute(mesh, ".edge_verts", count)
    if attr is None and _LEGACY_STRUCTS:
        fields = _items_array(mesh.edges, count, _MEDGE, lambda edge: (list(edge.vertices),))
        if fields is not None:
            return fields[0]
    out = np.empty(count * 2, np.int32)
    if attr is not None:
        attr.data.foreach_get("value", out)
    else:
        mesh.edges.foreach_get("vertices", out)
    return out.reshape(count, 2)


def _faces_of(mesh):
    """(loop_start, loop_total, ordered) of mesh's faces, int32; ordered: the
    loops are known to be stored face after face (Blender 4.0 and newer)."""
    f = len(mesh.polygons)
    if _FACE_OFFSETS and isinstance(mesh, bpy.types.Mesh):
        offsets = np.empty(f + 1, np.int32)
        fields = _items_array(mesh.polygons, f, _FACE_OFFSET, lambda face: (face.loop_start,))
        if fields is not None:
            offsets[:f] = fields[0]
        else:
            mesh.polygons.foreach_get("loop_start", offsets[:f])
        offsets[f] = len(mesh.loops)
        return offsets[:f], np.diff(offsets), True  # loop_total, as Blender derives it
    fields = _items_array(mesh.polygons, f, _MPOLY, lambda face: (face.loop_start, face.loop_total))
    if fields is not None:
        return fields[0], fields[1], False
    loop_start = np.empty(f, np.int32)
    face_sizes = np.empty(f, np.int32)
    mesh.polygons.foreach_get("loop_start", loop_start)
    mesh.polygons.foreach_get("loop_total", face_sizes)
    return loop_start, face_sizes, False


def read_face_sizes(mesh):
    """The number of corners of each of mesh's faces (int32)."""
    return _faces_of(mesh)[1]


def _face_vertices(loop_start, face_sizes, ordered, loop_vertex):
    """The corner vertices face after face: loop_vertex itself where the
    faces start at the first loop and each at the end of the one before."""
    f = len(face_sizes)
    if f and loop_start[0] == 0:
        if ordered:  # the faces' loops are consecutive: the first face's start fixes the rest
            return loop_vertex
        if (np.array_equal(loop_start[1:], loop_start[:-1] + face_sizes[:-1])  # each where the last ends
                and int(face_sizes.sum(dtype=np.int64)) == len(loop_vertex)):
            return loop_vertex
    # loops not stored in face order: gather them face by face
    offsets = np.zeros(f, np.int64)
    if f > 1:
        np.cumsum(face_sizes[:-1], out=offsets[1:])
    total = int(face_sizes.sum(dtype=np.int64))
    corner = np.arange(total, dtype=np.int64) - np.repeat(offsets, face_sizes)
    return np.ascontiguousarray(loop_vertex[np.repeat(loop_start.astype(np.int64), face_sizes) + corner])


def mesh_arrays(mesh):
    """Flat arrays of a Blender mesh, in the form native.Mesh takes them."""
    loop_start, face_sizes, ordered = _faces_of(mesh)
    face_vertices = _face_vertices(loop_start, face_sizes, ordered, _corner_vertices(mesh))
    edge_creases, vertex_creases = read_creases(mesh)
    return {
        "positions": read_positions(mesh),
        "face_sizes": face_sizes,
        "face_vertices": face_vertices,
        "edges": _edge_vertices(mesh),
        "edge_creases": edge_creases,
        "vertex_creases": vertex_creases,
    }


# ---------------------------------------------------------------------------
# The shared implementation

def check_source(obj):
    """Raise ValueError with a user-facing message if obj cannot be used."""
    if obj is None:
        raise ValueError("No active object: select a mesh object")
    if obj.type != 'MESH':
        raise ValueError("'%s' is not a mesh object (type %s)" % (obj.name, obj.type))
    mesh = obj.data
    if len(mesh.vertices) == 0:
        raise ValueError("Mesh '%s' has no vertices" % mesh.name)
    if len(mesh.polygons) == 0:
        raise ValueError("Mesh '%s' has no faces: subdivision needs faces" % mesh.name)


def native_mesh(mesh):
    """native.Mesh of a Blender mesh's data (positions, faces, edges, creases)."""
    arrays = mesh_arrays(mesh)
    return native.Mesh(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"],
                       edges=arrays["edges"],
                       edge_creases=arrays["edge_creases"],
                       vertex_creases=arrays["vertex_creases"])


def _require_library():
    if not native.available():
        raise RuntimeError("Subdivision PIA library not loaded: %s" % native.load_error())


def non_triangle_count(mesh):
    return int(np.count_nonzero(read_face_sizes(mesh) != 3))


def triangulated_copy(mesh, name=None):
    """A new mesh: a copy of mesh with every quad and n-gon split into triangles.

    bmesh.ops.triangulate with the 'BEAUTY' method for quads and n-gons; it
    adds no vertices, so vertex i of the copy is vertex i of mesh. Edge and
    vertex creases, UVs and materials are kept (new diagonals are uncreased).
    """
    copy = mesh.copy()
    if name:
        copy.name = name
    bm = bmesh.new()
    try:
        bm.from_mesh(copy)
        faces = [f for f in bm.faces if len(f.verts) != 3]
        if faces:
            bmesh.ops.triangulate(bm, faces=faces, quad_method='BEAUTY', ngon_method='BEAUTY')
        bm.to_mesh(copy)
    finally:
        bm.free()
    copy.update()
    return copy


def find_target(obj, settings):
    """The target object (the scan) named by settings["target"], or None when
    no target is set. ValueError with a user-facing message if it cannot be
    used: not found, not a mesh object, obj itself, or no faces after its
    modifiers."""
    name = settings.get("target") or ""
    if not name:
        return None
    target = bpy.data.objects.get(name)
    if target is None:
        raise ValueError("Target '%s' not found: give the name of the mesh object to fit to (the scan)"
                         % name)
    if target.type != 'MESH':
        raise ValueError("Target '%s' is not a mesh object (type %s): the scan must be a mesh"
                         % (target.name, target.type))
    if obj is not None and target == obj:
        raise ValueError("Target '%s' is the cage itself: pick the scan to fit '%s' to"
                         % (target.name, obj.name))
    return target


def scan_arrays(target, cage_obj, context=None, tick=None):
    """(positions (N, 3) float32, face_sizes, face_vertices) of target's
    evaluated mesh (its modifiers applied) in cage_obj's object space.
    ValueError if it has no faces.  tick(), when given, is called between
    the steps (each a fraction of a second on a scan of millions of faces);
    True stops the reading (native.PiaCancelled).

    Only what a scan needs is read (no edges, no creases), each array once
    and at once (foreach_get on Blender's own attributes), and the positions
    are transformed only when the two objects' spaces differ: a scan of
    millions of faces is read in a few hundredths of a second a million."""
    def step():
        if tick is not None and tick():
            raise native.PiaCancelled("CANCELLED", "cancelled while reading the scan")
    context = context or bpy.context
    # A mesh without modifiers or shape keys, in object mode, evaluates to
    # itself: it is read as it is, without the copy to_mesh() makes (on a
    # scan of 3.6M quads 0.12 s and some 300 MB).
    as_is = (target.type == 'MESH' and target.mode == 'OBJECT' and not target.modifiers
             and target.data.shape_keys is None and not target.data.is_editmode)
    evaluated = None if as_is else target.evaluated_get(context.evaluated_depsgraph_get())
    mesh = target.data if as_is else evaluated.to_mesh()
    try:
        if mesh is None or len(mesh.polygons) == 0:
            raise ValueError("Target '%s' has no faces: the scan must be a mesh with faces" % target.name)
        step()
        loop_start, face_sizes, ordered = _faces_of(mesh)
        step()
        corners = _corner_vertices(mesh)
        step()
        face_vertices = _face_vertices(loop_start, face_sizes, ordered, corners)
        del corners
        step()
        positions = read_positions(mesh)
    finally:
        if evaluated is not None:
            evaluated.to_mesh_clear()
    step()
    to_cage = np.array(cage_obj.matrix_world.inverted() @ target.matrix_world, dtype=np.float64)
    if not np.array_equal(to_cage, np.eye(4)):
        out = np.empty_like(positions)
        chunk = 1 << 18  # float64 work in pieces: no (N, 3) float64 copy of a large scan
        for begin in range(0, len(positions), chunk):
            block = positions[begin:begin + chunk].astype(np.float64)
            out[begin:begin + chunk] = block @ to_cage[:3, :3].T + to_cage[:3, 3]
            if begin % (1 << 21) == 0:
                step()
        positions = out
    return (np.ascontiguousarray(positions, np.float32), np.ascontiguousarray(face_sizes, np.int32),
            np.ascontiguousarray(face_vertices, np.int32))


def make_scan(target, cage_obj, context=None, progress=None):
    """native.Scan of target's evaluated mesh in cage_obj's object space.
    progress(iteration, relative_error), as interpolate's, is called with
    (0, 0.0) while the scan is read and through the build (seconds for a
    scan of millions of triangles) and once at its end; True cancels
    (native.PiaCancelled)."""
    return scan_work(target, cage_obj, context, progress)()


def scan_work(target, cage_obj, context=None, progress=None):
    """make_scan in two halves: reads the scan here (Blender's data) and
    returns the library's share, a function that builds the native.Scan and
    touches nothing of Blender's (InterpolateJob runs it on another thread)."""
    _require_library()
    tick = None if progress is None else (lambda: progress(0, 0.0))
    positions, face_sizes, face_vertices = scan_arrays(target, cage_obj, context, tick=tick)
    building = None if progress is None else (lambda _phase, _fraction: progress(0, 0.0))
    return lambda: native.Scan(native.Mesh(positions, face_sizes, face_vertices), progress=building)


def machine_memory():
    """The machine's physical memory in bytes, or None where it cannot be told."""
    try:
        if sys.platform == "win32":
            import ctypes

            class _Status(ctypes.Structure):
                _fields_ = [("length", ctypes.c_uint32), ("load", ctypes.c_uint32),
                            ("total_phys", ctypes.c_uint64), ("avail_phys", ctypes.c_uint64),
                            ("total_page", ctypes.c_uint64), ("avail_page", ctypes.c_uint64),
                            ("total_virtual", ctypes.c_uint64), ("avail_virtual", ctypes.c_uint64),
                            ("avail_extended", ctypes.c_uint64)]
            status = _Status()
            status.length = ctypes.sizeof(_Status)
            if ctypes.windll.kernel32.GlobalMemoryStatusEx(ctypes.byref(status)):
                return int(status.total_phys)
            return None
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


# Bytes per stored weight (a 4-byte column and an 8-byte weight), and how
# much more than the finished table building it takes at its peak.
_BYTES_PER_WEIGHT = 12
_BUILD_FACTOR = 4


def stencil_memory_estimate(face_sizes, vertex_count, settings, scan=None):
    """Bytes the library needs, at its peak, for the stencil table of a mesh
    with these face sizes: a vertex's limit stencil spans the faces around
    it (1 + sum of (size - 2) over them: 9 for a regular quad vertex, 7 for
    a regular triangle one); a surface fit's samples span 16 vertices each."""
    sizes = np.asarray(face_sizes)
    weights = int(vertex_count) + int(np.einsum("i,i->", sizes, np.maximum(sizes - 2, 0), dtype=np.int64))
    rows = int(vertex_count)
    if scan is not None and settings.get("fit") == 'SURFACE':
        k = int(settings.get("fit_samples", 4))
        samples = int(np.sum(np.where(sizes == 4, 1, sizes))) * k * k
        weights += 16 * samples
        rows += samples
    return _BUILD_FACTOR * (_BYTES_PER_WEIGHT * weights + 8 * rows)


def check_memory(mesh, settings, scan=None):
    """Refuses up front a mesh (a native.Mesh) whose stencils would not fit in
    the machine's memory."""
    total = machine_memory()
    if not total:
        return
    need = stencil_memory_estimate(mesh.face_sizes, mesh.vertex_count, settings, scan)
    if need > total:
        raise native.PiaError(
            'OUT_OF_MEMORY',
            "its stencil table would need about %.1f GB (%d vertices, %d faces), more than this "
            "machine's %.1f GB of memory; try a lower quality or a smaller mesh"
            % (need / 2.0 ** 30, mesh.vertex_count, len(mesh.face_sizes), total / 2.0 ** 30))


def compute_cage(obj, settings, progress=None, mesh=None, scan=None, measure_scan=True):
    """Run the solver on obj's mesh data (not its modifiers), or on mesh if given.
    With scan (a native.Scan), fit the cage to it instead (native.fit;
    measure_scan=False leaves out the scan-to-surface distances).

    Returns (cage, report): a native.Report, or a native.FitReport for a fit."""
    run, explain = prepare_cage(obj, settings, progress=progress, mesh=mesh, scan=scan, measure_scan=measure_scan)
    try:
        return run()
    except native.PiaError as error:
        named = explain(error)
        if named is None:
            raise
        raise named from None


def prepare_cage(obj, settings, progress=None, mesh=None, scan=None, measure_scan=True):
    """compute_cage in two halves: reads the mesh here (Blender's data) and
    returns (run, explain).  run() calls the library and touches nothing of
    Blender's (InterpolateJob runs it on another thread); explain(error), for
    a native.PiaError that run raised, returns the error to raise instead (in
    the mesh's terms), or None for the error itself."""
    scheme = settings["scheme"]
    _require_library()
    data = mesh if mesh is not None else obj.data
    shapes = {}
    values = None
    if scheme == 'DOO_SABIN':
        values = face_shape_parameters(data, settings)
        # Creases are not part of the Doo-Sabin scheme: ignored, as the panel shows.
        shapes = {"shape_parameter": settings["shape_parameter"], "face_shape_parameters": values}
    options = dict(scheme=scheme, boundary_rule=settings["boundary_rule"],
                   boundary_smooth=settings["boundary_smooth"],
                   use_creases=settings["use_creases"] and scheme != 'DOO_SABIN',
                   quality=settings["quality"], method=settings["method"],
                   tolerance=settings["tolerance"], max_iterations=settings["max_iterations"],
                   staged=settings["staged"] and scheme == 'LOOP', progress=progress,
                   opensubdiv_version=opensubdiv_version_of(settings), **shapes)
    cage_mesh = native_mesh(data)
    check_memory(cage_mesh, settings, scan)
    non_triangles = non_triangle_count(data) if scheme == 'LOOP' and not settings["triangulate"] else 0

    def run():
        if scan is not None:
            return native.fit(cage_mesh, scan, mode=settings["fit"],
                              samples_per_edge=settings["fit_samples"], cutoff=settings["fit_cutoff"],
                              smoothing=settings["fit_smoothing"], measure_scan=measure_scan, **options)
        return native.interpolate(cage_mesh, **options)

    def explain(error):
        named = _shape_error(error, values, settings)
        if named is not None:
            return named
        if non_triangles and error.code == 'TOPOLOGY':
            return type(error)(error.code, "%s, or turn on Triangulate to use a triangulated copy"
                               % error.message, error.index)
        return None

    return run, explain


_LOOP_TOTAL_READ_ONLY = bpy.types.MeshPolygon.bl_rna.properties["loop_total"].is_readonly


def _new_mesh(name, points, face_sizes, face_vertices):
    """A new mesh with these vertices and faces (edges calculated)."""
    points = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(face_vertices, np.int32).ravel()
    face_sizes = np.ascontiguousarray(face_sizes, np.int32).ravel()
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(points))
    attr = position_attribute(mesh)
    if attr is not None:
        attr.data.foreach_set("vector", points.ravel())
    else:
        mesh.vertices.foreach_set("co", points.ravel())
    count = len(face_sizes)
    mesh.loops.add(len(faces))
    attr = _builtin_attribute(mesh, ".corner_vert", len(faces))
    if attr is not None:
        attr.data.foreach_set("value", faces)
    else:
        mesh.loops.foreach_set("vertex_index", faces)
    mesh.polygons.add(count)
    starts = np.zeros(count, np.int32)
    if count > 1:
        np.cumsum(face_sizes[:-1], out=starts[1:])
    mesh.polygons.foreach_set("loop_start", starts)
    if not _LOOP_TOTAL_READ_ONLY:  # 4.0+: derived from loop_start
        mesh.polygons.foreach_set("loop_total", face_sizes)
    mesh.update(calc_edges=True)
    return mesh


def write_creases(mesh, edge_creases=None, vertex_creases=None):
    """Set mesh's edge creases (one per mesh.edges) and vertex creases, where given."""
    modern = bpy.app.version >= (4, 0, 0)
    if edge_creases is not None:
        values = np.ascontiguousarray(edge_creases, np.float32)
        if modern:
            attr = mesh.attributes.get("crease_edge") or mesh.attributes.new("crease_edge", 'FLOAT', 'EDGE')
            attr.data.foreach_set("value", values)
        elif "crease" in bpy.types.MeshEdge.bl_rna.properties:  # 3.4 to 3.6
            mesh.edges.foreach_set("crease", values)
        else:
            mesh.edge_creases_ensure()
            mesh.edge_creases.data.foreach_set("value", values)
    if vertex_creases is not None:
        values = np.ascontiguousarray(vertex_creases, np.float32)
        if modern:
            attr = mesh.attributes.get("crease_vert") or mesh.attributes.new("crease_vert", 'FLOAT', 'POINT')
            attr.data.foreach_set("value", values)
        else:
            bm = bmesh.new()
            try:
                bm.from_mesh(mesh)
                layer = bm.verts.layers.crease.verify()
                for vert, value in zip(bm.verts, values.tolist()):
                    vert[layer] = value
                bm.to_mesh(mesh)
            finally:
                bm.free()
    mesh.update()


_FACE_TYPES = {'FLOAT': np.float32, 'INT': np.int32, 'BOOLEAN': bool}


def _copy_face_data(source, mesh, face_map):
    """Per-face data of source onto mesh's faces (face i of mesh is face_map[i] of
    source): materials, material indices, smooth shading and the float, integer
    and boolean face attributes (the Doo-Sabin shape attribute among them)."""
    for material in source.materials:
        mesh.materials.append(material)
    if not len(face_map):
        return
    rna = bpy.types.MeshPolygon.bl_rna.properties
    for prop, dtype in (("material_index", np.int32), ("use_smooth", bool)):
        if prop in rna and not rna[prop].is_readonly:
            values = np.empty(len(source.polygons), dtype)
            source.polygons.foreach_get(prop, values)
            mesh.polygons.foreach_set(prop, np.ascontiguousarray(values[face_map]))
    for attr in list(getattr(source, "attributes", ())):
        dtype = _FACE_TYPES.get(attr.data_type)
        if (attr.domain != 'FACE' or dtype is None or attr.name.startswith(".")
                or getattr(attr, "is_internal", False) or attr.name in mesh.attributes
                or len(attr.data) != len(source.polygons)):
            continue
        values = np.empty(len(attr.data), dtype)
        attr.data.foreach_get("value", values)
        new = mesh.attributes.new(attr.name, attr.data_type, 'FACE')
        new.data.foreach_set("value", np.ascontiguousarray(values[face_map]))


def cleaned_copy(mesh, distance=cleanup.DEFAULT_DISTANCE, name=None):
    """(new mesh, stats): a cleaned copy of mesh (cleanup.clean on its arrays;
    mesh itself is not changed). Kept: vertex positions (of the first vertex
    of each merged group), edge creases (by vertex pair) and vertex creases,
    materials, material indices, smooth shading and float, integer and boolean
    face attributes. Dropped: UV maps, colours and other corner and vertex
    attributes, vertex groups and shape keys. ValueError if no face is left."""
    arrays = mesh_arrays(mesh)
    result = cleanup.clean(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"],
                           edges=arrays["edges"], edge_creases=arrays["edge_creases"],
                           vertex_creases=arrays["vertex_creases"], distance=distance)
    if not len(result["face_sizes"]):
        raise ValueError("Mesh '%s' has no faces left after cleanup (%s)"
                         % (mesh.name, cleanup.format_stats(result["stats"])))
    copy = _new_mesh(name or mesh.name + "_clean", result["positions"], result["face_sizes"],
                     result["face_vertices"])
    try:
        _copy_face_data(mesh, copy, result["face_map"])
        edge_creases = None
        if result["edge_creases"] is not None:
            m = len(result["positions"])
            keys = result["edges"][:, 0].astype(np.int64) * m + result["edges"][:, 1]
            ev = np.empty(len(copy.edges) * 2, np.int32)
            copy.edges.foreach_get("vertices", ev)
            ev = ev.reshape(-1, 2).astype(np.int64)
            mine = np.minimum(ev[:, 0], ev[:, 1]) * m + np.maximum(ev[:, 0], ev[:, 1])
            where = np.clip(np.searchsorted(keys, mine), 0, len(keys) - 1)
            edge_creases = np.where(keys[where] == mine, result["edge_creases"][where], 0.0)
        write_creases(copy, edge_creases, result["vertex_creases"])
    except BaseException:
        bpy.data.meshes.remove(copy)
        raise
    return copy, result["stats"]


def cleanup_hint(error, mesh, settings):
    """The library's refusal of mesh with a hint that the cleanup setting would
    fix it (and what it would do), or None when cleanup is on or would not help."""
    if settings.get("cleanup") or error.code not in ('DEGENERATE_FACE', 'TOPOLOGY'):
        return None
    if error.code == 'TOPOLOGY' and "triangles" in error.message:
        return None
    try:
        arrays = mesh_arrays(mesh)
        result = cleanup.clean(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"],
                               edges=arrays["edges"],
                               distance=settings.get("cleanup_distance", cleanup.DEFAULT_DISTANCE))
    except ValueError:
        return None
    if not cleanup.changed(result["stats"]):
        return None
    would = cleanup.format_stats(result["stats"], future=True)
    return type(error)(error.code, "%s; the Cleanup setting (cleanup=True, --cleanup) would %s on a "
                       "copy of the mesh" % (error.message, would), error.index)


def store_cleanup(obj, stats):
    """What the cleanup did, as custom properties of the cage."""
    for name in cleanup.STAT_NAMES:
        obj[CLEANUP_PREFIX + name] = int(stats.get(name, 0))


def cleanup_stats(obj):
    """What the cleanup did for the cage obj (a dict), or None if it had no cleanup."""
    if obj is None or not obj.get("pia_cleanup"):
        return None
    return {name: int(obj.get(CLEANUP_PREFIX + name, 0)) for name in cleanup.STAT_NAMES}


def format_cleanup(obj):
    """'cleanup: merged 3 vertices, ...' for a cage made with cleanup, else ''."""
    stats = cleanup_stats(obj)
    return "" if stats is None else "cleanup: " + cleanup.format_stats(stats)


def _link_like(source, new_obj, context):
    collections = list(source.users_collection) or [context.scene.collection]
    for collection in collections:
        collection.objects.link(new_obj)
    new_obj.parent = source.parent
    new_obj.parent_type = source.parent_type
    if source.parent_type == 'BONE':
        new_obj.parent_bone = source.parent_bone
    new_obj.matrix_parent_inverse = source.matrix_parent_inverse.copy()
    new_obj.rotation_mode = source.rotation_mode
    new_obj.matrix_basis = source.matrix_basis.copy()
    for i, slot in enumerate(source.material_slots):
        if i < len(new_obj.material_slots):
            new_obj.material_slots[i].link = slot.link
            new_obj.material_slots[i].material = slot.material


def limit_arrays(mesh, settings, positions=None):
    """(positions (M,3) float32, face_sizes (K,) int32, face_vertices int32):
    the surface the library shows for a Loop or Doo-Sabin cage mesh, refined
    settings["levels"] times. Loop: triangles, every vertex at its limit
    position. Doo-Sabin: the refined mesh, with the per-face shape parameters
    of the cage mesh (face_shape_parameters) in the first step.

    positions replaces the mesh's vertex positions (the solved cage) if given.
    """
    return limit_work(mesh, settings, positions)()


def limit_work(mesh, settings, positions=None, progress=None):
    """limit_arrays in two halves: reads the mesh here and returns the
    library's share, a function that refines and touches nothing of
    Blender's (InterpolateJob runs it on another thread).  progress(level,
    share_done) -> bool, as native.refine's: True cancels."""
    doo_sabin = settings["scheme"] == 'DOO_SABIN'
    _require_library()
    arrays = mesh_arrays(mesh)
    if positions is not None:
        arrays["positions"] = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    cage = native.Mesh(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"],
                       edges=arrays["edges"], edge_creases=arrays["edge_creases"],
                       vertex_creases=arrays["vertex_creases"])
    if not doo_sabin:
        return lambda: native.refine(cage, int(settings["levels"]), scheme='LOOP',
                                     boundary_rule=settings["boundary_rule"],
                                     boundary_smooth=settings["boundary_smooth"],
                                     use_creases=bool(settings["use_creases"]), progress=progress)
    values = face_shape_parameters(mesh, settings)

    def run():
        try:
            return native.refine(cage, int(settings["levels"]), scheme='DOO_SABIN', use_creases=False,
                                 shape_parameter=float(settings["shape_parameter"]),
                                 face_shape_parameters=values, progress=progress)
        except native.PiaError as error:
            named = _shape_error(error, values, settings)
            if named is not None:
                raise named from None
            raise
    return run


def limit_mesh(name, points, face_sizes, face_vertices, materials=()):
    """A new smooth-shaded mesh from limit_arrays' output."""
    mesh = _new_mesh(name, points, face_sizes, face_vertices)
    if hasattr(mesh, "shade_smooth"):  # Blender 4.1+
        mesh.shade_smooth()
    else:
        mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), bool))
    for material in materials:
        mesh.materials.append(material)
    mesh.update()
    return mesh


def find_limit_object(cage):
    """The child of cage that holds its limit surface, or None."""
    if cage is None:
        return None
    for child in cage.children:
        if child.get(LIMIT_MARK):
            return child
    return None


def limit_cage_of(obj):
    """The Loop or Doo-Sabin cage for obj: obj itself, or the cage whose limit
    surface obj is (None if there is none)."""
    if obj is None:
        return None
    if obj.get("pia_scheme") in LIMIT_SCHEMES:
        return obj
    if (obj.get(LIMIT_MARK) and obj.parent is not None
            and obj.parent.get("pia_scheme") in LIMIT_SCHEMES):
        return obj.parent
    return None


# The name from when Loop was the only scheme with a `_limit` child.
loop_cage_of = limit_cage_of


def stored_settings(cage):
    """The settings stored on a cage by build_object (defaults for missing ones)."""
    s = dict(DEFAULT_SETTINGS)
    for name in STORED_SETTINGS:
        key = "pia_" + name
        if key in cage:
            value = cage[key]
            s[name] = bool(value) if isinstance(DEFAULT_SETTINGS[name], bool) else value
    if "pia_requested_method" in cage:  # pia_method is the method AUTO chose
        s["method"] = cage["pia_requested_method"]
    return s


def set_limit_object(cage, limit, context=None):
    """Put the limit surface (limit_arrays' output) on cage's `_limit` child,
    creating the child if there is none. Returns the child."""
    context = context or bpy.context
    child = find_limit_object(cage)
    name = cage.name + LIMIT_SUFFIX
    mesh = limit_mesh(name, *limit, materials=[m for m in cage.data.materials if m is not None])
    if child is None:
        child = bpy.data.objects.new(name, mesh)
        for collection in list(cage.users_collection) or [context.scene.collection]:
            collection.objects.link(child)
        child.parent = cage
        child[LIMIT_MARK] = True
    else:
        old = child.data
        child.data = mesh
        if old is not None and old.users == 0:
            bpy.data.meshes.remove(old)
        mesh.name = name
    # Sits exactly on the cage: identity local transform, no parent inverse.
    child.matrix_parent_inverse.identity()
    child.matrix_basis.identity()
    return child


def heat_colors(distances, scale=HEAT_SCALE):
    """RGBA (N, 4) float32 for relative distances: blue at 0 through cyan,
    green and yellow to red at `scale` and beyond (hue 240 to 0 degrees)."""
    t = np.clip(np.asarray(distances, np.float64) / scale, 0.0, 1.0)
    hue = (1.0 - t) * 4.0  # 4 = blue, 2 = green, 0 = red, in sixths of the circle
    rgb = np.empty((len(t), 3))
    rgb[:, 0] = np.clip(2.0 - hue, 0.0, 1.0)                     # red: rises from green to red
    rgb[:, 1] = np.clip(np.minimum(hue, 4.0 - hue), 0.0, 1.0)    # green: 0 at blue and red
    rgb[:, 2] = np.clip(hue - 2.0, 0.0, 1.0)                     # blue: falls from blue to green
    rgba = np.ones((len(t), 4), np.float32)
    rgba[:, :3] = rgb
    return rgba


def store_fit(obj, report, settings):
    """Custom properties and distance attributes of a fitted cage."""
    obj["pia_status"] = str(report.status)
    # Surface: the library's least squares; Vertices: the interpolation's method as requested.
    obj["pia_method"] = "LEAST_SQUARES" if report.mode == 'SURFACE' else str(settings["method"])
    obj["pia_iterations"] = int(report.iterations)
    obj["pia_fit"] = str(report.mode)
    obj["pia_fit_target"] = str(settings["target"])
    obj["pia_fit_rounds"] = int(report.rounds)
    obj["pia_fit_sample_count"] = int(report.sample_count)
    for when, d in (("before", report.before), ("after", report.after)):
        obj["pia_fit_mean_%s" % when] = float(d.mean)
        obj["pia_fit_p95_%s" % when] = float(d.p95)
        obj["pia_fit_max_%s" % when] = float(d.max)
        obj["pia_fit_ignored_%s" % when] = int(d.ignored)
    # The other way: the scan's vertices to the limit surface; "unreached"
    # is the share of them farther than the cut-off.
    scan_points = int(report.scan_point_count)
    obj["pia_fit_scan_points"] = scan_points
    if scan_points:
        for when, d in (("before", report.scan_before), ("after", report.scan_after)):
            obj["pia_fit_scan_mean_%s" % when] = float(d.mean)
            obj["pia_fit_scan_p95_%s" % when] = float(d.p95)
            obj["pia_fit_scan_max_%s" % when] = float(d.max)
            obj["pia_fit_scan_unreached_%s" % when] = float(d.ignored) / scan_points
    if report.folded_after >= 0 and report.sample_count:
        obj["pia_fit_folded_before"] = float(report.folded_before) / report.sample_count
        obj["pia_fit_folded_after"] = float(report.folded_after) / report.sample_count
    for key in ("fit_cutoff", "fit_smoothing", "fit_samples"):
        obj["pia_" + key] = settings[key]
    obj["pia_distance_scale"] = HEAT_SCALE
    mesh = obj.data
    distances = np.ascontiguousarray(report.vertex_distances, np.float32)
    write_heat_map(mesh, DISTANCE_ATTRIBUTE, COLOR_ATTRIBUTE, distances, heat_colors(distances))


def write_heat_map(mesh, distance_name, color_name, distances, colors):
    """The point attribute distance_name (float) and the colour attribute
    color_name (the active one, and the one rendered) on mesh, replacing
    attributes of those names.  Both are written under names of their own
    first and take the old ones' places only once whole: if writing fails,
    mesh's attributes are as they were."""
    written = []  # the names Blender gave the new attributes
    try:
        attr = mesh.attributes.new(distance_name + "_pia_new", 'FLOAT', 'POINT')
        written.append(attr.name)
        attr.data.foreach_set("value", np.ascontiguousarray(distances, np.float32))
        color = mesh.color_attributes.new(color_name + "_pia_new", 'FLOAT_COLOR', 'POINT')
        written.append(color.name)
        color.data.foreach_set("color", np.ascontiguousarray(colors, np.float32).ravel())
    except BaseException:
        for name in written:
            made = mesh.attributes.get(name)
            if made is not None:
                mesh.attributes.remove(made)
        raise
    # Adding or removing an attribute may move the others: each is looked
    # up by name again.
    for name in (distance_name, color_name):
        old = mesh.attributes.get(name)
        if old is not None:
            mesh.attributes.remove(old)
    mesh.attributes[written[0]].name = distance_name
    mesh.attributes[written[1]].name = color_name
    mesh.color_attributes.active_color = mesh.color_attributes[color_name]
    if hasattr(mesh.color_attributes, "render_color_index"):
        mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
    mesh.update()


def paint_scan(target, report):
    """Writes report's scan distances onto the target's mesh: the point
    attribute pia_scan_distance (relative to the scan's diagonal; -1 for
    vertices no face uses) and its heat map pia_scan_distance_color (the
    active colour attribute; grey where not measured).  The scan changes in
    nothing else.  Returns None when painted, else why not (the scan is left
    as it was)."""
    distances = getattr(report, "scan_distances", None)
    if distances is None:
        return "no distances from the scan were measured (Catmull-Clark fits measure them)"
    mesh = target.data
    if mesh.library is not None:
        return "the scan's mesh is linked from a library"
    if target.mode == 'EDIT' or mesh.is_editmode:
        return "the scan is in Edit Mode"
    if len(mesh.vertices) != len(distances):
        return ("its modifiers change its vertices (%d measured, the mesh has %d)"
                % (len(distances), len(mesh.vertices)))
    colors = heat_colors(np.maximum(distances, 0.0))
    colors[distances < 0.0] = UNMEASURED_COLOR
    write_heat_map(mesh, SCAN_DISTANCE_ATTRIBUTE, SCAN_COLOR_ATTRIBUTE, distances, colors)
    return None


def write_unreachable_group(obj, report):
    """The vertex group UNREACHABLE_GROUP of obj: exactly the report's
    unreachable vertices, weight 1 (made active, for Select in Edit Mode);
    removed when there are none.  Vertex groups live on the mesh (Blender
    3.0 and later), so a mesh copied from a source brings the source's
    groups along, a `pia_unreachable` of its own among them (a cage made
    from a cage): the group is emptied of every vertex before the flagged
    ones are added.  Returns the group or None."""
    flags = getattr(report, "unreachable", None)
    indices = [] if flags is None else report.unreachable_indices.tolist()
    group = obj.vertex_groups.get(UNREACHABLE_GROUP)
    if not indices:
        if group is not None:
            obj.vertex_groups.remove(group)
        return None
    if group is None:
        group = obj.vertex_groups.new(name=UNREACHABLE_GROUP)
    group.remove(list(range(len(obj.data.vertices))))
    group.add(indices, 1.0, 'REPLACE')
    obj.vertex_groups.active_index = group.index
    return group


def store_report(obj, report, settings):
    """A solve's figures on obj (custom properties: pia_iterations,
    pia_max_error, pia_mean_error, pia_status, pia_method,
    pia_unreachable_count and, while there are unreachable vertices,
    pia_reachable_max_error) and its unreachable vertices (the vertex group
    pia_unreachable); a fit's through store_fit.  Used by build_object and
    by each update of a live cage."""
    if isinstance(report, native.FitReport):
        store_fit(obj, report, settings)
        return
    obj["pia_iterations"] = int(report.iterations)
    obj["pia_max_error"] = float(report.max_error_relative)
    obj["pia_mean_error"] = float(report.mean_error_relative)
    obj["pia_status"] = str(report.status)
    obj["pia_method"] = str(report.method)
    obj[UNREACHABLE_COUNT] = int(report.unreachable_count)
    if report.unreachable_count:
        obj[REACHABLE_MAX_ERROR] = float(report.reachable_max_error_relative)
    elif REACHABLE_MAX_ERROR in obj:
        del obj[REACHABLE_MAX_ERROR]
    write_unreachable_group(obj, report)


def build_object(source, cage, report, settings, context=None, name=None, mesh=None, limit=None):
    """New object with the cage positions on a copy of source's mesh (or on mesh).

    Catmull-Clark: with a limit-surface Subdivision Surface modifier.
    Loop, Doo-Sabin: no modifier; limit = limit_arrays' output goes to a
    `_limit` child.  A mesh passed in becomes the new object's.  If anything
    here fails, what it made (and the mesh passed in) is removed again
    before the error is raised.
    """
    context = context or bpy.context
    name = name or source.name + "_pia"
    if mesh is None:
        mesh = source.data.copy()
    new_obj = None
    try:
        mesh.name = name
        write_positions(mesh, cage)
        new_obj = bpy.data.objects.new(name, mesh)
        _dress_object(source, new_obj, report, settings, context, limit)
    except BaseException:
        discard_object(new_obj, mesh)
        raise
    return new_obj


def discard_object(obj, mesh=None):
    """Removes obj (may be None), its `_limit` child and their meshes, and
    mesh, where nothing else uses them: undoes build_object."""
    meshes = {} if mesh is None else {mesh.as_pointer(): mesh}
    if obj is not None:
        child = find_limit_object(obj)
        for o in ((child,) if child is not None else ()) + (obj,):
            if o.data is not None:
                meshes[o.data.as_pointer()] = o.data
            bpy.data.objects.remove(o)
    for m in meshes.values():
        if m.users == 0:
            bpy.data.meshes.remove(m)


def _dress_object(source, new_obj, report, settings, context, limit):
    """build_object's placement, modifier, properties, limit child and selection."""
    _link_like(source, new_obj, context)

    if settings["scheme"] == 'CATMULL_CLARK':
        mod = new_obj.modifiers.new("Subdivision", 'SUBSURF')
        mod.subdivision_type = 'CATMULL_CLARK'
        mod.use_limit_surface = True
        mod.levels = settings["levels"]
        mod.render_levels = settings["render_levels"]
        mod.quality = settings["quality"]
        mod.boundary_smooth = settings["boundary_smooth"]
        mod.use_creases = settings["use_creases"]
        if hasattr(mod, "use_adaptive_subdivision"):  # 5.0+: Cycles' dicing, not the limit surface
            mod.use_adaptive_subdivision = False
        src_mod = find_subsurf(source)
        if src_mod is not None:
            mod.uv_smooth = src_mod.uv_smooth
            mod.show_only_control_edges = src_mod.show_only_control_edges

    store_report(new_obj, report, settings)
    new_obj["pia_tolerance"] = float(settings["tolerance"])
    for key in STORED_SETTINGS:
        if key not in ("method", "tolerance"):  # pia_method is the method used
            value = settings[key]
            new_obj["pia_" + key] = value if isinstance(value, (bool, int, float, str)) else str(value)
    new_obj["pia_requested_method"] = str(settings["method"])
    new_obj["pia_source"] = source.name  # what a Live cage follows (live.py)
    if settings["scheme"] == 'CATMULL_CLARK':
        # Which OpenSubdiv's rules the cage was made for (Blender 5.1 and
        # later differ from earlier ones at some non-manifold vertices).
        new_obj["pia_opensubdiv_version"] = opensubdiv_version_string(opensubdiv_version_of(settings))

    if limit is not None:
        set_limit_object(new_obj, limit, context=context)

    view_layer = context.view_layer
    if view_layer is not None:
        for obj in (source, new_obj):
            try:
                obj.select_set(obj is new_obj, view_layer=view_layer)
            except RuntimeError:  # not in this view layer (excluded collection)
                pass
        if view_layer.objects.get(new_obj.name) is not None:
            view_layer.objects.active = new_obj
    return new_obj


def interpolate(obj, *, context=None, name=None, progress=None, live=False, **settings):
    """Make an interpolating cage object for the mesh object obj.

    Settings (keywords, defaults in DEFAULT_SETTINGS; names as the modifier's):
    scheme ('CATMULL_CLARK', 'LOOP' or 'DOO_SABIN'), levels, render_levels, quality,
    boundary_smooth, use_creases, method, tolerance (relative to the
    bounding-box diagonal), max_iterations; for Loop also boundary_rule
    ('SMOOTH' or 'HOPPE') and triangulate (use a triangulated copy of a mesh
    that has quads or n-gons); for Doo-Sabin (closed meshes) shape_parameter
    in (0, 1) and shape_attribute (a float FACE attribute whose per-face
    values replace shape_parameter where the mesh has it); for Catmull-Clark
    opensubdiv_version (e.g. '3.7.0'; empty: this Blender's), the OpenSubdiv
    whose rules the modifier that shows the cage follows: Blender 5.1 and
    later (3.7.0) evaluate some non-manifold vertices differently from
    earlier Blenders, so a cage is exact in the Blenders of its version.
    Settings not given are taken from obj's
    Subdivision Surface modifier if it has one, else the defaults.

    cleanup=True interpolates a cleaned copy of obj's mesh (cleaned_copy,
    cleanup.clean): vertices closer than cleanup_distance x bounding-box
    diagonal merged, repeated corners dissolved, degenerate, zero-area and
    loose geometry removed, faces turned to one orientation per part. The
    new object has the cleaned topology; what was cleaned is in its custom
    properties pia_cleanup_<count> (format_cleanup says it in words).

    Loop: the cage has no modifier; its child ``<cage>_limit`` (find it
    with find_limit_object) holds the Loop limit surface refined `levels`
    times, whose first vertices are the limit points of the cage vertices.
    Doo-Sabin: likewise, the child holds the cage refined `levels` times (a
    control mesh whose face centroids lie on the limit surface).

    Fitting to a scan: target (a mesh object or its name; its evaluated
    mesh, read in obj's object space) fits the cage to that surface instead
    of interpolating obj's vertices: fit 'SURFACE' (Catmull-Clark: the whole
    limit surface, least squares over fit_samples**2 samples per face) or
    'VERTICES' (each control vertex's limit point moves to its closest point
    on the target; any scheme). fit_cutoff (relative to the target's
    bounding-box diagonal): samples farther away do not pull (holes);
    fit_smoothing: fairness weight. The report is then a native.FitReport
    (before/after distances relative to the target's diagonal), and the new
    object has the point attributes pia_distance (per vertex, relative) and
    pia_distance_color (heat map, the active colour attribute).
    fit_paint_scan=True also writes each scan vertex's distance to the
    fitted surface onto the target's mesh (paint_scan: pia_scan_distance and
    its heat map pia_scan_distance_color), which changes the target in
    nothing else; pia_fit_scan_painted on the new object says whether it
    could (not through modifiers that change the scan's vertices, nor in
    Edit Mode), pia_fit_scan_not_painted why not.

    progress(iteration, relative_error) -> bool: return True to cancel
    (for a Surface fit: progress(round, mean relative distance)); while a
    Loop or Doo-Sabin preview is refined, it is called again with the
    solve's last figures about every 0.1 s.

    live=True turns the new cage's Live switch on (live.set_live): every
    later change of obj's vertex positions solves the cage again, in place.

    Returns (new_object, report); report.converged is False when the tolerance
    was not reached (the object is made anyway). Raises ValueError or
    native.PiaError on bad input, RuntimeError if the library is missing;
    nothing is created then and obj is never changed.
    """
    return run_steps(interpolate_steps(obj, context=context, name=name, progress=progress, live=live, **settings))


def run_steps(steps):
    """Drives a generator of interpolate_steps' kind on this thread: each
    function it yields is called at once and its result (or exception) sent
    back; returns what the generator returns."""
    try:
        work = next(steps)
        while True:
            try:
                result = work()
            except BaseException as error:  # into the steps, which clean up and re-raise
                work = steps.throw(error)
            else:
                work = steps.send(result)
    except StopIteration as stop:
        return stop.value


def interpolate_steps(obj, *, context=None, name=None, progress=None, live=False, **settings):
    """interpolate as a generator: Blender's data is read and written in the
    generator itself; the library's work (building the scan, solving or
    fitting: all of the time that grows with the mesh) is yielded as
    functions that touch nothing of Blender's, whose results (or exceptions)
    the driver sends back.  run_steps calls them at once (interpolate);
    InterpolateJob calls them on another thread so that Blender's window
    stays live and Esc can cancel.  Returns (new_object, report)."""
    check_source(obj)
    _require_library()
    if obj.mode == 'EDIT':  # edits live in the edit-mesh until synced
        obj.update_from_editmode()
        check_source(obj)
    merged = settings_from_modifier(obj)
    merged.update(settings)
    s = check_settings(merged)
    if live and s["cleanup"]:
        raise ValueError(LIVE_CLEANUP_MESSAGE % obj.name)
    loop = s["scheme"] == 'LOOP'
    separate_limit = s["scheme"] in LIMIT_SCHEMES
    target = find_target(obj, s)
    refining = None
    if progress is not None and separate_limit:
        user, last = progress, [0, 0.0]

        def progress(iteration, value):  # the solve's: remembered for the refinement's calls
            last[:] = iteration, value
            return user(iteration, value)

        def refining(_level, _share):  # the solve's last figures again, so that a cancel is heard
            return user(*last)
    scan = (yield scan_work(target, obj, context, progress)) if target is not None else None
    mesh = None
    made = []  # meshes made here: removed again on failure
    stats = None
    try:
        if s["cleanup"]:
            mesh, stats = cleaned_copy(obj.data, s["cleanup_distance"])
            made.append(mesh)
        data = mesh if mesh is not None else obj.data
        if loop and s["triangulate"] and non_triangle_count(data):
            mesh = triangulated_copy(data)
            made.append(mesh)
            data = mesh
        try:
            run, explain = prepare_cage(obj, s, progress=progress, mesh=mesh, scan=scan)
            try:
                cage, report = yield run
            except native.PiaError as error:
                named = explain(error)
                if named is None:
                    raise
                raise named from None
            limit = (yield limit_work(data, s, cage, progress=refining)) if separate_limit else None
        except native.PiaError as error:
            hinted = cleanup_hint(error, data, s)
            if hinted is not None:
                raise hinted from None
            raise
    except BaseException:
        for made_mesh in made:
            try:
                bpy.data.meshes.remove(made_mesh)
            except ReferenceError:  # gone already (an undo while a job worked)
                pass
        raise
    for made_mesh in made[:-1]:  # the cleaned copy, once triangulated
        bpy.data.meshes.remove(made_mesh)
    view_layer = (context or bpy.context).view_layer
    selection = (obj.select_get(view_layer=view_layer), view_layer.objects.active) if view_layer else None
    new_obj = build_object(obj, cage, report, s, context=context, name=name, mesh=mesh, limit=limit)
    from . import live as live_module
    try:
        if stats is not None:
            store_cleanup(new_obj, stats)
        if live:
            live_module.set_live(new_obj, True, source=obj)
        if target is not None and s["fit_paint_scan"]:  # last: the one step that writes to another object
            why_not = paint_scan(target, report)
            new_obj["pia_fit_scan_painted"] = why_not is None
            if why_not is not None:
                new_obj["pia_fit_scan_not_painted"] = "The scan '%s' was not painted: %s" % (target.name, why_not)
    except BaseException:
        if live:
            live_module.set_live(new_obj, False)
        discard_object(new_obj)
        if selection is not None and view_layer.objects.get(obj.name) is not None:  # as before build_object
            obj.select_set(selection[0], view_layer=view_layer)
            view_layer.objects.active = selection[1]
        raise
    return new_obj, report


class _JobProgress:
    """What an InterpolateJob's steps and its library thread share: the last
    progress call and the cancel flag (apart from the job, so that a job
    dropped by its caller is freed, and its steps closed, at once and on the
    caller's thread)."""

    def __init__(self, user_progress):
        self.iteration = 0
        self.value = 0.0
        self.calls = 0
        self.user_progress = user_progress
        self.cancel = threading.Event()

    def __call__(self, iteration, value):
        self.iteration, self.value = iteration, value
        self.calls += 1
        if self.user_progress is not None and self.user_progress(iteration, value):
            self.cancel.set()
        return self.cancel.is_set()


def _id_key(obj):
    """(name, address) of a Blender object, to tell later that it is still the same one."""
    return (obj.name, obj.as_pointer()) if obj is not None else None


def _same_id(key):
    if key is None:
        return True
    found = bpy.data.objects.get(key[0])
    return found is not None and found.as_pointer() == key[1]


class _StepsJob:
    """A generator of interpolate_steps' kind driven with the library's work
    on a thread of its own (InterpolateJob, RefreshLimitJob: see there).
    make_steps(progress) makes the generator; watched are the objects that
    must stay the same ones while the library works."""

    def __init__(self, make_steps, watched, progress):
        self._state = _JobProgress(progress)
        self._thread = None
        self._outcome = None
        self._done = False
        self._result = None
        self._error = None
        self._watched = [_id_key(o) for o in watched]
        self._steps = make_steps(self._state)
        self._advance(lambda: next(self._steps))

    @property
    def iteration(self):
        return self._state.iteration

    @property
    def value(self):
        return self._state.value

    @property
    def calls(self):
        return self._state.calls

    def _advance(self, step):
        """Runs step() (a move of the steps, here) and starts the work it yields."""
        try:
            work = step()
        except StopIteration as stop:
            self._done, self._result = True, stop.value
            return
        except BaseException as error:
            self._done, self._error = True, error
            raise
        outcome = self._outcome = [None]  # the thread holds this, not the job

        def target():
            try:
                outcome[0] = (True, work())
            except BaseException as error:  # handed to the steps by poll()
                outcome[0] = (False, error)
        self._thread = threading.Thread(target=target, name="subdiv_pia", daemon=True)
        self._thread.start()

    def cancel(self):
        self._state.cancel.set()

    @property
    def cancelled(self):
        return self._state.cancel.is_set()

    @property
    def done(self):
        return self._done

    def working(self):
        """True while the library's thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def poll(self):
        """None while the library works; then what the steps return
        (InterpolateJob: (new_object, report); RefreshLimitJob: the child),
        or the exception they raise (again at every later call).  Call it
        on Blender's thread."""
        if self._done:
            if self._error is not None:
                raise self._error
            return self._result
        if self.working():
            return None
        self._thread.join()
        self._thread = None
        ok, value = self._outcome[0]
        self._outcome = None
        if ok and self.cancelled:
            ok, value = False, native.PiaCancelled("CANCELLED", "cancelled")
        if not all(_same_id(key) for key in self._watched):
            ok, value = False, native.PiaCancelled(
                "CANCELLED", "cancelled: the source, the scan or the cage was changed (undone, deleted or "
                "renamed) while the library worked")
        if ok:
            self._advance(lambda: self._steps.send(value))
        else:
            self._advance(lambda: self._steps.throw(value))
        return self._result if self._done else None

    def wait(self, interval=0.01):
        """poll() until the job is done; returns its result."""
        while True:
            result = self.poll()
            if self._done:
                return result
            if self._thread is not None:
                self._thread.join(interval)

    def close(self):
        """Abandons the job (waiting for the library to stop): what it made
        so far (interpolate's cleaned copy of the mesh) is removed."""
        self._state.cancel.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if not self._done:
            self._done = True
            self._steps.close()

    def __del__(self):
        # Dropped unfinished: the library stops at its next progress call.
        state = getattr(self, "_state", None)
        if state is not None:
            state.cancel.set()


class InterpolateJob(_StepsJob):
    """interpolate with the library's work on a thread of its own, for a
    caller that must stay responsive (the operator's modal run in Blender's
    window): Blender's data is read and written only on the caller's thread,
    in the constructor (bad input raises there, as interpolate does) and in
    poll().

    cancel() makes the library stop at its next progress call (a fit's or
    solve's: a few tenths of a second apart at any scale; a Loop or
    Doo-Sabin preview's refinement's: see native.refine); poll()
    then raises native.PiaCancelled, and nothing is made.  A cancel that
    comes after the library has finished, but before poll() saw it, cancels
    as well; so does a change of the source or the scan beneath the job (an
    undo, a deletion), found when poll() resumes it.  close() abandons a job
    that has not finished (waiting for the library to stop): what it made
    so far is removed; call it, or poll() to the end, before dropping a job.

    progress (optional), as interpolate's, is called on the library's thread
    too: it must not touch Blender's data.  iteration and value hold the last
    progress call's arguments.  There is no context argument: an operator's
    context lasts only as long as the call it was given to, so each step
    reads bpy.context as it runs."""

    def __init__(self, obj, *, name=None, progress=None, live=False, **settings):
        target = settings.get("target")
        if isinstance(target, str):
            target = bpy.data.objects.get(target) if target else None
        watched = (obj, target) if isinstance(target, bpy.types.Object) else (obj,)
        super().__init__(lambda state: interpolate_steps(obj, name=name, progress=state, live=live, **settings),
                         watched, progress)


class RefreshLimitJob(_StepsJob):
    """refresh_limit with the refinement on a thread of its own, as
    InterpolateJob runs interpolate (the operator's modal run in Blender's
    window): poll() gives the `_limit` child once done; cancel() stops the
    refinement at its next progress call and leaves the child as it was.
    progress(level, share_done) -> bool is native.refine's, called on the
    library's thread."""

    def __init__(self, obj, *, progress=None):
        cage = limit_cage_of(obj) if obj is not None else None
        super().__init__(lambda state: refresh_limit_steps(obj, progress=state),
                         (cage,) if cage is not None else (), progress)


def refresh_limit(obj, context=None):
    """Recompute the limit surface of a Loop or Doo-Sabin cage from its current mesh.

    obj is the cage (pia_scheme 'LOOP' or 'DOO_SABIN') or its `_limit` child.
    The child's mesh is replaced (the child is made again if it was deleted);
    the settings are those stored on the cage, and a Doo-Sabin cage's shape
    parameters are read again from its own face attribute. Returns the child.
    Raises ValueError if obj is not such a cage, native.PiaError if the
    library refuses the edited cage (nothing is changed then).
    """
    return run_steps(refresh_limit_steps(obj, context=context))


def refresh_limit_steps(obj, *, context=None, progress=None):
    """refresh_limit as a generator of interpolate_steps' kind: the
    refinement is yielded as a function that touches nothing of Blender's
    (RefreshLimitJob runs it on another thread).  progress(level,
    share_done) -> bool as native.refine's.  Returns the child."""
    if obj is None:
        raise ValueError("No active object: select a Loop or Doo-Sabin cage or its limit surface")
    cage = limit_cage_of(obj)
    if cage is None:
        raise ValueError("'%s' is not a Loop cage or a Doo-Sabin cage: make one with "
                         "Make Interpolating Cage (scheme Loop or Doo-Sabin), or select "
                         "its limit surface" % obj.name)
    if cage.type != 'MESH':
        raise ValueError("'%s' is not a mesh object (type %s)" % (cage.name, cage.type))
    if cage.mode == 'EDIT':
        cage.update_from_editmode()
    check_source(cage)
    limit = yield limit_work(cage.data, stored_settings(cage), progress=progress)
    return set_limit_object(cage, limit, context=context)


def format_fit_report(report, target_name):
    """One line for the status bar and the command line, for a fit."""
    b, a = report.before, report.after
    line = ("%s fit to '%s': mean distance %.2g (was %.2g), 95th percentile %.2g (was %.2g), "
            "max %.2g (was %.2g) of the scan's diagonal"
            % (FIT_NAMES.get(report.mode, report.mode), target_name, a.mean, b.mean, a.p95, b.p95,
               a.max, b.max))
    if report.mode == 'SURFACE':
        line += ", %d round%s" % (report.rounds, "" if report.rounds == 1 else "s")
    else:
        line += ", %d iterations" % report.iterations
    if a.ignored:
        line += "; %d of %d samples beyond the cut-off ignored" % (a.ignored, report.sample_count)
    if report.scan_point_count:
        s = report.scan_after
        line += ("; scan to surface: mean %.2g, 95th percentile %.2g, max %.2g, %.2g%% of the scan "
                 "farther than the cut-off" % (s.mean, s.p95, s.max, 100.0 * s.ignored / report.scan_point_count))
    if report.folded_after > 0 and report.sample_count:
        line += "; %.2g%% of the samples face away from the scan" % (100.0 * report.folded_after / report.sample_count)
    if report.status != 'CONVERGED':
        line += " (%s: %s)" % (report.status.lower().replace("_", " "), report.message)
    return line


def report_converged(report):
    """True unless an interpolation or a fit stopped short of its tolerance."""
    return report.status == 'CONVERGED'


def format_unreachable(count, reachable_max_error):
    """What a result says of its unreachable vertices ('' when there are none)."""
    if not count:
        return ""
    return ("%d %s cannot be reached (in the vertex group '%s'); max error on the others %.3g of the "
            "bounding-box diagonal" % (count, "vertex" if count == 1 else "vertices", UNREACHABLE_GROUP,
                                       reachable_max_error))


def format_report(report):
    """One line for the status bar and the command line."""
    if report.converged:
        head = "Converged"
    elif report.status == 'STAGNATED':
        head = "Stagnated (tolerance not reached)"
    else:
        head = "Stopped at max iterations (tolerance not reached)"
    line = ("%s: %d iterations (%s), max error %.3g, mean error %.3g of the bounding-box diagonal"
            % (head, report.iterations, report.method,
               report.max_error_relative, report.mean_error_relative))
    if report.stage_iterations[0] > 0:
        line += "; boundary first: %d + %d iterations" % tuple(report.stage_iterations)
    unreachable = format_unreachable(report.unreachable_count, report.reachable_max_error_relative)
    if unreachable:  # the library's message says the same at more length
        line += "; " + unreachable
    elif not report.converged and report.message:
        line += " (%s)" % report.message
    return line
