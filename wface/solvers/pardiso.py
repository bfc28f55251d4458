"""A thin ctypes binding of MKL PARDISO for real SPD matrices: analysis once per sparsity, factors in slots.

PARDISO (Intel oneMKL) runs in three phases: 11 = fill-reducing ordering and symbolic factorisation
(the *analysis*), 22 = numeric factorisation, 33 = forward and back substitution. The analysis
depends only on the sparsity, so ``PardisoAnalysis`` does it once per pattern (a mesh and its
unknowns) and keeps up to ``slots`` numeric factors of matrices with that sparsity alive at the same
time (PARDISO's ``maxfct`` / ``mnum``): the tracker holds the factor of the previous equilibrium
(chord Newton) while it factors the new one (docs/design.md, "Linear solvers").

Settings (``_iparm``): ``pardisoinit`` defaults for mtype 2 (real SPD, upper triangle in CSR), then
zero-based indices (iparm[34] = 1, so the CSR arrays are passed as they are, never copied), no
iterative refinement (iparm[7] = 0; the default two steps per solve cost 5x the solve itself) and
conditional numerical reproducibility: sequential METIS ordering (iparm[1] = 2; the parallel
ordering iparm[1] = 3 rules the mode out) and iparm[33] = the thread count. Without that mode the
multi-threaded factorisation differed at round-off from run to run and the tracker amplified it.

The MKL runtime library comes from ``PYPARDISO_MKL_RT``, else the loader's search path, else the
Python prefix (where the ``mkl`` wheel that pypardiso depends on puts it).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import site
import sys
import threading
import time

import numpy as np
import scipy.sparse as sp

__all__ = ["PardisoAnalysis", "PardisoError", "PardisoFactor", "mkl_runtime", "pardiso_threads"]

_MTYPE_SPD = 2
_ERRORS = {
    -1: "input inconsistent",
    -2: "not enough memory",
    -3: "reordering problem",
    -4: "zero or negative pivot: the matrix is not positive definite",
    -5: "unclassified (internal) error",
    -6: "reordering failed",
    -7: "diagonal matrix is singular",
    -8: "32-bit integer overflow problem",
    -9: "not enough memory for out-of-core",
    -10: "error opening out-of-core files",
    -11: "read/write error with out-of-core files",
}
_LIB: dict = {}
_LOCK = threading.Lock()


class PardisoError(RuntimeError):
    """PARDISO returned a non-zero error code (``code``)."""

    def __init__(self, code: int, phase: int):
        self.code = int(code)
        super().__init__(f"PARDISO phase {phase}: error {code} ({_ERRORS.get(code, 'unknown')})")


def mkl_runtime():
    """The loaded MKL runtime (``ctypes.CDLL``), or None when it cannot be found here."""
    with _LOCK:
        if "lib" in _LIB:
            return _LIB["lib"]
        candidates = [os.environ.get("PYPARDISO_MKL_RT"), ctypes.util.find_library("mkl_rt")]
        for prefix in (sys.prefix, site.USER_BASE):
            candidates += sorted(glob.glob(f"{prefix}/[Ll]ib*/**/*mkl_rt*.so*", recursive=True), key=len)
        lib = None
        for path in candidates:
            if not path:
                continue
            try:
                lib = ctypes.CDLL(path)
                lib.pardiso  # noqa: B018 - the symbol must exist
                break
            except (OSError, AttributeError):
                lib = None
        if lib is not None:
            _bind(lib)
        _LIB["lib"] = lib
        return lib


def _bind(lib) -> None:
    i32p = ctypes.POINTER(ctypes.c_int32)
    lib.pardiso.argtypes = [ctypes.POINTER(ctypes.c_int64), i32p, i32p, i32p, i32p, i32p, ctypes.c_void_p]
    lib.pardiso.argtypes += [i32p, i32p, i32p, i32p, i32p, i32p, ctypes.c_void_p, ctypes.c_void_p, i32p]
    lib.pardiso.restype = None
    lib.pardisoinit.argtypes = [ctypes.POINTER(ctypes.c_int64), i32p, i32p]
    lib.pardisoinit.restype = None


def pardiso_threads() -> int:
    """The OpenMP thread count PARDISO runs with (``MKL_NUM_THREADS``, else every core); the
    reproducible mode needs it fixed."""
    env = os.environ.get("MKL_NUM_THREADS", "")
    return int(env) if env.strip().isdigit() and int(env) > 0 else max(1, os.cpu_count() or 1)


def _iparm(lib) -> np.ndarray:
    """``pardisoinit`` defaults for real SPD, zero-based indices, reproducible ordering (module docstring)."""
    pt = np.zeros(64, dtype=np.int64)
    iparm = np.zeros(64, dtype=np.int32)
    lib.pardisoinit(_ptr64(pt), ctypes.byref(ctypes.c_int32(_MTYPE_SPD)), _ptr32(iparm))
    iparm[0] = 1  # use the values below, not PARDISO's defaults
    iparm[1] = 2  # sequential METIS: the parallel ordering (3) rules out reproducibility
    iparm[7] = 0  # no iterative refinement: pardisoinit's 2 steps made every solve ~5x slower, and a
    # Cholesky factor of an SPD matrix (no perturbed pivots) is accurate to round-off without it
    iparm[33] = pardiso_threads()  # conditional numerical reproducibility
    iparm[34] = 1  # zero-based ia / ja
    return iparm


def _ptr32(a: np.ndarray):
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_int32))


def _ptr64(a: np.ndarray):
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_int64))


class PardisoAnalysis:
    """PARDISO's analysis of one sparsity pattern (an upper-triangular CSR structure) and its factor slots.

    Args:
        indptr, indices: the upper triangle of the symmetric matrix in CSR, sorted column indices,
            every row non-empty (its diagonal present); kept (as int32) for every later call.
        slots: how many numeric factors of this sparsity may be alive at the same time.
        single: factor and solve in single precision (iparm[27] = 1; values and right-hand sides are
            handed over as float32, solutions come back as float64).

    Attributes:
        n: matrix size.
        analysis_seconds: wall time of the analysis (0 until the first factorisation).
        analyses: 1 once the analysis is done (it is done once, on the first ``factor``).
        factorizations: numeric factorisations done.
        last_factor_seconds: wall time of the latest numeric factorisation.
    """

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, *, slots: int = 4, single: bool = False):
        self._lib = mkl_runtime()
        if self._lib is None:
            raise RuntimeError("MKL PARDISO not found (pip install pypardiso, or set PYPARDISO_MKL_RT)")
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int32)
        self.indices = np.ascontiguousarray(indices, dtype=np.int32)
        self.n = self.indptr.size - 1
        if self.n < 1 or np.any(np.diff(self.indptr) <= 0):
            raise ValueError("PARDISO needs a non-empty upper triangle with every row present")
        self.nnz = int(self.indptr[-1])
        self.slots = int(slots)
        self._pt = np.zeros(64, dtype=np.int64)
        self._iparm = _iparm(self._lib)
        self.single = bool(single)
        self._dtype = np.float32 if self.single else np.float64
        if self.single:
            self._iparm[27] = 1
        self._perm = np.zeros(1, dtype=np.int32)
        self._free_slots = list(range(self.slots, 0, -1))  # mnum values 1..slots
        self._analysed = False
        self._lock = threading.Lock()
        self.analyses = 0
        self.analysis_seconds = 0.0
        self.factorizations = 0
        self.last_factor_seconds = 0.0

    @classmethod
    def of_matrix(cls, A, *, slots: int = 1) -> tuple[PardisoAnalysis, np.ndarray]:
        """(analysis, upper-triangle values) of a full symmetric scipy sparse matrix (tests, small uses)."""
        U = sp.triu(sp.csr_matrix(A, dtype=np.float64), format="csr")
        U.sum_duplicates()
        U.sort_indices()
        return cls(U.indptr, U.indices, slots=slots), np.ascontiguousarray(U.data)

    def _call(self, phase: int, mnum: int, values, B: np.ndarray | None = None, X: np.ndarray | None = None):
        error = ctypes.c_int32(0)
        nrhs = 1 if B is None else (1 if B.ndim == 1 else B.shape[1])
        dummy = np.zeros(1, dtype=self._dtype)
        self._lib.pardiso(
            _ptr64(self._pt),
            ctypes.byref(ctypes.c_int32(self.slots)),  # maxfct
            ctypes.byref(ctypes.c_int32(mnum)),
            ctypes.byref(ctypes.c_int32(_MTYPE_SPD)),
            ctypes.byref(ctypes.c_int32(phase)),
            ctypes.byref(ctypes.c_int32(self.n)),
            (dummy if values is None else values).ctypes.data,
            _ptr32(self.indptr),
            _ptr32(self.indices),
            _ptr32(self._perm),
            ctypes.byref(ctypes.c_int32(nrhs)),
            _ptr32(self._iparm),
            ctypes.byref(ctypes.c_int32(0)),  # msglvl
            (dummy if B is None else B).ctypes.data,
            (dummy if X is None else X).ctypes.data,
            ctypes.byref(error),
        )
        if error.value != 0:
            raise PardisoError(error.value, phase)

    def factor(self, values: np.ndarray) -> PardisoFactor:
        """Numeric factorisation of the matrix with these upper-triangle values (the analysis is done
        on the first call). Raises ``PardisoError`` (code -4 when the matrix is not positive definite)."""
        values = np.ascontiguousarray(values, dtype=self._dtype)
        if values.shape != (self.nnz,):
            raise ValueError(f"values have shape {values.shape}, expected ({self.nnz},)")
        with self._lock:
            if not self._free_slots:
                raise RuntimeError(f"all {self.slots} PARDISO factor slots of this pattern are in use")
            mnum = self._free_slots.pop()
        try:
            if not self._analysed:
                t0 = time.perf_counter()
                self._call(11, mnum, values)
                self.analysis_seconds = time.perf_counter() - t0
                self._analysed, self.analyses = True, 1
            t0 = time.perf_counter()
            self._call(22, mnum, values)
            self.last_factor_seconds = time.perf_counter() - t0
            self.factorizations += 1
        except Exception:
            self._release(mnum)
            raise
        return PardisoFactor(self, mnum, values)

    @property
    def slots_in_use(self) -> int:
        return self.slots - len(self._free_slots)

    def _solve(self, mnum: int, values: np.ndarray, B: np.ndarray) -> np.ndarray:
        B = np.asfortranarray(B, dtype=self._dtype)
        X = np.zeros_like(B, order="F")
        self._call(33, mnum, values, B, X)
        return X.astype(np.float64, copy=False)

    def _release(self, mnum: int) -> None:
        with self._lock:
            if self._analysed and mnum not in self._free_slots:
                try:
                    self._call(0, mnum, None)  # release the numeric factor of slot mnum
                except PardisoError:  # pragma: no cover - nothing to release
                    pass
            if mnum not in self._free_slots:
                self._free_slots.append(mnum)

    def close(self) -> None:
        """Release everything PARDISO holds for this pattern (also done when it is garbage-collected)."""
        if getattr(self, "_analysed", False):
            self._call(-1, 1, None)
            self._analysed = False
            self._free_slots = list(range(self.slots, 0, -1))

    def __del__(self):  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass


class PardisoFactor:
    """One numeric factor held in a slot of a ``PardisoAnalysis``; ``solve(B)`` for (N,) or (N, k)."""

    def __init__(self, analysis: PardisoAnalysis, mnum: int, values: np.ndarray):
        self.analysis = analysis
        self._mnum = mnum
        self._values = values  # PARDISO's solve phase reads A (iterative refinement)
        self.seconds = analysis.last_factor_seconds

    def solve(self, B: np.ndarray) -> np.ndarray:
        if self._mnum is None:
            raise RuntimeError("this factorisation was freed")
        B = np.asarray(B, dtype=np.float64)
        X = self.analysis._solve(self._mnum, self._values, B.reshape(B.shape[0], -1))
        return np.ascontiguousarray(X).reshape(B.shape)

    def free(self) -> None:
        if self._mnum is not None:
            self.analysis._release(self._mnum)
            self._mnum = None

    def __del__(self):  # pragma: no cover - best effort
        try:
            self.free()
        except Exception:  # noqa: BLE001
            pass
