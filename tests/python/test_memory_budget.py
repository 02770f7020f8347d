# SPDX-License-Identifier: GPL-3.0-or-later
"""No setting may eat the machine: every call estimates what its settings
make it need before it pays it, and refuses, having allocated nothing, with
a message that names the setting and what would fit.

The creased meshes of crease_cases (every crease 0.7 to 0.99, so semi-sharp
edges of sharpness 4.9 to 9.8) run in child processes limited to 2 GB of
address space, as `ulimit -v` limits a shell: Loop (both boundary rules),
Catmull-Clark at qualities 1 to 10 and Doo-Sabin each finish within 2 s and
300 MB, and a refinement too deep for the limit is refused at once."""
import re

import pytest

from crease_cases import CREASES, MESHES, creased_mesh, run_limited
from spheres import cube_sphere

LIMIT = 2 << 30
PEAK_MB = 300.0
SECONDS = 2.0


def _calls():
    calls = [{"scheme": "LOOP"}, {"scheme": "LOOP", "boundary_rule": "HOPPE"}]
    calls += [{"scheme": "CATMULL_CLARK", "quality": q} for q in range(1, 11)]
    calls.append({"scheme": "DOO_SABIN"})
    return calls


@pytest.mark.parametrize("crease", CREASES)
@pytest.mark.parametrize("mesh", MESHES)
def test_creased_meshes_finish_in_bounded_time_and_memory(mesh, crease):
    calls = _calls()
    out = run_limited(mesh, crease, calls, LIMIT)
    assert out["killed"] is None, "the child was killed (%s): %s" % (out["killed"], out["stderr"])
    assert len(out["calls"]) == len(calls)
    for call, got in zip(calls, out["calls"]):
        assert got["outcome"] == "done", (call, got)
        assert got["result"]["status"] == "CONVERGED", (call, got)
        assert got["result"]["max_error"] <= 1e-6, (call, got)
        assert got["seconds"] <= SECONDS, (call, got)
    assert out["peak_mb"] <= PEAK_MB, out["peak_mb"]


def test_a_refinement_beyond_the_address_space_is_refused_before_it_allocates():
    # 8 levels of the 642-vertex icosphere: 84M triangles, some 20 GB.
    out = run_limited("icosphere-642", 0.9, [{"call": "refine", "levels": 8}, {"call": "refine", "levels": 2}], LIMIT)
    assert out["killed"] is None, out["stderr"]
    refused, done = out["calls"]
    assert refused["outcome"] == "refused" and refused["code"] == "OUT_OF_MEMORY", refused
    # (6 levels, 5.2M triangles, need about 1.5 GB: they fit in what the
    # interpreter leaves of 2 GB, unless its own address space grows past
    # 0.5 GB)
    assert "refining 8 levels" in refused["message"], refused
    assert re.search(r"at most [56] levels fit", refused["message"]), refused
    assert "GB of memory available" in refused["message"], refused
    assert refused["seconds"] < 0.5, refused
    assert done["outcome"] == "done" and done["result"]["faces"] == 1280 * 16, done
    # Nothing near the refused size was ever allocated.
    assert out["peak_mb"] < 150.0, out["peak_mb"]


def test_available_memory_is_positive_and_shrinks_under_an_address_space_limit(native):
    available = native.available_memory()
    assert available is not None and available > 0
    # In a child under the 2 GB limit the library sees less than 2 GB.
    out = run_limited("icosphere-642", 0.9, [{"call": "refine", "levels": 7}], LIMIT)
    message = out["calls"][0]["message"]
    gb = float(message.split("more than the ")[1].split(" GB")[0])
    assert 0.5 < gb < 2.0, message


def _sphere(native, k=8):
    p, f = cube_sphere(k)
    return native.Mesh.from_faces(p, f.tolist())


def test_every_entry_point_refuses_beyond_the_memory_budget(native):
    m = _sphere(native)
    small = 64 << 10
    cases = [
        (lambda: native.interpolate(m, memory_budget=small), "the limit stencils of 386 vertices"),
        (lambda: native.limit_stencils(m, memory_budget=small), "the limit stencils"),
        (lambda: native.subdivide(m, 3, memory_budget=small), "subdividing 3 levels"),
        (lambda: native.refine(m, 4, scheme="DOO_SABIN", memory_budget=small), "refining 4 levels"),
        (lambda: native.surface_stencils(m, 8, memory_budget=small), "with 8 samples per edge"),
    ]
    for call, words in cases:
        with pytest.raises(native.PiaError) as caught:
            call()
        assert caught.value.code == "OUT_OF_MEMORY", caught.value
        assert words in str(caught.value) and "memory budget of 0.00 GB" in str(caught.value), caught.value
    # A negative budget checks nothing; a generous one lets the same calls through.
    for budget in (-1, 1 << 30):
        cage, report = native.interpolate(m, memory_budget=budget)
        assert report.converged
        assert len(native.subdivide(m, 3, memory_budget=budget).face_sizes) == 384 * 4 ** 3


def test_the_fit_names_the_samples_per_edge_that_fit(native):
    cage = _sphere(native, 4)
    scan = native.Scan(_sphere(native, 16))
    samples = native.surface_stencils(cage, 16).row_count
    # Room for 8 samples per edge but not 16.
    budget = int(600 * native.surface_stencils(cage, 8).row_count + 2e6)
    with pytest.raises(native.PiaError) as caught:
        native.fit(cage, scan, samples_per_edge=16, memory_budget=budget)
    text = str(caught.value)
    assert caught.value.code == "OUT_OF_MEMORY", text
    assert "the fit with 16 samples per edge (%d samples)" % samples in text, text
    assert "at most 8 samples per edge fit" in text or "at most 9 samples per edge fit" in text, text
    fitted, report = native.fit(cage, scan, samples_per_edge=4, memory_budget=budget)
    assert fitted.shape == cage.positions.shape


def test_the_budget_must_be_a_whole_number(native):
    with pytest.raises(native.PiaError, match="memory_budget must be a whole number"):
        native.interpolate(_sphere(native, 2), memory_budget=1.5)


def test_a_creased_loop_cage_puts_its_limit_points_on_the_targets(native):
    """At crease 0.99 (ten levels to decay), the cage's limit points, the
    library's table applied to it in numpy, are the mesh's vertices."""
    import numpy as np
    p, f, e, c = creased_mesh("icosphere-42", 0.99)
    m = native.Mesh.from_faces(p, f.tolist(), edges=e, edge_creases=c)
    cage, report = native.interpolate(m, scheme="LOOP", tolerance=1e-9)
    table = native.limit_stencils(m, scheme="LOOP")
    limit = table.apply(cage.astype(np.float64))
    assert np.abs(limit - p).max() < 1e-5


def test_detail_levels_are_refused_before_the_first_is_made(native):
    cage = _sphere(native, 4)
    scan = native.Scan(_sphere(native, 16))
    two, _ = native.detail_memory_estimate(cage, 2)
    three, faces = native.detail_memory_estimate(cage, 3)
    assert two < three
    calls = []
    with pytest.raises(native.PiaError) as caught:
        native.fit_detail(cage, scan, 3, memory_budget=(two + three) // 2, progress=lambda *a: calls.append(a))
    text = str(caught.value)
    assert caught.value.code == "OUT_OF_MEMORY", text
    assert "3 detail levels (%.1fM faces at the finest)" % (faces / 1e6) in text, text
    assert "memory budget of" in text and "at most 2 levels fit" in text, text
    assert calls == [], "a level was started before the refusal"
    result = native.fit_detail(cage, scan, 1, memory_budget=(two + three) // 2)
    assert len(result.mesh.face_sizes) == 4 * len(cage.face_sizes)
