"""Chord Newton steps with a factor of a nearby stiffness (``Simulator.solve(chord=...)``) and their
Anderson acceleration: the same equilibrium as Newton, with back-solves instead of factorisations,
and a fall-back to Newton when the factor is too far away to pay."""

from __future__ import annotations

import numpy as np
import pytest

from wface.physics import Simulator
from wface.physics.newton import _Anderson
from wface.solvers.linear import direct_backend
from wface.testing.models import box_model

pytestmark = pytest.mark.skipif(direct_backend() is None, reason="chord steps need a sparse direct factor")


@pytest.fixture(scope="module")
def box():
    model = box_model((6, 3, 3), cranium_faces=("x-",), muscles=2)
    sim = Simulator(model)
    a0 = np.array([0.5, 0.2])
    return model, sim, a0, sim.solve(a0, tol=1e-10)


def test_chord_steps_reach_the_newton_equilibrium_without_factorising(box):
    model, sim, a0, eq0 = box
    a1 = np.array([0.55, 0.25])  # the next frame: a small change
    chord = sim.stiffness_solver(eq0.x, a0, project=False)
    eq = sim.solve(a1, x0=eq0.x, chord=chord, tol=1e-10)
    ref = sim.solve(a1, x0=eq0.x, tol=1e-10)
    assert eq.converged and eq.factorizations == 0 and eq.chord_steps == eq.iterations > 0
    assert eq.back_solves == eq.iterations
    scale = np.abs(ref.x - model.rest_positions_m).max()
    assert np.abs(eq.x - ref.x).max() <= 1e-8 * scale  # both to 1e-10 in the relative residual


def test_a_far_factor_hands_over_to_newton(box):
    model, sim, a0, eq0 = box
    rest = sim.stiffness_solver(model.rest_positions_m, np.zeros(2), project=False)  # the unloaded face
    eq = sim.solve(np.array([1.0, 1.0]), x0=eq0.x, chord=rest, tol=1e-10)
    assert eq.converged and eq.factorizations > 0  # the chord's rate did not pay: fresh factors took over
    assert 0 < eq.chord_steps < eq.iterations


def test_lift_with_the_chord_moves_attached_nodes_to_their_targets(box):
    from wface.controls import attached_positions_from_affines, jaw_opening_affine

    model, sim, a0, eq0 = box
    targets = attached_positions_from_affines(model, jaw=jaw_opening_affine(model, 0.5))
    chord = sim.stiffness_solver(eq0.x, a0, project=False)
    eq = sim.solve(a0, targets, eq0.x, chord=chord, tol=1e-10)
    ref = sim.solve(a0, targets, eq0.x, tol=1e-10)
    assert eq.converged and np.array_equal(eq.x[model.attached_nodes], targets)
    assert np.abs(eq.x - ref.x).max() <= 1e-8 * np.abs(ref.x - model.rest_positions_m).max()


def test_anderson_acceleration_solves_a_linear_fixed_point_like_gmres():
    """x <- x + M^-1 (b - A x) with a poor M: plain iteration crawls; Anderson(m) with m >= n is GMRES
    and ends in at most n + 1 steps on an n-dimensional problem."""
    rng = np.random.default_rng(0)
    n = 8
    Q = rng.normal(size=(n, n))
    A = Q @ Q.T + n * np.eye(n)
    M = np.diag(np.diag(A)) * 3.0  # a chord matrix three times too stiff
    b = rng.normal(size=n)
    exact = np.linalg.solve(A, b)
    acc, x = _Anderson(depth=n), np.zeros(n)
    for _ in range(n + 1):
        x = x + acc.step(x, np.linalg.solve(M, b - A @ x))
    plain = np.zeros(n)
    for _ in range(n + 1):
        plain = plain + np.linalg.solve(M, b - A @ plain)
    assert np.abs(x - exact).max() <= 1e-8 * np.abs(exact).max()  # exact in n + 1 steps, up to round-off
    assert np.abs(plain - exact).max() > 1e-3 * np.abs(exact).max()
