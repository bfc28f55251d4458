"""Generic linear algebra: sparse direct / conjugate-gradient solvers of SPD systems, the block
sparsity pattern of a tet mesh's stiffness, ``LinearSolver``, the one place that picks the engine, and
``bvls``, bounded least squares by a warm-startable active set (the basis's per-frame QP and the
tracker's Gauss-Newton steps)."""

from wface.solvers.linear import (
    SOLVERS,
    CGResult,
    DirectFactor,
    FactorPreconditioner,
    JacobiPreconditioner,
    NotPositiveDefiniteError,
    direct_backend,
    pcg,
    resolve_linear_solver,
)
from wface.solvers.pattern import BlockPattern
from wface.solvers.solver import BoundSolve, LinearSolver, MatrixOperator

__all__ = [
    "SOLVERS",
    "BlockPattern",
    "BoundSolve",
    "LinearSolver",
    "MatrixOperator",
    "CGResult",
    "DirectFactor",
    "FactorPreconditioner",
    "JacobiPreconditioner",
    "NotPositiveDefiniteError",
    "direct_backend",
    "pcg",
    "resolve_linear_solver",
]
