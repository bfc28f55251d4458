"""Linear solvers for the symmetric positive definite stiffness K: one interface, three engines.

- ``"direct"``: a sparse Cholesky-type factorisation, CHOLMOD (scikit-sparse, when importable) or
  PARDISO (pypardiso, x86-64), factored once and back-solved for any number of right-hand sides.
  A factor of a nearby matrix also serves as a CG preconditioner (``FactorPreconditioner``).
- ``"cg"``: preconditioned conjugate gradients. On the CPU the Krylov loop runs in numpy with the
  matrix-vector product supplied by the caller (a Warp kernel or a CSR matrix): Warp's own CG is
  ~100x slower per iteration on the CPU (docs/design.md, "Linear solvers"). Several right-hand sides iterate
  together, each with its own step lengths. On CUDA, ``warp_pcg`` runs the whole loop on the GPU.
- ``"auto"``: direct on the CPU when a backend is installed, else CG (with a one-line warning
  when direct was possible in principle but no backend is present).
"""

from __future__ import annotations

import ctypes
import os
import platform
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = [
    "CGResult",
    "DirectFactor",
    "FactorPreconditioner",
    "JacobiPreconditioner",
    "NotPositiveDefiniteError",
    "direct_backend",
    "pcg",
    "resolve_linear_solver",
    "SOLVERS",
]

SOLVERS = ("auto", "cg", "direct")


def direct_backend() -> str | None:
    """Name of the sparse direct backend available here: "cholmod", "pardiso" or None."""
    try:
        import sksparse.cholmod  # noqa: F401

        return "cholmod"
    except ImportError:
        pass
    if platform.machine().lower() in ("x86_64", "amd64"):
        try:
            import pypardiso  # noqa: F401

            return "pardiso"
        except (ImportError, OSError):
            pass
    return None


def resolve_linear_solver(solver: str, device: str = "cpu") -> str:
    """Map "auto" | "cg" | "direct" to the engine that will run here ("cg" or "direct").

    "auto" is direct on the CPU when a backend is installed and CG otherwise (always CG on CUDA).
    Asking for "direct" without a backend falls back to CG with a one-line warning.
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown linear solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    if solver == "cg":
        return "cg"
    backend = direct_backend()
    if solver == "auto" and str(device).startswith("cuda"):
        return "cg"
    if backend is None:
        warnings.warn(
            "no sparse direct solver (scikit-sparse CHOLMOD or pypardiso) is installed: using preconditioned CG",
            RuntimeWarning,
            stacklevel=2,
        )
        return "cg"
    return "direct"


def _pardiso_threads() -> int:
    """The OpenMP thread count PARDISO runs with (``MKL_NUM_THREADS``, else every core): its
    conditional numerical reproducibility mode (iparm[33] > 0) needs it fixed. Without that mode the
    multi-threaded factorisation gives results that differ at round-off from run to run, which the
    tracker amplifies (measured: activation RMS error 0.0676-0.0683 over repeated runs of the same
    8-frame demo)."""
    env = os.environ.get("MKL_NUM_THREADS", "")
    return int(env) if env.strip().isdigit() and int(env) > 0 else max(1, os.cpu_count() or 1)


def _reproducible_iparm(solver) -> None:
    """PARDISO's defaults for a real SPD matrix (``pardisoinit``), then conditional numerical
    reproducibility: sequential METIS ordering (the parallel one, iparm[1] = 3, rules CNR out) and
    iparm[33] = the thread count. PARDISO ignores iparm[1..63] unless iparm[0] = 1."""

    init = solver.libmkl.pardisoinit
    init.argtypes = [ctypes.POINTER(solver._pt_type[0]), ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_int32)]
    init.restype = None
    init(
        solver.pt.ctypes.data_as(ctypes.POINTER(solver._pt_type[0])),
        ctypes.byref(ctypes.c_int32(solver.mtype)),
        solver.iparm.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)),
    )
    solver.iparm[0] = 1  # use the values below, not PARDISO's defaults
    solver.iparm[1] = 2
    solver.iparm[33] = _pardiso_threads()


class NotPositiveDefiniteError(np.linalg.LinAlgError):
    """The matrix handed to a Cholesky-type factorisation or to CG is not positive definite."""


class DirectFactor:
    """Factorisation of a sparse SPD matrix; ``solve(B)`` for one (N,) or many (N, k) right-hand sides.

    Args:
        A: (N, N) symmetric positive definite scipy sparse matrix (float64).
        backend: "cholmod" or "pardiso"; default: ``direct_backend()``.
        reuse: an older factor of a matrix with the same sparsity (e.g. the previous Newton step):
            PARDISO keeps its analysis (ordering, symbolic factor) and refactors numerically only
            (about a third less time at 100K tets). ``reuse`` is unusable afterwards.
    """

    def __init__(self, A: sp.spmatrix, *, backend: str | None = None, reuse: DirectFactor | None = None):
        self.backend = backend or direct_backend()
        if self.backend is None:
            raise RuntimeError("no sparse direct backend installed (pip install pypardiso, or scikit-sparse)")
        self.shape = A.shape
        self.reused_analysis = False
        if self.backend == "cholmod":
            from sksparse.cholmod import CholmodNotPositiveDefiniteError, cholesky

            try:
                self._factor = cholesky(sp.csc_matrix(A, dtype=np.float64))
            except CholmodNotPositiveDefiniteError as exc:
                raise NotPositiveDefiniteError(str(exc)) from exc
        elif self.backend == "pardiso":
            import pypardiso

            # pypardiso searches the whole prefix for libmkl_rt on every new solver (~0.5 s);
            # point it at the library its module-level solver already found.
            os.environ.setdefault("PYPARDISO_MKL_RT", pypardiso.ps.libmkl._name)
            # Real SPD (mtype 2): PARDISO reads the upper triangle only.
            self._matrix = sp.triu(sp.csr_matrix(A, dtype=np.float64), format="csr")
            self._matrix.sort_indices()
            phase = 12  # analysis (fill-reducing ordering) + numeric factorisation
            if (
                reuse is not None
                and reuse.backend == "pardiso"
                and getattr(reuse, "_solver", None) is not None
                and reuse._matrix.shape == self._matrix.shape
                and np.array_equal(reuse._matrix.indptr, self._matrix.indptr)
                and np.array_equal(reuse._matrix.indices, self._matrix.indices)
            ):
                # Same sparsity (next Newton step): keep the analysis, refactor numerically only.
                self._solver, reuse._solver = reuse._solver, None
                phase = 22
                self.reused_analysis = True
            else:
                self._solver = pypardiso.PyPardisoSolver(mtype=2)
                _reproducible_iparm(self._solver)
            self._solver._check_A(self._matrix)  # CSR, sorted, no empty rows; sets iparm for CSR input
            self._solver.set_phase(phase)
            try:
                self._solver._call_pardiso(self._matrix, np.zeros((self._matrix.shape[0], 1)))
            except pypardiso.pardiso_wrapper.PyPardisoError as exc:
                self.free()
                if exc.value == -4:  # zero or negative pivot
                    raise NotPositiveDefiniteError("PARDISO: matrix is not positive definite") from exc
                raise
        else:
            raise ValueError(f"unknown direct backend {self.backend!r}")

    def solve(self, B: np.ndarray) -> np.ndarray:
        """A^-1 B for B of shape (N,) or (N, k)."""
        B = np.asarray(B, dtype=np.float64)
        if self.backend == "cholmod":
            return np.asarray(self._factor(B))
        if self._solver is None:
            raise RuntimeError("this factorisation was freed (or handed on to a newer one)")
        self._solver.set_phase(33)  # forward / back substitution with the stored factor
        X = self._solver._call_pardiso(self._matrix, np.asfortranarray(B.reshape(B.shape[0], -1)))
        return np.asarray(X).reshape(B.shape)

    def __call__(self, B: np.ndarray) -> np.ndarray:
        return self.solve(B)

    def free(self) -> None:
        """Release the factor's memory now (PARDISO keeps it until freed)."""
        if self.backend == "pardiso" and getattr(self, "_solver", None) is not None:
            self._solver.free_memory(everything=True)
            self._solver = None

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
