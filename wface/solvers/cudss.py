"""Sparse direct factorisation on the GPU with NVIDIA cuDSS, through nvmath-python (optional).

The stiffness K_UU is handed over as its upper triangle in CSR (``BlockPattern.upper``) with the
matrix type SPD, so cuDSS runs a Cholesky factorisation. ``nvmath.sparse.advanced.DirectSolver``
holds the reordering and symbolic factorisation (``plan``) of one sparsity pattern: a new matrix of
the same pattern only resets the values and refactors (``reset_operands`` + ``factorize``), the GPU
counterpart of PARDISO's kept analysis (docs/design.md, "Linear solvers"). The right-hand-side block
has a fixed width (47 columns, widened once, with a new plan, to the widest block asked for up to 256:
the built-in face's Jacobian has M + 12 = 48); narrower blocks are padded with zeros, which keeps one
plan per pattern but, measured on the H200, makes one column cost about as much as
48 (56 vs 60 ms at 100K tets, mostly the padded block's transfers): the tracker's single-column
chord solves are the GPU path's next cost.

Run on an H200 (docs/design.md, "The GPU path"): factors and solves match the CPU's to 1e-14
(``examples/gpu_check.py``). Only projected, definite stiffnesses are handed to it
(``LinearSolver.exact_tangents_ok``): an exact tangent at a line-search trial point stalled its
Cholesky there. A factorisation whose INFO is not 0 raises ``NotPositiveDefiniteError``.
"""

from __future__ import annotations

import logging
import weakref

import numpy as np
import scipy.sparse as sp

from wface.solvers.linear import NotPositiveDefiniteError

__all__ = ["CudssFactor", "cudss_session"]

_SESSIONS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
DEFAULT_WIDTH = 47
MAX_WIDTH = 256  # wider blocks are solved in pieces of the session's width


def _enums():
    import nvmath.sparse.advanced as adv

    mtype = getattr(adv, "DirectSolverMatrixType", None)
    view = getattr(adv, "DirectSolverMatrixViewType", None)
    if mtype is None or view is None:  # older layouts keep the enums in the cuDSS bindings
        from nvmath.bindings import cudss

        mtype, view = cudss.MatrixType, cudss.MatrixViewType
    return adv, mtype, view


def _quiet_logger() -> logging.Logger:
    """nvmath's logger for the solver: errors only (it warns at every ``reset_operands`` of the matrix
    that a refactorisation is due, which is what wface always does next)."""
    logger = logging.getLogger("wface.cudss")
    logger.setLevel(logging.ERROR)
    return logger


class _Session:
    """One ``DirectSolver`` (plan kept) for one sparsity pattern and right-hand-side width."""

    def __init__(self, upper, values: np.ndarray, width: int, device_id: int):
        adv, mtype, view = _enums()
        self.width = int(width)
        self.n = upper.n
        self._structure = (upper.indptr, upper.indices)
        A = sp.csr_matrix((np.asarray(values, np.float64), upper.indices, upper.indptr), shape=(upper.n, upper.n))
        B = np.zeros((self.n, self.width), order="F")
        options = adv.DirectSolverOptions(
            sparse_system_type=mtype.SPD, sparse_system_view=view.UPPER, logger=_quiet_logger()
        )
        self._solver = adv.DirectSolver(A, B, options=options, execution={"name": "cuda", "device_id": device_id})
        self._solver.plan()
        self._current = None  # the CudssFactor whose values are factored now

    def factor(self, values: np.ndarray, owner) -> None:
        if not np.isfinite(values.sum()):  # never hand cuDSS NaN or inf (PARDISO reports them; cuDSS may not):
            # one reduction, no mask the size of the matrix (a sum that overflows is refused too)
            raise NotPositiveDefiniteError("the stiffness has non-finite entries: not factored")
        indptr, indices = self._structure
        A = sp.csr_matrix((np.asarray(values, np.float64), indices, indptr), shape=(self.n, self.n))
        self._solver.reset_operands(a=A)
        info = self._solver.factorize()
        self._current = None
        status = int(getattr(info, "info", 0) or 0)
        if status != 0:  # cuDSS's Cholesky met a non-positive pivot (its INFO is not 0)
            raise NotPositiveDefiniteError(f"cuDSS factorisation failed (INFO {status}): K_UU is not positive definite")
        self._current = owner

    def solve(self, B: np.ndarray) -> np.ndarray:
        k = B.shape[1]
        out = np.empty_like(B)
        for s in range(0, k, self.width):
            block = np.zeros((self.n, self.width), order="F")
            block[:, : min(self.width, k - s)] = B[:, s : s + self.width]
            self._solver.reset_operands(b=block)
            X = np.asarray(self._solver.solve())
            out[:, s : s + self.width] = X[:, : min(self.width, k - s)]
        return out

    def free(self) -> None:
        self._solver.free()


def cudss_session(pattern, values: np.ndarray, *, width: int = DEFAULT_WIDTH, device_id: int = 0) -> _Session:
    """The cuDSS plan of a ``BlockPattern`` (made on first use with these values, then kept), for blocks
    of at least ``width`` columns: a wider request plans anew once and the wider plan is kept."""
    session = _SESSIONS.get(pattern)
    if session is None or session.width < width:
        session = _Session(pattern.upper, values, width, device_id)
        _SESSIONS[pattern] = session
    return session


class CudssFactor:
    """A cuDSS factorisation of K_UU; ``solve(B)`` for (N,) or (N, k). The pattern's one GPU factor:
    a newer ``CudssFactor`` of the same pattern replaces it (the tracker needs one at a time there)."""

    backend = "cudss"

    def __init__(self, pattern, values: np.ndarray, *, device_id: int = 0):
        self.shape = pattern.shape
        self._pattern, self._device_id = pattern, device_id
        self._values = np.ascontiguousarray(values, dtype=np.float64)
        self._session = cudss_session(pattern, self._values, device_id=device_id)
        self._session.factor(self._values, self)

    @classmethod
    def of_operator(cls, operator, pattern) -> CudssFactor:
        """Factor an operator that assembles upper-triangle values (``Tangent.assemble_upper``)."""
        device = str(getattr(operator, "device", "cuda:0"))
        device_id = int(device.split(":")[1]) if ":" in device else 0
        return cls(pattern, operator.assemble_upper(pattern), device_id=device_id)

    def solve(self, B: np.ndarray) -> np.ndarray:
        if self._session is None:
            raise RuntimeError("this factorisation was freed")
        B = np.asarray(B, dtype=np.float64)
        B2 = B.reshape(B.shape[0], -1)
        if self._session.width < B2.shape[1] <= MAX_WIDTH:  # e.g. M + 12 = 48 columns: one block, not two
            self._session = cudss_session(self._pattern, self._values, width=B2.shape[1], device_id=self._device_id)
        if self._session._current is not self:  # another factor of this pattern was made since
            self._session.factor(self._values, self)
        X = self._session.solve(B2)
        return X.reshape(B.shape)

    def free(self) -> None:
        self._session = None
