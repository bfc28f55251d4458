"""Hex meshes with contact and inertia (wface.physics.hex_solve): masses, the embedding, derivatives
against finite differences, balance of forces, the discrete equation of motion, conservation."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import data_path
from tests.test_hexes import SIZE_M, _box_hexes, _distorted_box
from wface.physics import Simulator
from wface.physics.contact import Contact, HalfSpace
from wface.physics.hex_solve import HexBody, hex_masses
from wface.physics.hexes import embedding_matrix, hex_quadrature, quadrature_model, shape_functions
from wface.testing.models import box_model


def _body(muscles=1, seed=0, **kwargs):
    model, hexes = _distorted_box(muscles=muscles, seed=seed)
    quad = hex_quadrature(model.rest_positions_m, hexes)
    sim = Simulator(quadrature_model(model, quad))
    return model, quad, sim


def test_masses_are_the_rows_of_the_consistent_mass():
    """Total mass rho V; on a regular grid each node gets an eighth of each cell it touches."""
    model = box_model((2, 2, 2), SIZE_M)
    quad = hex_quadrature(model.rest_positions_m, _box_hexes())
    m = hex_masses(quad, 1000.0)
    cell = 1000.0 * np.prod(SIZE_M) / 8
    assert m.sum() == pytest.approx(1000.0 * np.prod(SIZE_M), rel=1e-12)
    cells_touched = np.bincount(quad.hexes.reshape(-1), minlength=quad.n_nodes)
    np.testing.assert_allclose(m, cells_touched * cell / 8, rtol=1e-12)
    # distorted hexes: m_a = rho int N_a dV, checked against 3x3x3 Gauss-Legendre (N_a det J is cubic
    # in each natural coordinate, so both rules are exact), and the total is rho V
    model_d, quad_d, _ = _body()
    m_d = hex_masses(quad_d, 1000.0)
    assert m_d.sum() == pytest.approx(1000.0 * quad_d.volume_m3, rel=1e-12)
    p1, w1 = np.polynomial.legendre.leggauss(3)
    xi = np.stack(np.meshgrid(p1, p1, p1, indexing="ij"), -1).reshape(-1, 3)
    w = np.einsum("i,j,k->ijk", w1, w1, w1).reshape(-1)
    N, dN = shape_functions(xi)
    X = quad_d.rest_m[quad_d.hexes]  # (m, 8, 3)
    detJ = np.linalg.det(np.einsum("mad,gae->mgde", X, dN))  # (m, 27)
    per_hex = 1000.0 * np.einsum("g,mg,ga->ma", w, detJ, N)
    reference = np.bincount(quad_d.hexes.reshape(-1), weights=per_hex.reshape(-1), minlength=quad_d.n_nodes)
    np.testing.assert_allclose(m_d, reference, rtol=1e-12)
    # ArtiSynth's equal shares: the same on the regular grid; a collapsed hex (a wedge) gives each of
    # its 6 distinct nodes a sixth
    np.testing.assert_allclose(hex_masses(quad, 1000.0, "equal"), m, rtol=1e-12)
    x = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1]], dtype=float)
    wedge = hex_quadrature(x, [[0, 1, 2, 3, 4, 5, 5, 4]])
    np.testing.assert_allclose(hex_masses(wedge, 600.0, "equal"), 600.0 * 0.5 / 6, rtol=1e-12)
    with pytest.raises(ValueError, match="lumping"):
        hex_masses(quad, 1000.0, "consistent")


def test_embedding_reproduces_affine_fields():
    """Points of a finer grid inside the distorted hexes: weights sum to 1, an affine map of the hex
    nodes moves them affinely (trilinear fields contain the affine ones), hex nodes map to themselves."""
    model, quad, _ = _body()
    fine = box_model((4, 4, 4), SIZE_M).rest_positions_m
    B = embedding_matrix(quad, fine)
    np.testing.assert_allclose(np.asarray(B.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    A, t = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 1.2]]), np.array([0.01, -0.02, 0.003])
    X = quad.rest_m
    np.testing.assert_allclose(B @ (X @ A.T + t), fine @ A.T + t, atol=1e-12)
    np.testing.assert_allclose((embedding_matrix(quad, X) @ X), X, atol=1e-12)
    with pytest.raises(ValueError, match="in no hex"):
        embedding_matrix(quad, np.array([[1.0, 1.0, 1.0]]))


def _pressed_body(depth_m=1.5e-3):
    """The distorted box's hexes held at z = 0, a finer tet box embedded in them pressed from above by a
    plane ``depth_m`` below the top; contact acts on the fine box's boundary."""
    model, quad, sim = _body()
    fine = box_model((4, 4, 4), SIZE_M, cranium_faces=("z-",))
    B = embedding_matrix(quad, fine.rest_positions_m)
    plane = HalfSpace((0.0, 0.0, SIZE_M[2] - depth_m), (0.0, 0.0, -1.0))
    contact = Contact(fine, obstacles=[plane])
    free = np.flatnonzero(quad.rest_m[:, 2] > 1e-9)
    return HexBody(sim, quad, free, contact=contact, embedding=B), quad


def test_contact_forces_and_stiffness_match_finite_differences():
    """Flesh + contact energy through the embedding: forces are -dE/dx, the stiffness (exact flesh
    tangent + Gauss-Newton contact, exact for a plane) is dF/dx, float64 central differences; the
    projected one Newton uses differs from it only by a positive semi-definite part."""
    body, quad = _pressed_body()
    rng = np.random.default_rng(3)
    x = quad.rest_m + rng.normal(0, 2e-4, quad.rest_m.shape)
    x[:, 2] -= 1e-3 * quad.rest_m[:, 2] / SIZE_M[2]  # a mild squash: every top node presses on the plane
    a = np.array([0.3])
    e, f, pairs = body.energy_forces(x, a)
    assert pairs.stats()["active_nodes"] >= 20
    K = body.stiffness(x, a, pairs, project=False).toarray()
    K_projected = body.stiffness(x, a, pairs).toarray()
    assert np.linalg.eigvalsh(K_projected - K).min() > -1e-9 * np.abs(K).max()
    h = 1e-7
    for k in rng.choice(body.dofs.size, 12, replace=False):
        node, axis = divmod(int(body.dofs[k]), 3)
        dx = np.zeros_like(x)
        dx[node, axis] = h
        (ep, fp, _), (em, fm, _) = body.energy_forces(x + dx, a), body.energy_forces(x - dx, a)
        assert -(ep - em) / (2 * h) == pytest.approx(f[node, axis], rel=1e-6, abs=1e-9)
        col = -(fp - fm)[body.free].reshape(-1) / (2 * h)
        np.testing.assert_allclose(K[:, k], col, rtol=1e-5, atol=1e-5 * np.abs(K).max())
    np.testing.assert_allclose(K, K.T, atol=1e-10 * np.abs(K).max())


def test_pressed_equilibrium_balances_the_contact_force():
    """Pressed by the plane: Newton converges, and the net contact force on the face is balanced by the
    supports of the held nodes (which cancel the flesh's forces there; the flesh's forces sum to zero)."""
    body, quad = _pressed_body()
    r = body.solve(np.zeros(1), quad.rest_m, tol=1e-9)
    assert r.converged and r.iterations <= 20
    _, f_flesh = body.sim.energy_and_forces(quad.virtual_positions(r.x_m), np.zeros(1))
    f_flesh = quad.node_forces(f_flesh)
    pairs = body.contact.evaluate(body.embed(r.x_m))
    held = np.setdiff1d(np.arange(quad.n_nodes), body.free)
    push = pairs.force_on_face()
    support = -f_flesh[held].sum(axis=0)
    assert push[2] < -0.05  # newtons, downward
    np.testing.assert_allclose(push + support, 0.0, atol=1e-6 * abs(push[2]))
    # the top gave way by about the plane's depth, less the penalty's small penetration
    assert 0 < r.max_penetration_m < 0.1 * 1.5e-3


def test_free_fall_is_exact_backward_euler():
    """No held nodes, no stress: every step is x += h v + h^2 g, v += h g (backward Euler, exact)."""
    model, quad, sim = _body()
    body = HexBody(sim, quad, np.arange(quad.n_nodes))
    g, h = np.array([0.0, -9.8, 0.0]), 0.005
    x, v = quad.rest_m.copy(), np.zeros_like(quad.rest_m)
    for n in range(1, 5):
        x, v, r = body.step(x, v, h, np.zeros(1), gravity_m_s2=g, beta_s=0.05, alpha_per_s=0.0)
        np.testing.assert_allclose(v, np.broadcast_to(n * h * g, v.shape), atol=1e-9)
    np.testing.assert_allclose(x - quad.rest_m, np.broadcast_to(h * h * g * 10, x.shape), atol=1e-10)


@pytest.mark.parametrize("exact", [False, True])
def test_step_satisfies_the_discrete_equation_of_motion_and_conserves_momentum(exact):
    """A free body with random velocities, its muscle on, stiffness damping: the converged step solves
    M (v1 - v0) / h = f(x1) - beta K_n v1 (K_n assembled here, independently: projected, or exact as
    ArtiSynth damps), and the total momentum is unchanged (the flesh's and the damping's forces sum to zero)."""
    model, quad, sim = _body()
    body = HexBody(sim, quad, np.arange(quad.n_nodes), density_kg_m3=1040.0)
    rng = np.random.default_rng(7)
    x0, v0 = quad.rest_m + rng.normal(0, 3e-4, quad.rest_m.shape), rng.normal(0, 0.05, quad.rest_m.shape)
    a, h = np.array([0.6]), 0.004
    beta = 0.002 if exact else 0.02  # the exact K is indefinite here: a larger beta leaves the step's Hessian so
    x1, v1, r = body.step(x0, v0, h, a, beta_s=beta, tol=1e-9, exact_damping=exact)
    assert r.converged
    m = body.masses_kg
    _, f = body.sim.energy_and_forces(quad.virtual_positions(x1), a)
    f = quad.node_forces(f)
    Kn = quad.node_stiffness(sim.tangent(quad.virtual_positions(x0), a, project=not exact).assemble())
    other = quad.node_stiffness(sim.tangent(quad.virtual_positions(x0), a, project=exact).assemble())
    assert abs(Kn - other).max() > 1e-3 * abs(Kn).max()  # the two dampings differ here
    damp = (Kn @ (x1 - x0).reshape(-1)).reshape(-1, 3) / h
    lhs = m[:, None] * (v1 - v0) / h
    np.testing.assert_allclose(lhs, f - beta * damp, atol=1e-7 * np.abs(f).max())
    np.testing.assert_allclose(m @ v1, m @ v0, atol=1e-12 * np.abs(m @ np.abs(v0)).max())


def test_exact_damping_takes_the_exact_mean_dilatation():
    """With one volume ratio per hex (MeanDilatation), the exact damping is the exact tangent of the flesh and of
    the bulk term both: the step solves M (v1 - v0) / h = f(x1) - beta K_n v1 with K_n's bulk part unprojected, as
    ArtiSynth damps with its incompressibility (the projected bulk Hessian, which the step took before, differs)."""
    from dataclasses import replace

    from wface.physics.hex_dilatation import MeanDilatation

    model, hexes = _distorted_box()
    quad = hex_quadrature(model.rest_positions_m, hexes)
    flesh = replace(model, material=replace(model.material, kappa_pa=0.0, bulk_potential="quadratic"))
    sim = Simulator(quadrature_model(flesh, quad))
    bulk = MeanDilatation(quad, 2.5e4, "quadratic")
    body = HexBody(sim, quad, np.arange(quad.n_nodes), density_kg_m3=1040.0, dilatation=bulk)
    rng = np.random.default_rng(5)
    centre = quad.rest_m.mean(axis=0)
    x0 = centre + 0.8 * (quad.rest_m - centre) + rng.normal(0, 3e-4, quad.rest_m.shape)  # compressed: J ~ 0.5
    v0 = rng.normal(0, 0.05, quad.rest_m.shape)
    exact, projected = bulk.hessian(x0, project=False), bulk.hessian(x0)
    assert abs(exact - projected).max() > 1e-2 * abs(exact).max()  # the bulk term's Hessian is indefinite here
    a, h, beta = np.array([0.6]), 0.004, 0.002
    x1, v1, r = body.step(x0, v0, h, a, beta_s=beta, tol=1e-9, max_iterations=60, exact_damping=True)
    assert r.converged
    _, f = body.sim.energy_and_forces(quad.virtual_positions(x1), a)
    f = quad.node_forces(f) + bulk.energy_and_forces(x1)[1]
    Kn = quad.node_stiffness(sim.tangent(quad.virtual_positions(x0), a, project=False).assemble()) + exact
    damp = (Kn @ (x1 - x0).reshape(-1)).reshape(-1, 3) / h
    lhs = body.masses_kg[:, None] * (v1 - v0) / h
    np.testing.assert_allclose(lhs, f - beta * damp, atol=1e-7 * np.abs(f).max())


def test_held_nodes_moving_in_a_step_enter_the_damping():
    """Held nodes moved during the step: the free rows of the equation of motion hold with the damping
    K_n (x1 - x0) over all nodes, the held ones' motion included."""
    model, quad, sim = _body()
    free = np.flatnonzero(quad.rest_m[:, 0] > 1e-9)
    body = HexBody(sim, quad, free)
    x0 = quad.rest_m.copy()
    held_to = x0.copy()
    held_to[:, 1] += 2e-4  # the x = 0 face slides along y
    h, beta, alpha = 0.005, 0.05, 10.0
    x1, v1, r = body.step(
        x0, np.zeros_like(x0), h, np.array([0.2]), held_m=held_to, beta_s=beta, alpha_per_s=alpha, tol=1e-9
    )
    assert r.converged
    held = np.setdiff1d(np.arange(quad.n_nodes), free)
    np.testing.assert_allclose(x1[held], held_to[held], atol=0)
    m = body.masses_kg
    _, f = body.sim.energy_and_forces(quad.virtual_positions(x1), np.array([0.2]))
    f = quad.node_forces(f)
    Kn = quad.node_stiffness(sim.tangent(quad.virtual_positions(x0), np.array([0.2])).assemble())
    d = x1 - x0
    damp = alpha * m[:, None] * d / h + beta * (Kn @ d.reshape(-1)).reshape(-1, 3) / h
    lhs = m[:, None] * (v1 - 0.0) / h
    np.testing.assert_allclose(lhs[free], (f - damp)[free], atol=1e-7 * np.abs(f[free]).max())
    assert np.abs(x1[free, 1] - x0[free, 1]).max() > 1e-5  # the flesh was dragged along


def test_damped_motion_loses_energy():
    """Released from a stretch, no gravity, stiffness damping: kinetic + elastic energy never grows."""
    model, quad, sim = _body()
    free = np.flatnonzero(quad.rest_m[:, 0] > 1e-9)
    body = HexBody(sim, quad, free)
    x = quad.rest_m.copy()
    x[free, 0] *= 1.05
    v = np.zeros_like(x)
    a = np.zeros(1)
    energies = []
    for _ in range(8):
        x, v, r = body.step(x, v, 0.002, a, beta_s=0.002, tol=1e-10)
        e, _, _ = body.energy_forces(x, a)
        energies.append(e + 0.5 * float(body.masses_kg @ (v * v).sum(axis=1)))
    assert np.all(np.diff(energies) <= 1e-12 * energies[0])
    assert energies[-1] < 0.9 * energies[0]


def test_bad_arguments_are_named():
    model, quad, sim = _body()
    with pytest.raises(ValueError, match="free hex nodes"):
        HexBody(sim, quad, [quad.n_nodes])
    body = HexBody(sim, quad, np.arange(5))
    with pytest.raises(ValueError, match="dt_s"):
        body.step(quad.rest_m, np.zeros_like(quad.rest_m), 0.0, np.zeros(1))
    fine = box_model((4, 4, 4), SIZE_M)
    with pytest.raises(ValueError, match="embedding has shape"):
        HexBody(sim, quad, np.arange(5), contact=Contact(fine, obstacles=[HalfSpace((0, 0, 0), (0, 0, 1))]))


def test_badin_hexes_play_example(badin_model_path, tmp_path):
    """examples/badin_hexes_play.py for its first frames (the contact equilibrium at rest, pushed out of
    the bones, and 0.02 s of dynamics with lip and skull contact): converged, and the mouth opening as it
    settles under gravity (measured: 41.35 -> 44.71 mm^2)."""
    import json

    from tests.test_artisynth_reference import _example

    example = _example("badin_hexes_play")
    data = data_path("artisynth-face")
    argv = ["--model", str(badin_model_path), "--data", str(data), "--end", "0.02", "--out", str(tmp_path)]
    assert example.main(argv) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["mesh"]["hexes"] == 6342
    rows = (tmp_path / "lip_opening.csv").read_text().splitlines()
    assert rows[0].startswith("time_s,lip_opening_area_mm2") and len(rows) == 3
    area = [float(r.split(",")[1]) for r in rows[1:]]
    assert 39.5 < area[0] < 43 and area[1] > area[0] + 2  # 39.50 at rest, before the push
    assert report["summary"]["residual_rel_max"] <= 1e-4
    assert np.load(tmp_path / "states.npz")["x_hex_m"].shape[0] == 2


def test_badin_hexes_play_with_artisynths_muscle_laws(badin_model_path, tmp_path):
    """--fibre-stress blemker --idle-muscles off (BlemkerMuscle's curves; the other muscles' passive fibres
    off, as ArtiSynth's GenericMuscle's 0.05 Pa) runs, converges and says so in report.json."""
    import json

    from tests.test_artisynth_reference import _example

    example = _example("badin_hexes_play")
    argv = ["--model", str(badin_model_path), "--data", str(data_path("artisynth-face")), "--contact", ""]
    argv += ["--end", "0.02", "--fibre-stress", "blemker", "--idle-muscles", "off", "--out", str(tmp_path)]
    assert example.main(argv) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["fibre_stress"] == "blemker" and report["idle_muscles"] == "off"
    assert report["summary"]["residual_rel_max"] <= 1e-4
    # --muscle-curves artisynth is the same physics for the approximant: OOP BlemkerMuscle's curves, every other
    # muscle GenericMuscle's, which at activation 0 exerts nothing, as a muscle of strength 0
    own = tmp_path / "own"
    argv = argv[: argv.index("--fibre-stress")] + ["--muscle-curves", "artisynth", "--out", str(own)]
    assert example.main(argv) == 0
    assert json.loads((own / "report.json").read_text())["muscle_curves"] == "artisynth"
    x0, x1 = (np.load(d / "states.npz")["x_hex_m"] for d in (tmp_path, own))
    np.testing.assert_allclose(x1, x0, rtol=0, atol=1e-9)  # metres; the steps converge to 1e-4 of their load
    # another gesture with ArtiSynth's muscles: their elements and the OOMl exciter on the lower lip's OOM
    fric = tmp_path / "fricative"
    argv = argv[: argv.index("--muscle-curves")] + ["--gesture", "fricative", "--muscle-elements", "artisynth"]
    assert example.main([*argv, "--lower-oom", "lower", "--out", str(fric)]) == 0
    report = json.loads((fric / "report.json").read_text())
    assert (report["gesture"], report["muscle_elements"], report["lower_oom"]) == ("fricative", "artisynth", "lower")
