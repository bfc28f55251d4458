"""The small problem of one Gauss-Newton step of a frame (``wface.tracking.estimator``; docs/design.md,
"Tracking"): bounded least squares in the null space of the jaw-joint equalities, and the first-order
rigidity of a bone step that chooses the penalty weight.

The activation penalty is flat at its bound (no curvature at a = 0), so a linearised penalty model
cannot stop a step from crossing it: the box is enforced exactly instead. The joint equalities
psi1..psi3 are linear in the jaw parameters: the step lives in their null space (dc = T z,
T = blockdiag(I, N_jaw)), which leaves the activation box a box, and the reduced problem is a bounded
QP, solved by a primal active set (``wface.solvers.bvls``).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import null_space

from wface.controls import _joint_rows
from wface.solvers.bvls import bounded_qp

__all__ = ["bounded_step", "step_basis", "step_violation"]


def step_basis(joint, n_muscles: int) -> np.ndarray:
    """T (M + 24, M + 12 + 9): identity on the activations and the cranium, the null space of the jaw
    joint's equalities on the jaw's 12 affine numbers."""
    A, _, lo, hi = _joint_rows(joint)
    N = null_space(A[lo == hi])  # (12, 9)
    M = n_muscles
    T = np.zeros((M + 24, M + 12 + N.shape[1]))
    T[: M + 12, : M + 12] = np.eye(M + 12)
    T[M + 12 :, M + 12 :] = N
    return T


def bounded_step(T, H, g, c, lower, start=None, frozen=None) -> tuple[np.ndarray, tuple]:
    """(argmin 1/2 dc^T H dc + g^T dc over dc = T z with lower <= a + da <= 1, the reduced problem's
    (solution, working set): a neighbouring problem's ``start``), from z = 0 or warm-started at
    ``start`` (the same minimiser: the reduced Hessian is definite). ``c``: the controls (activations
    first), ``lower``: the activations' lower bounds; ``frozen`` (M,) bool: activations left out of
    the step (their columns of T dropped)."""
    M = len(lower)
    moving = np.ones(M, dtype=bool) if frozen is None else ~np.asarray(frozen, dtype=bool)
    if not moving.all():
        T = T[:, np.concatenate([moving, np.ones(T.shape[1] - M, dtype=bool)])]
    Hz = T.T @ (0.5 * (H + H.T)) @ T
    gz = T.T @ g
    p = len(gz)
    Hz += 1e-10 * max(np.trace(Hz) / p, 1e-30) * np.eye(p)  # damping for unobservable directions
    lo, hi = np.full(p, -np.inf), np.full(p, np.inf)
    low = np.asarray(lower)[moving]
    a = np.clip(c[:M][moving], low, 1.0)
    k = int(moving.sum())
    lo[:k], hi[:k] = low - a, 1.0 - a
    x0, state0 = start if start is not None else (np.zeros(p), None)
    res = bounded_qp(Hz, -gz, lo, hi, x0=x0, state0=state0)
    return T @ res.x, (res.x, res.state)


def step_violation(c: np.ndarray, dc: np.ndarray, n_muscles: int) -> float:
    """First-order rigidity violation of a step, |M^T dM + dM^T M|_F / |dM|_F, worst bone (the cranium's
    and the jaw's 3 x 3 blocks after the M activations)."""
    worst = 0.0
    for s0 in (n_muscles, n_muscles + 12):
        Mb, dM = c[s0 : s0 + 9].reshape(3, 3), dc[s0 : s0 + 9].reshape(3, 3)
        norm = np.linalg.norm(dM)
        if norm > 1e-12:
            worst = max(worst, np.linalg.norm(Mb.T @ dM + dM.T @ Mb) / norm)
    return worst
