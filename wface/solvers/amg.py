"""Smoothed-aggregation algebraic multigrid as a CG preconditioner for the elastic stiffness (pyamg).

The near-nullspace of a 3D elastic operator is the six rigid-body modes (three translations and
three infinitesimal rotations about the centroid, evaluated at the nodes of the unknowns): handed to
``pyamg.smoothed_aggregation_solver`` as ``B``, with the matrix in 3x3 blocks so that aggregates are
whole nodes (Vanek, Mandel & Brezina 1996). One V-cycle per application, symmetric, so it
preconditions CG. pyamg is optional: ``amg_available()``.
"""

from __future__ import annotations

import importlib

import numpy as np
import scipy.sparse as sp

__all__ = ["AMGPreconditioner", "amg_available", "rigid_body_modes"]


def amg_available() -> bool:
    """Whether pyamg is importable here."""
    try:
        importlib.import_module("pyamg")
        return True
    except ImportError:
        return False


def rigid_body_modes(positions_m: np.ndarray) -> np.ndarray:
    """(3k, 6) rigid-body modes at k node positions (k, 3): x, y, z translations, then rotations
    about the x, y and z axes through the centroid (unit angle, so metres per radian), orthonormalised."""
    p = np.asarray(positions_m, dtype=np.float64)
    r = p - p.mean(axis=0)
    k = len(p)
    B = np.zeros((k, 3, 6))
    for i in range(3):
        B[:, i, i] = 1.0
    # rotation about axis e_j: u = e_j x r
    B[:, 1, 3], B[:, 2, 3] = -r[:, 2], r[:, 1]
    B[:, 0, 4], B[:, 2, 4] = r[:, 2], -r[:, 0]
    B[:, 0, 5], B[:, 1, 5] = -r[:, 1], r[:, 0]
    Q, _ = np.linalg.qr(B.reshape(3 * k, 6))
    return Q


class AMGPreconditioner:
    """r -> M^-1 r with one smoothed-aggregation V-cycle (module docstring).

    Args:
        K: (3k, 3k) SPD matrix over k nodes (CSR or BSR).
        positions_m: (k, 3) positions of those nodes (the near-nullspace).
        max_coarse: size below which the coarsest level is solved directly.

    Attributes:
        levels: multigrid levels; operator_complexity: nonzeros of all levels / of K.
    """

    def __init__(self, K, positions_m: np.ndarray, *, max_coarse: int = 500):
        import pyamg

        A = sp.bsr_matrix(K, blocksize=(3, 3))
        self._ml = pyamg.smoothed_aggregation_solver(
            A,
            B=rigid_body_modes(positions_m),
            symmetry="symmetric",
            strength=("symmetric", {"theta": 0.0}),
            smooth=("jacobi", {"omega": 4.0 / 3.0}),
            presmoother=("block_gauss_seidel", {"sweep": "symmetric"}),
            postsmoother=("block_gauss_seidel", {"sweep": "symmetric"}),
            max_coarse=max_coarse,
            coarse_solver="splu",
        )
        self._M = self._ml.aspreconditioner(cycle="V")
        self.levels = len(self._ml.levels)
        self.operator_complexity = float(self._ml.operator_complexity())

    def __call__(self, r: np.ndarray) -> np.ndarray:
        if r.ndim == 1:
            return self._M @ r
        return np.stack([self._M @ r[:, j] for j in range(r.shape[1])], axis=1)
