# SPDX-License-Identifier: GPL-3.0-or-later
"""The benchmark's direct solvers (bench/direct.py) solve what they claim to:
SuperLU, UMFPACK and CHOLMOD (through ctypes) against scipy's spsolve on the
limit stencils of a small sphere, and the diagonal D of L = D S against the
Catmull-Clark limit mask, whose rows are w_ij / (n (n + 5)) with w symmetric
(n^2 on the vertex, 4 on edge neighbours, 1 on face neighbours)."""
import os
import sys

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

BENCH = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "bench")
sys.path.insert(0, BENCH)

import direct  # noqa: E402
from meshes import quad_sphere  # noqa: E402


@pytest.fixture(scope="module")
def system(native):
    P, fv = quad_sphere(7, noise=0.01)
    mesh = native.Mesh(P, np.full(len(fv), 4, np.int32), fv.ravel())
    L = native.limit_stencils(mesh).to_scipy()
    valence = np.bincount(fv.ravel(), minlength=len(P))  # closed quad mesh: faces per vertex = valence
    return L, np.asarray(P, np.float64), valence


def test_diagonal_matches_the_catmull_clark_mask(system):
    L, _P, n = system
    d = direct.symmetrizing_diagonal(L)
    scaled = d * n * (n + 5)
    assert np.ptp(scaled) < 1e-12 * scaled.mean()
    S = direct.symmetric_part(L, d)
    assert direct.symmetry_error(S) < 1e-13
    assert set(np.unique(n)) == {3, 4}  # both kinds of row were checked


def test_diagonal_of_a_nonsymmetrizable_matrix_fails_the_check():
    A = scipy.sparse.csr_matrix(np.array([[0.5, 0.3, 0.2], [0.1, 0.6, 0.3], [0.3, 0.1, 0.6]]))
    S = direct.symmetric_part(A, direct.symmetrizing_diagonal(A))
    assert direct.symmetry_error(S) > 1e-3


@pytest.mark.parametrize("solve", [direct.solve_splu, direct.solve_umfpack, direct.solve_cholmod],
                         ids=["SuperLU", "UMFPACK", "CHOLMOD"])
def test_solvers_agree_with_spsolve(system, solve):
    L, P, _n = system
    reference = scipy.sparse.linalg.spsolve(scipy.sparse.csc_matrix(L), P)
    V = solve(L, P)
    assert V.shape == P.shape
    assert np.abs(V - reference).max() < 1e-10
    assert np.abs(L @ V - P).max() < 1e-12


def test_cholmod_reports_a_zero_pivot():
    A = scipy.sparse.csr_matrix(np.array([[1.0, 1.0], [1.0, 1.0]]))
    with pytest.raises(direct.DirectSolverError, match="not positive definite"):
        direct.solve_cholmod_spd(A, np.ones(2))
