# SPDX-License-Identifier: GPL-3.0-or-later
"""Detail levels on a fitted cage (:func:`fit_detail`): the cage subdivided
one level at a time and each level fitted to the scan, with the memory
that takes told in advance (:func:`detail_memory_estimate`)."""

import sys
from dataclasses import dataclass, field

import numpy as np

from .errors import PiaError
from .library import available_memory
from .mesh import Mesh


def _stages():
    """subdivide, fit and flat_positions as the spia package holds them at
    the call: fit_detail calls them through the package, as a script calls
    them, so that one put in their place there (a profiler timing each
    stage, say) sees the calls fit_detail makes too."""
    package = sys.modules[__package__]
    return package.subdivide, package.fit, package.flat_positions


@dataclass
class DetailResult:
    """What :func:`fit_detail` made: the finest level's control mesh, the
    positions of its vertices as a Multires modifier's finest level shows
    them (flat faces straddling its limit surface), and each level's fit."""
    levels: int
    mesh: Mesh                  # the finest level's control mesh, fitted (mesh.positions)
    points: np.ndarray = field(repr=False)   # (N, 3) float32: the finest level's vertices, drawn flat
    reports: list = field(default_factory=list)  # a FitReport per level, coarse to fine
    # (vertex count, face_sizes, face_vertices) of the cage and each level,
    # 0 to levels, as subdivide numbered them
    level_topology: list = field(default_factory=list, repr=False)

    @property
    def report(self):
        """The finest level's fit."""
        return self.reports[-1]


def detail_samples(samples_per_edge, level):
    """Samples per ptex edge for detail level ``level``: the base's count
    halved a level (each level's faces are a quarter of the last's), down to
    two, the fewest with which the fold guard sees a sample's neighbours."""
    return max(2, int(samples_per_edge) >> int(level))


# The peak of fit_detail is the fit of its level with the most samples
# (the finest, unless halving samples_per_edge drops a remainder): the
# samples' stencils, closest points and normals, the fold guard's and the
# scan's pull's buffers and the level itself, DETAIL_BYTES_PER_SAMPLE; at
# the finest level, the grid that measures the scan's distances besides
# (:func:`_measure_grid`): its points, and the hierarchy over its quads, or
# over one quad a ptex face once the grid has more than 2M quads.  (The
# fit frees its rounds' buffers before it measures the scan, so the two
# do not add up: the sum keeps a margin.)  Measured on two threads, the
# growth of the resident size: over the bunny's cage's 3 levels, 0.36e9
# bytes (0.72M samples, a grid of 0.72M quads); over the whole call in
# Blender, the scan's hierarchy included, 4.7e9 for the dragon's
# 50k-vertex cage at 3 levels (12.9M samples, 3.2M ptex faces searched)
# and 4.6e9 for a 3,044-vertex cage at 5 levels (12.5M samples).  The
# estimate is 0.57e9, 5.25e9 and 5.08e9: the fixed part weighs on small
# cages, and it keeps a tenth over the large ones.
DETAIL_BYTES_PER_SAMPLE = 290
DETAIL_BYTES_PER_GRID_POINT = 16
DETAIL_BYTES_PER_SEARCHED_QUAD = 280
DETAIL_BYTES_FIXED = 128 << 20
# The largest grid searched through a hierarchy of its own (the library's
# SCAN_GRID_FACES).
MEASURE_GRID_QUADS = 2 << 20


def _measure_grid(ptex, per_edge):
    """(points, quads searched) of the grid on which the library measures
    the scan's distances to a surface of ``ptex`` ptex faces sampled
    ``per_edge`` times an edge: 2^L quads along a ptex edge, L one more
    than ceil(log2 per_edge) and one fewer while the grid would have more
    than MEASURE_GRID_QUADS quads (at least one); a grid still larger is
    searched through one quad a ptex face."""
    levels = 1
    while (1 << levels) < per_edge:
        levels += 1
    levels += 1
    while levels > 1 and ptex << (2 * levels) > MEASURE_GRID_QUADS:
        levels -= 1
    quads = ptex << (2 * levels)
    return ptex * ((1 << levels) + 1) ** 2, ptex if quads > MEASURE_GRID_QUADS else quads


def detail_memory_estimate(cage, levels, samples_per_edge=4):
    """Bytes :func:`fit_detail` needs at its peak for ``cage`` at
    ``levels``, and the finest level's face count, as (bytes, faces).
    ``cage``: a :class:`Mesh`, or its number of face corners (the sum of
    its face sizes).  Each level turns an n-sided face into n quads (a quad
    into 4), each level's fit takes DETAIL_BYTES_PER_SAMPLE per sample
    (:func:`detail_samples` squared per face) and the finest level's the
    grid that measures the scan besides (:func:`_measure_grid`); the level
    that needs the most sets the peak, with DETAIL_BYTES_FIXED besides:
    about 1.6 KB per finest face of a large cage at the default samples.
    fit_detail itself does not refuse: a script checks this against the
    memory it has."""
    levels = int(levels)
    if levels <= 0:
        return 0, 0
    corners = int(np.sum(np.asarray(cage.face_sizes, np.int64))) if hasattr(cage, "face_sizes") else int(cage)

    def need(level):
        ptex, per_edge = corners * 4 ** (level - 1), detail_samples(samples_per_edge, level)
        total = DETAIL_BYTES_PER_SAMPLE * ptex * per_edge ** 2
        if level == levels:
            points, searched = _measure_grid(ptex, per_edge)
            total += DETAIL_BYTES_PER_GRID_POINT * points + DETAIL_BYTES_PER_SEARCHED_QUAD * searched
        return total
    return DETAIL_BYTES_FIXED + max(need(level) for level in range(1, levels + 1)), corners * 4 ** (levels - 1)


def check_detail_memory(cage, levels, samples_per_edge=4, memory_budget=0):
    """Raises :class:`PiaError` OUT_OF_MEMORY, naming the levels that fit,
    when ``levels`` detail levels on ``cage`` (a :class:`Mesh` or its corner
    count) would need more than ``memory_budget`` bytes (0: what
    :func:`available_memory` reports; negative: no check)."""
    budget = int(memory_budget)
    if budget == 0:
        budget = available_memory() or -1
    if budget < 0:
        return
    need, faces = detail_memory_estimate(cage, levels, samples_per_edge)
    if need <= budget:
        return
    fit = max((k for k in range(levels) if detail_memory_estimate(cage, k, samples_per_edge)[0] <= budget), default=0)
    where = "the memory budget of" if memory_budget else "the"
    raise PiaError("OUT_OF_MEMORY", "%d detail levels (%.1fM faces at the finest) need about %.2f GB, more than "
                   "%s %.2f GB of memory%s: %s" % (
                       levels, faces / 1e6, need / 2.0 ** 30, where, budget / 2.0 ** 30,
                       "" if memory_budget else " available",
                       "at most %d level%s fit" % (fit, "" if fit == 1 else "s") if fit else "not one level fits"))


# Detail levels start on the scan already: they are held firmer than a
# first fit (fairness, and samples held back from sliding past one another),
# which on the bunny's raw scan at 3 levels turns 0.09% of the finest faces
# over against the starting cage instead of 1.1%, as close to the scan.
DETAIL_SMOOTHING = 1e-3
DETAIL_SLIDE_WEIGHT = 0.1
# And they need fewer rounds and steps: 3 rounds of 5 conjugate-gradient
# steps a level left the bunny's, armadillo's and Chinese dragon's finest
# levels within 2% of 16 rounds of 20 steps (closer, for the bunny), in less
# than half the time.
DETAIL_ROUNDS = 3
DETAIL_SOLVER_ITERATIONS = 5
# The finest level of three or more starts on a surface fitted at a
# quarter of its faces and takes the scan's finest detail in two rounds:
# on bench_detail.py's five scans at 3 levels a third round moved the
# 95th percentiles by at most 2.5% either way, the means by at most 3% (the
# Chinese dragon's from the surface) and the folds by at most 0.001% of
# the faces, and at production size (a 50k-vertex cage, 12.9M samples at
# the finest level) it took 7.7 s of that level's 43.7 s.  At 2 levels it
# still gained 1-3% and kept the armadillo's folds at 0.023% instead of
# 0.031%; with 1 level, the elephant's at 0.024% instead of 0.055%.
DETAIL_FINEST_ROUNDS = 2
DETAIL_FINEST_FROM_LEVEL = 3
# The robust kernel's scale is a multiple of the median distance, and a
# detail level starts with a median a fraction of the base fit's: at the
# base's multiple (6) the kernel took the armadillo's claws, scan just
# beyond the base surface, for outliers.  At 15 the scan's mean
# distance from the finest level falls 3% (elephant) to 26% (armadillo) on
# bench_detail.py's five cases, and the folds stay at most 0.04% on the covered
# scans; at 30 the armadillo's folds tripled to 0.08%.
DETAIL_ROBUST_SCALE = 15.0


def fit_detail(cage, scan, levels, samples_per_edge=4, progress=None, boundary_smooth="ALL", use_creases=True,
               quality=3, opensubdiv_version=None, threads=0, measure_scan=True, smoothing=DETAIL_SMOOTHING,
               slide_weight=DETAIL_SLIDE_WEIGHT, scan_pull=True, free_rims=True, max_rounds=DETAIL_ROUNDS,
               finest_rounds=DETAIL_FINEST_ROUNDS, solver_iterations=DETAIL_SOLVER_ITERATIONS,
               robust_scale=DETAIL_ROBUST_SCALE, memory_budget=0, **fit_options):
    """Detail levels on a cage whose limit surface lies on ``scan`` (usually
    the result of :func:`fit`): the cage subdivided one level at a time
    (:func:`subdivide`), and each level fitted to the scan as a cage of its
    own (:func:`fit`, with its guards: the fairness term holds each level to
    the level above where the scan says nothing, so holes are spanned
    smoothly; folds and outliers do not pull; with ``scan_pull`` the scan's
    vertices pull each level too, so that it meets the scan from both
    sides; with ``free_rims`` the cage's rims are not held smoother, as the
    fit of a cage not yet on the scan holds them).  Coarse levels take the
    broad shape, fine levels the detail.  The finest level's vertices are
    then placed so that its faces, drawn flat as Multires draws them,
    straddle the fitted limit surface (:func:`flat_positions`).
    ``levels``: 1 to 6.  Each level's samples per edge:
    :func:`detail_samples`.  ``progress(level, round, mean) -> bool``
    follows each level's fit; True cancels (:class:`PiaCancelled`).
    ``fit_options``: those of :func:`fit` (cutoff, ...); ``smoothing``,
    ``slide_weight``, ``max_rounds``, ``solver_iterations`` and
    ``robust_scale`` default to DETAIL_SMOOTHING, DETAIL_SLIDE_WEIGHT,
    DETAIL_ROUNDS, DETAIL_SOLVER_ITERATIONS and DETAIL_ROBUST_SCALE.
    ``max_rounds`` bounds each level's rounds but the finest's when there
    are DETAIL_FINEST_FROM_LEVEL levels or more: ``finest_rounds`` bounds
    that one (None: ``max_rounds``).  ``measure_scan``: the finest level
    measures the scan's vertices against the surface it wrote
    (``report.scan_after``; its ``scan_before`` is None: the surface it
    started from is the level above's, not measured).
    The finest level's vertices are numbered as :func:`subdivide` applied
    one level at a time numbers them.  ``memory_budget`` (bytes; 0: what
    the machine has available, negative: no check): the levels are refused
    before the first is made when :func:`detail_memory_estimate` says they
    would need more (:func:`check_detail_memory`).  A level's report has status
    'MAX_ITERATIONS' when its rounds were all used (the defaults' few rounds
    usually are): the level is written all the same.  Returns a
    :class:`DetailResult`."""
    levels = int(levels)
    if not 1 <= levels <= 6:
        raise PiaError("INVALID_ARGUMENT", f"levels must be 1 to 6, not {levels!r}")
    check_detail_memory(cage, levels, samples_per_edge, memory_budget)
    surface = dict(boundary_smooth=boundary_smooth, use_creases=use_creases, quality=quality,
                   opensubdiv_version=opensubdiv_version, memory_budget=memory_budget)
    subdivide, fit, flat_positions = _stages()
    current = cage
    reports, topology = [], [(cage.vertex_count, cage.face_sizes, cage.face_vertices)]
    for level in range(1, levels + 1):
        finest = level == levels
        rounds = (finest_rounds if finest and levels >= DETAIL_FINEST_FROM_LEVEL and finest_rounds is not None
                  else max_rounds)
        tick = None if progress is None else (lambda _l, _s, level=level: progress(level, 0, 0.0))
        refined = subdivide(current, 1, progress=tick, **surface)
        follow = None if progress is None else (lambda it, value, level=level: progress(level, it, value))
        positions, report = fit(refined, scan, samples_per_edge=detail_samples(samples_per_edge, level),
                                measure_scan="after" if measure_scan and finest else False, progress=follow,
                                threads=threads,
                                smoothing=smoothing, slide_weight=slide_weight, scan_pull=scan_pull,
                                free_rims=free_rims, max_rounds=rounds, solver_iterations=solver_iterations,
                                robust_scale=robust_scale, flat=finest, **surface, **fit_options)
        reports.append(report)
        topology.append((refined.vertex_count, refined.face_sizes, refined.face_vertices))
        current = Mesh(positions, refined.face_sizes, refined.face_vertices, edges=refined.edges,
                       edge_creases=refined.edge_creases, vertex_creases=refined.vertex_creases)
    # The finest level's fit gives them from its own limit points where it
    # can (a fifth of the time flat_positions takes).
    points = reports[-1].flat_positions
    if points is None:
        points = flat_positions(current, threads=threads, **surface)
    return DetailResult(levels=levels, mesh=current, points=points, reports=reports, level_topology=topology)
