# SPDX-License-Identifier: GPL-3.0-or-later
"""Script API (subdiv_pia.interpolate) and the command line (cli.py)."""

import os
import re
import subprocess
import sys

import bpy
import numpy as np
import pytest

import shapes
import subdiv_pia
from subdiv_pia import native
from conftest import (DATA, MATCH, assert_unchanged, diagonal, evaluated_control_points, operator_exists,
                      positions, relative_miss, snapshot)


def test_api_returns_object_and_report():
    source = shapes.ngon_cylinder()
    before = snapshot(source)
    targets = positions(source.data).astype(np.float64)
    new_obj, report = subdiv_pia.interpolate(source, levels=1, quality=4, method='GS_PIA')
    assert report.converged and report.status == 'CONVERGED'
    assert report.max_error_relative <= 1e-6
    assert new_obj["pia_iterations"] == report.iterations
    assert new_obj["pia_method"] == report.method
    assert new_obj.modifiers[0].quality == 4
    assert relative_miss(new_obj, targets) <= MATCH
    assert_unchanged(source, before)


def test_api_not_converged_is_not_an_error():
    source = shapes.open_grid()
    new_obj, report = subdiv_pia.interpolate(source, max_iterations=1, tolerance=1e-12, method='PIA')
    assert not report.converged and report.status in ('MAX_ITERATIONS', 'STAGNATED')
    assert new_obj["pia_status"] == report.status


def test_api_errors():
    n_objects = len(bpy.data.objects)
    with pytest.raises(ValueError, match="No active object"):
        subdiv_pia.interpolate(None)
    empty = bpy.data.objects.new("Empty", None)
    with pytest.raises(ValueError, match=r"'Empty' is not a mesh object \(type EMPTY\)"):
        subdiv_pia.interpolate(empty)
    source = shapes.cube()
    with pytest.raises(ValueError, match="Unknown setting"):
        subdiv_pia.interpolate(source, level=2)
    with pytest.raises(ValueError, match="quality"):
        subdiv_pia.interpolate(source, quality=0)
    co = positions(source.data).copy()
    co[0, 0] = np.inf
    source.data.vertices.foreach_set("co", co.ravel())
    with pytest.raises(native.PiaError):
        subdiv_pia.interpolate(source)
    assert len(bpy.data.objects) == n_objects + 2  # the empty and the cube only


class Broken(Exception):
    pass


def _broken(*args, **kwargs):
    raise Broken("broken on purpose")


# Each case breaks one step of writing the new object, late in it: the cage
# object (and its Loop limit child, the triangulated or cleaned copy it was
# given, a Live registration) must be gone again, the source unchanged and
# its selection as it was.
WRITE_FAILURES = {
    "modifier's settings": (shapes.cube, "objects", "opensubdiv_version_string", {}),
    "Loop limit child": (shapes.cube, "objects", "set_limit_object", {"scheme": 'LOOP', "triangulate": True}),
    "cleaned copy's figures": (shapes.cube, "steps", "store_cleanup", {"cleanup": True}),
    "Live": (shapes.cube, "live", "set_live", {"live": True}),
}


@pytest.mark.parametrize("case", sorted(WRITE_FAILURES))
def test_api_failure_while_writing_leaves_nothing(monkeypatch, case):
    from subdiv_pia import live, objects, steps
    make, module, function, settings = WRITE_FAILURES[case]
    source = make()
    source.select_set(False)  # active, not selected: so it stays
    before = snapshot(source)
    counts = (len(bpy.data.objects), len(bpy.data.meshes))
    module = {"objects": objects, "steps": steps, "live": live}[module]
    real = getattr(module, function)
    if function == "set_live":  # only turning it on fails; turning it off again must work
        monkeypatch.setattr(module, function, lambda cage, enable=True, source=None:
                            _broken() if enable else real(cage, enable, source))
    else:
        monkeypatch.setattr(module, function, _broken)
    with pytest.raises(Broken):
        subdiv_pia.interpolate(source, **settings)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == counts
    assert not [m for m in bpy.data.meshes if m.users == 0]
    assert_unchanged(source, before)
    assert bpy.context.view_layer.objects.active == source and not source.select_get()
    if function == "set_live":
        assert not live._states


def test_api_takes_settings_from_modifier():
    source = shapes.cube()
    mod = source.modifiers.new("Subsurf", 'SUBSURF')
    mod.levels, mod.quality, mod.use_limit_surface = 1, 2, False
    new_obj, report = subdiv_pia.interpolate(source)
    assert (new_obj.modifiers[0].levels, new_obj.modifiers[0].quality) == (1, 2)
    assert new_obj.modifiers[0].use_limit_surface


# --- cli.py ----------------------------------------------------------------------

CLI = os.path.join(os.path.dirname(os.path.abspath(subdiv_pia.__file__)), "cli.py")


def cli_command():
    """cli.py run as a user runs it: by the blender executable, or by Python
    where Blender is the bpy module (no executable)."""
    if getattr(bpy.app, "module", False) or not bpy.app.binary_path:
        return [sys.executable, CLI, "--"]
    return [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1",
            "--python", CLI, "--"]


def run_cli(*args):
    return subprocess.run(cli_command() + list(args), capture_output=True, text=True, timeout=120)


def run_cli_on_terminal(*args):
    """(exit status, what it wrote) for cli.py with its output on a
    terminal (a pseudo-terminal), where it shows its progress."""
    import pty
    main, side = pty.openpty()
    with subprocess.Popen(cli_command() + list(args), stdin=subprocess.DEVNULL, stdout=side, stderr=side) as run:
        os.close(side)
        chunks = []
        while True:
            try:
                chunk = os.read(main, 65536)
            except OSError:  # the other side closed (Linux raises EIO)
                break
            if not chunk:
                break
            chunks.append(chunk)
        status = run.wait(timeout=120)
    os.close(main)
    return status, b"".join(chunks).decode("utf-8", "replace")


def test_cli_uses_its_own_package():
    """cli.py beside the package in use imports that package (the installed
    copy when SUBDIV_PIA_PACKAGE is set) and its library."""
    result = run_cli("--version")
    assert result.returncode == 0, result.stdout + result.stderr
    folder = os.path.dirname(os.path.abspath(subdiv_pia.__file__))
    assert ": %s\n" % folder in result.stdout, result.stdout
    binding = os.path.dirname(os.path.abspath(native.__file__))  # spia: in the add-on, or the extension's wheel
    assert "library %s\n" % os.path.join(binding, native.library_name()) in result.stdout, result.stdout


def test_cli_writes_blend(tmp_path):
    output = str(tmp_path / "mushroom_cage.blend")
    result = run_cli(os.path.join(DATA, "mushroom.obj"), output, "--levels", "1",
                     "--quality", "4", "--boundary-smooth", "PRESERVE_CORNERS")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Converged" in result.stdout
    assert os.path.isfile(output)
    with bpy.data.libraries.load(output) as (data_from, data_to):
        names = list(data_from.objects)
    assert "mushroom_pia" in names and "mushroom" in names


def test_cli_progress_on_a_terminal(tmp_path):
    output = str(tmp_path / "mushroom_cage.blend")
    status, text = run_cli_on_terminal(os.path.join(DATA, "mushroom.obj"), output, "--method", "PIA")
    assert status == 0, text
    lines = re.findall(r"\riteration (\d+): max error ([0-9.e+-]+)", text)
    assert len(lines) >= 2 and int(lines[-1][0]) >= 2, text
    assert "round" not in text


def test_cli_error_exit_status(tmp_path):
    output = str(tmp_path / "never.blend")
    result = run_cli(os.path.join(DATA, "no_such_mesh.obj"), output)
    assert result.returncode == 1
    assert "Input file not found" in result.stderr
    assert not os.path.exists(output)


def test_cli_help():
    result = run_cli("--help")
    assert result.returncode == 0
    assert "--boundary-smooth" in result.stdout


@pytest.mark.parametrize("version", ("this", "other"))
def test_cli_opensubdiv_version(tmp_path, version):
    """--opensubdiv-version makes the cage for Blenders of another OpenSubdiv
    (default: this Blender's); they differ at the fins' centre (vertex 4)."""
    source = shapes.double_sided_fins()
    targets = positions(source.data).astype(np.float64)
    path = str(tmp_path / "fins.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    this = tuple(bpy.app.opensubdiv.version)
    other = "3.6.0" if this > (3, 6, 0) else "3.7.0"
    output = str(tmp_path / "out.blend")
    extra = ["--opensubdiv-version", other] if version == "other" else []
    result = run_cli(path, output, "--levels", "1", *extra)
    assert result.returncode == 0, result.stdout + result.stderr
    with bpy.data.libraries.load(output) as (data_from, data_to):
        data_to.objects = ["DoubleSidedFins_pia"]
    cage = data_to.objects[0]
    bpy.context.scene.collection.objects.link(cage)
    assert cage["pia_opensubdiv_version"] == ("%d.%d.%d" % this if version == "this" else other)
    miss = np.abs(evaluated_control_points(cage, len(targets)) - targets).max(axis=1) / diagonal(targets)
    if version == "this":
        assert miss.max() <= MATCH, miss
    else:
        assert miss[4] > 1e-3 and np.delete(miss, 4).max() <= MATCH, miss


def test_cli_bad_opensubdiv_version(tmp_path):
    output = str(tmp_path / "never.blend")
    result = run_cli(os.path.join(DATA, "mushroom.obj"), output, "--opensubdiv-version", "three")
    assert result.returncode == 1
    assert "opensubdiv_version" in result.stderr
    assert not os.path.exists(output)


def _export(kind, path):
    """Write the active object to .ply / .stl with whichever exporter this Blender has."""
    candidates = {"ply": (("wm", "ply_export"), ("export_mesh", "ply")),
                  "stl": (("wm", "stl_export"), ("export_mesh", "stl"))}[kind]
    for module, name in candidates:
        if operator_exists(module, name):
            return getattr(getattr(bpy.ops, module), name)(filepath=path)
    pytest.skip("no %s exporter" % kind)


@pytest.mark.parametrize("kind", ("ply", "stl", "blend"))
def test_cli_other_inputs(tmp_path, kind):
    source = shapes.uv_sphere()
    source.name = "Ball"
    path = str(tmp_path / ("ball." + kind))
    extra = []
    if kind == "blend":
        shapes.cube()  # the active object is the cube, --object picks the ball
        bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
        extra = ["--object", "Ball"]
    else:
        _export(kind, path)
    output = str(tmp_path / "out.blend")
    result = run_cli(path, output, "--levels", "1", *extra)
    assert result.returncode == 0, result.stdout + result.stderr
    with bpy.data.libraries.load(output) as (data_from, data_to):
        names = list(data_from.objects)
    assert any(name.endswith("_pia") for name in names), names
    if kind == "blend":
        assert "Ball_pia" in names
