"""Trilinear hexes as quadrature tets (wface.physics.hexes): patch tests, derivatives, the Badin mesh."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import data_path
from wface.physics import Simulator
from wface.physics.hex_solve import HexBody
from wface.physics.hexes import (
    GAUSS_POINTS,
    hex_quadrature,
    quadrature_model,
    shape_functions,
    trilinear_points,
)
from wface.testing.models import box_model

CELLS = (2, 2, 2)
SIZE_M = (0.02, 0.016, 0.012)


def _box_hexes(cells=CELLS):
    """(m, 8) ANSYS-ordered hexes of ``box_model``'s grid (node (i, j, k) = (i (ny+1) + j)(nz+1) + k)."""
    nx, ny, nz = cells

    def node(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    order = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
    return np.array(
        [[node(i + a, j + b, k + c) for a, b, c in order] for i in range(nx) for j in range(ny) for k in range(nz)]
    )


def _distorted_box(muscles: int = 1, seed: int = 0):
    """The box model with its interior node moved (so its hexes are not parallelepipeds), its hexes."""
    model = box_model(CELLS, SIZE_M, muscles=muscles, fibre_direction=(0.8, 0.6, 0.0))
    x = model.rest_positions_m.copy()
    interior = np.flatnonzero(np.all((x > 1e-9) & (x < np.array(SIZE_M) - 1e-9), axis=1))
    x[interior] += np.random.default_rng(seed).normal(0.0, 1.2e-3, (interior.size, 3))
    from dataclasses import replace

    return replace(model, rest_positions_m=x).validate(), _box_hexes()


def test_shape_functions_partition_unity_and_gradients():
    xi = np.random.default_rng(1).uniform(-1, 1, (20, 3))
    N, dN = shape_functions(xi)
    np.testing.assert_allclose(N.sum(axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(dN.sum(axis=1), 0.0, atol=1e-14)
    h = 1e-6
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        fd = (shape_functions(xi + e)[0] - shape_functions(xi - e)[0]) / (2 * h)
        np.testing.assert_allclose(dN[:, :, i], fd, atol=1e-9)


def test_affine_patch_gradient_volume_and_energy():
    """An affine motion gives F = A at every Gauss point, the hexes tile the box's volume, and the hex
    energy equals the tet model's (both exact for a uniform F and a uniform fibre field)."""
    model, hexes = _distorted_box()
    quad = hex_quadrature(model.rest_positions_m, hexes)
    assert quad.volume_m3 == pytest.approx(np.prod(SIZE_M), rel=1e-12)
    A = np.array([[1.1, 0.05, -0.02], [0.03, 0.93, 0.04], [-0.01, 0.02, 1.02]])
    x = model.rest_positions_m @ A.T + np.array([0.01, -0.02, 0.005])
    y = quad.virtual_positions(x)
    Y0 = quad.virtual_rest_m
    t = quad.virtual_tets
    Ds = np.stack([y[t[:, k]] - y[t[:, 0]] for k in (1, 2, 3)], axis=2)
    Dm = np.stack([Y0[t[:, k]] - Y0[t[:, 0]] for k in (1, 2, 3)], axis=2)
    np.testing.assert_allclose(Ds @ np.linalg.inv(Dm), np.broadcast_to(A, Ds.shape), atol=1e-12)
    a = np.array([0.4])
    e_hex = Simulator(quadrature_model(model, quad)).energy(y, a)
    e_tet = Simulator(model).energy(x, a)
    assert e_hex == pytest.approx(e_tet, rel=1e-10)


def test_forces_and_tangent_match_finite_differences():
    """f = -dE/dx and K = -df/dx of the hexes (float64, central differences, a non-affine state)."""
    model, hexes = _distorted_box(seed=3)
    quad = hex_quadrature(model.rest_positions_m, hexes)
    sim = Simulator(quadrature_model(model, quad))
    rng = np.random.default_rng(4)
    x = model.rest_positions_m + rng.normal(0.0, 1e-3, model.rest_positions_m.shape)
    a = np.array([0.6])

    def energy_forces(xx):
        e, fy = sim.energy_and_forces(quad.virtual_positions(xx), a)
        return e, quad.node_forces(fy)

    _, f = energy_forces(x)
    K = quad.node_stiffness(sim.tangent(quad.virtual_positions(x), a, project=False).assemble()).toarray()
    h = 1e-7
    for dof in rng.choice(x.size, 8, replace=False):
        dx = np.zeros(x.size)
        dx[dof] = h
        dx = dx.reshape(x.shape)
        (ep, fp), (em, fm) = energy_forces(x + dx), energy_forces(x - dx)
        assert -(ep - em) / (2 * h) == pytest.approx(f.reshape(-1)[dof], rel=1e-6, abs=1e-9)
        np.testing.assert_allclose(-(fp - fm).reshape(-1) / (2 * h), K[:, dof], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(K, K.T, atol=1e-9 * np.abs(K).max())


def test_patch_equilibrium_is_affine():
    """Boundary nodes on an affine map, a uniform material and fibre field, the muscle on: the free
    interior node's equilibrium is the affine position (a uniform stress has no divergence)."""
    model, hexes = _distorted_box(seed=5)
    quad = hex_quadrature(model.rest_positions_m, hexes)
    sim = Simulator(quadrature_model(model, quad))
    X = model.rest_positions_m
    A = np.array([[1.05, 0.02, 0.0], [0.0, 0.97, 0.03], [0.01, 0.0, 1.01]])
    target = X @ A.T
    free = np.flatnonzero(np.all((X > 1e-9) & (X < np.array(SIZE_M) - 1e-9), axis=1))
    x0 = target.copy()
    x0[free] += 1e-3
    r = HexBody(sim, quad, free).solve(np.array([0.5]), x0, tol=1e-10)
    assert r.converged and r.iterations <= 10
    np.testing.assert_allclose(r.x_m[free], target[free], atol=1e-10)


def test_wedge_and_sheared_hex_volumes():
    """A collapsed hex (a wedge, as the Badin mesh's 318) and a sheared one: exact volumes."""
    from wface.physics.hexes import CORNERS

    box = (CORNERS + 1.0) * np.array([0.5, 1.0, 1.5])  # 1 x 2 x 3
    shear = box @ np.array([[1.0, 0.0, 0.0], [0.3, 1.0, 0.0], [0.0, 0.2, 1.0]])
    wedge = box.copy()
    wedge[[5, 6]] = wedge[[4, 7]]  # top edge collapsed: half the volume
    for x, volume in ((box, 6.0), (shear, 6.0), (wedge, 3.0)):
        assert hex_quadrature(x, np.arange(8)[None]).volume_m3 == pytest.approx(volume, rel=1e-12)


def _artisynth_wedge(v):
    """Positions, deformation gradients' rest Jacobians and weights of ArtiSynth's WedgeElement rule on the
    wedge with bottom triangle v[0:3] and top v[3:6] (its getN / getdNds and integration coordinates)."""
    a, b, q = 1 / 6, 2 / 3, 1 / np.sqrt(3)
    pts = [(s1, s2, r) for r in (-q, q) for s1, s2 in ((a, a), (b, a), (a, b))]
    out = []
    for s1, s2, r in pts:
        N = 0.5 * np.array([(1 - s1 - s2) * (1 - r), s1 * (1 - r), s2 * (1 - r)])
        N = np.concatenate([N, N * (1 + r) / (1 - r)])
        dN = np.array(
            [
                [-0.5 * (1 - r), -0.5 * (1 - r), -0.5 * (1 - s1 - s2)],
                [0.5 * (1 - r), 0, -0.5 * s1],
                [0, 0.5 * (1 - r), -0.5 * s2],
                [-0.5 * (1 + r), -0.5 * (1 + r), 0.5 * (1 - s1 - s2)],
                [0.5 * (1 + r), 0, 0.5 * s1],
                [0, 0.5 * (1 + r), 0.5 * s2],
            ]
        )
        J = v.T @ dN  # dX / ds
        out.append((N @ v, J, abs(np.linalg.det(J)) / 6))  # either handedness of the node order
    return out


@pytest.mark.parametrize("collapse", [((2, 3), (6, 7)), ((4, 7), (5, 6)), ((1, 2), (5, 6))])
def test_wedge_rule_is_artisynths_wedge_element(collapse):
    """hex_quadrature(wedges="wedge") on a hex with two parallel edges collapsed: the points, volumes and
    deformation gradients of ArtiSynth's WedgeElement (written out here from its source) under a nonlinear
    motion, and the same wedge volume as the 2x2x2 rule; a regular hex or another degeneracy keeps 2x2x2."""
    from wface.physics.hexes import CORNERS, wedge_rule

    rng = np.random.default_rng(7)
    x = (CORNERS + 1.0) * np.array([0.5, 1.0, 1.5]) + rng.normal(0, 0.08, (8, 3))
    hexes = np.arange(8)
    for a, b in collapse:
        x[b] = x[a]
        hexes[b] = a
    quad = hex_quadrature(x, hexes[None], wedges="wedge")
    collapsed = hex_quadrature(x, hexes[None])
    assert quad.volume_m3 == pytest.approx(collapsed.volume_m3, rel=1e-12)  # the volume is exact either way
    # the wedge's triangles: the corners on the collapsed edges' face are the apex, the others two per layer
    pair = {a: b for a, b in collapse} | {b: a for a, b in collapse}
    layers = {}
    for c in range(8):
        if c in pair and pair[c] < c:
            continue
        k = [i for i in range(3) if CORNERS[collapse[0][0], i] != CORNERS[collapse[1][0], i]][0]
        layers.setdefault(CORNERS[c, k], []).append(c)
    bottom, top = (sorted(layers[s], key=lambda c: (c in pair, c)) for s in (-1.0, 1.0))
    top = [next(t for t in top if np.array_equal(np.delete(CORNERS[t], k), np.delete(CORNERS[c], k))) for c in bottom]
    motion = lambda p: p + 0.1 * np.sin(p[..., ::-1]) + 0.05 * p**2  # noqa: E731
    ref = _artisynth_wedge(x[bottom + top])
    ref_moved = _artisynth_wedge(motion(x[bottom + top]))
    points = quad.gauss_points_m
    assert len(points) == 8 and wedge_rule(hexes) is not None
    for (p, J, vol), (_, J_moved, _) in zip(ref, ref_moved, strict=True):
        at = np.flatnonzero(np.linalg.norm(points - p, axis=1) < 1e-12)
        assert at.size in (1, 2)  # two slots hold a point twice, at half its weight
        assert quad.gauss_volume_m3[at].sum() == pytest.approx(vol, rel=1e-12)
        F_ref = J_moved @ np.linalg.inv(J)
        for g in at:
            F = motion(x).T @ quad.shape_gradients_per_m[g]
            np.testing.assert_allclose(F, F_ref, rtol=1e-12, atol=1e-12)
    assert wedge_rule(np.arange(8)) is None
    other = np.arange(8)
    other[[1, 3]] = [0, 0]  # three corners of a face collapsed to one: not a wedge
    assert wedge_rule(other) is None
    with pytest.raises(ValueError, match="wedges must be one of collapsed, wedge"):
        hex_quadrature(x, hexes[None], wedges="prism")


def test_mirrored_hex_is_reoriented_and_inverted_hex_named():
    model, hexes = _distorted_box()
    mirrored = hexes[:, [0, 3, 2, 1, 4, 7, 6, 5]]
    q1, q2 = hex_quadrature(model.rest_positions_m, hexes), hex_quadrature(model.rest_positions_m, mirrored)
    assert q2.volume_m3 == pytest.approx(q1.volume_m3, rel=1e-12)
    twisted = hexes.copy()
    twisted[0, [4, 6]] = twisted[0, [6, 4]]  # a top face crossed over itself
    with pytest.raises(ValueError, match="non-positive Jacobian"):
        hex_quadrature(model.rest_positions_m, twisted)


def test_points_located_and_fibre_entries_carried():
    model, hexes = _distorted_box(muscles=2)
    quad = hex_quadrature(model.rest_positions_m, hexes)
    owner, xi = trilinear_points(quad, model.rest_positions_m, quad.gauss_points_m)
    np.testing.assert_array_equal(owner, quad.hex_of_point)
    np.testing.assert_allclose(np.abs(xi), 1 / np.sqrt(3.0), atol=1e-9)
    np.testing.assert_allclose(np.sort(xi, axis=0), np.sort(np.tile(GAUSS_POINTS, (len(hexes), 1)), axis=0), atol=1e-9)
    qm = quadrature_model(model, quad)
    # muscle k is the k-th slab along y of the tets: each Gauss point gets its own slab's muscle
    slab_y = SIZE_M[1] / 2
    expected = (quad.gauss_points_m[qm.fibre_tet, 1] > slab_y).astype(int)
    near_cut = np.abs(quad.gauss_points_m[qm.fibre_tet, 1] - slab_y) < 2e-3
    np.testing.assert_array_equal(qm.fibre_muscle[~near_cut], expected[~near_cut])
    assert np.bincount(qm.fibre_tet).max() == 1 and qm.fibre_tet.size == quad.virtual_tets.shape[0]


def test_badin_hexes(badin_model):
    """The Badin face's own hexes: positive Jacobians at every Gauss point and the tet split's volume."""
    from wface.speech.artisynth_demo import face_hexes

    hexes = face_hexes(data_path("artisynth-face"))
    n = int(hexes.max()) + 1
    quad = hex_quadrature(badin_model.rest_positions_m[:n], hexes)
    assert len(hexes) == 6342 and quad.gauss_volume_m3.min() > 0
    assert quad.volume_m3 == pytest.approx(float(badin_model.rest_volume_m3.sum()), rel=5e-4)
    # its 318 wedges (K = L, O = P) take ArtiSynth's wedge rule: the same volume, only their points move
    wedged = hex_quadrature(badin_model.rest_positions_m[:n], hexes, wedges="wedge")
    moved = np.linalg.norm(wedged.gauss_points_m - quad.gauss_points_m, axis=1).reshape(-1, 8).max(axis=1) > 0
    assert moved.sum() == 318 and wedged.gauss_volume_m3.min() > 0
    assert wedged.volume_m3 == pytest.approx(quad.volume_m3, rel=1e-12)


def test_badin_hexes_example(badin_model_path, tmp_path):
    """examples/badin_hexes.py at one level: the four variants, each converged, hexes beside tets
    (measured at OOP 0.01: 20.13 mm^2 tets, 20.50 hexes, from 39.50 at rest)."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / "badin_hexes.py"
    spec = importlib.util.spec_from_file_location("badin_hexes_example", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    data = data_path("artisynth-face")
    argv = ["--model", str(badin_model_path), "--data", str(data), "--levels", "0.01", "--out", str(tmp_path)]
    assert example.main(argv) == 0
    result = json.loads((tmp_path / "hexes_vs_tets.json").read_text())
    assert set(result["labels"]) == {"tets", "tets_delaunay", "hexes", "hexes_delaunay"}
    assert (tmp_path / "hexes_vs_tets.png").stat().st_size > 10_000
    rest = result["rest"]["area_mm2"]
    areas = {k: result[k][0]["area_mm2"] for k in result["labels"]}
    assert all(result[k][0]["residual_rel"] <= 1e-6 for k in result["labels"])
    assert all(0.3 * rest < a < 0.7 * rest for a in areas.values())
    assert abs(areas["hexes"] - areas["tets"]) < 2.0
    assert result["mesh"]["hexes"] == 6342 and result["mesh"]["wedges"] == 318
