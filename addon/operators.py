# SPDX-License-Identifier: GPL-3.0-or-later
"""The operator: reads the operator settings and reports; the work is in api."""

import bpy

from bpy.props import BoolProperty

from . import api, live, native, sections
from .properties import SETTING_NAMES, settings_annotations

LIVE_DESCRIPTION = ("Live: while on, every change of the source mesh's vertex positions solves the "
                    "cage again and moves its vertices in place (topology changes rebuild it)")


def library_missing():
    """The operators' report when the native library cannot be loaded."""
    return "Subdivision PIA library not loaded: %s" % native.load_error()


class _Progress:
    """Blender's progress indicator, driven by the solver's progress callback."""

    def __init__(self, context, total):
        wm = getattr(context, "window_manager", None)
        self.wm = wm if (wm is not None and not bpy.app.background) else None
        if self.wm is not None:
            self.wm.progress_begin(0, max(int(total), 1))

    def __call__(self, iteration, relative_error):
        if self.wm is not None:
            self.wm.progress_update(iteration)
        return False  # never cancel

    def end(self):
        if self.wm is not None:
            self.wm.progress_end()
            self.wm = None


def result_line(new_obj, report, settings):
    """The operator's report: the interpolation's or fit's line, and what the cleanup did."""
    if isinstance(report, native.FitReport):
        line = api.format_fit_report(report, settings["target"])
    else:
        line = api.format_report(report)
    cleaned = api.format_cleanup(new_obj)
    not_painted = new_obj.get("pia_fit_scan_not_painted")
    detail = api.format_detail(new_obj)
    return "%s: %s%s%s%s" % (new_obj.name, line, "; " + detail if detail else "", "; " + cleaned if cleaned else "",
                             "; " + not_painted if not_painted else "")


# Why the last run on an object (by name) made nothing, for the panel's
# status line; kept while Blender runs, forgotten when a run on it succeeds.
LAST_FAILURES = {}

# native.fit's default number of least-squares rounds: the progress bar's length.
FIT_ROUNDS = 20
# How often (seconds) the running operator looks at the library's thread.
MODAL_INTERVAL = 0.05


class _ModalJob:
    """An operator's library work on a job's thread (api.InterpolateJob,
    api.RefreshLimitJob) while Blender's window stays live: the status bar
    and the progress cursor show it, and Esc cancels.  The operator gives
    _status_text(), _job_failed(context, error) and _job_done(context,
    result)."""

    def _start_modal(self, context, job, total):
        self._job = job
        self._total = max(int(total), 1)
        wm = context.window_manager
        wm.progress_begin(0, self._total)
        self._timer = wm.event_timer_add(MODAL_INTERVAL, window=context.window)
        wm.modal_handler_add(self)
        self._show_status(context)
        return {'RUNNING_MODAL'}

    def _show_status(self, context):
        text = self._status_text()
        context.workspace.status_text_set(text + ("" if self._job.cancelled else "   (Esc to cancel)"))
        context.window_manager.progress_update(min(max(self._job.iteration, 0), self._total))

    def _end_modal(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)

    def modal(self, context, event):
        if event.type == 'ESC' and event.value == 'PRESS':
            self._job.cancel()
        elif event.type != 'TIMER':
            return {'RUNNING_MODAL'}  # nothing else while the mesh is being worked on
        try:
            result = self._job.poll()
        except Exception as error:  # whatever it is, the window must not stay in the run
            self._end_modal(context)
            return self._job_failed(context, error)
        if not self._job.done:
            self._show_status(context)
            return {'RUNNING_MODAL'}
        self._end_modal(context)
        return self._job_done(context, result)

    def cancel(self, context):
        # Blender ends the operator (the window closes): stop the library,
        # remove what was made so far.
        job = getattr(self, "_job", None)
        if job is not None:
            job.close()
        self._end_modal(context)


class OBJECT_OT_subdiv_pia_interpolate(_ModalJob, bpy.types.Operator):
    """Make a new object whose subdivision limit surface passes through this mesh's vertices"""
    bl_idname = "object.subdiv_pia_interpolate"
    bl_label = "Make Interpolating Cage"
    bl_options = {'REGISTER', 'UNDO'}
    __annotations__ = dict(settings_annotations(),
                           live=BoolProperty(name="Live", default=False, description=LIVE_DESCRIPTION))

    @classmethod
    def poll(cls, context):
        # Keep the operator callable so that bad input gets a clear message.
        return True

    def _defaults_from_modifier(self, context):
        # The source's Subdivision Surface modifier gives the defaults for
        # settings the caller did not set explicitly (its use_limit_surface
        # is ignored: the cage is always made for the limit surface).
        for name, value in api.settings_from_modifier(context.active_object).items():
            if not self.properties.is_property_set(name):
                setattr(self, name, value)

    def invoke(self, context, event):
        self._defaults_from_modifier(context)
        if bpy.app.background or context.window is None or not native.available():
            return self.execute(context)
        # In Blender's window the library works on a thread of its own: the
        # window stays live, shows the progress, and Esc cancels.
        settings = {name: getattr(self, name) for name in SETTING_NAMES}
        self._settings = settings
        self._fit = bool(settings["target"])
        try:
            obj = self._source(context)
            job = api.InterpolateJob(obj, live=self.live, **settings)
        except (native.PiaError, ValueError, RuntimeError) as error:
            return self._failed(context, context.active_object, error)
        except BaseException:  # unforeseen: reported by Blender as it is, the mode as it was
            self._back_to_edit(context)
            raise
        surface_fit = self._fit and settings["fit"] == 'SURFACE'
        return self._start_modal(context, job, FIT_ROUNDS if surface_fit else settings["max_iterations"])

    def _source(self, context):
        """The active object, checked, and out of Edit Mode (the new object becomes active)."""
        obj = context.active_object
        api.check_source(obj)
        self._source_name = obj.name
        self._source_key = api._id_key(obj)
        self._was_edit = obj.mode == 'EDIT'
        if self._was_edit:
            bpy.ops.object.mode_set(mode='OBJECT')
        return obj

    def _back_to_edit(self, context):
        """Nothing was made: a source that was in Edit Mode goes back to it."""
        if not getattr(self, "_was_edit", False):
            return
        if not api._same_id(self._source_key):  # deleted, or another object took its name
            return
        obj = bpy.data.objects.get(self._source_name)
        if obj == context.view_layer.objects.active and obj.mode != 'EDIT':
            try:
                bpy.ops.object.mode_set(mode='EDIT')
            except RuntimeError:  # not possible here (hidden, linked): it stays in Object Mode
                pass

    def _failed(self, context, source, error):
        """Reports why nothing was made, and keeps it for the panel; {'CANCELLED'}."""
        self._back_to_edit(context)
        name = getattr(source, "name", source)
        if isinstance(error, native.PiaError):  # the library's words, with the object named
            message = "'%s': %s" % (name, error)
        elif isinstance(error, (ValueError, RuntimeError)):  # already in the user's terms
            message = str(error)
        else:
            message = "'%s': %s: %s" % (name, type(error).__name__, error)
        if isinstance(name, str) and name:
            LAST_FAILURES[name] = message
        self.report({'ERROR'}, message)
        return {'CANCELLED'}

    def _made(self, new_obj, report, settings):
        """Reports the new object; {'FINISHED'}."""
        LAST_FAILURES.pop(getattr(self, "_source_name", None), None)
        fine = api.report_converged(report) and not new_obj.get("pia_fit_scan_not_painted")
        self.report({'INFO'} if fine else {'WARNING'}, result_line(new_obj, report, settings))
        return {'FINISHED'}

    def _status_text(self):
        job = self._job
        what = "Fitting" if self._fit else "Solving"
        if job.cancelled:
            return "%s '%s': cancelling" % (what, self._source_name)
        if job.stage is not None:
            text, rounds = job.stage
            if rounds and job.iteration > 0:
                text += ", round %d, mean distance %.3g of the scan's diagonal" % (job.iteration, job.value)
            return "%s '%s': %s" % (what, self._source_name, text)
        if job.iteration <= 0:
            return "%s '%s': %s" % (what, self._source_name,
                                    "reading and preparing the scan" if self._fit else "preparing")
        if self._fit:
            return "%s '%s': round %d, mean distance %.3g of the scan's diagonal" % (
                what, self._source_name, job.iteration, job.value)
        return "%s '%s': iteration %d, error %.3g" % (what, self._source_name, job.iteration, job.value)

    def _job_failed(self, context, error):
        if isinstance(error, native.PiaCancelled) and self._job.cancelled:
            self._back_to_edit(context)
            self.report({'WARNING'}, "Cancelled: '%s' is unchanged and nothing was made" % self._source_name)
            return {'CANCELLED'}
        return self._failed(context, self._source_name, error)

    def _job_done(self, context, result):
        return self._made(*result, self._settings)

    def draw(self, context):
        """The redo panel (F9), grouped as the Modifiers-tab panel: the top,
        then each group of settings that applies under its label."""
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(self, "scheme")
        sections.draw_levels(layout, self)
        layout.prop_search(self, "target", context.blend_data, "objects")
        layout.prop(self, "live")
        sections.draw_groups_inline(layout, self, bool(self.target))

    def execute(self, context):
        if not native.available():  # say what is needed; touch nothing
            self.report({'ERROR'}, library_missing())
            return {'CANCELLED'}
        # Also here: scripts call the operator without invoke (EXEC_DEFAULT).
        self._defaults_from_modifier(context)
        settings = {name: getattr(self, name) for name in SETTING_NAMES}
        surface_fit = bool(settings["target"]) and settings["fit"] == 'SURFACE'
        progress = _Progress(context, FIT_ROUNDS if surface_fit else settings["max_iterations"])
        try:
            obj = self._source(context)
            new_obj, report = api.interpolate(obj, context=context, progress=progress, live=self.live,
                                              **settings)
        except (native.PiaError, ValueError, RuntimeError) as error:
            return self._failed(context, context.active_object, error)
        except BaseException:  # unforeseen: reported by Blender as it is, the mode as it was
            self._back_to_edit(context)
            raise
        finally:
            progress.end()
        return self._made(new_obj, report, settings)


class OBJECT_OT_subdiv_pia_refresh_limit(_ModalJob, bpy.types.Operator):
    """Recompute the Loop or Doo-Sabin limit surface (the cage's "_limit" child) from the cage's current shape and shape attribute"""
    bl_idname = "object.subdiv_pia_refresh_limit"
    bl_label = "Refresh Limit Surface"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        # Keep the operator callable so that bad input gets a clear message.
        return True

    def invoke(self, context, event):
        if bpy.app.background or context.window is None or not native.available():
            return self.execute(context)
        # In Blender's window the refinement runs on a thread of its own, as
        # Make Interpolating Cage's work does: Esc cancels.
        obj = context.active_object
        try:
            job = api.RefreshLimitJob(obj)
        except (native.PiaError, ValueError, RuntimeError) as error:
            return self._refused(obj, error)
        cage = api.limit_cage_of(obj)
        self._cage_name = cage.name
        return self._start_modal(context, job, api.stored_settings(cage)["levels"])

    def execute(self, context):
        if not native.available():
            self.report({'ERROR'}, library_missing())
            return {'CANCELLED'}
        obj = context.active_object
        try:
            child = api.refresh_limit(obj, context=context)
        except (native.PiaError, ValueError, RuntimeError) as error:
            return self._refused(obj, error)
        return self._refreshed(child)

    def _refused(self, obj, error):
        if isinstance(error, native.PiaError):  # the library's words, with the cage named
            cage = api.limit_cage_of(obj) if isinstance(obj, bpy.types.Object) else None
            self.report({'ERROR'}, "'%s': %s" % (cage.name if cage is not None else obj, error))
        else:
            self.report({'ERROR'}, str(error))
        return {'CANCELLED'}

    def _refreshed(self, child):
        self.report({'INFO'}, "%s: %d vertices, %d faces"
                    % (child.name, len(child.data.vertices), len(child.data.polygons)))
        return {'FINISHED'}

    def _status_text(self):
        job = self._job
        if job.cancelled:
            return "Refreshing the limit surface of '%s': cancelling" % self._cage_name
        return "Refreshing the limit surface of '%s': level %d of %d" % (
            self._cage_name, max(job.iteration, 1), self._total)

    def _job_failed(self, context, error):
        if isinstance(error, native.PiaCancelled) and self._job.cancelled:
            self.report({'WARNING'}, "Cancelled: the limit surface of '%s' is as it was" % self._cage_name)
            return {'CANCELLED'}
        if isinstance(error, native.PiaError):
            self.report({'ERROR'}, "'%s': %s" % (self._cage_name, error))
        else:
            self.report({'ERROR'}, "'%s': %s: %s" % (self._cage_name, type(error).__name__, error))
        return {'CANCELLED'}

    def _job_done(self, context, result):
        return self._refreshed(result)


class OBJECT_OT_subdiv_pia_live(bpy.types.Operator):
    """Turn Live on or off for the active cage: while on, the cage follows every change of its source mesh"""
    bl_idname = "object.subdiv_pia_live"
    bl_label = "Live"
    bl_options = {'REGISTER', 'UNDO'}

    enable: BoolProperty(name="Live", default=True, description=LIVE_DESCRIPTION)

    @classmethod
    def poll(cls, context):
        return True

    def execute(self, context):
        if not native.available():
            self.report({'ERROR'}, library_missing())
            return {'CANCELLED'}
        cage = api.limit_cage_of(context.active_object) or context.active_object
        try:
            state = live.set_live(cage, self.enable)
        except native.PiaError as error:
            self.report({'ERROR'}, "'%s': %s" % (cage.name, error))
            return {'CANCELLED'}
        except (ValueError, RuntimeError) as error:
            self.report({'ERROR'}, str(error))
            return {'CANCELLED'}
        message = cage.get(live.MESSAGE, "")
        if state:
            self.report({'WARNING'} if message else {'INFO'},
                        "%s follows '%s'%s" % (cage.name, cage[live.SOURCE], ": " + message if message else ""))
        else:
            self.report({'INFO'}, "%s: Live off" % cage.name)
        return {'FINISHED'}


classes = (OBJECT_OT_subdiv_pia_interpolate, OBJECT_OT_subdiv_pia_refresh_limit, OBJECT_OT_subdiv_pia_live)
_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()


def unregister():
    _unregister()
