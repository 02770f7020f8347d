# SPDX-License-Identifier: GPL-3.0-or-later
"""Live cages: while a cage's Live switch is on, every change of its source
mesh's positions solves the cage again and writes its positions in place
(same object, same mesh data-block, same modifier).

What is stored on the cage (custom properties, so that a saved .blend keeps
it and undo restores it with the rest of the object):

    pia_live          bool: the switch
    pia_source        the name of the source object (build_object writes it)
    pia_live_name     the cage's own name when Live was turned on (a rename
                      of the cage turns Live off)
    pia_live_message  why Live stopped, or why the last edit was not
                      followed (the panel shows it); empty when all is well

Detection: a depsgraph_update_post handler, added only while at least one
cage is live, looks at depsgraph.updates for a source object (or its mesh)
with is_updated_geometry. The source's positions are read from its mesh
(after obj.update_from_editmode() in Edit Mode). The stencils (the
library's stencil table) are cached per cage while the source's topology
stays the same: the counts of vertices, edges, face corners and faces,
the creases and the Doo-Sabin shape values are compared on every update,
the faces and edges themselves whenever one of those changed (reading
them costs more than the solve). A topology change rebuilds the cage's
mesh from the source with the cage's settings, once per change. spia_solve takes no initial guess: each
edit is a fresh solve from the targets with the cached stencils.

load_post (a .blend opened) and undo_post/redo_post find the live cages
again (persistent handlers, always installed: they do nothing in a file
without live cages) and bring each cage in line with its source.
"""

import time

import bpy
import numpy as np
from bpy.app.handlers import persistent

from . import native
from .compute import check_source, compute_cage, find_target, limit_arrays, make_scan
from .mesh_io import (face_shape_parameters, mesh_arrays, native_mesh, non_triangle_count, read_creases,
                      read_positions, triangulated_copy, write_positions)
from .objects import find_limit_object, set_limit_object, store_report, stored_settings
from .reports import format_unreachable, report_converged
from .settings import LIMIT_SCHEMES, LIVE_CLEANUP_MESSAGE, check_settings, opensubdiv_version_of

LIVE = "pia_live"
SOURCE = "pia_source"
LIVE_NAME = "pia_live_name"
MESSAGE = "pia_live_message"
FIT_KEYS = ("fit_cutoff", "fit_smoothing", "fit_samples")

# cage name -> _State; only live cages are in it.
_states = {}
# True while the handler writes: writing the cage triggers another depsgraph update.
_busy = False
# Seconds the handler spent on its last update of each cage (for the benchmark).
last_seconds = {}


class _State:
    __slots__ = ("source", "topology", "stencils", "positions", "cage_uid")

    def __init__(self, source, cage_uid):
        self.source = source          # source object name
        self.topology = None          # (quick key, face key) of the source the stencils are for
        self.stencils = None          # native.Stencils of the cage's topology
        self.positions = None         # the source positions last solved for
        self.cage_uid = cage_uid


def _uid(obj):
    return getattr(obj, "session_uid", None)


def is_live(cage):
    return cage is not None and bool(cage.get(LIVE, False))


def live_cages():
    """The names of the cages registered as live."""
    return sorted(_states)


def source_of(cage):
    """The source object of a cage (by its stored name), or None."""
    name = cage.get(SOURCE, "") if cage is not None else ""
    return bpy.data.objects.get(name) if name else None


def settings_of(cage):
    """The settings a cage was made with: stored_settings, the OpenSubdiv
    version it is exact for, and its fit (target and fit settings) if it was fitted."""
    s = stored_settings(cage)
    if cage.get("pia_scheme", 'CATMULL_CLARK') == 'CATMULL_CLARK' and cage.get("pia_opensubdiv_version"):
        s["opensubdiv_version"] = str(cage["pia_opensubdiv_version"])
    if cage.get("pia_fit_target"):
        s["target"] = str(cage["pia_fit_target"])
        s["fit"] = str(cage.get("pia_fit", 'SURFACE'))
        for key in FIT_KEYS:
            if "pia_" + key in cage:
                s[key] = cage["pia_" + key]
    return check_settings(s)


def _ensure_handler():
    handlers = bpy.app.handlers.depsgraph_update_post
    if _states and on_depsgraph_update not in handlers:
        handlers.append(on_depsgraph_update)
    elif not _states:
        while on_depsgraph_update in handlers:
            handlers.remove(on_depsgraph_update)


def _stop(cage, message):
    """Turn Live off on cage, saying why."""
    _states.pop(cage.name, None)
    cage[LIVE] = False
    cage[MESSAGE] = message
    _ensure_handler()


def set_live(cage, enable=True, source=None):
    """Turn Live on or off for a cage (an object made by interpolate).

    source: the mesh object to follow (an object or its name); default the
    cage's stored source (pia_source). Turning it on solves the cage once
    for the source's current shape. Returns the cage's Live state; turning
    it on raises ValueError with a message if the cage or source cannot be
    used (nothing changes then).
    """
    if cage is None or cage.type != 'MESH' or "pia_scheme" not in cage:
        raise ValueError("'%s' is not an interpolating cage: make one with Make Interpolating Cage"
                         % getattr(cage, "name", None))
    if not enable:
        _states.pop(cage.name, None)
        cage[LIVE] = False
        cage[MESSAGE] = ""
        _ensure_handler()
        return False
    if isinstance(source, bpy.types.Object):
        source = source.name
    name = source or cage.get(SOURCE, "")
    if not name:
        raise ValueError("'%s' does not name its source object: give the source to follow" % cage.name)
    obj = bpy.data.objects.get(name)
    if obj is None:
        raise ValueError("Source '%s' of '%s' not found (deleted or renamed)" % (name, cage.name))
    if obj == cage:
        raise ValueError("'%s' cannot follow itself" % cage.name)
    check_source(obj)
    if settings_of(cage).get("cleanup"):  # ValueError for settings that cannot be used
        raise ValueError(LIVE_CLEANUP_MESSAGE % obj.name)
    cage[SOURCE] = obj.name
    cage[LIVE] = True
    cage[LIVE_NAME] = cage.name
    cage[MESSAGE] = ""
    _states[cage.name] = _State(obj.name, _uid(cage))
    _ensure_handler()
    sync(cage, force=True)
    return is_live(cage)


def _quick_key(mesh, shapes):
    """What is cheap to read each update: element counts, creases and the
    Doo-Sabin shape values. Reading the faces themselves costs more than
    the solve; they are compared (_face_key) only when this key changes."""
    edge, vertex = read_creases(mesh)
    return (len(mesh.vertices), len(mesh.edges), len(mesh.loops), len(mesh.polygons),
            None if edge is None else hash(edge.tobytes()),
            None if vertex is None else hash(vertex.tobytes()),
            None if shapes is None else hash(shapes.tobytes()))


def _face_key(arrays):
    return (hash(arrays["face_sizes"].tobytes()),
            hash(np.ascontiguousarray(arrays["face_vertices"]).tobytes()),
            hash(arrays["edges"].tobytes()))


def _stencils(cage, settings):
    """The limit stencils of the cage's own mesh (its topology), with its settings."""
    scheme = settings["scheme"]
    options = dict(scheme=scheme, boundary_rule=settings["boundary_rule"],
                   boundary_smooth=settings["boundary_smooth"],
                   use_creases=settings["use_creases"] and scheme != 'DOO_SABIN',
                   quality=settings["quality"], opensubdiv_version=opensubdiv_version_of(settings))
    if scheme == 'DOO_SABIN':
        options.update(shape_parameter=settings["shape_parameter"],
                       face_shape_parameters=face_shape_parameters(cage.data, settings))
    return native.limit_stencils(native_mesh(cage.data), **options)


def _refresh_limit(cage, settings):
    """The `_limit` child of a Loop or Doo-Sabin cage, in place when its size stays."""
    if settings["scheme"] not in LIMIT_SCHEMES:
        return
    limit = limit_arrays(cage.data, settings)
    child = find_limit_object(cage)
    if (child is not None and child.data is not None and len(child.data.vertices) == len(limit[0])
            and len(child.data.polygons) == len(limit[1])):
        write_positions(child.data, limit[0])
    else:
        set_limit_object(cage, limit)


def _rebuild(cage, source, settings, scan):
    """A new mesh for the cage from the source's topology, swapped in under the old name."""
    mesh = source.data.copy()
    if settings["scheme"] == 'LOOP' and settings["triangulate"] and non_triangle_count(mesh):
        tri = triangulated_copy(mesh)
        bpy.data.meshes.remove(mesh)
        mesh = tri
    try:
        # an update is about the cage: the scan-to-surface distances (a
        # hierarchy over the refined surface) are left to a full fit
        positions, report = compute_cage(source, settings, mesh=mesh, scan=scan, measure_scan=False)
    except BaseException:
        bpy.data.meshes.remove(mesh)
        raise
    old = cage.data
    name = old.name
    flat = np.ascontiguousarray(positions, np.float32).reshape(-1)
    mesh.vertices.foreach_set("co", flat)
    keys = mesh.shape_keys
    if keys is not None and keys.reference_key is not None:
        keys.reference_key.data.foreach_set("co", flat)
    mesh.update()
    cage.data = mesh
    if old.users == 0:
        bpy.data.meshes.remove(old)
    mesh.name = name
    return report


def sync(cage, force=False):
    """Bring a live cage in line with its source now: solve and write in
    place (or rebuild after a topology change). Returns True if the cage was
    written. Never raises for a bad source: the reason goes to pia_live_message,
    and the cage stays as it was."""
    global _busy
    state = _states.get(cage.name)
    if state is None:
        return False
    source = bpy.data.objects.get(state.source)
    if source is None or source.type != 'MESH':
        _stop(cage, "Live off: source '%s' was deleted or renamed" % state.source)
        return False
    if cage.mode == 'EDIT':
        cage[MESSAGE] = "Not followed: the cage is in Edit Mode"
        return False
    started = time.perf_counter()
    _busy = True
    try:
        if source.mode == 'EDIT':
            source.update_from_editmode()
        mesh = source.data
        targets = read_positions(mesh)
        settings = settings_of(cage)
        shapes = face_shape_parameters(mesh, settings) if settings["scheme"] == 'DOO_SABIN' else None
        key = _quick_key(mesh, shapes)
        if (not force and state.positions is not None and key == state.topology[0]
                and np.array_equal(state.positions, targets)):
            return False
        if len(targets) == 0 or len(mesh.polygons) == 0:
            raise ValueError("source '%s' has no faces" % source.name)
        if not np.isfinite(targets).all():
            bad = int(np.flatnonzero(~np.isfinite(targets).all(axis=1))[0])
            raise ValueError("vertex %d of '%s' is not a finite position" % (bad, source.name))
        target = find_target(cage, settings)
        scan = make_scan(target, cage) if target is not None else None
        faces = state.topology[1] if state.topology is not None else None
        new_stencils = state.stencils is None
        if state.topology is None or key != state.topology[0]:
            arrays = mesh_arrays(mesh)
            new_faces = _face_key(arrays)
            if len(cage.data.vertices) != len(targets):
                rebuild = True
            elif faces is None:  # first solve: the cage may already have these faces
                rebuild = not _same_faces(cage.data, arrays, settings)
            else:  # creases and shape values live on the cage's mesh too: a new copy
                rebuild = True
            faces = new_faces
            new_stencils = True
        else:
            rebuild = False
        if rebuild:
            report = _rebuild(cage, source, settings, scan)
            state.stencils = None
        elif scan is not None:
            positions, report = compute_cage(source, settings, scan=scan)
            write_positions(cage.data, positions)
        else:
            if new_stencils or state.stencils is None:
                state.stencils = _stencils(cage, settings)
                initial = None
            else:  # the same topology: start from the cage solved for the last positions
                initial = read_positions(cage.data)
            positions, report = state.stencils.solve(
                targets, initial=initial, method=settings["method"], tolerance=settings["tolerance"],
                max_iterations=settings["max_iterations"],
                staged=settings["staged"] and settings["scheme"] == 'LOOP')
            if not np.isfinite(positions).all():
                raise ValueError("the solve gave non-finite positions")
            write_positions(cage.data, positions)
        state.topology = (key, faces)
        state.positions = targets
        store_report(cage, report, settings)  # figures and the pia_unreachable group
        _refresh_limit(cage, settings)
        message = ""
        if not report_converged(report):
            message = "Last edit: %s" % (report.status.lower().replace("_", " "))
            unreachable = format_unreachable(getattr(report, "unreachable_count", 0),
                                                 getattr(report, "reachable_max_error_relative", 0.0))
            if unreachable:
                message += "; " + unreachable
        cage[MESSAGE] = message
        return True
    except (ValueError, RuntimeError, native.PiaError) as error:
        cage[MESSAGE] = "Not followed: %s" % error
        state.positions = None
        return False
    finally:
        _busy = False
        last_seconds[cage.name] = time.perf_counter() - started


def _same_faces(mesh, arrays, settings):
    """True if the cage mesh has the source's faces (no rebuild needed on
    the first sync of a cage made from this source)."""
    if settings["scheme"] == 'LOOP' and settings["triangulate"]:
        return len(mesh.vertices) == len(arrays["positions"])
    mine = mesh_arrays(mesh)
    return (np.array_equal(mine["face_sizes"], arrays["face_sizes"])
            and np.array_equal(mine["face_vertices"], arrays["face_vertices"]))


def _check_links():
    """Live off, with a message, for cages whose source or own name changed."""
    for name, state in list(_states.items()):
        cage = bpy.data.objects.get(name)
        if cage is None or not is_live(cage) or _uid(cage) != state.cage_uid:
            _states.pop(name, None)
            renamed = next((o for o in bpy.data.objects
                            if state.cage_uid is not None and _uid(o) == state.cage_uid), None)
            if renamed is not None and is_live(renamed):
                renamed[LIVE] = False
                renamed[MESSAGE] = "Live off: the cage was renamed from '%s'" % name
            continue
        source = bpy.data.objects.get(state.source)
        if source is None or source.type != 'MESH':
            _stop(cage, "Live off: source '%s' was deleted or renamed" % state.source)
    _ensure_handler()


@persistent
def on_depsgraph_update(scene, depsgraph=None):
    if _busy or not _states:
        return
    _check_links()
    if not _states:
        return
    if depsgraph is None:
        depsgraph = bpy.context.evaluated_depsgraph_get()
    sources = {}
    for name, state in _states.items():
        sources.setdefault(state.source, []).append(name)
    meshes = {}
    for source_name in sources:
        obj = bpy.data.objects.get(source_name)
        if obj is not None and obj.data is not None:
            meshes.setdefault(obj.data.name, []).append(source_name)
    changed = set()
    for update in depsgraph.updates:
        if not update.is_updated_geometry:
            continue
        ident = update.id.original if update.id is not None else None
        if isinstance(ident, bpy.types.Object) and ident.name in sources:
            changed.add(ident.name)
        elif isinstance(ident, bpy.types.Mesh) and ident.name in meshes:
            changed.update(meshes[ident.name])
    for source_name in changed:
        for cage_name in sources[source_name]:
            cage = bpy.data.objects.get(cage_name)
            if cage is not None:
                sync(cage)


def rescan(resync=True):
    """Register the live cages of the open file (after loading it, undo,
    redo); with resync, bring each in line with its source."""
    old = dict(_states)
    _states.clear()
    for obj in bpy.data.objects:
        if obj.type == 'MESH' and is_live(obj):
            if obj.get(LIVE_NAME, obj.name) != obj.name:
                obj[LIVE] = False
                obj[MESSAGE] = "Live off: the cage was renamed from '%s'" % obj.get(LIVE_NAME)
                continue
            state = old.get(obj.name)
            source = obj.get(SOURCE, "")
            if state is None or state.source != source:
                state = _State(source, _uid(obj))
            else:
                state.cage_uid = _uid(obj)
                state.positions = None
            _states[obj.name] = state
    _ensure_handler()
    if resync:
        for name in list(_states):
            cage = bpy.data.objects.get(name)
            if cage is not None and name in _states:
                sync(cage)


@persistent
def on_load(*_args):
    rescan()


@persistent
def on_undo(*_args):
    rescan()


_PERSISTENT = (("load_post", on_load), ("undo_post", on_undo), ("redo_post", on_undo))


def register():
    for name, function in _PERSISTENT:
        handlers = getattr(bpy.app.handlers, name)
        if function not in handlers:
            handlers.append(function)
    try:
        rescan(resync=False)
    except AttributeError:  # enabled at start-up: bpy.data is not open yet (load_post follows)
        pass


def unregister():
    for name, function in _PERSISTENT:
        handlers = getattr(bpy.app.handlers, name)
        while function in handlers:
            handlers.remove(function)
    _states.clear()
    while on_depsgraph_update in bpy.app.handlers.depsgraph_update_post:
        bpy.app.handlers.depsgraph_update_post.remove(on_depsgraph_update)
