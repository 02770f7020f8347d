# SPDX-License-Identifier: GPL-3.0-or-later
"""interpolate and refresh_limit with the library's work on a thread of its
own (InterpolateJob, RefreshLimitJob), for a caller that must stay
responsive: the operators' modal runs in Blender's window.
"""

import threading

import bpy

from . import native
from .objects import limit_cage_of
from .steps import interpolate_steps, refresh_limit_steps


class _JobProgress:
    """What an InterpolateJob's steps and its library thread share: the last
    progress call and the cancel flag (apart from the job, so that a job
    dropped by its caller is freed, and its steps closed, at once and on the
    caller's thread)."""

    def __init__(self, user_progress):
        self.iteration = 0
        self.value = 0.0
        self.calls = 0
        self.stage = None
        self.user_progress = user_progress
        self.cancel = threading.Event()

    def begin(self, text, rounds=False):
        """The steps name the stage they begin (detail levels: each
        level's fit, whose rounds the progress calls count, and Blender's
        stages after them); the operator shows it."""
        self.stage = (text, bool(rounds))

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

    @property
    def stage(self):
        """(text, rounds) of the stage the steps last began (None before
        the first): rounds, whether the progress calls count its rounds."""
        return self._state.stage

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
