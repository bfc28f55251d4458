"""Implicit dynamics (``wface.physics.dynamics``) and take re-simulation (``wface.resim``).

Small float64 box meshes (96-144 tets); every reference value comes from an independent
computation: momentum conservation, the quasistatic solver, the generalized eigenproblem
K v = omega^2 M v (scipy eigsh) and the energy balance of each scheme.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh

from wface.physics import Simulator
from wface.physics.dynamics import Damping, DynamicSimulator, lumped_masses
from wface.physics.testmodels import box_model

_MOMENTUM_TOL = 1e-12  # relative to the initial momentum scale: float64 round-off of a few hundred sums
_PERIOD_TOL = 0.01  # implicit midpoint at 40 steps per period: relative period error (h omega)^2 / 12 = 0.2 %
_ENERGY_TOL = 1e-3  # midpoint, 1 mm amplitude on a 4 cm block (mildly nonlinear), 3 periods: measured 3e-4


@pytest.fixture(scope="module")
def clamped():
    """A 4 x 2 x 2 cm block (96 tets), x- face clamped, no muscle."""
    model = box_model((4, 2, 2), muscles=0)
    return model, Simulator(model)


@pytest.fixture(scope="module")
def first_mode(clamped):
    model, sim = clamped
    pattern = sim.pattern("free")
    K = sim.assemble_stiffness(None, None, nodes="free")
    mass = np.repeat(lumped_masses(model)[pattern.dof_nodes], 3)
    w2, V = eigsh(K, k=1, M=sp.diags(mass), sigma=0, which="LM")
    mode = pattern.scatter(V[:, 0])
    return float(np.sqrt(w2[0])), mode / np.abs(mode).max()


def test_lumped_mass_is_the_total_mass():
    model = box_model((3, 2, 2))
    m = lumped_masses(model)
    assert m.shape == (model.n_nodes,) and np.all(m > 0)
    assert m.sum() == pytest.approx(model.material.density_kg_m3 * 0.04 * 0.02 * 0.02, rel=1e-12)


@pytest.mark.parametrize("scheme", ["be", "midpoint"])
def test_free_body_conserves_linear_momentum(scheme):
    model = box_model((3, 2, 2), cranium_faces=(), muscles=1)  # no attached nodes
    dyn = DynamicSimulator(Simulator(model), scheme=scheme, damping=Damping(0.0, 1e-4))  # beta K is momentum-free
    rng = np.random.default_rng(1)
    x0 = model.rest_positions_m + 5e-4 * rng.normal(size=(model.n_nodes, 3))
    state = dyn.initial_state(x0, 0.05 * rng.normal(size=(model.n_nodes, 3)), np.array([0.5]))
    p0 = dyn.momentum(state)
    scale = float(dyn.masses_kg @ np.linalg.norm(state.v_m_s, axis=1))
    for _ in range(10):
        state, stats = dyn.step(state, 1e-3)
        assert stats.converged
    assert np.abs(dyn.momentum(state) - p0).max() <= _MOMENTUM_TOL * scale
    assert not np.allclose(state.x_m, x0)  # it did move


def test_constant_activation_with_damping_reaches_the_quasistatic_equilibrium():
    model = box_model((4, 2, 2), muscles=1)
    sim = Simulator(model)
    a = np.array([0.8])
    eq = sim.solve(a)
    moved = np.abs(eq.x - model.rest_positions_m).max()
    assert moved > 1e-3  # a real load: ~9 mm
    for scheme, steps in (("be", 15), ("midpoint", 60)):
        dyn = DynamicSimulator(sim, scheme=scheme, damping=Damping(200.0, 1e-3))
        state = dyn.initial_state()
        for _ in range(steps):  # sudden activation at t = 0, held
            state, _ = dyn.step(state, 5e-3, a)
        assert np.abs(state.x_m - eq.x).max() <= 2e-3 * moved, scheme


def _project(model, mode, x):
    return float(np.sum(lumped_masses(model)[:, None] * mode * (x - model.rest_positions_m)))


def test_midpoint_period_matches_the_first_eigenfrequency(clamped, first_mode):
    model, sim = clamped
    omega, mode = first_mode
    period = 2 * np.pi / omega
    h = period / 40
    dyn = DynamicSimulator(sim, scheme="midpoint", damping=Damping.none())
    state = dyn.initial_state(model.rest_positions_m + 1e-5 * mode)  # 10 um: the linear regime
    signal = []
    for _ in range(100):  # 2.5 periods
        signal.append(_project(model, mode, state.x_m))
        state, _ = dyn.step(state, h)
    s = np.array(signal)
    k = np.flatnonzero(s[:-1] * s[1:] < 0)
    crossings = (k + s[k] / (s[k] - s[k + 1])) * h
    assert crossings.size >= 4
    measured = 2 * np.mean(np.diff(crossings))
    assert measured == pytest.approx(period, rel=_PERIOD_TOL)


def test_energy_midpoint_conserves_and_backward_euler_dissipates(clamped, first_mode):
    model, sim = clamped
    omega, mode = first_mode
    h = 2 * np.pi / omega / 30
    energies = {}
    for scheme in ("midpoint", "be"):
        dyn = DynamicSimulator(sim, scheme=scheme, damping=Damping.none())
        state = dyn.initial_state(model.rest_positions_m + 1e-3 * mode)  # 1 mm on a 4 cm block
        e = [dyn.total_energy(state)]
        for _ in range(90):  # 3 periods
            state, stats = dyn.step(state, h)
            assert stats.converged
            e.append(dyn.total_energy(state))
        energies[scheme] = np.array(e)
    mid, be = energies["midpoint"], energies["be"]
    assert mid[0] > 0
    assert np.abs(mid - mid[0]).max() <= _ENERGY_TOL * mid[0]
    assert np.all(np.diff(be) <= 1e-12 * be[0])  # monotone (round-off slack)
    assert be[-1] < 0.5 * be[0]  # and visibly so at 30 steps per period


def test_damping_defaults_and_ratio():
    d = Damping()
    assert d.alpha_per_s == 0.0 and d.beta_s > 0
    assert d.ratio(100.0) == pytest.approx(np.pi * 100.0 * d.beta_s)
    assert Damping.none().ratio(50.0) == 0.0


def test_bad_inputs_raise_clear_errors(clamped):
    model, sim = clamped
    dyn = DynamicSimulator(sim)
    state = dyn.initial_state()
    with pytest.raises(ValueError, match="dt_s"):
        dyn.step(state, 0.0)
    with pytest.raises(ValueError, match="dt_s"):
        dyn.step(state, float("nan"))
    with pytest.raises(ValueError, match="attached_positions_m has shape"):
        dyn.step(state, 1e-3, None, np.zeros((3, 3)))
    bad = model.rest_positions_m.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        dyn.initial_state(bad)
    with pytest.raises(ValueError, match="x_m has shape"):
        dyn.initial_state(bad[:-1])
    with pytest.raises(ValueError, match="scheme"):
        DynamicSimulator(sim, scheme="rk4")
    with pytest.raises(ValueError, match="beta_s"):
        Damping(0.0, -1.0)
    with pytest.raises(ValueError, match="substeps"):
        dyn.advance(state, 0.01, 0)
