"""Contact (wface.physics.contact): derivatives, definiteness, force balance, lips, teeth, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wface.faces.builtin import build_face
from wface.mesh.signed_distance import SignedSurface, oriented_outward
from wface.physics import Simulator
from wface.physics.contact import Contact, HalfSpace, MeshObstacle, Sphere, parse_obstacle
from wface.testing.models import box_model

_FD_RTOL = 1e-5  # central differences of a piecewise-quadratic energy in float64, step 1e-8 m
# The lip pose of the measurements: full orbicularis oris and mentalis with the jaw closed presses the
# lips into each other (6.5 mm of overlap without contact at 3000 tets).
_PRESS = ("orbicularis_oris_upper", "orbicularis_oris_lower", "mentalis_l", "mentalis_r")


@pytest.fixture(scope="module")
def face():
    return build_face(3000)


@pytest.fixture(scope="module")
def sim(face):
    return Simulator(face)


@pytest.fixture(scope="module")
def pressed(face, sim):
    """Equilibrium of the lip-pressing pose without contact."""
    return sim.solve({m: 1.0 for m in _PRESS})


def _lips_plate(face):
    x = face.rest_positions_m
    z = x[np.unique(face.surface_groups["upper_lip"]), 2].max()
    return HalfSpace((0.0, 0.0, z - 0.004), (0.0, 0.0, -1.0))  # a plate pushing the lips 4 mm back


def test_gradient_matches_central_differences(face, pressed):
    contact = Contact(face, regions="lips,teeth", obstacles=[Sphere((0.03, -0.04, 0.11), 0.02)])
    rng = np.random.default_rng(0)
    # Off the mirror plane: a node deep inside a crease of the other lip that lies exactly on its
    # bisector (the medial axis) has a kink in its distance, so central differences need symmetry broken.
    x = pressed.x + 1e-5 * rng.standard_normal(pressed.x.shape)
    pairs = contact.evaluate(x)
    assert {"upper_lip/lower_lip", "lower_lip/upper_lip", "upper_teeth"} <= {
        pairs.names[s] for s in np.unique(pairs.source)
    }
    f = pairs.forces()
    involved = np.unique(np.concatenate([pairs.node, pairs.others.ravel()]))
    h = 1e-8
    for _ in range(6):
        v = np.zeros_like(x)
        v[involved] = rng.standard_normal((involved.size, 3))
        fd = (contact.energy(x + h * v) - contact.energy(x - h * v)) / (2 * h)
        assert fd == pytest.approx(-np.sum(f * v), rel=_FD_RTOL, abs=1e-9)


def test_hessian_is_psd_and_consistent(face, sim, pressed):
    contact = Contact(face, regions="lips,teeth")
    pairs = contact.evaluate(pressed.x)
    assert np.count_nonzero(pairs.tangential) > 0  # edge / vertex features are exercised
    pattern = sim.pattern("all")
    H = pairs.assemble(pattern)
    v = np.random.default_rng(1).standard_normal(pressed.x.shape)
    assert np.allclose(pairs.matvec(v).ravel(), H @ v.ravel(), rtol=1e-10, atol=1e-8)
    assert np.allclose(pairs.diagonal().ravel(), H.diagonal())
    dofs = np.unique(H.nonzero()[0])
    Hd = H[dofs][:, dofs].toarray()
    assert np.allclose(Hd, Hd.T, atol=1e-9 * np.abs(Hd).max())
    lam = np.linalg.eigvalsh(Hd)
    assert lam.min() >= -1e-9 * lam.max()  # PSD up to round-off


def test_half_space_hessian_is_exact():
    model = box_model((2, 2, 2), (0.02, 0.02, 0.02), muscles=0)
    contact = Contact(model, obstacles=[HalfSpace((0, 0, 0.019), (0.02, 0.01, -1.0))], stiffness_n_per_m=1e4)
    x = model.rest_positions_m
    pairs = contact.evaluate(x)
    assert len(pairs.node) > 0
    H = pairs.assemble(_all_pattern(model)).toarray()
    h = 1e-9
    J = np.zeros_like(H)
    for j in range(x.size):
        d = np.zeros(x.size)
        d[j] = h
        J[:, j] = -(contact.forces(x + d.reshape(-1, 3)) - contact.forces(x - d.reshape(-1, 3))).ravel() / (2 * h)
    assert np.allclose(H, J, atol=1e-6 * np.abs(H).max())


def _all_pattern(model):
    from wface.solvers.pattern import BlockPattern

    return BlockPattern(model.tets, model.n_nodes)


def test_sphere_pressed_into_block_balances_the_support():
    model = box_model((4, 4, 2), (0.04, 0.04, 0.02), cranium_faces=("z-",), muscles=0)
    sim = Simulator(model)
    indent = 0.003
    ball = Sphere((0.02, 0.02, 0.02 + 0.01 - indent), 0.01)
    contact = Contact(model, obstacles=[ball])
    eq = sim.solve(contact=contact, tol=1e-9)
    assert eq.converged and eq.inverted_elements == 0
    assert eq.contact_active_nodes >= 1
    # Penetration: the default stiffness (100 x E h) keeps it below 5 % of the imposed indentation.
    assert 0 < eq.contact_max_penetration_m < 0.05 * indent
    f_el = sim.forces(eq.x)
    pairs = contact.evaluate(eq.x)
    push = pairs.force_on_face()
    assert push[2] < 0 and abs(push[2]) == pytest.approx(eq.contact_force_n, rel=0.2)
    # Internal forces sum to zero, so the support reaction (-f_el on the fixed nodes) balances the ball.
    reaction = -f_el[model.attached_nodes].sum(axis=0)
    assert np.linalg.norm(reaction + push) <= 1e-6 * np.linalg.norm(push) + 10 * eq.residual_abs


def test_no_contact_is_unchanged(face, sim, pressed):
    again = sim.solve({m: 1.0 for m in _PRESS}, contact=None)
    assert np.array_equal(again.x, pressed.x) and again.iterations == pressed.iterations
    assert again.contact_active_nodes == 0 and again.contact_force_n == 0.0
    # A contact whose obstacle never touches gives the same equilibrium bit for bit.
    far = Contact(face, obstacles=[Sphere((0.0, 0.0, 1.0), 0.01)])
    untouched = sim.solve({m: 1.0 for m in _PRESS}, contact=far)
    assert np.array_equal(untouched.x, pressed.x) and untouched.contact_active_nodes == 0


def test_lips_stop_interpenetrating(face, sim, pressed):
    lips = Contact(face, regions="lips")
    assert lips.penetration(face.rest_positions_m)["active_nodes"] == 0  # lips touch at rest, no force
    before = lips.penetration(pressed.x)["max_penetration_m"]
    assert before > 3e-3  # measured 6.5 mm
    eq = sim.solve({m: 1.0 for m in _PRESS}, contact=lips)
    assert eq.converged and eq.inverted_elements == 0
    assert eq.contact_active_nodes > 0
    assert eq.contact_max_penetration_m < 5e-5  # measured 11 micrometres
    assert lips.penetration(eq.x)["max_penetration_m"] == pytest.approx(eq.contact_max_penetration_m)


def test_lips_pushed_back_stay_outside_the_teeth(face, sim):
    plate = _lips_plate(face)
    teeth = Contact(face, regions="teeth")
    without = sim.solve(contact=Contact(face, obstacles=[plate]))
    assert teeth.penetration(without.x)["max_penetration_m"] > 1e-3  # measured 2.5 mm into the teeth
    eq = sim.solve(contact=Contact(face, regions="lips,teeth", obstacles=[plate]))
    assert eq.converged
    pen = teeth.penetration(eq.x)
    assert pen["sources"]["upper_teeth"]["active_nodes"] > 0
    assert pen["max_penetration_m"] < 2e-4  # measured 0.08 mm, against 2.5 mm without
    # Teeth follow the jaw: the lower teeth rotate with a 10 degree opening.
    from wface.controls import attached_positions_from_affines, jaw_opening_affine

    targets = attached_positions_from_affines(face, jaw=jaw_opening_affine(face, 10.0))
    teeth.set_pose(targets)
    lower = teeth.rigid[[n for n, _ in teeth.rigid].index("lower_teeth")][1]
    moved = lower.surface(teeth.bone_affines).vertices_m - lower.vertices_m
    assert np.linalg.norm(moved, axis=1).max() > 5e-3


def test_signed_surface_of_inconsistent_closed_mesh():
    # A unit cube (12 triangles) with half of its faces wound the wrong way.
    v = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=float)
    t = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6], [0, 2, 6],
         [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )  # fmt: skip
    t[::3] = t[::3, ::-1]
    surf = SignedSurface(v, t)
    p = np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 1.5], [1.2, 1.3, 1.4], [0.9, 0.5, 0.5], [0.5, -0.1, 0.5]])
    hit = surf.signed(p)
    assert np.allclose(hit.phi_m, [-0.5, 0.5, np.sqrt(0.04 + 0.09 + 0.16), -0.1, 0.1])
    assert surf.closed and np.array_equal(oriented_outward(v, surf.triangles), surf.triangles)
    # The mesh as a rigid obstacle, moved by an affine.
    A = np.hstack([np.eye(3), [[1.0], [0.0], [0.0]]])
    ob = MeshObstacle(v, t, affine=A)
    phi, n, near, _, _ = ob.signed(np.array([[1.5, 0.5, 0.5], [0.5, 0.5, 0.5]]), {})
    assert phi[0] == pytest.approx(-0.5) and bool(near[0]) and not near[1]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"regions": "lips,gums"}, "unknown contact region"),
        ({"obstacles": ["sphere:0,0,0"]}, "sphere needs 4 numbers"),
        ({"obstacles": ["cone:0,0,0,1"]}, "unknown kind"),
        ({"obstacles": ["sphere:0,0,nan,0.1"]}, "finite"),
        ({"obstacles": ["sphere:0,0,0,-1"]}, "radius"),
        ({"regions": "lips", "stiffness_n_per_m": float("nan")}, "stiffness"),
        ({}, "nothing to do"),
        ({"self_pairs": [("upper_lip", "nose")]}, "unknown surface group"),
        # a ball round the whole face pushed it out through itself (resim: the sparse solver's raw message)
        ({"obstacles": ["sphere:0,0,0,0.5"]}, r"holds (\d+) of the face's \1 surface nodes at rest"),
        ({"obstacles": ["plane:0,0,0.5,0,0,1"]}, "is a solid the skin is pushed out of"),
        ({"regions": "teeth", "inside_at_rest": "keep"}, "inside_at_rest must be one of ignore, push, hold"),
    ],
)
def test_bad_input_is_refused(face, kwargs, message):
    kwargs = dict(kwargs)
    specs = kwargs.pop("obstacles", [])
    with pytest.raises(ValueError, match=message):
        Contact(face, obstacles=[parse_obstacle(o) for o in specs], **kwargs)


def test_nodes_inside_at_rest_are_held_at_their_rest_depth(face):
    """inside_at_rest="hold": the flesh nodes inside the teeth at rest stay in contact with their rest depth as
    their gap. The rest state carries no force; deeper by d they carry the penalty of d (k d^2 / 2 each, the
    plain penalty), outward none, and the forces are the energy's gradient."""
    import dataclasses

    from wface.model import BoneMesh

    # the built-in face's flesh clears its teeth at rest: teeth moved 1.5 mm forward, into the lips
    meshes = {
        name: BoneMesh(m.vertices_m + (0.0, 0.0, 1.5e-3 if "teeth" in name else 0.0), m.triangles, m.bone)
        for name, m in face.bone_meshes.items()
    }
    face = dataclasses.replace(face, bone_meshes=meshes)
    x0 = face.rest_positions_m
    ignore = Contact(face, regions="teeth")
    push = Contact(face, regions="teeth", inside_at_rest="push")
    hold = Contact(face, regions="teeth", inside_at_rest="hold")
    assert hold.held_at_rest == ignore.ignored_at_rest and sum(hold.held_at_rest.values()) > 0
    assert hold.ignored_at_rest == {} and push.held_at_rest == {}
    assert [len(n) for n in hold.rigid_nodes] == [len(n) for n in push.rigid_nodes]  # every node may touch
    assert push.energy(x0) > 0 and hold.energy(x0) == 0.0 and not np.any(hold.forces(x0))
    at_rest = push.evaluate(x0)  # the held nodes, each with its deepest mesh's outward normal
    deepest = {}
    for i, n, g in zip(at_rest.node, at_rest.normal, at_rest.penetration_m, strict=True):
        if g > deepest.get(i, (0.0, None))[0]:
            deepest[i] = (g, n)
    ids = np.array(sorted(deepest))
    normals = np.array([deepest[i][1] for i in ids])
    d_m = 1e-5
    deeper, outward = x0.copy(), x0.copy()
    deeper[ids] -= d_m * normals
    outward[ids] += d_m * normals
    assert hold.energy(outward) == 0.0
    k = hold.stiffness_n_per_m
    pairs = hold.evaluate(deeper)
    assert set(pairs.node) == set(ids)
    assert np.median(pairs.penetration_m) == pytest.approx(d_m, rel=1e-6)  # the rest depth is the gap
    assert hold.energy(deeper) == pytest.approx(0.5 * k * np.sum(pairs.penetration_m**2))
    rng = np.random.default_rng(3)
    f, h = pairs.forces(), 1e-9
    for _ in range(4):
        v = np.zeros_like(x0)
        v[ids] = rng.standard_normal((ids.size, 3))
        fd = (hold.energy(deeper + h * v) - hold.energy(deeper - h * v)) / (2 * h)
        assert fd == pytest.approx(-np.sum(f * v), rel=_FD_RTOL, abs=1e-12)


def test_bad_positions_are_refused(face):
    contact = Contact(face, regions="lips")
    x = face.rest_positions_m.copy()
    with pytest.raises(ValueError, match="shape"):
        contact.evaluate(x[:-1])
    x[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        contact.evaluate(x)
    box = box_model((1, 1, 1), muscles=0)
    with pytest.raises(ValueError, match="no lip surface groups"):
        Contact(box, regions="lips")
    with pytest.raises(ValueError, match="no teeth mesh"):
        Contact(box, regions="teeth")


def test_lip_groups_survive_save_and_load(face, tmp_path):
    from wface.model import load_model, save_model

    back = load_model(save_model(face, tmp_path / "f.npz"))
    for name in ("upper_lip", "lower_lip"):
        assert np.array_equal(back.surface_groups[name], face.surface_groups[name])
    assert Contact(back, regions="lips").names == Contact(face, regions="lips").names


def _cheek_sphere(face, radius_m=0.01, indent_m=0.002) -> str:
    """Spec of a ball pressed ``indent_m`` into the left cheek."""
    from wface.mesh.surface import vertex_normals

    x = face.rest_positions_m
    skin = np.unique(face.skin_triangles)
    cheek = skin[(x[skin, 0] > 0.03) & (np.abs(x[skin, 1] + 0.04) < 0.01)]
    i = cheek[np.argmax(x[cheek, 2])]
    c = x[i] + vertex_normals(x, face.skin_triangles)[i] * (radius_m - indent_m)
    return "sphere:" + ",".join(f"{v:.5f}" for v in (*c, radius_m))


def test_simulate_cli_with_contact(face, tmp_path, capsys):
    from wface.cli import main
    from wface.model import save_model

    path = save_model(face, tmp_path / "face.npz")
    args = ["simulate", "--model", str(path), "--out", str(tmp_path / "run"), "--json"]
    for m in _PRESS:
        args += ["--activation", f"{m}=1"]
    assert main(args + ["--contact", "lips,teeth", "--obstacle", _cheek_sphere(face), "--picture"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["converged"] and summary["contact_active_nodes"] > 0
    assert summary["contact_max_penetration_mm"] < 0.05
    assert summary["contact_sources"]["sphere0"]["active_nodes"] > 0
    assert (tmp_path / "run" / "lips_section.png").stat().st_size > 1000
    assert main(args + ["--contact", "lips,tongue"]) == 2  # a usage error
    assert "unknown contact region" in capsys.readouterr().err
    assert main(args + ["--obstacle", "sphere:1,2"]) == 2  # a usage error
    assert "sphere needs 4 numbers" in capsys.readouterr().err


def test_smoothed_penalty_is_c2_and_matches_the_plain_one_beyond_the_ramp():
    from wface.physics.contact import penalty_profile

    k, d = 2.0e4, 1e-4
    g = np.array([-1e-4, 0.0, 2e-5, 5e-5, 9.9e-5, 1.5e-4, 1e-3])
    e, fn, kn = penalty_profile(g, k, d)
    h = 1e-9
    ep, fp, _ = penalty_profile(g + h, k, d)
    em, fm, _ = penalty_profile(g - h, k, d)
    assert np.allclose((ep - em) / (2 * h), fn, rtol=1e-6, atol=1e-8)  # round-off of E ~ 1e-2 J / h
    assert np.allclose((fp - fm) / (2 * h), kn, rtol=1e-6, atol=0.1)  # k h / 4d at g = 0
    # continuous stiffness at both ends of the ramp, the plain force shifted by d/2 beyond it
    assert penalty_profile(np.array([d - 1e-12]), k, d)[2][0] == pytest.approx(k)
    assert fn[-1] == pytest.approx(k * (g[-1] - d / 2)) and e[0] == 0 and fn[1] == 0 and kn[1] == 0
    e0, f0, k0 = penalty_profile(g, k, 0.0)
    assert np.allclose(f0, k * np.maximum(g, 0)) and np.allclose(k0, np.where(g >= 0, k, 0))


def test_frozen_features_match_the_contact_where_frozen(face, pressed):
    """At the freezing configuration the frozen pairs give the same energy and forces; nearby, their
    forces are the gradient of their energy (central differences)."""
    from wface.physics.frozen import FrozenContact

    contact = Contact(face, regions="lips,teeth", smoothing_m=5e-5)
    rng = np.random.default_rng(3)
    x = pressed.x + 1e-5 * rng.standard_normal(pressed.x.shape)
    frozen = FrozenContact(contact, x, margin_m=5e-4)
    live = contact.evaluate(x)
    assert frozen.n_frozen >= np.count_nonzero(live.source >= len(contact.rigid)) > 0
    assert frozen.energy(x) == pytest.approx(contact.energy(x), rel=1e-12)
    assert np.allclose(frozen.evaluate(x).forces(), contact.forces(x), rtol=1e-9, atol=1e-9)
    y = x + 2e-5 * rng.standard_normal(x.shape)  # features may have switched for the contact, not frozen
    pairs = frozen.evaluate(y)
    f = pairs.forces()
    h = 1e-8
    for _ in range(4):
        v = rng.standard_normal(x.shape)
        fd = (frozen.energy(y + h * v) - frozen.energy(y - h * v)) / (2 * h)
        assert fd == pytest.approx(-np.sum(f * v), rel=_FD_RTOL, abs=1e-9)


@pytest.mark.parametrize("smoothing_m", [0.0, 5e-4], ids=["c1", "ramp-0.5mm"])
def test_exact_self_hessian_is_the_derivative_of_the_frozen_forces(face, pressed, smoothing_m):
    """``exact_self_hessian`` (the tracking Jacobians' contact tangent, all 120 second differences of
    every pair in a few vectorised calls) against central differences of the frozen pairs' forces:
    H v = -(f(y + h v) - f(y - h v)) / 2h. Its own second differences (1e-5 m on mm edges) are good to
    about (1e-5 / 1e-3)^2 = 1e-4 relative; measured 5e-6 to 1.3e-5 (max over nodes, relative to the largest)."""
    from wface.physics.frozen import FrozenContact, exact_self_hessian

    contact = Contact(face, regions="lips", smoothing_m=smoothing_m)
    rng = np.random.default_rng(5)
    y = pressed.x + 1e-5 * rng.standard_normal(pressed.x.shape)
    frozen = FrozenContact(contact, y, margin_m=0.0)
    pairs = frozen.evaluate(y)
    assert np.count_nonzero(pairs.penetration_m > 0) > 20
    pattern = _all_pattern(face)
    H = exact_self_hessian(contact, pairs, y, pattern)
    assert abs(H - H.T).max() <= 1e-9 * abs(H).max()
    h = 1e-8
    for _ in range(3):
        v = rng.standard_normal(y.shape)
        fd = -(frozen.evaluate(y + h * v).forces() - frozen.evaluate(y - h * v).forces()) / (2 * h)
        hv = (H @ v.reshape(-1)).reshape(-1, 3)
        assert np.abs(hv - fd).max() <= 1e-4 * np.abs(fd).max(), np.abs(hv - fd).max() / np.abs(fd).max()


# Freezing changes Newton's path, not the problem: the frozen solve must end at an equilibrium of the
# true (re-detected) contact with the plain solve's contact points and energy, but not necessarily at
# the plain solve's point. These pressed lips have twin equilibria 1.34e-6 m apart (max norm; 4.8e-6 m
# 2-norm), with the same 23 contact points and the same energy (|dE| <= 2e-15 J), in which points lying
# on an edge of the other lip (barycentric weight 1e-4) measure to one or the other triangle of that
# edge. Round-off picks the twin: a 1e-13 m change of the start reaches either (issue 13: 1.3e-6 m
# apart elsewhere with the same numpy 2.4.6, scipy 1.17.1, mkl 2026.2.1, warp-lang 1.19.0; 3e-15 m here).
_FREEZE_TOL = 1e-8  # relative residual of both solves (force scale 193.7 N: |r| <= 1.94e-6 N)
_SAME_BRANCH_M = 2e-8  # 2-norm: each solve is within |r| / lambda_min = 1.94e-6 N / 259 N/m = 7.5e-9 m of
# its equilibrium (lambda_min: smallest eigenvalue of the exact tangent K_UU there, contact curvature
# included; measured 1.0e-9 m by one Newton step, J^-1 r), so two solves of one equilibrium are 1.5e-8 m apart
_ENERGY_J = 1e-13  # E(x) - E(x_eq) <= |r|^2 / (2 lambda_min) = 7e-15 J per solve, + round-off of the energy sum
# (64 eps sum|E_e| = 6e-14 J, sum|E_e| = 4.18 J); measured |dE| <= 2e-15 J (twins included), 2.4e-6 J and more
# between equilibria with other contact points


def _true_contact_state(face, sim, activations, x, force_scale):
    """(relative residual, total energy, {contact point: its triangle}) at x, the lip contact re-detected."""
    a = face.activation_vector(activations)
    pairs = Contact(face, regions="lips").evaluate(x)
    free = sim.pattern("free").dof_nodes
    residual = float(np.linalg.norm((sim.forces(x, a) + pairs.forces())[free])) / force_scale
    on = pairs.penetration_m > 0
    columns = (pairs.point_nodes[on], pairs.point_weights[on].round(12), pairs.source[on], pairs.others[on])
    points = {(tuple(n), tuple(w), int(s)): tuple(t) for n, w, s, t in zip(*columns, strict=True)}
    return residual, sim.energy(x, a) + pairs.energy, points


def _assert_same_equilibrium(face, sim, activations, plain, frozen):
    r_plain, e_plain, at_plain = _true_contact_state(face, sim, activations, plain.x, plain.force_scale)
    r_frozen, e_frozen, at_frozen = _true_contact_state(face, sim, activations, frozen.x, plain.force_scale)
    assert r_plain <= _FREEZE_TOL and r_frozen <= _FREEZE_TOL  # both equilibria of the true contact
    assert set(at_frozen) == set(at_plain)  # the same contact points (active set)
    assert abs(e_frozen - e_plain) <= _ENERGY_J
    if at_frozen == at_plain:  # the same closest triangles: one smooth branch, one equilibrium
        assert np.linalg.norm(frozen.x - plain.x) <= _SAME_BRANCH_M  # measured 1.3e-14 m
    else:  # twins: a point on an edge is as deep below one of its triangles' planes as below the other to within
        # its penetration, and the twins are as far apart (not a tolerance: measured 1.34e-6 m, penetration 8.1e-6 m)
        assert np.abs(frozen.x - plain.x).max() <= plain.contact_max_penetration_m


def test_freezing_reaches_the_same_equilibrium(face, sim):
    act = {m: 1.0 for m in _PRESS}
    plain = sim.solve(act, contact=Contact(face, regions="lips"), tol=_FREEZE_TOL)
    frozen = sim.solve(act, contact=Contact(face, regions="lips", freeze_below=0.1), tol=_FREEZE_TOL)
    assert plain.converged and frozen.converged
    assert frozen.contact_refreezes >= 1  # the true (re-detected) residual decides convergence
    _assert_same_equilibrium(face, sim, act, plain, frozen)
