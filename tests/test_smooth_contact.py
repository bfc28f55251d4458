"""Smooth lip surfaces (wface.mesh.subdivision, wface.mesh.smooth_distance, wface.physics.smooth_contact).

Loop subdivision as a linear map, the blended-plane distance (exact on planes, derivatives against
central differences), the smooth self-contact energy's gradient and exact Hessian against central
differences, and Newton's quadratic convergence with it on the lip-pressing pose of the built-in face.
"""

from __future__ import annotations

import numpy as np
import pytest

from wface.faces.builtin import build_face
from wface.mesh.smooth_distance import SmoothSurface
from wface.mesh.subdivision import loop_subdivision
from wface.physics import Simulator
from wface.physics.contact import Contact
from wface.physics.contact_solve import solve_restarted

_PRESS = ("orbicularis_oris_upper", "orbicularis_oris_lower", "mentalis_l", "mentalis_r")
_FD_STEP_M = 1e-8
_GRAD_RTOL = 1e-6  # central differences of a C2 energy with step 1e-8 m on mm-scale geometry
_HESS_RTOL = 1e-6  # the Hessian blocks come from central differences of closed-form gradients (step 1e-7 m)


def _grid(n: int, size: float = 0.01, z=lambda x, y: 0.0 * x):
    """An n x n vertex grid of size ``size`` (m) on the height field z(x, y), wound up (+z)."""
    u = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    v = np.column_stack([X.ravel(), Y.ravel(), z(X, Y).ravel()])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def test_loop_subdivision_is_an_affine_invariant_linear_map():
    v, t = _grid(5)
    for levels in (1, 2):
        nodes, S, tri = loop_subdivision(t, levels)
        assert np.array_equal(nodes, np.arange(len(v))) and len(tri) == 4**levels * len(t)
        assert np.allclose(np.asarray(S.sum(axis=1)).ravel(), 1.0, atol=1e-14)  # rows sum to 1
        y = S @ v
        assert np.allclose(y[:, 2], 0.0, atol=1e-15)  # a plane stays that plane
        A = np.array([[1.0, 0.2, 0.0], [0.1, 0.9, 0.3], [0.0, -0.2, 1.1]])
        assert np.allclose(S @ (v @ A.T + 0.01), y @ A.T + 0.01, atol=1e-15)  # affine invariance
    # the interior mask: an old interior vertex of valence 6 moves to 5/8 v + 3/48 sum of its neighbours
    nodes, S, _ = loop_subdivision(t, 1)
    row = S.getrow(12).toarray().ravel()  # grid centre, valence 6
    assert row[12] == pytest.approx(1 - 6 * (0.625 - (0.375 + 0.25 * np.cos(np.pi / 3)) ** 2) / 6, abs=1e-15)
    assert np.count_nonzero(row) == 7


def test_blended_planes_are_exact_on_a_plane_and_signed():
    v, t = _grid(9)
    surf = SmoothSurface(t, v, levels=1)
    rng = np.random.default_rng(0)
    q = np.column_stack([rng.uniform(-0.003, 0.003, 50), rng.uniform(-0.003, 0.003, 50), rng.uniform(-5e-4, 5e-4, 50)])
    hit = surf.evaluate(q, v)
    assert np.allclose(hit.phi_m, q[:, 2], atol=1e-15)  # the signed distance to the plane, up (+z) outside
    assert np.allclose(hit.grad_q(), [0.0, 0.0, 1.0], atol=1e-12)
    far = surf.evaluate(np.array([[0.0, 0.0, 0.01]]), v)
    assert np.isnan(far.phi_m[0]) and far.weight[0] == 0.0  # beyond every support radius


def _dome(n: int = 9):
    """A convex cap (curvature radius ~1.7-3.3 cm), wound up: the blend lies below its nodes."""
    return _grid(n, z=lambda x, y: -30.0 * (x**2 + 0.5 * y**2))


def test_through_nodes_offsets_put_the_blend_through_the_nodes():
    v, t = _dome()
    inner = np.flatnonzero(np.abs(v[:, :2]).max(axis=1) < 0.003)  # away from the open rim
    plain = SmoothSurface(t, v, levels=1)
    fitted = SmoothSurface(t, v, levels=1, through_nodes=True)
    before = plain.evaluate(v[inner], v).phi_m
    after = fitted.evaluate(v[inner], v).phi_m
    # measured: the plain blend lies 15.6-15.9 um below the cap's nodes, the fitted one within 0.04 um
    assert before.min() > 1e-6
    assert np.abs(after).max() < 0.05 * before.min()
    assert np.allclose(fitted.rest_node_phi_m[inner], after, atol=1e-15)
    assert np.all(fitted.offset_m[fitted.interior == 1] > 0)  # planes moved out on a convex surface (rim aside)
    # on a plane there is nothing to fit: offsets zero, the distance exact as before
    vp, tp = _grid(9)
    flat = SmoothSurface(tp, vp, levels=1, through_nodes=True)
    assert np.abs(flat.offset_m).max() < 1e-15
    q = np.array([[0.001, -0.002, 3e-4]])
    assert flat.evaluate(q, vp).phi_m[0] == pytest.approx(3e-4, abs=1e-15)


@pytest.mark.parametrize("through_nodes", [False, True])
def test_blended_plane_derivatives_match_central_differences(through_nodes):
    v, t = _grid(9, z=lambda x, y: 30.0 * (x**2 + 0.5 * y**2))  # a bowl, curvature radius ~1.7-3.3 cm
    surf = SmoothSurface(t, v, levels=1, radius_factor=1.5, through_nodes=through_nodes)
    assert np.any(surf.offset_m != 0) == through_nodes
    rng = np.random.default_rng(1)
    q = v[rng.choice(len(v), 20)] + rng.normal(0, 3e-4, (20, 3))
    q = q[np.abs(q[:, :2]).max(axis=1) < 0.003]
    hit = surf.evaluate(q, v)
    h = _FD_STEP_M
    g = hit.grad_q()
    for j in range(3):
        d = np.zeros(3)
        d[j] = h
        fd = (surf.evaluate(q + d, v).phi_m - surf.evaluate(q - d, v).phi_m) / (2 * h)
        assert np.allclose(fd, g[:, j], rtol=_GRAD_RTOL, atol=1e-7)
    dv = rng.standard_normal(v.shape)
    fd = (surf.evaluate(q, v + h * dv).phi_m - surf.evaluate(q, v - h * dv).phi_m) / (2 * h)
    an = np.zeros(len(q))
    np.add.at(an, hit.entry_point, np.einsum("eaj,eaj->e", hit.grad_phi[:, 1:], surf.refined(dv)[hit.corners]))
    assert np.allclose(fd, an, rtol=_GRAD_RTOL, atol=1e-7)


@pytest.fixture(scope="module")
def face():
    return build_face(3000)


@pytest.fixture(scope="module")
def pressed(face):
    """The lip-pressing pose solved with smooth lip contact."""
    sim = Simulator(face)
    contact = Contact(face, regions="lips", surface="smooth", smoothing_m=1e-4)
    return sim, contact, solve_restarted(sim, {m: 1.0 for m in _PRESS}, tol=1e-8, max_iterations=40, contact=contact)


def test_newton_converges_quadratically_with_smooth_lips(pressed):
    sim, contact, eq = pressed
    assert eq.converged and eq.inverted_elements == 0
    # measured (3,000 tets): 10 iterations, ... 8.9e-3, 1.9e-3, 6.4e-5, 8.5e-8: each residual about C r^2
    tail = np.array(eq.history[-3:])
    assert tail[-1] < 1e-8 and tail[-1] < 100 * tail[-2] ** 2 and tail[-2] < 100 * tail[-3] ** 2
    assert 0 < eq.contact_max_penetration_m < 1e-4  # within the 0.1 mm ramp
    # Against the faceted surfaces: the Loop surfaces round off the coarse lips' corners, where the faceted
    # lips may overlap (measured: -0.42 mm at 3,000 tets, at points whose smooth distance is +1.4 mm).
    assert -6e-4 < contact.self_distance_m(eq.x) < 1e-4


def test_lips_offset_through_their_nodes_meet_as_faceted_surfaces(face, pressed):
    """The plain blend rounds the lips inside their nodes (up to 2.7 mm at 3,000 tets), so pressed lips
    overlap as faceted surfaces; offset through the nodes they meet where the mesh is, still quadratically."""
    sim, plain, eq_plain = pressed
    contact = Contact(face, regions="lips", surface="smooth_through_nodes", smoothing_m=1e-4)
    assert max(np.abs(s.rest_node_phi_m).max() for s in plain.smooth.surfaces) > 1e-3
    assert max(np.abs(s.rest_node_phi_m).max() for s in contact.smooth.surfaces) < 5e-5
    eq = solve_restarted(sim, {m: 1.0 for m in _PRESS}, tol=1e-8, max_iterations=40, contact=contact)
    assert eq.converged and eq.inverted_elements == 0
    tail = np.array(eq.history[-3:])  # measured: 12 iterations, ... 2.8e-4, 5.9e-6, 3.9e-9
    assert tail[-1] < 1e-8 and tail[-1] < 1000 * tail[-2] ** 2
    # measured: the faceted lips' smallest distance -0.42 mm with the plain blend, +0.10 mm offset
    assert plain.self_distance_m(eq_plain.x) < -3e-4
    assert contact.self_distance_m(eq.x) > -5e-5


@pytest.mark.parametrize("surface", ["smooth", "smooth_through_nodes"])
def test_smooth_contact_gradient_and_exact_hessian_match_central_differences(face, pressed, surface):
    _, contact, eq = pressed
    if surface != contact.surface:  # the same pressed pose against lips offset through their nodes
        contact = Contact(face, regions="lips", surface=surface, smoothing_m=1e-4)
        assert max(np.abs(s.offset_m).max() for s in contact.smooth.surfaces) > 1e-5
    rng = np.random.default_rng(2)
    x = eq.x + 1e-6 * rng.standard_normal(eq.x.shape)
    pairs = contact.evaluate(x)
    smooth = pairs.smooth
    assert len(smooth.node) > 5 and np.all(smooth.blend == 1.0)
    involved = np.unique(np.concatenate([s.nodes for s in contact.smooth.surfaces]))
    f = pairs.forces()
    H = smooth.hessian(True)
    G = smooth.hessian(False)
    h = _FD_STEP_M
    for _ in range(3):
        v = np.zeros_like(x)
        v[involved] = rng.standard_normal((involved.size, 3))
        fd = (contact.energy(x + h * v) - contact.energy(x - h * v)) / (2 * h)
        assert fd == pytest.approx(-np.sum(f * v), rel=_GRAD_RTOL)
        fdH = -(contact.forces(x + h * v) - contact.forces(x - h * v)).ravel() / (2 * h)
        assert np.linalg.norm(H @ v.ravel() - fdH) < _HESS_RTOL * 10 * np.linalg.norm(fdH)
        assert np.linalg.norm(G @ v.ravel() - fdH) > 1e-4 * np.linalg.norm(fdH)  # Gauss-Newton misses the curvature
    dofs = np.unique(G.nonzero()[0])
    lam = np.linalg.eigvalsh(G[dofs][:, dofs].toarray())
    assert lam.min() >= -1e-9 * lam.max()  # the projected (Gauss-Newton) Hessian is PSD
    # the pairs' forces sum to zero: the smooth distance is translation invariant
    assert np.linalg.norm(f.sum(axis=0)) < 1e-9 * np.abs(f).sum()


def test_smooth_surface_options_are_checked(face):
    with pytest.raises(ValueError, match="freeze"):
        Contact(face, regions="lips", surface="smooth", freeze_below=1.0)
    with pytest.raises(ValueError, match="surface must be"):
        Contact(face, regions="lips", surface="nagata")
    with pytest.raises(ValueError, match="radius_factor"):
        SmoothSurface(face.surface_groups["upper_lip"], face.rest_positions_m, radius_factor=0.0)
