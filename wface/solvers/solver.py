"""The one place that chooses and runs the linear solver of the stiffness systems K_UU X = B.

Every stiffness solve in wface goes through ``LinearSolver``: the Newton steps of the quasistatic
solve (``wface.physics.newton``), the right-hand sides of ``Simulator.stiffness_solver`` and of the
tracking Jacobians (``wface.tracking.rig``), and the time steps of the implicit dynamics
(``wface.physics.dynamics``). Callers hand an *operator* on nodal fields, never a simulator:

- ``matvec(v)``: K v for v of shape (n, 3), returning (n, 3);
- ``diagonal()``: diag(K) as (n, 3);
- ``assemble(pattern)``: K restricted to the unknowns of ``pattern`` as scipy CSR (3k, 3k);
- optionally ``assemble_upper(pattern)``: the upper triangle's values in the order of
  ``pattern.upper`` (no format conversion; the factor then reuses the pattern's kept analysis);
- optionally, for CG entirely on a Warp device (``warp_pcg``): ``device`` (a Warp device name),
  ``n_nodes``, ``dtype`` (numpy float type) and ``device_matvec(x, out)`` on Warp vec3 arrays.

and a ``wface.solvers.pattern.BlockPattern`` of the unknowns: right-hand sides and solutions are
(3k,) or (3k, c) arrays over them. The engine comes from ``resolve_linear_solver``: "direct" factors
the assembled K (PARDISO, CHOLMOD or, on CUDA, cuDSS) and back-solves every column; "cg" runs Jacobi-preconditioned
conjugate gradients, in numpy on the CPU (Warp's CG is ~100x slower per iteration there) and in
Warp on CUDA when the operator supports it. The measurements behind these choices are in
docs/design.md ("Linear solvers").
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from wface.solvers.amg import AMGPreconditioner
from wface.solvers.cudss import CudssFactor
from wface.solvers.linear import (
    DirectFactor,
    FactorPreconditioner,
    JacobiPreconditioner,
    NotPositiveDefiniteError,
    cudss_available,
    pcg,
    resolve_linear_solver,
)
from wface.solvers.warp_cg import warp_pcg

__all__ = ["BoundSolve", "LinearSolver", "MatrixOperator"]

# Measured on an H200 (docs/design.md, "The GPU path"): cuDSS's SPD factorisation of an exact tangent
# at a line-search trial point of a 100K-tet track did not return in 100 s, where PARDISO reports the
# matrix indefinite at once; so the GPU factors only projected (definite by construction) stiffnesses.
_CUDSS_EXACT = (
    "cuDSS factors projected stiffnesses only (an indefinite exact tangent can stall its Cholesky); "
    "use the projected tangent on CUDA"
)


def _unknown_matvec(operator, pattern):
    """v (3k,) or (3k, c) on the unknowns -> K_UU v, through the nodal ``operator.matvec``."""

    def matvec(v):
        if v.ndim == 1:
            return pattern.gather(operator.matvec(pattern.scatter(v)))
        return np.stack([matvec(v[:, j]) for j in range(v.shape[1])], axis=1)

    return matvec


def _on_device(operator) -> bool:
    return str(getattr(operator, "device", "cpu")).startswith("cuda") and hasattr(operator, "device_matvec")


class MatrixOperator:
    """An assembled (3n, 3n) sparse matrix over all nodes as an operator (module docstring)."""

    def __init__(self, matrix: sp.spmatrix):
        self.matrix = sp.csr_matrix(matrix)
        self.n_nodes = self.matrix.shape[0] // 3

    def matvec(self, v: np.ndarray) -> np.ndarray:
        return (self.matrix @ np.asarray(v, dtype=np.float64).reshape(-1)).reshape(-1, 3)

    def diagonal(self) -> np.ndarray:
        return self.matrix.diagonal().reshape(-1, 3)

    def assemble(self, pattern) -> sp.csr_matrix:
        dofs = (3 * pattern.dof_nodes[:, None] + np.arange(3)).ravel()
        return self.matrix[dofs][:, dofs]


class LinearSolver:
    """Solves K_UU X = B for operators K over the unknowns of a pattern (module docstring).

    Args:
        solver: "auto" (direct when a backend is installed for the device, else CG), "direct" or "cg".
        device: the Warp device the operators live on.
        keep_factor: keep the latest factorisation between ``solve`` calls (``precondition`` uses it;
            the analysis of a pattern is kept anyway, see ``wface.solvers.linear.pattern_analysis``).
        precondition: with ``keep_factor``, first try CG preconditioned by the kept (older) factor,
            for at most ``reuse_iterations`` iterations, before factoring anew.
        preconditioner: of the CPU CG engine: "jacobi" (default; measured faster than pyamg's AMG at
            20K-400K tets on the 2-core CPU, docs/design.md, "Linear solvers") or "amg" (smoothed
            aggregation with the rigid-body modes, ``wface.solvers.amg``; needs pyamg and an
            operator with ``rest_positions_m``).
        factor_precision: "float64" or "float32" (single-precision PARDISO / cholespy factors of
            pattern operators, see ``DirectFactor.of_pattern``).

    Attributes:
        engine: "direct" or "cg", what runs here.
        factorizations: numeric factorisations done so far; factor_seconds: their wall time.
        back_solves: right-hand sides solved with a factor so far; solve_seconds: their wall time.
        cg_iterations: CG iterations done so far.
    """

    def __init__(
        self,
        solver: str = "auto",
        device: str = "cpu",
        *,
        keep_factor: bool = False,
        precondition: bool = False,
        reuse_iterations: int = 12,
        preconditioner: str = "jacobi",
        factor_precision: str = "float64",
    ):
        if preconditioner not in ("jacobi", "amg"):
            raise ValueError(f"preconditioner must be 'jacobi' or 'amg', got {preconditioner!r}")
        self.engine = resolve_linear_solver(solver, device)
        self.preconditioner = preconditioner
        self.factor_precision = factor_precision
        self.device = str(device)
        self.keep_factor = bool(keep_factor)
        self.precondition = bool(precondition)
        self.reuse_iterations = int(reuse_iterations)
        self.factorizations = 0
        self.factor_seconds = 0.0
        self.back_solves = 0
        self.solve_seconds = 0.0
        self.cg_iterations = 0
        self._factor: DirectFactor | None = None

    @property
    def exact_tangents_ok(self) -> bool:
        """Whether this solver may be handed an exact (unprojected, possibly indefinite) stiffness:
        True but for cuDSS factors on CUDA, which take projected ones only (``_CUDSS_EXACT``).
        Newton's exact steps and the tracker's exact chords ask this first."""
        return not (self.engine == "direct" and self.device.startswith("cuda") and cudss_available())

    def counters(self) -> dict:
        """The counters above as a dict (for statistics)."""
        keys = ("factorizations", "factor_seconds", "back_solves", "solve_seconds", "cg_iterations")
        return {k: getattr(self, k) for k in keys}

    def solve(self, operator, pattern, rhs: np.ndarray, *, rtol: float = 1e-10, x0=None) -> np.ndarray:
        """X = K_UU^-1 rhs for rhs of shape (3k,) or (3k, c).

        ``rtol``: relative residual of CG (the direct solve is exact to round-off). Raises
        ``NotPositiveDefiniteError`` when K_UU is not positive definite (the factorisation fails or
        CG meets a direction of non-positive curvature).
        """
        rhs = np.asarray(rhs, dtype=np.float64)
        if self.engine == "direct":
            return self._direct(operator, pattern, rhs, rtol)
        return self._cg(operator, pattern, rhs, rtol=rtol, x0=x0)

    def bind(self, operator, pattern) -> BoundSolve:
        """A solve of one operator for right-hand sides given later: factored once (direct)."""
        factor = self.factor(operator, pattern) if self.engine == "direct" else None
        return BoundSolve(self, operator, pattern, factor)

    def factor(self, operator, pattern):
        """A new factorisation of K_UU (direct engine): through the pattern's kept analysis when the
        operator assembles upper-triangle values (``assemble_upper``), on the GPU with cuDSS for a
        CUDA operator, else from the assembled CSR matrix."""
        t0 = time.perf_counter()
        if _on_device(operator) and cudss_available():
            if getattr(operator, "projected", True) is False:
                raise NotPositiveDefiniteError(_CUDSS_EXACT)
            factor = CudssFactor.of_operator(operator, pattern)
        elif hasattr(operator, "assemble_upper") and pattern.square:
            values = operator.assemble_upper(pattern)
            factor = DirectFactor.of_pattern(pattern, values, precision=self.factor_precision)
        else:
            factor = DirectFactor(operator.assemble(pattern))
        self.factorizations += 1
        self.factor_seconds += time.perf_counter() - t0
        return factor

    def back_solve(self, factor, B: np.ndarray) -> np.ndarray:
        """factor^-1 B, counted in ``back_solves`` / ``solve_seconds``."""
        t0 = time.perf_counter()
        X = factor.solve(B)
        self.back_solves += 1 if B.ndim == 1 else B.shape[1]
        self.solve_seconds += time.perf_counter() - t0
        return X

    def free(self) -> None:
        """Release the kept factorisation now."""
        if self._factor is not None:
            self._factor.free()
            self._factor = None

    # ------------------------------------------------------------------ engines
    def _direct(self, operator, pattern, rhs, rtol):
        old = self._factor
        if old is not None and self.precondition:
            res = pcg(
                _unknown_matvec(operator, pattern),
                rhs,
                preconditioner=FactorPreconditioner(old),
                rtol=rtol,
                maxiter=self.reuse_iterations,
            )
            self.back_solves += res.iterations + 1
            if res.converged and not res.indefinite:
                self.cg_iterations += res.iterations
                return res.x
        self._factor = None
        if old is not None:
            old.free()
        factor = self.factor(operator, pattern)
        if not self.keep_factor:
            try:
                return self.back_solve(factor, rhs)
            finally:
                factor.free()
        self._factor = factor
        return self.back_solve(factor, rhs)

    def _cg(self, operator, pattern, rhs, *, rtol, x0=None):
        if _on_device(operator):
            X, its = warp_pcg(operator, pattern, rhs, rtol=rtol)
            self.cg_iterations += its
            return X
        precond = self._cg_preconditioner(operator, pattern)
        res = pcg(
            _unknown_matvec(operator, pattern),
            rhs,
            x0=x0,
            preconditioner=precond,
            rtol=rtol,
            maxiter=20 * rhs.shape[0],
        )
        self.cg_iterations += res.iterations
        if res.indefinite:
            raise NotPositiveDefiniteError("CG met a direction of non-positive curvature")
        return res.x

    def _cg_preconditioner(self, operator, pattern):
        positions = getattr(operator, "rest_positions_m", None)
        if self.preconditioner == "amg" and positions is not None:
            return AMGPreconditioner(operator.assemble(pattern), positions[pattern.dof_nodes])
        return JacobiPreconditioner(pattern.gather(operator.diagonal()))


class BoundSolve:
    """``LinearSolver.bind``: one operator, solved for any number of right-hand sides."""

    def __init__(self, solver: LinearSolver, operator, pattern, factor: DirectFactor | None):
        self.solver = solver
        self.operator = operator
        self.pattern = pattern
        self._factor = factor

    @property
    def engine(self) -> str:
        return self.solver.engine

    @property
    def factor(self):
        """The factorisation (direct engine) or None (CG)."""
        return self._factor

    def solve(self, B: np.ndarray, *, rtol: float = 1e-10) -> np.ndarray:
        """X = K_UU^-1 B for B of shape (3k,) or (3k, c)."""
        B = np.asarray(B, dtype=np.float64)
        if self._factor is not None:
            return self.solver.back_solve(self._factor, B)
        return self.solver._cg(self.operator, self.pattern, B, rtol=rtol)

    def free(self) -> None:
        if self._factor is not None:
            self._factor.free()
            self._factor = None
