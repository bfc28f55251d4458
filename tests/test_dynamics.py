"""Implicit dynamics (``wface.physics.dynamics``) and take re-simulation (``wface.takes.dynamic``).

Small float64 box meshes (96-144 tets); every reference value comes from an independent
computation: momentum conservation, the quasistatic solver, the generalized eigenproblem
K v = omega^2 M v (scipy eigsh) and the energy balance of each scheme.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh

from wface.physics import Simulator
from wface.physics.dynamics import Damping, DynamicSimulator, lumped_masses
from wface.testing.models import box_model

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


@pytest.mark.parametrize("exact", [False, True])
def test_backward_euler_step_solves_the_damped_equation_of_motion(exact):
    """One converged backward Euler step of a free body with its muscle on solves
    M (v1 - v0) / h = f(x1) - beta K_n v1, K_n at the step's start assembled here: projected, or exact
    as ArtiSynth damps (``Damping.exact_tangent``); the two K_n differ at this state."""
    model = box_model((3, 2, 2), cranium_faces=(), muscles=1)
    sim = Simulator(model, precision="float64")
    h, beta, a = 1e-3, 2e-4, np.array([0.6])
    dyn = DynamicSimulator(sim, scheme="be", damping=Damping(0.0, beta, exact_tangent=exact), tol=1e-10)
    rng = np.random.default_rng(3)
    x0 = model.rest_positions_m + 5e-4 * rng.normal(size=(model.n_nodes, 3))
    state = dyn.initial_state(x0, 0.05 * rng.normal(size=(model.n_nodes, 3)), a)
    new, stats = dyn.step(state, h)
    assert stats.converged
    f = sim.energy_and_forces(new.x_m, a)[1]
    k_n = sim.tangent(x0, a, project=not exact).assemble()
    other = sim.tangent(x0, a, project=exact).assemble()
    assert abs(k_n - other).max() > 1e-3 * abs(k_n).max()
    lhs = dyn.masses_kg[:, None] * (new.v_m_s - state.v_m_s) / h
    damp = (k_n @ new.v_m_s.reshape(-1)).reshape(-1, 3)
    np.testing.assert_allclose(lhs, f - beta * damp, atol=1e-6 * np.abs(f).max())


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


def test_cg_and_direct_engines_agree():
    model = box_model((4, 2, 2), muscles=1)
    sim = Simulator(model)
    a = np.array([0.7])
    ends = []
    for solver in ("cg", "direct"):
        from wface.solvers.linear import direct_backend

        if solver == "direct" and direct_backend() is None:
            pytest.skip("no sparse direct backend installed")
        dyn = DynamicSimulator(sim, scheme="midpoint", solver=solver)
        assert dyn.engine == solver
        state = dyn.initial_state()
        for _ in range(4):
            state, stats = dyn.step(state, 2e-3, a)
            assert stats.converged
        ends.append(state.x_m)
    moved = np.abs(ends[1] - model.rest_positions_m).max()
    assert np.abs(ends[0] - ends[1]).max() <= 1e-5 * moved  # both solve each step to tol = 1e-6


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


# ---------------------------------------------------------------------- re-simulation of a take
@pytest.fixture(scope="module")
def jaw_box():
    """A block with its x- face on the cranium and its x+ face on the jaw, one muscle (96 tets)."""
    return box_model((4, 2, 2), cranium_faces=("x-",), jaw_faces=("x+",), muscles=1)


def _ramp_take(model, frames: int = 6, fps: float = 30.0):
    from wface.controls import IDENTITY_BONES
    from wface.takes.take import Take

    s = np.linspace(0.0, 1.0, frames)
    bones = np.tile(IDENTITY_BONES, (frames, 1))
    bones[:, 22] = -2e-3 * s  # jaw (x+ face) moves 2 mm down
    return Take(activations=(0.6 * s)[:, None], fps=fps, bones=bones)


def test_heavily_damped_resimulation_reproduces_the_quasistatic_frames(jaw_box):
    from wface.takes.dynamic import deviation_mm, resimulate, take_attached_positions
    from wface.takes.quasistatic import quasistatic_frames

    model = jaw_box
    take = _ramp_take(model)
    sim = Simulator(model)
    reference = quasistatic_frames(sim, take.activations, take_attached_positions(model, take))
    motion_mm = np.linalg.norm(reference - reference[0], axis=2).max() * 1e3
    assert motion_mm > 1.0
    result = resimulate(model, take, scheme="be", substeps=1, damping=Damping(0.0, 2e-3), sim=sim)
    assert result.positions_m.shape == reference.shape
    assert np.all(result.converged) and np.all(result.inverted_elements == 0)
    # backward Euler at dt = 33 ms, 2 periods of the block's 56 Hz mode per step: inertia ~ 1e-4
    assert deviation_mm(result.positions_m, reference).max() <= 2e-3 * motion_mm
    summary = result.summary()
    assert summary["frames"] == take.n_frames and summary["steps"] == take.n_frames - 1
    assert len(summary["kinetic_energy_j"]) == take.n_frames


def test_undamped_midpoint_resimulation_shows_inertia(jaw_box):
    from wface.takes.dynamic import deviation_mm, resimulate, take_attached_positions
    from wface.takes.quasistatic import quasistatic_frames

    model = jaw_box
    take = _ramp_take(model)
    sim = Simulator(model)
    reference = quasistatic_frames(sim, take.activations, take_attached_positions(model, take))
    result = resimulate(model, take, scheme="midpoint", substeps=8, damping=Damping.none(), sim=sim)
    assert np.all(result.converged)
    assert result.kinetic_energy_j[1:].max() > 0
    dev = deviation_mm(result.positions_m, reference)
    assert dev[0] == pytest.approx(0.0, abs=1e-9)  # frame 0 starts from its equilibrium
    assert dev.max() > 1e-3  # the flesh lags and rings (the damped run above stays within ~1e-4 mm)


def test_load_take_from_a_tracking_directory_and_write_usd(jaw_box, tmp_path):
    from wface.takes.dynamic import resimulate
    from wface.takes.store import FrameRecord, load_take, write_frame, write_resim_npz
    from wface.takes.usd import write_take_usd

    model = jaw_box
    take = _ramp_take(model, frames=4)
    for f in range(4):  # what `wface track` writes per frame, with fake equilibria
        c = np.concatenate([take.activations[f], take.bones[f]])
        x = model.rest_positions_m + 1e-4 * f
        write_frame(tmp_path, FrameRecord(f, c, x, x, np.zeros((0, 3)), np.zeros(0), {}))
    loaded = load_take(tmp_path, model, fps=24.0)
    assert loaded.fps == 24.0 and loaded.n_frames == 4
    np.testing.assert_array_equal(loaded.activations, take.activations)
    np.testing.assert_array_equal(loaded.bones, take.bones)
    assert loaded.reference_positions_m.shape == (4, model.n_nodes, 3)
    np.savez(
        tmp_path / "controls.npz",
        frames=np.arange(4),
        activations=take.activations,
        bones=take.bones,
        muscle_names=np.array(model.muscle_names),
    )
    part = load_take(tmp_path, model, frames=slice(1, 3))
    assert part.fps == 30.0 and part.n_frames == 2 and list(part.frames) == [1, 2]

    result = resimulate(model, part, scheme="be", substeps=2)
    usd = write_take_usd(tmp_path / "anim.usda", model, result.positions_m, fps=part.fps)
    npz = write_resim_npz(tmp_path / "resim.npz", result, reference_positions_m=part.reference_positions_m)
    from pxr import Usd, UsdGeom

    from wface.io.usd import assert_stage_valid, check_extents

    assert_stage_valid(usd)
    assert check_extents(usd) == []
    stage = Usd.Stage.Open(str(usd))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Mesh"))
    assert stage.GetTimeCodesPerSecond() == 30.0
    assert len(mesh.GetPointsAttr().GetTimeSamples()) == 2
    with np.load(npz) as d:
        assert d["positions_m"].shape == (2, model.n_nodes, 3)

    with pytest.raises(FileNotFoundError, match="not a tracking output"):
        load_take(tmp_path / "frames", model)
    with pytest.raises(ValueError, match="muscle names differ"):
        load_take(tmp_path, box_model((4, 2, 2), muscles=2))


def test_take_validation(jaw_box):
    from wface.takes.take import Take

    with pytest.raises(ValueError, match="fps"):
        Take(np.zeros((3, 1)), fps=0.0)
    with pytest.raises(ValueError, match="bones"):
        Take(np.zeros((3, 1)), fps=30.0, bones=np.zeros((2, 24)))
    with pytest.raises(ValueError, match="NaN"):
        Take(np.full((3, 1), np.nan), fps=30.0)


# ---------------------------------------------------------------------- command line and bench
def test_resim_cli_synthetic_sudden_smile(tmp_path, capsys):
    from wface.cli import main

    out = tmp_path / "smile"
    args = ["resim", "--out", str(out), "--tets", "2000", "--frames", "3", "--substeps", "2", "--json"]
    assert main(args) == 0
    printed = json.loads(capsys.readouterr().out)  # --json: the summary only on stdout
    report = json.loads((out / "report.json").read_text())
    assert printed["frames"] == report["frames"] == 3 and report["steps"] == 4
    for key in ("kinetic_energy_j", "newton_iterations", "residual_rel", "inverted_elements", "seconds_per_frame"):
        assert len(report[key]) == 3, key
    assert report["converged"] and report["inverted_elements_max"] == 0
    assert report["displacement_mm"] > 1.0 and np.isfinite(report["overshoot_mm"])
    assert report["kinetic_energy_j"][0] == 0.0 and max(report["kinetic_energy_j"]) > 0
    assert (out / "animation.usdc").exists() and (out / "resim.npz").exists()


def test_resim_cli_replays_a_tracking_directory(jaw_box, tmp_path, capsys):
    from wface.cli import main
    from wface.model import save_model

    model_path = save_model(jaw_box, tmp_path / "box.npz")
    take = _ramp_take(jaw_box, frames=3)
    take_dir = tmp_path / "run1"
    take_dir.mkdir()
    np.savez(take_dir / "controls.npz", frames=np.arange(3), activations=take.activations, bones=take.bones)
    out = tmp_path / "dyn"
    rc = main(
        [
            "resim",
            "--take",
            str(take_dir),
            "--model",
            str(model_path),
            "--out",
            str(out),
            "--scheme",
            "be",
            "--damping",
            "none",
            "--no-usd",
        ]
    )
    assert rc == 0
    assert "wrote" in capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    assert report["scheme"] == "be" and report["damping"] == {"alpha_per_s": 0.0, "beta_s": 0.0}
    assert report["frames"] == 3 and report["deviation_mm_max"] >= 0 and "overshoot_mm" not in report
    assert (
        main(["resim", "--take", str(take_dir), "--model", str(model_path), "--out", str(out), "--damping", "1,2,3"])
        == 1
    )
    assert "--damping expects ALPHA,BETA" in capsys.readouterr().err
    base = ["resim", "--take", str(take_dir), "--model", str(model_path)]
    assert main([*base, "--out", str(take_dir), "--overwrite"]) == 1  # would delete its own input
    assert "is the take being re-simulated" in capsys.readouterr().err
    assert (take_dir / "controls.npz").exists()
    assert main([*base, "--out", str(tmp_path / "none"), "--frames", "5:9"]) == 1
    assert "selects none of the take's 3 frames" in capsys.readouterr().err


def test_resim_help_teaches(capsys):
    from wface.cli import main

    assert main(["resim", "--help"]) == 0  # the top-level handler turns argparse's exit into a code
    text = capsys.readouterr().out
    for word in ("midpoint", "backward Euler", "zeta", "report.json", "--substeps", "examples"):
        assert word in text, word


def test_dynamic_bench_prints_json(capsys):
    from wface.cli import main

    assert main(["bench", "--suite", "dynamic", "--tets", "2000", "--repeat", "1", "--device", "cpu", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    (size,) = result["results"]
    for scheme in ("midpoint", "be"):
        assert size[scheme]["seconds_per_step_median"] > 0
        assert size[scheme]["newton_iterations_per_step_mean"] >= 1
    assert size["steps"] == 4 and result["suite"] == "dynamic"


def test_dynamic_smile_example_runs(tmp_path, capsys):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / "dynamic_smile.py"
    spec = importlib.util.spec_from_file_location("dynamic_smile_example", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    out = tmp_path / "smile"
    assert example.main(["--tets", "2000", "--duration", "0.004", "--out", str(out)]) == 0
    assert "overshoot" in capsys.readouterr().out
    table = np.loadtxt(out / "trajectory.csv", delimiter=",")
    assert table.shape == (5, 4) and table[0, 1] == 0.0 and table[-1, 1] > 0  # the corner moved
    assert (out / "smile.usdc").exists()


def test_bone_interpolation_keeps_rotations_rigid():
    from wface.controls import IDENTITY_BONES, interpolate_bones, params_from_affine, rotation_about_axis

    def bones(deg):
        b = IDENTITY_BONES.copy()
        R = rotation_about_axis(np.array([0.0, 1.0, 0.0]), np.radians(deg))
        b[:12] = params_from_affine(R, np.array([0.0, 0.0, 0.01 * deg]))
        b[12:] = params_from_affine(rotation_about_axis(np.array([1.0, 0.0, 0.0]), np.radians(deg / 2)), np.zeros(3))
        return b

    b0, b1 = bones(0.0), bones(40.0)
    np.testing.assert_allclose(interpolate_bones(b0, b1, 0.0), b0, atol=1e-14)
    np.testing.assert_allclose(interpolate_bones(b0, b1, 1.0), b1, atol=1e-14)
    np.testing.assert_allclose(interpolate_bones(b0, b1, 0.5), bones(20.0), atol=1e-12)  # slerp: half the angle
    linear = 0.5 * (b0 + b1)
    Ml = linear[:9].reshape(3, 3)
    assert abs(np.linalg.det(Ml) - 1.0) > 0.05  # what a linear blend would do: shrink the head


def test_resim_cli_head_shake_without_muscles(tmp_path):
    from wface.cli import main

    out = tmp_path / "shake"
    args = ["resim", "--out", str(out), "--tets", "2000", "--frames", "3", "--substeps", "2"]
    assert main([*args, "--activation", "none", "--head-shake", "10,3", "--no-usd"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert "overshoot_mm" not in report and report["kinetic_energy_peak_j"] > 0
    assert 0 < report["deviation_mm_max"] < 5.0  # the flesh lags behind the turning head
    with np.load(out / "resim.npz") as d:
        x, ref = d["positions_m"], d["reference_positions_m"]
    assert np.abs(x[-1] - x[0]).max() > 1e-3  # the head turned
    assert x.shape == ref.shape


def test_contact_stops_a_block_falling_on_a_half_space(clamped):
    from wface.physics.contact import Contact
    from wface.physics.obstacles import HalfSpace

    model, sim = clamped  # x- face clamped, bottom face at y = 0
    floor = Contact(model, obstacles=[HalfSpace((0.0, -5e-4, 0.0), (0.0, 1.0, 0.0))])
    v0 = np.zeros((model.n_nodes, 3))
    v0[model.free_nodes, 1] = -0.5  # 0.5 m/s down
    lowest = {}
    for contact in (None, floor):
        dyn = DynamicSimulator(sim, scheme="be", damping=Damping.none(), contact=contact)
        state = dyn.initial_state(None, v0)
        energy = [dyn.total_energy(state)]
        low = 0.0
        for _ in range(60):
            state, stats = dyn.step(state, 2e-4)
            assert stats.converged
            energy.append(dyn.total_energy(state))
            low = min(low, float(state.x_m[:, 1].min()))
        lowest[contact is None] = low
        assert np.all(np.diff(energy) <= 1e-9 * energy[0])  # backward Euler dissipates, contact included
    assert lowest[True] < -1.5e-3  # without contact the cantilever swings well below the floor (1.9 mm)
    assert -5e-4 - 5e-5 < lowest[False]  # with it, penetration stays within 0.05 mm (penalty contact)


def test_the_midpoint_rule_gains_energy_at_penalty_contact(clamped):
    """Why `wface resim` takes backward Euler with contact: the midpoint rule holds the contact at
    each step's midpoint, its end point 2 y - x_n overshoots into the penalty, and every bounce
    returns more energy than it took (no damping; the same fall as the backward Euler test above,
    whose energy never rises). Measured: x1.12 after the first bounce, x3.4 after 380 steps."""
    from wface.physics.contact import Contact
    from wface.physics.obstacles import HalfSpace

    model, sim = clamped
    floor = Contact(model, obstacles=[HalfSpace((0.0, -5e-4, 0.0), (0.0, 1.0, 0.0))])
    v0 = np.zeros((model.n_nodes, 3))
    v0[model.free_nodes, 1] = -0.5
    dyn = DynamicSimulator(sim, scheme="midpoint", damping=Damping.none(), contact=floor)
    state = dyn.initial_state(None, v0)
    e0 = dyn.total_energy(state)
    for _ in range(100):
        state, stats = dyn.step(state, 2e-4)
        assert stats.converged
    assert dyn.total_energy(state) > 1.5 * e0


def test_auto_scheme_is_backward_euler_with_contact(clamped):
    """``DynamicSimulator(scheme="auto")`` (the default) owns the choice the test above measures."""
    from wface.physics.contact import Contact
    from wface.physics.obstacles import HalfSpace

    model, sim = clamped
    floor = Contact(model, obstacles=[HalfSpace((0.0, -5e-4, 0.0), (0.0, 1.0, 0.0))])
    assert DynamicSimulator(sim).scheme == "midpoint"
    assert DynamicSimulator(sim, contact=floor).scheme == "be"
    assert DynamicSimulator(sim, scheme="midpoint", contact=floor).scheme == "midpoint"  # asked for: kept
    with pytest.raises(ValueError, match="scheme must be one of"):
        DynamicSimulator(sim, scheme="rk4")


def test_a_diverging_step_raises_diverged_error(clamped):
    """A step that throws a node farther than the mesh is across stops with DivergedError (a
    FloatingPointError) naming the step, the node and the cure, instead of handing on garbage."""
    from wface.physics.dynamics import DivergedError

    model, sim = clamped
    v0 = np.zeros((model.n_nodes, 3))
    v0[model.free_nodes, 1] = -1e5  # 100 km/s: 1 km in the step
    for scheme, cure in (("be", "a smaller time step"), ("midpoint", "backward Euler")):
        dyn = DynamicSimulator(sim, scheme=scheme, damping=Damping.none())
        with pytest.raises(DivergedError, match=f"the {scheme} step from t = 0 s .*diverged: node .*{cure}"):
            dyn.step(dyn.initial_state(None, v0), 1e-2)
    assert issubclass(DivergedError, FloatingPointError)


def test_resim_takes_backward_euler_with_contact(tmp_path, capsys):
    """`--scheme auto` (default): midpoint without contact, backward Euler with it (the test above)."""
    from wface.cli import main

    schemes = {}
    for contact in ([], ["--contact", "lips"]):
        out = tmp_path / f"run{len(contact)}"
        args = ["resim", "--out", str(out), "--tets", "1000", "--frames", "3", "--no-usd", "--no-reference"]
        assert main([*args, "--activation", "orbicularis_oris_upper=1", *contact]) == 0
        schemes[bool(contact)] = json.loads((out / "report.json").read_text())["scheme"]
    assert schemes == {False: "midpoint", True: "be"}
    capsys.readouterr()


def test_a_diverged_run_exits_3_with_one_line(tmp_path, capsys, monkeypatch):
    """The command line turns a diverged solve (FloatingPointError) into `wface CMD: error: ...` and
    exit 3, the code of a solve that did not converge, not an internal error."""
    import wface.cli.resim as resim_cli
    from wface.cli import EXIT_NOT_CONVERGED, main
    from wface.physics.dynamics import DivergedError

    def diverge(*args, **kwargs):
        raise DivergedError("the midpoint step from t = 0.05 s (dt_s = 0.002) diverged: node 7 moved 300 mm")

    monkeypatch.setattr(resim_cli, "resimulate", diverge)
    rc = main(["resim", "--out", str(tmp_path / "o"), "--tets", "1000", "--frames", "3", "--no-reference"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_NOT_CONVERGED == 3
    assert (
        err[-1] == "wface resim: error: the midpoint step from t = 0.05 s (dt_s = 0.002) diverged: node 7 moved 300 mm"
    )
    assert not (tmp_path / "o" / "report.json").exists()


def test_a_take_of_every_third_frame_is_simulated_over_its_true_intervals(jaw_box):
    """A take that kept capture frames 0, 3, 6, ... at 30 fps is the same motion as the consecutive take
    at 10 fps: resimulate steps 3 / 30 s between its frames in 3 x substeps steps (the time step of a
    capture frame), so it replays as the consecutive take with three times the substeps, to round-off."""
    from dataclasses import replace

    from wface.takes.dynamic import resimulate

    sim = Simulator(jaw_box)
    consecutive = _ramp_take(jaw_box, frames=4, fps=10.0)
    strided = replace(consecutive, fps=30.0, frames=np.arange(4) * 3)
    np.testing.assert_allclose(strided.frame_intervals_s, 0.1)
    runs = [resimulate(jaw_box, t, scheme="be", substeps=n, sim=sim) for t, n in ((consecutive, 6), (strided, 2))]
    assert runs[0].dt_s == pytest.approx(runs[1].dt_s) == pytest.approx(1 / 60)
    assert runs[0].steps == runs[1].steps == 18
    np.testing.assert_allclose(runs[1].positions_m, runs[0].positions_m, rtol=0, atol=1e-12)


def test_a_step_that_stops_short_with_inverted_elements_is_a_divergence(clamped):
    """A step whose Newton stops short of tol and leaves elements inverted ends the run (wface resim: exit
    3) instead of being accepted: a midpoint lip press went on for 2 minutes to 170 inverted tets and
    248 J. A step that merely stops short, nothing inverted, is still accepted."""
    from wface.physics.dynamic_state import DivergedError

    model, sim = clamped
    free = np.setdiff1d(np.arange(model.n_nodes), model.attached_nodes)
    x0 = model.rest_positions_m
    far = free[np.argmax(x0[free, 0])]  # a free corner at the unclamped end
    dyn = DynamicSimulator(sim, scheme="midpoint", tol=1e-14, max_iterations=1)

    def flung(speed_m_s):
        v = np.zeros_like(x0)
        v[far] = [-speed_m_s, 0.0, 0.0]  # into the block: 20 mm in one 1 ms step
        return dyn.initial_state(x0, v, np.zeros(0))

    with pytest.raises(DivergedError, match=r"broke down: Newton stopped .* inverted"):
        dyn.step(flung(20.0), 1e-3)
    _, stats = dyn.step(flung(5.0), 1e-3)
    assert not stats.converged and stats.inverted_elements == 0
