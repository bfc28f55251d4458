"""Linear solvers: PCG (single and many right-hand sides) against the sparse direct factorisation
and a dense solve, the factor as a preconditioner, detection of indefinite matrices, and the
"auto" choice with its fallback when no direct backend is installed."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from wface.physics import Simulator
from wface.solvers import linear
from wface.solvers.linear import (
    DirectFactor,
    FactorPreconditioner,
    JacobiPreconditioner,
    NotPositiveDefiniteError,
    direct_backend,
    pcg,
    resolve_linear_solver,
)
from wface.testing.models import box_model

needs_direct = pytest.mark.skipif(direct_backend() is None, reason="no sparse direct backend installed")


@pytest.fixture(scope="module")
def stiffness():
    """Projected stiffness of a deformed, activated box, Dirichlet rows removed (SPD, cond ~1e4)."""
    model = box_model((4, 2, 2), cranium_faces=("x-",), muscles=2)
    sim = Simulator(model)
    X = model.rest_positions_m
    x = X + 0.002 * np.random.default_rng(0).normal(size=X.shape)
    a = np.array([0.8, 0.3])
    return sim, x, a, sim.assemble_stiffness(x, a, nodes="free")


@needs_direct
def test_direct_and_cg_solve_many_right_hand_sides(stiffness):
    _, _, _, K = stiffness
    B = np.random.default_rng(1).normal(size=(K.shape[0], 44))  # the Jacobian issue's column count
    dense = np.linalg.solve(K.toarray(), B)
    factor = DirectFactor(K)
    X_direct = factor.solve(B)
    np.testing.assert_allclose(X_direct, dense, rtol=0, atol=1e-9 * np.abs(dense).max())
    np.testing.assert_allclose(factor.solve(B[:, 3]), dense[:, 3], rtol=0, atol=1e-9 * np.abs(dense).max())
    res = pcg(lambda v: K @ v, B, preconditioner=JacobiPreconditioner(K.diagonal()), rtol=1e-10)
    assert res.converged and res.x.shape == B.shape
    np.testing.assert_allclose(res.x, dense, rtol=0, atol=1e-7 * np.abs(dense).max())  # rtol 1e-10 x cond ~1e4
    assert np.all(np.linalg.norm(K @ res.x - B, axis=0) <= 1.01e-10 * np.linalg.norm(B, axis=0))


@needs_direct
def test_factor_of_a_nearby_matrix_preconditions_cg(stiffness):
    sim, x, a, K0 = stiffness
    K1 = sim.assemble_stiffness(x * 1.01, a * 0.9, nodes="free")  # next Newton step's matrix
    b = np.random.default_rng(2).normal(size=K1.shape[0])
    jacobi = pcg(lambda v: K1 @ v, b, preconditioner=JacobiPreconditioner(K1.diagonal()), rtol=1e-10)
    factored = pcg(lambda v: K1 @ v, b, preconditioner=FactorPreconditioner(DirectFactor(K0)), rtol=1e-10)
    assert factored.converged and jacobi.converged
    assert factored.iterations < jacobi.iterations / 3, (factored.iterations, jacobi.iterations)
    np.testing.assert_allclose(factored.x, jacobi.x, atol=1e-7 * np.abs(jacobi.x).max())


@settings(max_examples=25, deadline=None)
@given(n=st.integers(2, 40), k=st.integers(1, 4), seed=st.integers(0, 2**31 - 1))
def test_pcg_solves_random_spd_systems(n, k, seed):
    rng = np.random.default_rng(seed)
    Q = rng.normal(size=(n, n))
    A = Q @ Q.T + n * np.eye(n)  # SPD, condition number bounded by construction
    B = rng.normal(size=(n, k))
    res = pcg(lambda v: A @ v, B, preconditioner=JacobiPreconditioner(np.diag(A)), rtol=1e-12)
    assert res.converged and res.iterations <= 3 * n
    np.testing.assert_allclose(A @ res.x, B, atol=1e-9 * np.abs(B).max())


def test_indefinite_matrices_are_reported():
    A = sp.diags([2.0, 1.0, -1.0, 3.0]).tocsr()
    b = np.ones(4)
    assert pcg(lambda v: A @ v, b).indefinite
    if direct_backend() is not None:
        with pytest.raises(NotPositiveDefiniteError):
            DirectFactor(A)


def test_auto_picks_direct_and_falls_back_to_cg_with_a_notice(monkeypatch):
    if direct_backend() is not None:
        assert resolve_linear_solver("auto", "cpu") == "direct"
    assert resolve_linear_solver("auto", "cuda:0") == "cg"
    assert resolve_linear_solver("cg", "cpu") == "cg"
    monkeypatch.setattr(linear, "direct_backend", lambda: None)
    with pytest.warns(RuntimeWarning, match="no sparse direct solver"):
        assert resolve_linear_solver("auto", "cpu") == "cg"
    with pytest.warns(RuntimeWarning):
        assert resolve_linear_solver("direct", "cpu") == "cg"
    with pytest.raises(ValueError, match="unknown linear solver"):
        resolve_linear_solver("lu", "cpu")


def test_simulator_without_direct_backend_still_solves(monkeypatch):
    monkeypatch.setattr(linear, "direct_backend", lambda: None)
    model = box_model((3, 2, 2), cranium_faces=("x-",), muscles=1)
    with pytest.warns(RuntimeWarning):
        sim = Simulator(model, solver="auto")
    eq = sim.solve({"muscle_0": 0.5})
    assert eq.converged and eq.solver == "cg" and eq.cg_iterations > 0


def test_warp_cg_path_solves_the_masked_system(stiffness):
    """The device-side CG used on CUDA (warp.optim.linear.cg + matrix-free K.v + Jacobi), run here
    on the CPU device for correctness: K_UU X = B for two right-hand sides."""
    from wface.solvers.warp_cg import warp_pcg

    sim, x, a, K = stiffness
    tan = sim.tangent(x, a)
    B = np.random.default_rng(3).normal(size=(K.shape[0], 2))
    X, iterations = warp_pcg(tan, sim.pattern("free"), B, rtol=1e-10)
    assert iterations > 0
    assert np.abs(K @ X - B).max() < 1e-8 * np.abs(B).max()  # rtol 1e-10 on ||r||, max-norm slack


def test_activation_jacobian_by_one_factorisation_matches_finite_differences():
    """dX/da_i = K_UU^-1 f_i(X*) (Sifakis et al. 2005, eq. 5), all muscles against one factor / with CG,
    compared with central differences of the equilibrium (h = 1e-4 in activation; Newton to 1e-11)."""
    model = box_model((4, 2, 2), cranium_faces=("x-",), muscles=2)
    sim = Simulator(model)
    a = np.array([0.4, 0.6])
    eq = sim.solve(a, tol=1e-11)
    fi = sim.muscle_forces(eq.x)
    J_direct = sim.stiffness_solver(eq.x, a, project=False, solver="direct").solve_nodal(fi)
    J_cg = sim.stiffness_solver(eq.x, a, project=False, solver="cg").solve_nodal(fi)
    np.testing.assert_allclose(J_cg, J_direct, atol=1e-7 * np.abs(J_direct).max())
    h = 1e-4
    for i in range(2):
        e = np.eye(2)[i] * h
        xp = sim.solve(a + e, x0=eq.x, tol=1e-11).x
        xm = sim.solve(a - e, x0=eq.x, tol=1e-11).x
        fd = (xp - xm) / (2 * h)
        assert np.abs(J_direct[i] - fd).max() < 1e-4 * np.abs(fd).max()  # O(h^2) + Newton tolerance


@needs_direct
def test_refactorisation_with_the_same_sparsity_reuses_the_analysis(stiffness):
    sim, x, a, K0 = stiffness
    K1 = sim.assemble_stiffness(x * 1.02, a * 0.5, nodes="free")
    b = np.random.default_rng(4).normal(size=(K1.shape[0], 3))
    first = DirectFactor(K0)
    second = DirectFactor(K1, reuse=first)
    fresh = DirectFactor(K1)
    assert second.reused_analysis == (second.backend == "pardiso") and not fresh.reused_analysis
    X = second.solve(b)
    np.testing.assert_allclose(X, fresh.solve(b), rtol=0, atol=1e-9 * np.abs(X).max())
    np.testing.assert_allclose(K1 @ X, b, rtol=0, atol=1e-8 * np.abs(b).max())
    if second.backend == "pardiso":
        with pytest.raises(RuntimeError, match="freed"):
            first.solve(b)  # its PARDISO handle now belongs to the newer factor
