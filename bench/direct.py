# SPDX-License-Identifier: GPL-3.0-or-later
"""Sparse direct solvers for the limit system L V = P, for the benchmarks.

- splu: scipy's SuperLU on L (COLAMD ordering).
- umfpack: SuiteSparse's UMFPACK on L, through ctypes (libumfpack).
- cholmod: SuiteSparse's CHOLMOD on S V = D^-1 P, where L = D S with D a
  positive diagonal and S symmetric positive definite (closed meshes),
  through ctypes (libcholmod).

Only numpy, scipy and the shared libraries of Debian's libsuitesparse-dev are
used.  Each solver returns V as an (n, 3) float64 array.
"""
import ctypes
import ctypes.util

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg


class DirectSolverError(Exception):
    pass


def _load(name):
    path = ctypes.util.find_library(name)
    if path is None:
        raise DirectSolverError(f"lib{name} not found (Debian: libsuitesparse-dev)")
    return ctypes.CDLL(path)


# --------------------------------------------------------------------------
# L = D S
# --------------------------------------------------------------------------

def symmetrizing_diagonal(L):
    """A positive d with L = diag(d) S, S symmetric, if there is one: d_i / d_j
    must equal L_ij / L_ji along every edge.  The ratios are taken along a
    breadth-first spanning forest (log d summed root to leaf by pointer
    doubling); symmetry_error() says whether they hold on every edge."""
    L = scipy.sparse.csr_matrix(L)
    n = L.shape[0]
    pattern = (abs(L) + abs(L.T)).tocsr()
    _ncomp, labels = scipy.sparse.csgraph.connected_components(pattern, directed=False)
    parent = np.full(n, -1, np.int64)
    for comp in np.unique(labels):
        root = int(np.flatnonzero(labels == comp)[0])
        _order, pred = scipy.sparse.csgraph.breadth_first_order(pattern, root, directed=False,
                                                                return_predecessors=True)
        reached = pred >= 0
        parent[reached] = pred[reached]
        parent[root] = root
    child = np.flatnonzero(parent != np.arange(n))
    up = np.asarray(L[child, parent[child]]).ravel()      # L_{i, parent}
    down = np.asarray(L[parent[child], child]).ravel()    # L_{parent, i}
    if np.any(up <= 0) or np.any(down <= 0):
        raise DirectSolverError("L has a non-positive weight between neighbours: no positive diagonal D")
    acc = np.zeros(n)
    acc[child] = np.log(up / down)                        # log d_i - log d_parent
    ptr = parent.copy()
    while np.any(ptr != ptr[ptr]):   # invariant: acc_i = log d_i - log d_ptr(i); roots have acc 0
        acc = acc + acc[ptr]
        ptr = ptr[ptr]
    return np.exp(acc)


def symmetric_part(L, d):
    """S = D^-1 L (CSR)."""
    return scipy.sparse.diags(1.0 / d) @ scipy.sparse.csr_matrix(L)


def symmetry_error(S):
    """max |S - S^T| / max |S|."""
    diff = abs(S - S.T)
    return float(diff.max() / abs(S).max()) if diff.nnz else 0.0


# --------------------------------------------------------------------------
# SuperLU
# --------------------------------------------------------------------------

def solve_splu(L, P):
    lu = scipy.sparse.linalg.splu(scipy.sparse.csc_matrix(L))
    return lu.solve(np.asarray(P, np.float64))


# --------------------------------------------------------------------------
# UMFPACK
# --------------------------------------------------------------------------

_UMFPACK_A = 0


def solve_umfpack(L, P):
    lib = _load("umfpack")
    A = scipy.sparse.csc_matrix(L)
    A.sort_indices()
    n = A.shape[0]
    # The "dl" (int64) interface: the "di" one runs out of integer
    # workspace on meshes of about 2M vertices.
    Ap = np.ascontiguousarray(A.indptr, np.int64)
    Ai = np.ascontiguousarray(A.indices, np.int64)
    Ax = np.ascontiguousarray(A.data, np.float64)
    vp = ctypes.c_void_p
    dp = ctypes.POINTER(ctypes.c_double)
    ip = ctypes.POINTER(ctypes.c_int64)
    lib.umfpack_dl_symbolic.argtypes = [ctypes.c_int64, ctypes.c_int64, ip, ip, dp, ctypes.POINTER(vp), dp, dp]
    lib.umfpack_dl_numeric.argtypes = [ip, ip, dp, vp, ctypes.POINTER(vp), dp, dp]
    lib.umfpack_dl_solve.argtypes = [ctypes.c_int64, ip, ip, dp, dp, dp, vp, dp, dp]
    lib.umfpack_dl_free_symbolic.argtypes = [ctypes.POINTER(vp)]
    lib.umfpack_dl_free_numeric.argtypes = [ctypes.POINTER(vp)]
    for f in ("umfpack_dl_symbolic", "umfpack_dl_numeric", "umfpack_dl_solve"):
        getattr(lib, f).restype = ctypes.c_int64  # SuiteSparse_long in the dl interface
    ptr = lambda a, t: a.ctypes.data_as(t)  # noqa: E731
    symbolic, numeric = vp(), vp()
    code = lib.umfpack_dl_symbolic(n, n, ptr(Ap, ip), ptr(Ai, ip), ptr(Ax, dp), ctypes.byref(symbolic), None, None)
    if code != 0:
        raise DirectSolverError(f"umfpack_dl_symbolic: status {code}")
    try:
        code = lib.umfpack_dl_numeric(ptr(Ap, ip), ptr(Ai, ip), ptr(Ax, dp), symbolic, ctypes.byref(numeric),
                                      None, None)
        if code != 0:
            raise DirectSolverError(f"umfpack_dl_numeric: status {code}")
        B = np.asfortranarray(np.asarray(P, np.float64))
        X = np.empty_like(B, order="F")
        for a in range(B.shape[1]):
            b = np.ascontiguousarray(B[:, a])
            x = np.empty(n)
            code = lib.umfpack_dl_solve(_UMFPACK_A, ptr(Ap, ip), ptr(Ai, ip), ptr(Ax, dp), ptr(x, dp), ptr(b, dp),
                                        numeric, None, None)
            if code != 0:
                raise DirectSolverError(f"umfpack_dl_solve: status {code}")
            X[:, a] = x
        return np.ascontiguousarray(X)
    finally:
        if numeric:
            lib.umfpack_dl_free_numeric(ctypes.byref(numeric))
        lib.umfpack_dl_free_symbolic(ctypes.byref(symbolic))


# --------------------------------------------------------------------------
# CHOLMOD
# --------------------------------------------------------------------------

class _Sparse(ctypes.Structure):  # cholmod_sparse (cholmod_core.h)
    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("p", ctypes.c_void_p), ("i", ctypes.c_void_p), ("nz", ctypes.c_void_p),
                ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
                ("stype", ctypes.c_int), ("itype", ctypes.c_int), ("xtype", ctypes.c_int),
                ("dtype", ctypes.c_int), ("sorted", ctypes.c_int), ("packed", ctypes.c_int)]


class _Dense(ctypes.Structure):  # cholmod_dense
    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("d", ctypes.c_size_t), ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
                ("xtype", ctypes.c_int), ("dtype", ctypes.c_int)]


class _FactorHead(ctypes.Structure):  # the first two fields of cholmod_factor
    _fields_ = [("n", ctypes.c_size_t), ("minor", ctypes.c_size_t)]


_CHOLMOD_INT, _CHOLMOD_REAL, _CHOLMOD_DOUBLE, _CHOLMOD_A = 0, 1, 0, 0
_COMMON_BYTES = 1 << 16  # cholmod_common is 2,664 bytes in CHOLMOD 3; it is opaque here


def solve_cholmod_spd(S, B):
    """Solves S X = B for a symmetric positive definite S (only its upper
    triangle is read) with CHOLMOD's defaults (AMD or METIS ordering,
    simplicial LDL' or supernodal LL' as it chooses).  A zero pivot (or, in
    LL', a non-positive one) raises DirectSolverError."""
    lib = _load("cholmod")
    vp = ctypes.c_void_p
    lib.cholmod_start.argtypes = [vp]
    lib.cholmod_finish.argtypes = [vp]
    lib.cholmod_analyze.argtypes = [ctypes.POINTER(_Sparse), vp]
    lib.cholmod_analyze.restype = vp
    lib.cholmod_factorize.argtypes = [ctypes.POINTER(_Sparse), vp, vp]
    lib.cholmod_solve.argtypes = [ctypes.c_int, vp, ctypes.POINTER(_Dense), vp]
    lib.cholmod_solve.restype = ctypes.POINTER(_Dense)
    lib.cholmod_free_factor.argtypes = [ctypes.POINTER(vp), vp]
    lib.cholmod_free_dense.argtypes = [ctypes.POINTER(ctypes.POINTER(_Dense)), vp]

    upper = scipy.sparse.triu(scipy.sparse.csc_matrix(S), format="csc")
    upper.sort_indices()
    n = upper.shape[0]
    Ap = np.ascontiguousarray(upper.indptr, np.int32)
    Ai = np.ascontiguousarray(upper.indices, np.int32)
    Ax = np.ascontiguousarray(upper.data, np.float64)
    A = _Sparse(nrow=n, ncol=n, nzmax=len(Ax), p=Ap.ctypes.data, i=Ai.ctypes.data, nz=None, x=Ax.ctypes.data,
                z=None, stype=1, itype=_CHOLMOD_INT, xtype=_CHOLMOD_REAL, dtype=_CHOLMOD_DOUBLE, sorted=1, packed=1)
    Bf = np.asfortranarray(np.asarray(B, np.float64).reshape(n, -1))
    Bd = _Dense(nrow=n, ncol=Bf.shape[1], nzmax=Bf.size, d=n, x=Bf.ctypes.data, z=None, xtype=_CHOLMOD_REAL,
                dtype=_CHOLMOD_DOUBLE)
    common = ctypes.create_string_buffer(_COMMON_BYTES)
    cp = ctypes.cast(common, vp)
    lib.cholmod_start(cp)
    factor = vp()
    try:
        factor = vp(lib.cholmod_analyze(ctypes.byref(A), cp))
        if not factor:
            raise DirectSolverError("cholmod_analyze failed")
        lib.cholmod_factorize(ctypes.byref(A), factor, cp)
        head = ctypes.cast(factor, ctypes.POINTER(_FactorHead)).contents
        if head.minor < head.n:
            raise DirectSolverError(f"CHOLMOD: not positive definite (column {head.minor})")
        X = lib.cholmod_solve(_CHOLMOD_A, factor, ctypes.byref(Bd), cp)
        if not X:
            raise DirectSolverError("cholmod_solve failed")
        x = X.contents
        out = np.ctypeslib.as_array(ctypes.cast(x.x, ctypes.POINTER(ctypes.c_double)), shape=(x.ncol * x.d,))
        result = out.reshape(x.ncol, x.d)[:, :n].T.copy()
        lib.cholmod_free_dense(ctypes.byref(X), cp)
        return result
    finally:
        if factor:
            lib.cholmod_free_factor(ctypes.byref(factor), cp)
        lib.cholmod_finish(cp)


def solve_cholmod(L, P, d=None):
    """Solves L V = P as S V = D^-1 P with CHOLMOD (L = D S, S SPD)."""
    if d is None:
        d = symmetrizing_diagonal(L)
    S = symmetric_part(L, d)
    return solve_cholmod_spd(S, np.asarray(P, np.float64) / d[:, None])
