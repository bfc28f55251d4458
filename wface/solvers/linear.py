"""Linear solvers for the symmetric positive definite stiffness K: one interface, three engines.

- ``"direct"``: a sparse Cholesky-type factorisation, factored once and back-solved for any number of
  right-hand sides: PARDISO (MKL, x86-64; ``wface.solvers.pardiso``, its analysis done once per
  sparsity pattern), CHOLMOD through scikit-sparse or through the cholespy wheel that bundles it, and
  on CUDA NVIDIA cuDSS (``wface.solvers.cudss``). A factor of a nearby matrix also serves as a CG
  preconditioner (``FactorPreconditioner``) or as the matrix of chord Newton steps.
- ``"cg"``: preconditioned conjugate gradients. On the CPU the Krylov loop runs in numpy with the
  matrix-vector product supplied by the caller (a Warp kernel or a CSR matrix): Warp's own CG is
  ~100x slower per iteration on the CPU (docs/design.md, "Linear solvers"). Several right-hand sides
  iterate together, each with its own step lengths. On CUDA, ``warp_pcg`` runs the whole loop on
  the GPU. Preconditioners: Jacobi, or smoothed-aggregation AMG with the rigid-body near-nullspace
  (``wface.solvers.amg``, pyamg).
- ``"auto"``: direct when a backend is installed for the device, else CG (with a one-line warning
  on the CPU); docs/design.md, "Linear solvers", has the measurements behind the choice.
"""

from __future__ import annotations

import functools
import importlib
import platform
import time
import warnings
import weakref
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from wface.solvers.pardiso import PardisoAnalysis, PardisoError, mkl_runtime

__all__ = [
    "DIRECT_BACKENDS",
    "CGResult",
    "DirectFactor",
    "FactorPreconditioner",
    "JacobiPreconditioner",
    "NotPositiveDefiniteError",
    "available_direct_backends",
    "cudss_available",
    "direct_backend",
    "forget_analysis",
    "pattern_analysis",
    "pcg",
    "resolve_linear_solver",
    "SOLVERS",
]

SOLVERS = ("auto", "cg", "direct")


DIRECT_BACKENDS = ("pardiso", "cholmod", "cholespy")


def available_direct_backends() -> list[str]:
    """The sparse direct backends importable here, in the order "auto" prefers them (docs/design.md,
    "Linear solvers": PARDISO measured fastest on the CPU; CHOLMOD through scikit-sparse, or the
    CHOLMOD that the cholespy wheel bundles, where MKL is absent). Found once per process: a failed
    import searches the path again each time (5-6 ms, and every factor asks)."""
    return list(_find_direct_backends())


@functools.cache
def _find_direct_backends() -> tuple[str, ...]:
    out = []
    if platform.machine().lower() in ("x86_64", "amd64") and mkl_runtime() is not None:
        out.append("pardiso")
    for name, module in (("cholmod", "sksparse.cholmod"), ("cholespy", "cholespy")):
        try:
            importlib.import_module(module)
            out.append(name)
        except ImportError:
            pass
    return tuple(out)


def direct_backend() -> str | None:
    """Name of the sparse direct backend "auto" uses here: "pardiso", "cholmod", "cholespy" or None."""
    found = available_direct_backends()
    return found[0] if found else None


def resolve_linear_solver(solver: str, device: str = "cpu") -> str:
    """Map "auto" | "cg" | "direct" to the engine that will run here ("cg" or "direct").

    "auto" is direct on the CPU when a backend is installed and CG otherwise; on CUDA it is direct
    when NVIDIA cuDSS (nvmath-python) is importable, else the matrix-free Warp CG. Asking for
    "direct" without a backend falls back to CG with a one-line warning.
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown linear solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    if solver == "cg":
        return "cg"
    if str(device).startswith("cuda"):
        if cudss_available():
            return "direct"
        if solver == "direct":
            warnings.warn("NVIDIA cuDSS (nvmath-python) is not installed: using Warp CG on the GPU", stacklevel=2)
        return "cg"
    if direct_backend() is None:
        warnings.warn(
            "no sparse direct solver (pypardiso/MKL, scikit-sparse or cholespy) is installed: using preconditioned CG",
            RuntimeWarning,
            stacklevel=2,
        )
        return "cg"
    return "direct"


def cudss_available() -> bool:
    """Whether NVIDIA cuDSS can be reached through nvmath-python (the GPU sparse direct option)."""
    try:
        importlib.import_module("nvmath.sparse.advanced")
        return True
    except Exception:  # noqa: BLE001 - ImportError, or a CUDA library that fails to load
        return False


_ANALYSES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def pattern_analysis(pattern, precision: str = "float64") -> PardisoAnalysis:
    """PARDISO's analysis of a square ``BlockPattern``'s upper triangle, done once per pattern (and
    precision) and kept as long as the pattern lives (the simulator caches its patterns: once per mesh)."""
    kept = _ANALYSES.setdefault(pattern, {})
    if precision not in kept:
        upper = pattern.upper
        kept[precision] = PardisoAnalysis(upper.indptr, upper.indices, slots=4, single=precision == "float32")
    return kept[precision]


def forget_analysis(pattern) -> None:
    """Drop the kept analysis of a pattern (the next factorisation analyses anew; benchmarks)."""
    _ANALYSES.pop(pattern, None)


class NotPositiveDefiniteError(np.linalg.LinAlgError):
    """The matrix handed to a Cholesky-type factorisation or to CG is not positive definite."""


class DirectFactor:
    """Factorisation of a sparse SPD matrix; ``solve(B)`` for one (N,) or many (N, k) right-hand sides.

    Args:
        A: (N, N) symmetric positive definite scipy sparse matrix (float64); only its upper
            triangle is read.
        backend: "pardiso", "cholmod" or "cholespy"; default: ``direct_backend()``.
        reuse: an older PARDISO factor of a matrix with the same sparsity (e.g. the previous Newton
            step): its analysis (ordering, symbolic factor) is kept and only the numeric
            factorisation is done. ``reuse`` is unusable afterwards.

    ``DirectFactor.of_pattern`` factors the upper-triangle values of a ``BlockPattern`` against the
    analysis kept for that pattern (``pattern_analysis``), with no sparse-format conversion.

    Attributes:
        backend: the engine. reused_analysis: whether the analysis was reused (PARDISO).
        seconds: wall time of the numeric factorisation (the analysis excluded when it was reused).
    """

    def __init__(self, A: sp.spmatrix | None, *, backend: str | None = None, reuse: DirectFactor | None = None):
        self.backend = backend or direct_backend()
        if self.backend is None:
            raise RuntimeError("no sparse direct backend installed (pip install pypardiso, or cholespy)")
        self.reused_analysis = False
        self.precision = "float64"
        self._impl = None
        if A is None:  # of_pattern fills it in
            return
        U = sp.triu(sp.csr_matrix(A, dtype=np.float64), format="csr")
        U.sum_duplicates()
        U.sort_indices()
        self.shape = A.shape
        analysis = None
        pardiso_reuse = reuse is not None and reuse.backend == self.backend == "pardiso"
        old = getattr(reuse, "_impl", None) if pardiso_reuse else None
        same = old is not None and np.array_equal(old.analysis.indptr, U.indptr)
        if same and np.array_equal(old.analysis.indices, U.indices):
            analysis = old.analysis
            reuse.free()
            self.reused_analysis = True
        if self.backend == "pardiso" and analysis is None:
            analysis = PardisoAnalysis(U.indptr, U.indices, slots=1)
        self._factor(U.indptr, U.indices, np.ascontiguousarray(U.data), analysis)

    @classmethod
    def of_pattern(
        cls, pattern, values: np.ndarray, *, backend: str | None = None, precision: str = "float64"
    ) -> DirectFactor:
        """Factor the matrix with upper-triangle ``values`` in the order of ``pattern.upper``.

        ``precision``: "float64", or "float32" for a single-precision factor (PARDISO and cholespy;
        measured at 99,684 tets: 1.5x faster factorisation and solves, solutions within 8e-6 of the
        double-precision ones; docs/design.md, "Linear solvers")."""
        if precision not in ("float64", "float32"):
            raise ValueError(f"precision must be 'float64' or 'float32', got {precision!r}")
        self = cls(None, backend=backend)
        self.shape = pattern.shape
        self.precision = precision if self.backend in ("pardiso", "cholespy") else "float64"
        upper = pattern.upper
        analysis = pattern_analysis(pattern, self.precision) if self.backend == "pardiso" else None
        if analysis is not None and analysis.slots_in_use == analysis.slots:  # every kept slot is taken
            analysis = PardisoAnalysis(upper.indptr, upper.indices, slots=1, single=self.precision == "float32")
        self.reused_analysis = analysis is not None and analysis.analyses > 0
        self._factor(upper.indptr, upper.indices, values, analysis)
        return self

    def _factor(self, indptr, indices, values, analysis) -> None:
        t0 = time.perf_counter()
        n = indptr.size - 1
        if self.backend == "pardiso":
            try:
                self._impl = analysis.factor(values)
            except PardisoError as exc:
                if exc.code == -4:
                    raise NotPositiveDefiniteError(f"PARDISO: matrix is not positive definite ({exc})") from exc
                raise
        elif self.backend == "cholespy":
            from cholespy import CholeskySolverD, CholeskySolverF, MatrixType

            single = getattr(self, "precision", "float64") == "float32"
            kind, dtype = (CholeskySolverF, np.float32) if single else (CholeskySolverD, np.float64)
            try:  # the upper triangle in CSR is the lower triangle in CSC, which CHOLMOD reads
                self._impl = kind(n, indptr, indices, np.ascontiguousarray(values, dtype), MatrixType.CSC)
            except ValueError as exc:
                raise NotPositiveDefiniteError(f"CHOLMOD (cholespy): {exc}") from exc
        elif self.backend == "cholmod":
            from sksparse.cholmod import CholmodNotPositiveDefiniteError, cholesky

            U = sp.csr_matrix((values, indices, indptr), shape=(n, n))
            try:
                self._impl = cholesky(sp.csc_matrix(U + sp.triu(U, k=1).T))
            except CholmodNotPositiveDefiniteError as exc:
                raise NotPositiveDefiniteError(str(exc)) from exc
        else:
            raise ValueError(f"unknown direct backend {self.backend!r}")
        self.seconds = time.perf_counter() - t0

    def solve(self, B: np.ndarray) -> np.ndarray:
        """A^-1 B for B of shape (N,) or (N, k)."""
        B = np.asarray(B, dtype=np.float64)
        if self._impl is None:
            raise RuntimeError("this factorisation was freed (or handed on to a newer one)")
        if self.backend == "pardiso":
            return self._impl.solve(B)
        if self.backend == "cholespy":
            single = getattr(self, "precision", "float64") == "float32"
            Bc = np.ascontiguousarray(B, dtype=np.float32 if single else np.float64)
            X = np.zeros_like(Bc)
            self._impl.solve(Bc, X)
            return X.astype(np.float64, copy=False)
        return np.asarray(self._impl(B))

    def __call__(self, B: np.ndarray) -> np.ndarray:
        return self.solve(B)

    def free(self) -> None:
        """Release the factor's memory now."""
        impl, self._impl = getattr(self, "_impl", None), None
        if impl is not None and self.backend == "pardiso":
            impl.free()

    def __del__(self):  # pragma: no cover - best effort
        try:
            self.free()
        except Exception:  # noqa: BLE001
            pass


class JacobiPreconditioner:
    """z = r / diag(A) (zero or negative diagonal entries are treated as 1)."""

    def __init__(self, diagonal: np.ndarray):
        d = np.asarray(diagonal, dtype=np.float64).reshape(-1)
        self.inverse = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 1.0)

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return r * (self.inverse if r.ndim == 1 else self.inverse[:, None])


class FactorPreconditioner:
    """Use the factor of a (possibly older) nearby matrix as the CG preconditioner."""

    def __init__(self, factor: DirectFactor):
        self.factor = factor

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return self.factor.solve(r)


@dataclass
class CGResult:
    """Outcome of ``pcg``. ``residual``: ||b - A x|| / ||b|| per column (recursive estimate).

    ``indefinite`` is set when a search direction p had p.A p <= 0 (A not positive definite); the
    iteration then stops.
    """

    x: np.ndarray
    iterations: int
    residual: np.ndarray
    converged: bool
    indefinite: bool = False


def pcg(
    matvec: Callable[[np.ndarray], np.ndarray],
    b: np.ndarray,
    *,
    x0: np.ndarray | None = None,
    preconditioner: Callable[[np.ndarray], np.ndarray] | None = None,
    rtol: float = 1e-8,
    atol: float = 0.0,
    maxiter: int | None = None,
) -> CGResult:
    """Preconditioned conjugate gradients for SPD A, numpy Krylov loop.

    Args:
        matvec: v -> A v for v of shape (N,) or (N, k) (the same shape as ``b``).
        b: right-hand side(s), (N,) or (N, k); columns are independent systems iterated together.
        x0: initial guess, same shape as b (default zeros).
        preconditioner: r -> M^-1 r (same shapes), e.g. ``JacobiPreconditioner`` or ``FactorPreconditioner``.
        rtol, atol: stop a column when ||r|| <= max(rtol ||b||, atol).
        maxiter: iteration cap (default 10 N).

    Returns:
        CGResult with x, iterations done, per-column relative residuals and whether all converged.
    """
    b = np.asarray(b, dtype=np.float64)
    single = b.ndim == 1
    B = b[:, None] if single else b
    X = np.zeros_like(B) if x0 is None else np.array(x0, dtype=np.float64).reshape(B.shape)

    def A(v):
        out = matvec(v[:, 0] if single else v)
        return out[:, None] if single else out

    def M(r):
        if preconditioner is None:
            return r.copy()
        out = preconditioner(r[:, 0] if single else r)
        return out[:, None] if single else out

    maxiter = 10 * B.shape[0] if maxiter is None else int(maxiter)
    bnorm = np.linalg.norm(B, axis=0)
    tol = np.maximum(rtol * bnorm, atol)
    R = B - A(X) if np.any(X) else B.copy()
    Z = M(R)
    P = Z.copy()
    rz = np.einsum("ij,ij->j", R, Z)
    it = 0
    rnorm = np.linalg.norm(R, axis=0)
    indefinite = False
    while it < maxiter:
        active = rnorm > tol
        if not np.any(active):
            break
        AP = A(P)
        pap = np.einsum("ij,ij->j", P, AP)
        if np.any(active & (pap <= 0)):
            indefinite = True
            break
        alpha = np.where(active & (pap > 0), rz / np.where(pap > 0, pap, 1.0), 0.0)
        X += alpha * P
        R -= alpha * AP
        rnorm = np.linalg.norm(R, axis=0)
        it += 1
        Z = M(R)
        rz_new = np.einsum("ij,ij->j", R, Z)
        beta = np.where(active & (rz != 0), rz_new / np.where(rz != 0, rz, 1.0), 0.0)
        P = Z + beta * P
        rz = rz_new
    rel = rnorm / np.where(bnorm > 0, bnorm, 1.0)
    x = X[:, 0] if single else X
    return CGResult(x=x, iterations=it, residual=rel, converged=bool(np.all(rnorm <= tol)), indefinite=indefinite)
