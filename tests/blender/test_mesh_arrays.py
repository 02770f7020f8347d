# SPDX-License-Identifier: GPL-3.0-or-later
"""Reading a mesh into flat arrays: face order, loops stored out of order,
creases from Blender's own storage, whole arrays read at once as item by item."""

import numpy as np

import shapes
import subdiv_pia
from subdiv_pia import api, mesh_io


class _Collection:
    def __init__(self, **arrays):
        self.arrays = {k: np.asarray(v) for k, v in arrays.items()}
        self.length = len(next(iter(self.arrays.values())))

    def __len__(self):
        return self.length

    def __getitem__(self, i):
        return object()

    def foreach_get(self, name, out):
        out[:] = self.arrays[name].ravel()


class _Mesh:
    """Just what api.mesh_arrays reads; loops deliberately not in face order."""

    def __init__(self):
        # face 0 = (0, 1, 2, 3) stored at loops 3..6, face 1 = (1, 4, 2) at loops 0..2
        self.vertices = _Collection(co=np.arange(15, dtype=np.float32).reshape(5, 3))
        self.polygons = _Collection(loop_start=[3, 0], loop_total=[4, 3])
        self.loops = _Collection(vertex_index=[1, 4, 2, 0, 1, 2, 3])
        self.edges = _Collection(vertices=[[0, 1], [1, 2], [2, 3], [3, 0], [1, 4], [4, 2]])


def test_loops_out_of_face_order_are_gathered():
    arrays = api.mesh_arrays(_Mesh())
    assert arrays["face_sizes"].tolist() == [4, 3]
    assert arrays["face_vertices"].tolist() == [0, 1, 2, 3, 1, 4, 2]
    assert arrays["face_vertices"].dtype == np.int32 and arrays["face_vertices"].flags.c_contiguous
    assert arrays["positions"].shape == (5, 3) and arrays["positions"].dtype == np.float32
    assert arrays["edges"].shape == (6, 2)
    assert arrays["edge_creases"] is None and arrays["vertex_creases"] is None


def test_real_mesh_arrays_match_polygons():
    obj = shapes.ngon_cylinder()
    arrays = api.mesh_arrays(obj.data)
    expected = [v for p in obj.data.polygons for v in p.vertices]
    assert arrays["face_vertices"].tolist() == expected
    assert arrays["face_sizes"].tolist() == [len(p.vertices) for p in obj.data.polygons]


def test_creases_are_read():
    obj = shapes.edge_creases()
    edge, vertex = api.read_creases(obj.data)
    assert vertex is None
    assert sorted(set(np.round(edge.astype(float), 4).tolist())) == [0.0, 0.3, 0.5, 0.9, 1.0]
    obj = shapes.vertex_creases()
    edge, vertex = api.read_creases(obj.data)
    assert edge is None
    assert len(vertex) == len(obj.data.vertices)
    assert sorted(set(np.round(vertex.astype(float), 4).tolist())) == [0.0, 0.3, 0.5, 0.9, 1.0]
    # the copy on the new object carries them along
    new_obj, _ = subdiv_pia.interpolate(obj)
    np.testing.assert_array_equal(api.read_creases(new_obj.data)[1], vertex)


def _degenerate_faces():
    """Faces of two corners and one repeated corner, as from_pydata leaves them without validate()."""
    from conftest import object_from_pydata
    return object_from_pydata("Degenerate", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)],
                              [(0, 1, 2, 3), (1, 4), (1, 4, 4, 2), (0, 3, 2)], validate=False)


def _item_by_item(monkeypatch):
    """Make mesh_io read every array element by element, as it does where Blender
    keeps them neither as attributes nor as arrays it can copy at once."""
    monkeypatch.setattr(mesh_io, "_builtin_attribute", lambda *args: None)
    monkeypatch.setattr(mesh_io, "_items_array", lambda *args: None)


def test_arrays_read_at_once_are_those_read_item_by_item(monkeypatch):
    objects = [make() for make in shapes.ALL] + [_degenerate_faces()]
    at_once = [api.mesh_arrays(obj.data) for obj in objects]
    _item_by_item(monkeypatch)
    for obj, fast in zip(objects, at_once):
        slow = api.mesh_arrays(obj.data)
        for key, value in slow.items():
            if value is None:
                assert fast[key] is None, (obj.name, key)
                continue
            assert fast[key].dtype == value.dtype and fast[key].flags.c_contiguous, (obj.name, key)
            np.testing.assert_array_equal(fast[key], value, err_msg="%s: %s" % (obj.name, key))


def test_faces_are_read_at_once(monkeypatch):
    # Blender keeps the faces (4.0+: their offsets; 3.4, 3.5 also the loops and
    # edges) in arrays that mesh_io copies at once: each read finds its array.
    obj = shapes.ngon_cylinder()
    found = []
    read = mesh_io._items_array

    def recording(*args):
        fields = read(*args)
        found.append(fields is not None)
        return fields
    monkeypatch.setattr(mesh_io, "_items_array", recording)
    api.mesh_arrays(obj.data)
    assert found and all(found), found


def test_positions_are_written_where_they_are_read():
    obj = shapes.uv_sphere()
    points = np.arange(len(obj.data.vertices) * 3, dtype=np.float32).reshape(-1, 3)
    api.write_positions(obj.data, points)
    np.testing.assert_array_equal(api.read_positions(obj.data), points)
    co = np.empty(points.size, np.float32)
    obj.data.vertices.foreach_get("co", co)
    np.testing.assert_array_equal(co.reshape(-1, 3), points)
