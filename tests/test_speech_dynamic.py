"""wface.speech.dynamic: excitation curves through the implicit dynamic FEM, read at every step's time."""

import numpy as np
import pytest

from wface.physics.simulator import Simulator
from wface.speech.dynamic import GestureDynamics, play_dynamic
from wface.testing.models import box_model

# Backward Euler with C = beta K relaxes the stiff part by (1 + h / beta)^-1 per step: after 95 steps of
# 10 ms with beta = 0.055 s that is 1.4e-7 of the travel; each step's Newton stops at a relative
# residual of 1e-6. 1e-4 of the travel leaves room for both.
_SETTLED_TOL = 1e-4


class _Mapping:
    """Duck-typed ``GestureMapping``: the box's one muscle follows ``curve(t)``."""

    def __init__(self, curve):
        self.curve = curve

    def activations(self, gesture, model, times_s):
        return np.array([[self.curve(t)] for t in np.atleast_1d(times_s)])


class _Gesture:
    name = "test"


@pytest.fixture(scope="module")
def box():
    model = box_model((4, 2, 2), muscles=1)
    return model, Simulator(model)


def test_held_excitation_settles_to_the_quasistatic_equilibrium(box):
    model, sim = box
    ramp = _Mapping(lambda t: 0.8 * min(t / 0.05, 1.0))
    dyn = GestureDynamics(max_step_s=0.01, gravity_m_s2=None)  # ArtiSynth's damping, no gravity
    out = play_dynamic(sim, _Gesture(), ramp, np.array([0.0, 0.05, 1.0]), dynamics=dyn)
    assert out["converged"].all() and out["steps"].tolist() == [0, 5, 95]
    eq = sim.solve(np.array([0.8]), tol=1e-9)
    travel = np.abs(eq.x - model.rest_positions_m).max()
    assert travel > 1e-3  # a real load
    assert np.abs(out["x_m"][-1] - eq.x).max() <= _SETTLED_TOL * travel
    # the face lags the excitation: at the end of the 50 ms ramp it is half way (measured 0.50)
    assert np.abs(out["x_m"][1] - model.rest_positions_m).max() < 0.9 * travel


def test_every_step_reads_the_curve_at_its_own_time(box):
    """A pulse between two frames whose own activations are zero: interpolating the frames would
    leave the box at rest; the steps, sampled every 5 ms, see the pulse."""
    model, sim = box
    pulse = _Mapping(lambda t: 0.8 if 0.02 <= t <= 0.06 else 0.0)
    out = play_dynamic(sim, _Gesture(), pulse, np.array([0.0, 0.1]), dynamics=GestureDynamics(gravity_m_s2=None))
    assert out["activations"][:, 0].tolist() == [0.0, 0.0] and out["steps"][1] == 20
    travel = np.abs(sim.solve(np.array([0.8])).x - model.rest_positions_m).max()
    moved = np.abs(out["x_m"][1] - model.rest_positions_m).max()
    # measured 0.31 of the travel: 40 ms of pull, then 40 ms of relaxation with tau ~ beta
    assert 0.05 * travel < moved < 0.9 * travel
    assert np.array_equal(out["x_m"][0], sim.solve(np.array([0.0])).x)  # frame 0: quasistatic start
