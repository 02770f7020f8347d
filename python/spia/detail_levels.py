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
# scan's pull's buffers, the level itself, and the scan side's hierarchy.
# Measured on the bunny's cage on two threads, the peak resident size over
# the call: 0.25e9, 0.41e9, 1.61e9 and 6.32e9 bytes at 2 to 5 levels
# (0.18M to 11.5M samples): 547 bytes a sample from 4 to 5 levels, and up
# to 0.15e9 bytes besides.  The estimate keeps a tenth or more over both.
# A measuring grid of more than 2M quads is now searched through its faces'
# corners, a quarter of it: the dragon's 50k-vertex cage at 3 levels (12.9M
# samples) grew 5.64e9 bytes over its finest fit, 437 a sample, and 5.8e9
# over the whole call in Blender; a 3,052-face cage at 5 levels (12.5M
# samples) 5.6e9.  The estimate keeps 600, which grids at the cap need.
DETAIL_BYTES_PER_SAMPLE = 600
DETAIL_BYTES_FIXED = 256 << 20


def detail_memory_estimate(cage, levels, samples_per_edge=4):
    """Bytes :func:`fit_detail` needs at its peak for ``cage`` at
    ``levels``, and the finest level's face count, as (bytes, faces).
    ``cage``: a :class:`Mesh`, or its number of face corners (the sum of
    its face sizes).  Each level turns an n-sided face into n quads (a quad
    into 4), each level's fit takes DETAIL_BYTES_PER_SAMPLE per sample
    (:func:`detail_samples` squared per face), and the level with the most
    samples sets the peak, with DETAIL_BYTES_FIXED besides: about 2.4 KB
    per finest face at the default samples.  fit_detail itself does not
    refuse: a script checks this against the memory it has."""
    levels = int(levels)
    if levels <= 0:
        return 0, 0
    corners = int(np.sum(np.asarray(cage.face_sizes, np.int64))) if hasattr(cage, "face_sizes") else int(cage)
    samples = max(corners * 4 ** (level - 1) * detail_samples(samples_per_edge, level) ** 2
                  for level in range(1, levels + 1))
    return DETAIL_BYTES_FIXED + DETAIL_BYTES_PER_SAMPLE * samples, corners * 4 ** (levels - 1)


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
               solver_iterations=DETAIL_SOLVER_ITERATIONS, robust_scale=DETAIL_ROBUST_SCALE, memory_budget=0,
               **fit_options):
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
    reports = []
    for level in range(1, levels + 1):
        tick = None if progress is None else (lambda _l, _s, level=level: progress(level, 0, 0.0))
        refined = subdivide(current, 1, progress=tick, **surface)
        follow = None if progress is None else (lambda it, value, level=level: progress(level, it, value))
        positions, report = fit(refined, scan, samples_per_edge=detail_samples(samples_per_edge, level),
                                measure_scan=measure_scan and level == levels, progress=follow, threads=threads,
                                smoothing=smoothing, slide_weight=slide_weight, scan_pull=scan_pull,
                                free_rims=free_rims, max_rounds=max_rounds, solver_iterations=solver_iterations,
                                robust_scale=robust_scale, **surface, **fit_options)
        reports.append(report)
        current = Mesh(positions, refined.face_sizes, refined.face_vertices, edges=refined.edges,
                       edge_creases=refined.edge_creases, vertex_creases=refined.vertex_creases)
    points = flat_positions(current, threads=threads, **surface)
    return DetailResult(levels=levels, mesh=current, points=points, reports=reports)
