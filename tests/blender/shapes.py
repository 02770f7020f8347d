# SPDX-License-Identifier: GPL-3.0-or-later
"""Generated test shapes. Each function builds one mesh object, links it to the
scene, makes it active and returns it. Vertices are jittered (fixed seed) so
the cage differs from the mesh everywhere."""

import bmesh
import bpy
import numpy as np

from conftest import link_and_activate, object_from_pydata

CREASE_VALUES = (0.3, 0.5, 0.9, 1.0)


def jitter(obj, amount=0.05, seed=1):
    mesh = obj.data
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    rng = np.random.default_rng(seed)
    co += rng.uniform(-amount, amount, co.shape).astype(np.float32)
    mesh.vertices.foreach_set("co", co)
    mesh.update()
    return obj


def set_edge_creases(mesh, values):
    values = np.ascontiguousarray(values, np.float32)
    if bpy.app.version >= (4, 0, 0):
        attr = mesh.attributes.get("crease_edge") or mesh.attributes.new("crease_edge", 'FLOAT', 'EDGE')
        attr.data.foreach_set("value", values)
    else:
        mesh.edges.foreach_set("crease", values)
    mesh.update()


def set_vertex_creases(mesh, values):
    values = np.ascontiguousarray(values, np.float32)
    if bpy.app.version >= (4, 0, 0):
        attr = mesh.attributes.get("crease_vert") or mesh.attributes.new("crease_vert", 'FLOAT', 'POINT')
        attr.data.foreach_set("value", values)
    else:
        bm = bmesh.new()
        bm.from_mesh(mesh)
        layer = bm.verts.layers.crease.verify()
        for vert, value in zip(bm.verts, values.tolist()):
            vert[layer] = value
        bm.to_mesh(mesh)
        bm.free()
    mesh.update()


def _from_bmesh(name, build):
    bm = bmesh.new()
    build(bm)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    return link_and_activate(bpy.data.objects.new(name, mesh))


def _subdivided_cube(bm, cuts=2):
    bmesh.ops.create_cube(bm, size=2.0)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)


def plain_cube():
    """The 8-vertex cube: its limit matrix is singular (the alternating
    +1/-1 mode maps to 0: (9 - 4*3 + 3) / 24), so it cannot be interpolated."""
    bpy.ops.mesh.primitive_cube_add()
    return jitter(bpy.context.active_object)


def cube():
    """Cube cut once: eight valence-3 extraordinary vertices among valence-4 ones."""
    return jitter(_from_bmesh("Cube", lambda bm: _subdivided_cube(bm, cuts=1)))


def uv_sphere():
    """Quads with triangle fans around two valence-10 poles."""
    bpy.ops.mesh.primitive_uv_sphere_add(segments=10, ring_count=6)
    return jitter(bpy.context.active_object)


def ico_sphere():
    """Triangles only, valence 5 and 6."""
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2)
    return jitter(bpy.context.active_object, 0.03)


def ngon_cylinder():
    """Quads around two 7-gon caps."""
    bpy.ops.mesh.primitive_cylinder_add(vertices=7, end_fill_type='NGON')
    return jitter(bpy.context.active_object)


def open_grid():
    """Open quad grid: boundary edges and four valence-2 corners."""
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=5, y_subdivisions=4, size=2.0)
    return jitter(bpy.context.active_object, 0.1)


def edge_creases():
    """Semi-sharp and sharp edge creases (0.3, 0.5, 0.9, 1.0) on a subdivided cube."""
    obj = jitter(_from_bmesh("EdgeCreases", _subdivided_cube))
    values = np.zeros(len(obj.data.edges), np.float32)
    values[::3] = np.resize(np.array(CREASE_VALUES, np.float32), len(values[::3]))
    set_edge_creases(obj.data, values)
    return obj


def vertex_creases():
    """Vertex creases 0.3 .. 1.0 on a subdivided cube, with one creased edge loop."""
    obj = jitter(_from_bmesh("VertexCreases", _subdivided_cube))
    values = np.zeros(len(obj.data.vertices), np.float32)
    values[::5] = np.resize(np.array(CREASE_VALUES, np.float32), len(values[::5]))
    set_vertex_creases(obj.data, values)
    return obj


def loose_parts():
    """A cube plus loose vertices, a loose edge chain and a loose edge hanging off a face vertex."""
    verts = [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1),
             (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1),
             (3, 0, 0), (3, 1, 0),            # loose vertices
             (0, 3, 0), (0, 3, 1), (0, 4, 1),  # loose edge chain
             (2, 2, 2)]                        # end of an edge attached to vertex 6
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    edges = [(10, 11), (11, 12), (6, 13)]
    return jitter(object_from_pydata("LooseParts", verts, faces, edges))


def fin():
    """Non-manifold: three quads share one edge (a strip with a fin)."""
    verts = [(0, 0, 0), (0, 1, 0),                  # shared edge
             (1, 0, 0), (1, 1, 0), (-1, 0, 0), (-1, 1, 0), (0, 0, 1), (0, 1, 1),
             (2, 0, 0), (2, 1, 0), (-2, 0, 0), (-2, 1, 0)]
    faces = [(0, 2, 3, 1), (4, 0, 1, 5), (0, 1, 7, 6), (2, 8, 9, 3), (10, 4, 5, 11)]
    return jitter(object_from_pydata("Fin", verts, faces))


def double_sided_fins():
    """Non-manifold: double-sided triangle fins (a triangle and its reversed
    twin, as scans have them) hanging from two edges of the centre of a 2 x 2
    grid. OpenSubdiv 3.6.0 leaves the centre smooth, 3.7.0 (Blender 5.1 and
    later) makes it infinitely sharp."""
    verts = [(x, y, 0.1 * ((3 * x + 5 * y) % 3)) for y in range(3) for x in range(3)]
    verts += [(1.5, 1.2, 1.0), (0.8, 1.5, 0.9)]
    faces = [(0, 1, 4, 3), (1, 2, 5, 4), (3, 4, 7, 6), (4, 5, 8, 7),
             (4, 5, 9), (4, 9, 5), (4, 10, 7), (4, 7, 10)]
    # Not validated: that would take the twins for duplicates and drop them.
    return jitter(object_from_pydata("DoubleSidedFins", verts, faces, validate=False))


def creased_pages():
    """Non-manifold creases with semi-sharp features: three sheets meeting
    along a spine of four vertices, a double-sided triangle fin hanging
    from the spine's middle edge (listed first, so that the two middle
    spine vertices are evaluated on it), edge creases across the spine and
    a vertex crease on it. The middle spine vertices are on a non-manifold
    crease for OpenSubdiv 3.6.0 and older, with the fin's span ending twice
    at one edge; 3.7.0 (Blender 5.1 and later) makes them infinitely sharp."""
    verts = [(0.2 * z * z, 0.1 * z, z) for z in range(4)]
    verts.append((0.7, -0.6, 1.5))  # the fin's tip, vertex 4
    faces = [(1, 2, 4), (2, 1, 4)]
    for sheet in range(3):
        a = 2.1 * sheet
        first = len(verts)
        for w in (1, 2):
            for z in range(4):
                verts.append((0.2 * z * z + w * np.cos(a), 0.1 * z + w * np.sin(a), z + 0.1 * w * sheet))

        def at(w, z):
            return z if w == 0 else first + (w - 1) * 4 + z
        for w in range(2):
            for z in range(3):
                quad = (at(w, z), at(w + 1, z), at(w + 1, z + 1), at(w, z + 1))
                faces.append(quad[::-1] if sheet == 1 else quad)
    # Not validated: that would take the fin's twin for a duplicate.
    obj = jitter(object_from_pydata("CreasedPages", verts, faces, validate=False), 0.03)
    mesh = obj.data
    # Sharpness 0.9 to 2.5 (10 c^2), gone within three levels: at quality 6
    # Blender still takes the fin's span at the isolation level, three
    # levels below where the creases have gone.
    across = {frozenset((1, 5 + 8 * s + 1)): 0.3 + 0.1 * s for s in range(3)}
    across[frozenset((2, 5 + 2))] = 0.3
    set_edge_creases(mesh, [across.get(frozenset(e.vertices), 0.0) for e in mesh.edges])
    vertex = np.zeros(len(mesh.vertices), np.float32)
    vertex[2] = 0.5
    set_vertex_creases(mesh, vertex)
    return obj


def mixed():
    """Triangles, quads and an n-gon in one open surface."""
    verts = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0.3), (2, 1, 0),
             (0, 2, 0), (1, 2, 0), (2, 2, 0.2), (3, 0.5, 0), (3, 1.5, 0.1)]
    faces = [(0, 1, 4, 3), (1, 2, 5, 4), (3, 4, 7, 6), (4, 5, 8), (4, 8, 7),
             (2, 9, 10, 8, 5)]
    return jitter(object_from_pydata("Mixed", verts, faces))


ALL = (cube, uv_sphere, ico_sphere, ngon_cylinder, open_grid, edge_creases,
       vertex_creases, loose_parts, fin, double_sided_fins, creased_pages, mixed)


def quad_sphere(name="Cage", cuts=3, radius=1.0):
    """A cube cut `cuts` times and pushed onto a sphere: all quads, eight
    valence-3 vertices; its vertices lie on the sphere, as if shrinkwrapped."""
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=2.0)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)
    for vert in bm.verts:
        vert.co = vert.co.normalized() * radius
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    return link_and_activate(bpy.data.objects.new(name, mesh))


def fine_sphere(name="Scan", segments=256, rings=128):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=segments, ring_count=rings, radius=1.0)
    scan = bpy.context.active_object
    scan.name = name
    return scan
