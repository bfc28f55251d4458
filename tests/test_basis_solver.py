"""The active-set bounded least-squares solver against scipy.optimize.lsq_linear."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import lsq_linear

from wface.solvers.bvls import bounded_lstsq, bounded_qp

# Optimal costs agree to round-off relative to |b|^2 (both are exact active-set / interior
# solutions of the same convex QP); minimisers agree only when A has full column rank.
_COST_RTOL = 1e-9
_X_ATOL = 1e-7


def _problem(seed, m, n, rank, upper_inf):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(m, rank)) @ rng.normal(size=(rank, n))
    if rng.random() < 0.3:
        a[:, rng.integers(n)] = 0.0  # an element no marker sees
    b = rng.normal(size=m) * rng.uniform(0.1, 10)
    upper = np.inf if upper_inf else 1.0
    return a, b, upper


def _scipy_cost(a, b, upper):
    """Best of scipy's two methods (its BVLS can stop early on rank-deficient A)."""
    best = None
    for method in ("bvls", "trf"):
        ref = lsq_linear(a, b, bounds=(0.0, upper), method=method, tol=1e-15, lsq_solver="exact", max_iter=10_000)
        cost = 0.5 * float(np.sum((a @ ref.x - b) ** 2))
        if best is None or cost < best[0]:
            best = (cost, ref.x)
    return best


def _assert_kkt(a, b, x, lower, upper):
    g = a.T @ (a @ x - b)
    tol = 1e-9 * np.linalg.norm(a) * (np.linalg.norm(b) + 1.0)
    at_lo, at_hi = x <= lower + 1e-12, x >= upper - 1e-12
    free = ~at_lo & ~at_hi
    assert np.all(np.abs(g[free]) <= tol)
    assert np.all(g[at_lo & ~at_hi] >= -tol) and np.all(g[at_hi & ~at_lo] <= tol)


@settings(max_examples=150, deadline=None)
@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # scipy trf on rank-deficient A
@given(
    seed=st.integers(0, 2**31 - 1),
    m=st.integers(1, 40),
    n=st.integers(1, 25),
    rank_frac=st.floats(0.2, 1.0),
    upper_inf=st.booleans(),
)
def test_matches_scipy(seed, m, n, rank_frac, upper_inf):
    rank = max(1, int(round(rank_frac * min(m, n))))
    a, b, upper = _problem(seed, m, n, rank, upper_inf)
    res = bounded_lstsq(a, b, 0.0, upper)
    assert res.converged
    assert np.all(res.x >= 0) and np.all(res.x <= upper)
    _assert_kkt(a, b, res.x, 0.0, upper)
    cost_ref, x_ref = _scipy_cost(a, b, upper)
    if np.abs(x_ref).max() > 1e6:
        # With x >= 0 only and a null-space direction of A inside the cone, scipy runs off to
        # |x| ~ 1e15 and "beats" the optimum by round-off in A x; the KKT check above decides.
        assert upper_inf
        return
    assert abs(res.cost - cost_ref) <= _COST_RTOL * (b @ b + 1.0)
    if rank == n and m >= n and np.linalg.matrix_rank(a) == n:
        np.testing.assert_allclose(res.x, x_ref, atol=_X_ATOL * (1 + np.abs(x_ref).max()))


def test_kkt_conditions_rank_deficient():
    a, b, _ = _problem(3, 30, 20, 6, True)
    res = bounded_lstsq(a, b, 0.0, 1.0)
    assert res.converged
    _assert_kkt(a, b, res.x, 0.0, 1.0)


def test_warm_start_same_answer_fewer_iterations():
    rng = np.random.default_rng(7)
    a = rng.normal(size=(123, 57))
    x_true = np.clip(rng.normal(0.3, 0.4, size=57), 0, 1)
    b1 = a @ x_true + 0.01 * rng.normal(size=123)
    b2 = b1 + 0.001 * rng.normal(size=123)
    cold1 = bounded_lstsq(a, b1, 0.0, 1.0)
    cold2 = bounded_lstsq(a, b2, 0.0, 1.0)
    warm2 = bounded_lstsq(a, b2, 0.0, 1.0, x0=cold1.x, state0=cold1.state)
    np.testing.assert_allclose(warm2.x, cold2.x, atol=1e-10)
    assert warm2.iterations < cold2.iterations


def test_general_box_and_errors():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(10, 4)), rng.normal(size=10)
    lo, hi = np.array([-1.0, 0.2, -np.pi, 0.0]), np.array([1.0, 0.3, 0.0, np.inf])
    res = bounded_lstsq(a, b, lo, hi)
    ref = lsq_linear(a, b, bounds=(lo, hi), method="bvls", tol=1e-14)
    np.testing.assert_allclose(res.x, ref.x, atol=1e-9)
    with pytest.raises(ValueError, match="b has"):
        bounded_lstsq(a, b[:3])
    with pytest.raises(ValueError, match="below its lower"):
        bounded_lstsq(a, b, 1.0, 0.0)
    with pytest.raises(ValueError, match="bounds must be numbers"):
        bounded_lstsq(a, b, np.nan, 1.0)


@pytest.mark.parametrize("warm", [False, True])
def test_unbounded_variables_beside_a_box(warm):
    """The tracker's Gauss-Newton QP: boxed activations beside free bone parameters (lower -inf,
    upper inf), in normal-equation form, against scipy's BVLS; cold, and warm-started from a
    neighbouring problem's working set (the same minimiser in fewer iterations)."""
    rng = np.random.default_rng(4)
    m, n_box, n_free = 120, 36, 21
    a = rng.normal(size=(m, n_box + n_free))
    b = a @ np.concatenate([rng.uniform(-0.4, 1.2, n_box), rng.normal(size=n_free)]) + 0.05 * rng.normal(size=m)
    c0 = rng.uniform(0.0, 1.0, n_box)  # current activations: the step's box is [-c0, 1 - c0]
    lo = np.concatenate([-c0, np.full(n_free, -np.inf)])
    hi = np.concatenate([1.0 - c0, np.full(n_free, np.inf)])
    ref = lsq_linear(a, b, bounds=(lo, hi), method="bvls", tol=1e-14).x
    q, c = a.T @ a, a.T @ b
    start = {}
    if warm:
        near = bounded_qp(q + 1e-3 * np.eye(len(c)), c, lo, hi, x0=np.zeros(len(c)))
        start = {"x0": near.x, "state0": near.state}
        cold = bounded_qp(q, c, lo, hi, x0=np.zeros(len(c)))
    res = bounded_qp(q, c, lo, hi, **({"x0": np.zeros(len(c))} | start))
    assert res.converged
    assert np.all(res.state[n_box:] == 0)  # the unbounded ones never join the working set
    assert 0 < np.count_nonzero(res.state[:n_box]) < n_box  # some activations at a bound
    np.testing.assert_allclose(res.x, ref, atol=1e-8)
    if warm:
        assert res.iterations < cold.iterations
    cold_start = bounded_qp(q, c, lo, hi)  # no start: the finite bound, 0 where there is none
    np.testing.assert_allclose(cold_start.x, ref, atol=1e-8)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 60), n=st.integers(1, 30), rank_frac=st.floats(0.2, 1.0),
       upper_inf=st.booleans())  # fmt: skip
def test_normal_equation_form_matches(seed, m, n, rank_frac, upper_inf):
    """bounded_qp on (A^T A, A^T b) reaches the same optimum as the least-squares form."""
    rank = max(1, int(round(rank_frac * min(m, n))))
    a, b, upper = _problem(seed, m, n, rank, upper_inf)
    ref = bounded_lstsq(a, b, 0.0, upper)
    res = bounded_qp(a.T @ a, a.T @ b, 0.0, upper, b_norm2=float(b @ b))
    assert res.converged
    cost = 0.5 * float(np.sum((a @ res.x - b) ** 2))
    # Normal equations square the condition number: agreement to ~1e-8 of |b|^2, not 1e-12.
    assert abs(cost - ref.cost) <= 1e-8 * (b @ b + 1.0)
