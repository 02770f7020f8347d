# SPDX-License-Identifier: GPL-3.0-or-later
"""api.InterpolateJob, what the operator runs in Blender's window: the
library's work on a thread of its own, Blender's data only on the caller's
thread, the same result as interpolate, and a cancel that leaves nothing."""

import gc
import threading

import bpy
import numpy as np
import pytest

import shapes
from subdiv_pia import api, native
from test_fit import fine_sphere, quad_sphere


def positions(obj):
    return api.read_positions(obj.data).astype(np.float64)


def counts():
    return len(bpy.data.objects), len(bpy.data.meshes)


def test_job_makes_what_interpolate_makes():
    source = shapes.open_grid()
    before = positions(source)
    plain, plain_report = api.interpolate(source, method='PIA', name="Plain")
    job = api.InterpolateJob(source, method='PIA', name="Job")
    new_obj, report = job.wait()
    assert job.done and not job.cancelled
    assert new_obj.name == "Job" and new_obj is not plain
    assert np.array_equal(positions(new_obj), positions(plain))
    assert (report.iterations, report.status) == (plain_report.iterations, plain_report.status)
    assert new_obj["pia_status"] == plain["pia_status"]
    assert np.array_equal(positions(source), before)


@pytest.mark.parametrize("scheme", ['LOOP', 'DOO_SABIN'])
def test_job_limit_schemes_make_what_interpolate_makes(scheme):
    # the limit surface's preview is refined on the job's thread too
    source = shapes.ico_sphere() if scheme == 'LOOP' else shapes.cube()
    plain, _ = api.interpolate(source, scheme=scheme, levels=2, name="Plain")
    job = api.InterpolateJob(source, scheme=scheme, levels=2, name="Job")
    new_obj, report = job.wait()
    assert np.array_equal(positions(new_obj), positions(plain))
    limit, plain_limit = api.find_limit_object(new_obj), api.find_limit_object(plain)
    assert limit is not None and plain_limit is not None
    assert len(limit.data.vertices) > len(new_obj.data.vertices)
    assert np.array_equal(positions(limit), positions(plain_limit))


@pytest.mark.parametrize("scheme", ['LOOP', 'DOO_SABIN'])
def test_job_cancel_during_the_preview_refinement_makes_nothing(scheme):
    # The refinement calls progress with the solve's last figures again: the
    # first call after the solve's first iteration that repeats the one
    # before comes from it.
    source = shapes.ico_sphere() if scheme == 'LOOP' else shapes.cube()
    before = positions(source)
    count = counts()
    calls = []

    def progress(iteration, error):
        calls.append((iteration, error, threading.get_ident()))
        if len(calls) >= 2 and iteration >= 1 and calls[-1][:2] == calls[-2][:2]:
            job.cancel()
        return False
    job = api.InterpolateJob(source, scheme=scheme, levels=3, progress=progress)
    with pytest.raises(native.PiaCancelled) as e:
        job.wait()
    assert "cancelled refining level" in str(e.value), str(e.value)
    assert job.done and job.cancelled
    assert calls[-1][2] != threading.get_ident()
    assert counts() == count
    assert np.array_equal(positions(source), before)


def test_job_fit_runs_the_library_off_this_thread_and_matches():
    scan = fine_sphere(segments=64, rings=32)
    cage = quad_sphere(cuts=2)
    plain, plain_report = api.interpolate(cage, target=scan, fit='SURFACE', name="Plain")
    threads = []
    job = api.InterpolateJob(cage, target=scan.name, fit='SURFACE', name="Job",
                             progress=lambda r, d: threads.append((r, threading.get_ident())) and False)
    new_obj, report = job.wait()
    main = threading.get_ident()
    # The scan is read here (the calls before its build), built and fitted there.
    assert any(t == main for _, t in threads) and any(t != main for _, t in threads), threads
    assert all(t != main for r, t in threads if r >= 1)
    assert job.iteration == report.rounds
    assert np.array_equal(positions(new_obj), positions(plain))
    assert report.after.mean == plain_report.after.mean
    assert report.scan_after.mean == plain_report.scan_after.mean
    assert new_obj["pia_fit_mean_after"] == plain["pia_fit_mean_after"]


def test_job_cancel_during_the_fit_makes_nothing():
    scan = fine_sphere(segments=64, rings=32)
    cage = quad_sphere(cuts=2)
    before = positions(cage), positions(scan)
    count = counts()
    seen = []

    def progress(round_, mean):
        seen.append(round_)
        if round_ >= 1:
            job.cancel()  # as Esc does: from the window's thread in the operator, here from the library's
        return False
    job = api.InterpolateJob(cage, target=scan, fit='SURFACE', cleanup=True, progress=progress)
    with pytest.raises(native.PiaCancelled) as e:
        job.wait()
    assert "round 1" in str(e.value), str(e.value)
    assert job.done and job.cancelled and max(seen) == 1
    # the cleaned copy made before the fit is removed again
    assert counts() == count
    assert np.array_equal(positions(cage), before[0]) and np.array_equal(positions(scan), before[1])


def test_job_cancel_after_the_library_finished_makes_nothing():
    source = shapes.open_grid()
    count = counts()
    job = api.InterpolateJob(source, method='PIA')
    while job.working():
        threading.Event().wait(0.01)
    job.cancel()
    with pytest.raises(native.PiaCancelled):
        job.poll()
    assert job.done and counts() == count


def fit_under_way():
    """A job fitting the quad sphere to the fine one (a cleaned copy of the
    cage made), held at its first round until the returned event is set."""
    scan = fine_sphere(segments=64, rings=32)
    cage = quad_sphere(cuts=2)
    started, release = threading.Event(), threading.Event()

    def progress(round_, mean):
        if round_ >= 1:
            started.set()
            release.wait(10.0)
        return False
    job = api.InterpolateJob(cage, target=scan, fit='SURFACE', cleanup=True, progress=progress)
    while not started.is_set():
        assert job.poll() is None
        started.wait(0.01)
    return job, cage, scan, release


def test_job_close_removes_what_it_made():
    count = counts()
    job, cage, scan, release = fit_under_way()
    # the fit under way: the cleaned copy of the cage exists
    assert counts() == (count[0] + 2, count[1] + 3)
    release.set()
    job.close()
    assert job.done and counts() == (count[0] + 2, count[1] + 2)


def test_job_bad_input_raises_at_once():
    cage = quad_sphere(cuts=2)
    count = counts()
    with pytest.raises(ValueError) as e:
        api.InterpolateJob(cage, target="No such scan")
    assert "not found" in str(e.value)
    assert counts() == count


def test_job_whose_source_is_deleted_meanwhile_cancels():
    count = counts()
    job, cage, scan, release = fit_under_way()
    bpy.data.objects.remove(cage)
    release.set()
    with pytest.raises(native.PiaCancelled) as e:
        job.wait()
    assert "changed" in str(e.value) and not job.cancelled
    # the scan, and its mesh and the cage's (now without an object); the cleaned copy removed
    assert counts() == (count[0] + 1, count[1] + 2)
    # a later poll says the same again
    with pytest.raises(native.PiaCancelled):
        job.poll()


def test_job_dropped_unfinished_cleans_up_here_and_stops_the_library():
    count = counts()
    job, cage, scan, release = fit_under_way()
    state = job._state
    made = len(bpy.data.meshes)
    assert made == count[1] + 3  # scan, cage, the cleaned copy
    thread = job._thread
    del job  # no close(): freed at once, on this thread
    assert len(bpy.data.meshes) == made - 1
    assert state.cancel.is_set()
    release.set()
    thread.join(60.0)
    assert not thread.is_alive()
    gc.collect()
    assert counts() == (count[0] + 2, count[1] + 2)


# --- api.RefreshLimitJob: Refresh Limit Surface in Blender's window -------------------------

def edited_limit_cage(scheme):
    """A Loop or Doo-Sabin cage (levels 3) with one vertex moved after it was made."""
    source = shapes.ico_sphere() if scheme == 'LOOP' else shapes.cube()
    cage, _ = api.interpolate(source, scheme=scheme, levels=3)
    co = positions(cage).astype(np.float32)
    co[0] += np.float32(0.2)
    cage.data.vertices.foreach_set("co", co.ravel())
    cage.data.update()
    return cage


@pytest.mark.parametrize("scheme", ['LOOP', 'DOO_SABIN'])
def test_refresh_job_makes_what_refresh_limit_makes(scheme):
    cage = edited_limit_cage(scheme)
    child = api.find_limit_object(cage)
    stale = positions(child)
    calls = []
    job = api.RefreshLimitJob(child, progress=lambda level, share: calls.append(threading.get_ident()) and False)
    assert job.wait() is child and job.done and not job.cancelled
    refreshed = positions(child)
    assert calls and calls[-1] != threading.get_ident()  # refined on the job's thread
    assert refreshed.shape != stale.shape or not np.array_equal(refreshed, stale)  # the edit shows
    assert api.refresh_limit(cage) is child
    assert np.array_equal(positions(child), refreshed)


@pytest.mark.parametrize("scheme", ['LOOP', 'DOO_SABIN'])
def test_refresh_job_cancelled_leaves_the_limit_surface_as_it_was(scheme):
    cage = edited_limit_cage(scheme)
    child = api.find_limit_object(cage)
    mesh, stale, count = child.data, positions(child), counts()
    job = api.RefreshLimitJob(cage, progress=lambda level, share: True)  # True: cancel
    with pytest.raises(native.PiaCancelled):
        job.wait()
    assert job.done and job.cancelled
    assert child.data == mesh and np.array_equal(positions(child), stale)
    assert counts() == count


def test_refresh_job_whose_cage_is_deleted_meanwhile_cancels():
    cage = edited_limit_cage('LOOP')
    started, release = threading.Event(), threading.Event()

    def progress(level, share):
        started.set()
        release.wait(10.0)
        return False
    job = api.RefreshLimitJob(cage, progress=progress)
    started.wait(10.0)
    bpy.data.objects.remove(cage)
    release.set()
    with pytest.raises(native.PiaCancelled) as e:
        job.wait()
    assert "changed" in str(e.value) and not job.cancelled


def test_refresh_job_bad_input_raises_at_once():
    count = counts()
    with pytest.raises(ValueError, match="not a Loop cage or a Doo-Sabin cage"):
        api.RefreshLimitJob(shapes.cube())
    with pytest.raises(ValueError, match="No active object"):
        api.RefreshLimitJob(None)
    assert counts() == (count[0] + 1, count[1] + 1)  # the cube
