"""Solvers: sparse direct / conjugate-gradient linear solvers and the quasistatic Newton method."""

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

__all__ = [
    "SOLVERS",
    "CGResult",
    "DirectFactor",
    "FactorPreconditioner",
    "JacobiPreconditioner",
    "NotPositiveDefiniteError",
    "direct_backend",
    "pcg",
    "resolve_linear_solver",
]
