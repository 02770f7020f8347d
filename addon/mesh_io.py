# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender meshes in and out as flat numpy arrays, across the layouts of
Blender 3.4 to 5.x: vertex positions, faces, edges, creases, face
attributes, the evaluated mesh of a scan, and new meshes made from arrays
(a cleaned or triangulated copy, a limit surface).

Touches mesh data-blocks only, never objects' other data.
"""

import ctypes

import bmesh
import numpy as np
import bpy

from . import cleanup, native


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


def native_mesh(mesh):
    """native.Mesh of a Blender mesh's data (positions, faces, edges, creases)."""
    arrays = mesh_arrays(mesh)
    return native.Mesh(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"],
                       edges=arrays["edges"],
                       edge_creases=arrays["edge_creases"],
                       vertex_creases=arrays["vertex_creases"])


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


_LOOP_TOTAL_READ_ONLY = bpy.types.MeshPolygon.bl_rna.properties["loop_total"].is_readonly


def new_mesh(name, points, face_sizes, face_vertices):
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
    copy = new_mesh(name or mesh.name + "_clean", result["positions"], result["face_sizes"],
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
