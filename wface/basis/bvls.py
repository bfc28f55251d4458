"""Bounded least squares by a primal active-set method (Lawson & Hanson 1974; Stark & Parker 1995).

    minimise  1/2 |A x - b|^2   subject to  lower <= x <= upper      (upper may be +inf)

This is the convex QP of Choe & Ko (2001, sec. 4.2) with Q = 2 A^T A, c = 2 A^T b. The working
set W holds variables fixed at a bound; the others are free. Each iteration solves the
unconstrained problem in the free variables for a step p (minimum-norm least squares, so a
rank-deficient A is fine):  A_F p_F = r,  r = b - A x.
- If x + p is feasible, take it; else step to the first bound it crosses (ratio test) and add
  that variable to W.
- When p = 0 (x minimises over the free subspace) check the multipliers of W: the gradient
  g = -A^T r must satisfy g_i >= 0 at a lower bound and g_i <= 0 at an upper bound. If so x is
  optimal (KKT); else release the most violating variable.
Why the minimum-norm step matters when A is rank deficient: right after releasing j,
A_F^T r = -g_j e_j, so p = (A_F^T A_F)^+ (-g_j e_j) has p_j = -g_j [(A_F^T A_F)^+]_jj, of the right
sign and non-zero (e_j cannot be orthogonal to range(A_F^T A_F) since A_F^T r lies in it).
The objective falls strictly at every release, so no working set repeats (finite termination,
barring ties broken by round-off; an iteration cap guards that).

Warm start: pass the previous frame's solution and working set; only the changes are paid for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BoundedLSQResult", "bounded_lstsq"]


@dataclass
class BoundedLSQResult:
    """Solution of :func:`bounded_lstsq`.

    Attributes:
        x: (n,) minimiser.
        state: (n,) int8 working set: -1 at the lower bound, +1 at the upper bound, 0 free.
        cost: 1/2 |A x - b|^2.
        iterations: active-set iterations (subproblem solves).
        converged: KKT conditions met within tolerance.
    """

    x: np.ndarray
    state: np.ndarray
    cost: float
    iterations: int
    converged: bool


def _free_step(a: np.ndarray, r: np.ndarray, free: np.ndarray, rcond: float) -> np.ndarray:
    p = np.zeros(a.shape[1])
    if free.any():
        p[free] = np.linalg.lstsq(a[:, free], r, rcond=rcond)[0]
    return p


def bounded_lstsq(
    a: np.ndarray,
    b: np.ndarray,
    lower: np.ndarray | float = 0.0,
    upper: np.ndarray | float = np.inf,
    *,
    x0: np.ndarray | None = None,
    state0: np.ndarray | None = None,
    max_iter: int | None = None,
    tol: float = 1e-12,
    rcond: float = 1e-12,
) -> BoundedLSQResult:
    """Solve min 1/2 |A x - b|^2 subject to lower <= x <= upper.

    Args:
        a: (m, n) matrix (any rank).
        b: (m,) right-hand side.
        lower: (n,) or scalar lower bounds (finite).
        upper: (n,) or scalar upper bounds (may be inf).
        x0: warm-start point (clipped into the box); default all at the lower bound.
        state0: warm-start working set (-1 / +1 / 0); variables it marks are put at their bound.
        max_iter: iteration cap (default 10 (n + 1) + 50).
        tol: relative tolerance of the multiplier test, scaled by |A|_F |b|.
        rcond: cut-off for small singular values in the subproblems.

    Returns:
        :class:`BoundedLSQResult`.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64).reshape(-1)
    m, n = a.shape
    if b.shape != (m,):
        raise ValueError(f"bounded_lstsq: A is {a.shape} but b has {b.shape[0]} entries")
    lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (n,)).copy()
    hi = np.broadcast_to(np.asarray(upper, dtype=np.float64), (n,)).copy()
    if not np.all(np.isfinite(lo)):
        raise ValueError("bounded_lstsq: lower bounds must be finite")
    if np.any(hi < lo):
        raise ValueError("bounded_lstsq: some upper bound is below its lower bound")
    if max_iter is None:
        max_iter = 10 * (n + 1) + 50

    # Feasible start consistent with the working set.
    if x0 is None:
        x = lo.copy()
        state = np.full(n, -1, dtype=np.int8)
    else:
        x = np.clip(np.asarray(x0, dtype=np.float64).reshape(n), lo, hi)
        state = np.zeros(n, dtype=np.int8)
        state[x <= lo] = -1
        state[x >= hi] = 1
    if state0 is not None:
        s0 = np.asarray(state0, dtype=np.int8).reshape(n)
        state = s0.copy()
        state[(state == 1) & ~np.isfinite(hi)] = 0
    x[state == -1] = lo[state == -1]
    x[state == 1] = hi[state == 1]
    fixed_eq = hi == lo
    state[fixed_eq] = -1
    x[fixed_eq] = lo[fixed_eq]

    scale = max(np.linalg.norm(a) * max(np.linalg.norm(b), np.linalg.norm(a @ x)), 1e-300)
    gtol = tol * scale
    it = 0
    converged = False
    while it < max_iter:
        it += 1
        r = b - a @ x
        free = state == 0
        p = _free_step(a, r, free, rcond)
        step_norm = np.linalg.norm(p)
        if step_norm > 1e-14 * (1.0 + np.linalg.norm(x)):
            # Ratio test against the bounds of the free variables.
            alpha, block, block_side = 1.0, -1, 0
            neg = free & (p < 0)
            if neg.any():
                t = (lo[neg] - x[neg]) / p[neg]
                k = int(np.argmin(t))
                if t[k] < alpha:
                    alpha, block, block_side = float(t[k]), int(np.flatnonzero(neg)[k]), -1
            pos = free & (p > 0) & np.isfinite(hi)
            if pos.any():
                t = (hi[pos] - x[pos]) / p[pos]
                k = int(np.argmin(t))
                if t[k] < alpha:
                    alpha, block, block_side = float(t[k]), int(np.flatnonzero(pos)[k]), 1
            alpha = max(alpha, 0.0)
            x = x + alpha * p
            x[free] = np.clip(x[free], lo[free], hi[free])
            if block >= 0:
                state[block] = block_side
                x[block] = lo[block] if block_side < 0 else hi[block]
                # Other free variables landing exactly on a bound join too.
                on_lo = free & (x <= lo) & (p < 0)
                on_hi = free & (x >= hi) & (p > 0)
                state[on_lo], state[on_hi] = -1, 1
                continue
            # Full step taken: x is the minimiser over the free subspace; fall through to the
            # multiplier test with the new residual.
            r = b - a @ x
        g = -(a.T @ r)
        viol = np.zeros(n)
        at_lo = (state == -1) & ~fixed_eq
        at_hi = (state == 1) & ~fixed_eq
        viol[at_lo] = -g[at_lo]  # wants to increase
        viol[at_hi] = g[at_hi]  # wants to decrease
        j = int(np.argmax(viol))
        if viol[j] <= gtol:
            converged = True
            break
        state[j] = 0
    r = b - a @ x
    return BoundedLSQResult(x, state, 0.5 * float(r @ r), it, converged)
