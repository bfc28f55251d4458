"""The one place that chooses and runs the linear solver of the stiffness systems K_UU X = B.

Every stiffness solve in wface goes through ``LinearSolver``: the Newton steps of the quasistatic
solve (``wface.physics.newton``), the right-hand sides of ``Simulator.stiffness_solver`` and of the
tracking Jacobians (``wface.tracking.rig``), and the time steps of the implicit dynamics
(``wface.physics.dynamics``). Callers hand an *operator* on nodal fields, never a simulator:

- ``matvec(v)``: K v for v of shape (n, 3), returning (n, 3);
- ``diagonal()``: diag(K) as (n, 3);
- ``assemble(pattern)``: K restricted to the unknowns of ``pattern`` as scipy CSR (3k, 3k);
- optionally, for CG entirely on a Warp device (``warp_pcg``): ``device`` (a Warp device name),
  ``n_nodes``, ``dtype`` (numpy float type) and ``device_matvec(x, out)`` on Warp vec3 arrays.

and a ``wface.solvers.pattern.BlockPattern`` of the unknowns: right-hand sides and solutions are
(3k,) or (3k, c) arrays over them. The engine comes from ``resolve_linear_solver``: "direct" factors
the assembled K (PARDISO or CHOLMOD) and back-solves every column; "cg" runs Jacobi-preconditioned
conjugate gradients, in numpy on the CPU (Warp's CG is ~100x slower per iteration there) and in
Warp on CUDA when the operator supports it. The measurements behind these choices are in
docs/design.md ("Linear solvers").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from wface.solvers.linear import (
    DirectFactor,
    FactorPreconditioner,
    JacobiPreconditioner,
    NotPositiveDefiniteError,
    pcg,
    resolve_linear_solver,
)
from wface.solvers.warp_cg import warp_pcg

__all__ = ["BoundSolve", "LinearSolver", "MatrixOperator"]


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
        solver: "auto" (direct on the CPU when a backend is installed, else CG), "direct" or "cg".
        device: the Warp device the operators live on ("auto" on CUDA is CG).
        keep_factor: keep the latest factorisation between ``solve`` calls, so the next
            factorisation of the same sparsity keeps PARDISO's analysis and refactors numerically
            only (successive Newton iterations and time steps).
        precondition: with ``keep_factor``, first try CG preconditioned by the kept (older) factor,
            for at most ``reuse_iterations`` iterations, before factoring anew.

    Attributes:
        engine: "direct" or "cg", what runs here.
        factorizations: sparse factorisations done so far.
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
    ):
        self.engine = resolve_linear_solver(solver, device)
        self.keep_factor = bool(keep_factor)
        self.precondition = bool(precondition)
        self.reuse_iterations = int(reuse_iterations)
        self.factorizations = 0
        self.cg_iterations = 0
        self._factor: DirectFactor | None = None

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
        factor = None
        if self.engine == "direct":
            factor = DirectFactor(operator.assemble(pattern))
            self.factorizations += 1
        return BoundSolve(self, operator, pattern, factor)

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
            if res.converged and not res.indefinite:
                self.cg_iterations += res.iterations
                return res.x
        if not self.keep_factor:
            factor = DirectFactor(operator.assemble(pattern))
            self.factorizations += 1
            try:
                return factor.solve(rhs)
            finally:
                factor.free()
        self._factor = None
        factor = DirectFactor(operator.assemble(pattern), reuse=old)  # keeps PARDISO's analysis
        if old is not None:
            old.free()
        self._factor = factor
        self.factorizations += 1
        return factor.solve(rhs)

    def _cg(self, operator, pattern, rhs, *, rtol, x0=None):
        if _on_device(operator):
            X, its = warp_pcg(operator, pattern, rhs, rtol=rtol)
            self.cg_iterations += its
            return X
        precond = JacobiPreconditioner(pattern.gather(operator.diagonal()))
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

    def solve(self, B: np.ndarray, *, rtol: float = 1e-10) -> np.ndarray:
        """X = K_UU^-1 B for B of shape (3k,) or (3k, c)."""
        B = np.asarray(B, dtype=np.float64)
        if self._factor is not None:
            return self._factor.solve(B)
        return self.solver._cg(self.operator, self.pattern, B, rtol=rtol)

    def free(self) -> None:
        if self._factor is not None:
            self._factor.free()
            self._factor = None
