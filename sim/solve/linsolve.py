"""Sparse symmetric positive-definite solves behind one small interface.

``make_solver(pattern, backend)`` returns an object with ``factor(data)`` and ``solve(b)``; the
symbolic analysis (fill-reducing ordering) is done once per pattern and reused for every Newton
iteration of a run. Backends:

- ``pardiso``: MKL PARDISO (from the ``mkl`` wheel that ``pypardiso`` installs) through a thin
  ctypes wrapper: phase 11 once, then 22 / 33; several times faster than SuperLU (q3t bench).
- ``scipy``: SuperLU with a symmetric ordering, always available (slower, no reuse of analysis).

``factor`` raises ``SingularMatrix`` on a zero or negative pivot, so the caller can regularise.
"""

from __future__ import annotations

import ctypes
import glob
import os
import sys
from typing import Protocol

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from sim.solve.assembly import Pattern


class SingularMatrix(RuntimeError):
    """The matrix is not positive definite (zero/negative pivot)."""


class LinearSolver(Protocol):
    """What ``make_solver`` returns: ``factor`` the Hessian data ``(nnz,)`` of its pattern,
    then ``solve`` for right-hand sides ``(n_dof,)``."""

    name: str

    def factor(self, data: np.ndarray) -> None: ...

    def solve(self, b: np.ndarray) -> np.ndarray: ...


def _find_mkl() -> ctypes.CDLL | None:
    # MKL's OpenMP threads spin 200 ms after each call by default, stealing both cores from
    # the numba assembly that follows (q3t bench's assembly time shows it)
    os.environ.setdefault("KMP_BLOCKTIME", "0")
    paths = [os.environ.get("Q3T_MKL_RT", "")]
    paths += sorted(glob.glob(f"{sys.prefix}/lib*/libmkl_rt.so*"), key=len)
    for p in filter(None, paths):
        try:
            return ctypes.CDLL(p)
        except OSError:
            continue
    return None


_MKL = None


def mkl() -> ctypes.CDLL | None:
    global _MKL
    if _MKL is None:
        _MKL = _find_mkl() or False
    return _MKL or None


class Pardiso:
    """MKL PARDISO, real SPD (mtype 2), upper triangle CSR, zero-based indices."""

    name = "pardiso"

    def __init__(self, pattern: Pattern):
        lib = mkl()
        if lib is None:
            raise ImportError("libmkl_rt not found (pip install pypardiso)")
        self._f = lib.pardiso
        i32p = ctypes.POINTER(ctypes.c_int32)
        self._f.argtypes = [ctypes.c_void_p, i32p, i32p, i32p, i32p, i32p, ctypes.c_void_p,
                            i32p, i32p, i32p, i32p, i32p, i32p, ctypes.c_void_p,
                            ctypes.c_void_p, i32p]
        self._f.restype = None
        self.n = pattern.n_dof
        self.ia = pattern.indptr.astype(np.int32)
        self.ja = pattern.indices.astype(np.int32)
        self.pt = np.zeros(64, np.int64)
        self.iparm = np.zeros(64, np.int32)
        self.iparm[0] = 1  # our own settings, not MKL defaults
        self.iparm[1] = 2  # METIS nested dissection
        self.iparm[9] = 8  # pivot perturbation 1e-8 (only used for indefinite types)
        self.iparm[7] = 0  # no automatic refinement: the caller refines only when needed
        self.iparm[34] = 1  # zero-based indexing
        # conditional numerical reproducibility with MKL's thread count: PARDISO's threads
        # otherwise sum in an order that changes from call to call, so the same run repeated
        # took other Newton paths wherever a solve was near-singular
        self.iparm[33] = max(1, int(lib.MKL_Get_Max_Threads()))
        self.data = np.zeros(len(self.ja))
        self._call(11, np.zeros(self.n))

    def _call(self, phase: int, b: np.ndarray) -> np.ndarray:
        x = np.zeros_like(b)
        err = ctypes.c_int32(0)

        def i32(v: int) -> ctypes._CArgObject:
            return ctypes.byref(ctypes.c_int32(v))

        self._f(self.pt.ctypes.data, i32(1), i32(1), i32(2), i32(phase), i32(self.n),
                self.data.ctypes.data, self.ia.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)),
                self.ja.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)), None, i32(1),
                self.iparm.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)), i32(0),
                b.ctypes.data, x.ctypes.data, ctypes.byref(err))
        if err.value == -4:
            raise SingularMatrix("zero or negative pivot in PARDISO factorisation")
        if err.value != 0:
            raise RuntimeError(f"PARDISO phase {phase} failed with error {err.value}")
        return x

    def factor(self, data: np.ndarray) -> None:
        self.data = np.ascontiguousarray(data, float)
        self._call(22, np.zeros(self.n))

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._call(33, np.ascontiguousarray(b, float))

    def __del__(self) -> None:
        try:
            self._call(-1, np.zeros(self.n))
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


class SciPyLU:
    """SuperLU with a symmetric ordering and diagonal pivots only, so the signs of U's diagonal
    are the inertia of the matrix (a positive-definiteness check like Cholesky's)."""

    name = "scipy"

    def __init__(self, pattern: Pattern):
        self.pattern = pattern
        self._lu = None

    def factor(self, data: np.ndarray) -> None:
        A = self.pattern.matrix(data).tocsc()
        try:
            self._lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                 options=dict(SymmetricMode=True))
        except RuntimeError as exc:
            raise SingularMatrix(str(exc)) from exc
        d = self._lu.U.diagonal()
        if np.any(d <= 0) or not np.all(np.isfinite(d)):
            raise SingularMatrix("non-positive pivot in SuperLU factorisation")

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._lu.solve(b)


BACKENDS = {"pardiso": Pardiso, "scipy": SciPyLU}


def make_solver(pattern: Pattern, backend: str = "auto") -> Pardiso | SciPyLU:
    """``auto`` picks PARDISO when MKL is installed, else SciPy."""
    if backend == "auto":
        backend = "pardiso" if mkl() is not None else "scipy"
    if backend not in BACKENDS:
        raise ValueError(f"unknown linear solver {backend!r}; known: auto, {', '.join(BACKENDS)}")
    return BACKENDS[backend](pattern)


def full_matrix(pattern: Pattern, data: np.ndarray) -> sp.csr_matrix:
    return pattern.matrix(data)
