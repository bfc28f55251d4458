"""Bounded least squares by a primal active-set method (Lawson & Hanson 1974; Stark & Parker 1995).

    minimise  1/2 |A x - b|^2   subject to  lower <= x <= upper      (either bound may be infinite)

This is the convex QP of Choe & Ko (2001, sec. 4.1.2) with Q = 2 A^T A, c = 2 A^T b. The working
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
Without one the start is the lower bound (the upper where only that is finite, 0 where neither is).
Users: the basis's per-frame contractions (``wface.basis.analysis``) and the tracker's bounded
Gauss-Newton steps (``wface.tracking.estimator``, unbounded bone parameters beside boxed activations).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve as _cho_solve
from scipy.linalg import cholesky as _cholesky

__all__ = ["BoundedLSQResult", "bounded_lstsq", "bounded_qp"]


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


def _free_step_gram(q: np.ndarray, rhs: np.ndarray, free: np.ndarray, rcond: float) -> np.ndarray:
    """Minimum-norm solution of Q_FF p_F = rhs_F (Cholesky; eigen-pseudo-inverse if singular)."""
    p = np.zeros(q.shape[0])
    if not free.any():
        return p
    idx = np.flatnonzero(free)
    qf = q[idx[:, None], idx]
    rf = rhs[idx]
    try:
        chol = _cholesky(qf, lower=True, check_finite=False)
        dg = np.diag(chol)
        if dg.min() ** 2 > rcond * dg.max() ** 2:
            p[idx] = _cho_solve((chol, True), rf, check_finite=False)
            return p
    except np.linalg.LinAlgError:
        pass
    w, v = np.linalg.eigh(qf)
    keep = w > rcond * max(w.max(), 0.0)
    p[idx] = v[:, keep] @ ((v[:, keep].T @ rf) / w[keep])
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
        lower: (n,) or scalar lower bounds (may be -inf).
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
    lo, hi = _bounds(lower, upper, n)
    if max_iter is None:
        max_iter = 10 * (n + 1) + 50
    scale = max(np.linalg.norm(a) * np.linalg.norm(b), 1e-300)

    def step(x, free):
        return _free_step(a, b - a @ x, free, rcond)

    def grad(x):
        return a.T @ (a @ x - b)

    x, state, it, converged = _active_set(step, grad, lo, hi, x0, state0, max_iter, tol * scale)
    r = b - a @ x
    return BoundedLSQResult(x, state, 0.5 * float(r @ r), it, converged)


def bounded_qp(
    q: np.ndarray,
    c: np.ndarray,
    lower: np.ndarray | float = 0.0,
    upper: np.ndarray | float = np.inf,
    *,
    x0: np.ndarray | None = None,
    state0: np.ndarray | None = None,
    max_iter: int | None = None,
    tol: float = 1e-12,
    rcond: float = 1e-13,
    b_norm2: float = 0.0,
) -> BoundedLSQResult:
    """The same problem in normal-equation form: min 1/2 x^T Q x - c^T x, lower <= x <= upper.

    With Q = A^T A and c = A^T b this is :func:`bounded_lstsq` (cost reported as
    1/2 x^T Q x - c^T x + 1/2 ``b_norm2``). Each subproblem is a Cholesky solve on Q_FF (an
    eigen pseudo-inverse when Q_FF is singular): much cheaper than least squares on A_F when A
    has many more rows than columns or is reused across frames, at the price of squaring the
    condition number (fine for bases whose shapes are not nearly parallel).

    Args:
        q: (n, n) symmetric positive semidefinite.
        c: (n,) linear term.
        b_norm2: |b|^2, only to report the least-squares cost.
    """
    q = np.asarray(q, dtype=np.float64)
    c = np.asarray(c, dtype=np.float64).reshape(-1)
    n = q.shape[0]
    if q.shape != (n, n) or c.shape != (n,):
        raise ValueError(f"bounded_qp: Q is {q.shape} and c has {c.shape[0]} entries")
    lo, hi = _bounds(lower, upper, n)
    if max_iter is None:
        max_iter = 10 * (n + 1) + 50
    # Multiplier scale |A|_F |b| when b is known, else |c| (= |A^T b|).
    scale = max(np.sqrt(max(np.trace(q), 0.0) * b_norm2), float(np.linalg.norm(c)), 1e-300)

    def step(x, free):
        return _free_step_gram(q, c - q @ x, free, rcond)

    def grad(x):
        return q @ x - c

    x, state, it, converged = _active_set(step, grad, lo, hi, x0, state0, max_iter, tol * scale)
    cost = 0.5 * float(x @ q @ x) - float(c @ x) + 0.5 * b_norm2
    return BoundedLSQResult(x, state, cost, it, converged)


def _bounds(lower, upper, n):
    lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (n,)).copy()
    hi = np.broadcast_to(np.asarray(upper, dtype=np.float64), (n,)).copy()
    if np.isnan(lo).any() or np.isnan(hi).any() or np.any(lo == np.inf) or np.any(hi == -np.inf):
        raise ValueError("bounded least squares: bounds must be numbers, lower < inf and upper > -inf")
    if np.any(hi < lo):
        raise ValueError("bounded least squares: some upper bound is below its lower bound")
    return lo, hi


def _active_set(step, grad, lo, hi, x0, state0, max_iter, gtol):
    """The primal active-set loop shared by both front ends (see the module docstring)."""
    n = len(lo)
    # Feasible start consistent with the working set.
    if x0 is None:
        x = np.where(np.isfinite(lo), lo, np.where(np.isfinite(hi), hi, 0.0))
        state = np.where(np.isfinite(lo), -1, np.where(np.isfinite(hi), 1, 0)).astype(np.int8)
    else:
        x = np.clip(np.asarray(x0, dtype=np.float64).reshape(n), lo, hi)
        state = np.zeros(n, dtype=np.int8)
        state[x <= lo] = -1
        state[x >= hi] = 1
    if state0 is not None:
        state = np.asarray(state0, dtype=np.int8).reshape(n).copy()
        state[(state == 1) & ~np.isfinite(hi)] = 0
        state[(state == -1) & ~np.isfinite(lo)] = 0
    x[state == -1] = lo[state == -1]
    x[state == 1] = hi[state == 1]
    fixed_eq = hi == lo
    state[fixed_eq] = -1
    x[fixed_eq] = lo[fixed_eq]

    it = 0
    converged = False
    # Release every violating bound at once while that makes progress (far fewer iterations
    # from a cold start); after the first zero-length step fall back to the classical single
    # release, which guarantees termination.
    multi = True
    released = np.zeros(n, dtype=bool)
    while it < max_iter:
        it += 1
        free = state == 0
        p = step(x, free)
        step_norm = np.linalg.norm(p)
        if step_norm > 1e-14 * (1.0 + np.linalg.norm(x)):
            # Ratio test against the bounds of the free variables.
            alpha, block, block_side = 1.0, -1, 0
            neg = free & (p < 0) & np.isfinite(lo)
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
            if alpha == 0.0 and block >= 0 and released[block]:
                multi = False
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
        # x minimises over the free subspace: multiplier test on the working set.
        g = grad(x)
        viol = np.zeros(n)
        at_lo = (state == -1) & ~fixed_eq
        at_hi = (state == 1) & ~fixed_eq
        viol[at_lo] = -g[at_lo]  # wants to increase
        viol[at_hi] = g[at_hi]  # wants to decrease
        j = int(np.argmax(viol))
        if viol[j] <= gtol:
            converged = True
            break
        released[:] = False
        if multi:
            released[viol > gtol] = True
        else:
            released[j] = True
        state[released] = 0
    return x, state, it, converged
