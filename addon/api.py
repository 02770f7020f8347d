# SPDX-License-Identifier: GPL-3.0-or-later
"""Script API: what scripts, the operators and cli.py use.

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

The work is done in modules by what each touches, each importing only
those listed before it (tests/python/test_layering.py checks it):

    settings   the settings, their defaults and checks, memory estimates
    mesh_io    Blender meshes in and out as flat arrays (every Blender's layout)
    compute    the library's work on those arrays: cage, scan, limit surfaces
    objects    the objects made: cage, `_limit` child, properties, heat maps
    reports    one-line reports for the status bar and the command line
    live       Live cages (live.py)
    steps      interpolate and refresh_limit as steps, run here
    jobs       the same steps with the library's work on a thread

This module names what scripts use from all of them.
"""

from . import cleanup, native  # noqa: F401
from .settings import (  # noqa: F401
    BOUNDARY_RULES, BOUNDARY_SMOOTH, DEFAULT_SETTINGS, FIT_MODES, LIMIT_SCHEMES, LIVE_CLEANUP_MESSAGE,
    LOOP_MAX_LEVELS, METHODS, MODIFIER_SETTINGS, SCHEME_NAMES, SCHEMES, blender_opensubdiv_version,
    check_memory, check_settings, find_subsurf, machine_memory, opensubdiv_version_of, opensubdiv_version_string,
    settings_from_modifier, stencil_memory_estimate)
from .mesh_io import (  # noqa: F401
    _builtin_attribute, _items_array, cleaned_copy, face_shape_parameters, mesh_arrays, native_mesh, new_mesh,
    non_triangle_count, position_attribute, read_creases, read_face_sizes, read_positions, scan_arrays,
    triangulated_copy, write_creases, write_positions)
from .compute import (  # noqa: F401
    check_source, cleanup_hint, compute_cage, find_target, limit_arrays, limit_work, make_scan, prepare_cage,
    require_library, scan_work)
from .objects import (  # noqa: F401
    CLEANUP_PREFIX, COLOR_ATTRIBUTE, DISTANCE_ATTRIBUTE, HEAT_SCALE, LIMIT_MARK, LIMIT_SUFFIX,
    REACHABLE_MAX_ERROR, SCAN_COLOR_ATTRIBUTE, SCAN_DISTANCE_ATTRIBUTE, STORED_SETTINGS, UNMEASURED_COLOR,
    UNREACHABLE_COUNT, UNREACHABLE_GROUP, build_object, cleanup_stats, discard_object, find_limit_object,
    heat_colors, limit_cage_of, limit_mesh, loop_cage_of, paint_scan, set_limit_object, store_cleanup, store_fit,
    store_report, stored_settings, write_heat_map, write_unreachable_group)
from .reports import (  # noqa: F401
    FIT_NAMES, format_cleanup, format_detail, format_fit_report, format_report, format_unreachable, report_converged)
from .live import is_live, set_live  # noqa: F401
from .steps import (  # noqa: F401
    interpolate, interpolate_steps, refresh_limit, refresh_limit_steps, run_steps)
from .jobs import InterpolateJob, RefreshLimitJob, _id_key, _same_id  # noqa: F401
