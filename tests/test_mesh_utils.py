"""Mesh utilities: exact closest points, boundary faces, quality metrics, meshio round trips."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wface.mesh.closest import SurfaceQuery, closest_point_on_triangles
from wface.mesh.quality import count_inverted, dihedral_angles_deg, quality_report, signed_volumes, volume_ratio_quality
from wface.mesh.surface import boundary_faces, triangle_normals
from wface.mesh.tetio import read_tet_mesh, write_tet_mesh

REGULAR = np.array([[1, 1, 1], [-1, 1, -1], [1, -1, -1], [-1, -1, 1]], dtype=float)  # positively oriented


def _box(n=3):
    """Kuhn-split unit cube grid, positively oriented."""
    from wface.faces.builtin.grid import build_grid

    g = build_grid(np.linspace(0.5, 1.5, n + 1), np.linspace(0, 1, n + 1), n, theta_mouth=0.0, y_mouth=-1.0)
    x = np.stack([g.theta, g.y, g.w], axis=1)
    t = g.tets.copy()
    p = x[t]
    neg = np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])) < 0
    t[neg] = t[neg][:, [0, 2, 1, 3]]
    return x, t


def _sphere(n=40):
    import pyvista as pv

    s = pv.Sphere(theta_resolution=n, phi_resolution=n).triangulate()
    return np.asarray(s.points, float), np.asarray(s.faces).reshape(-1, 4)[:, 1:]


_SPHERE = _sphere()
_QUERY = SurfaceQuery(*_SPHERE)
_BVH_QUERY = SurfaceQuery(*_SPHERE, engine="bvh")


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3), st.sampled_from(["kdtree", "bvh"]))
def test_closest_point_matches_brute_force(p, engine):
    v, t = _SPHERE
    p = np.asarray(p)[None]
    hit = {"kdtree": _QUERY, "bvh": _BVH_QUERY}[engine].closest(p)
    w = closest_point_on_triangles(np.repeat(p, len(t), 0), v[t[:, 0]], v[t[:, 1]], v[t[:, 2]])
    d = np.linalg.norm(np.einsum("kj,kjd->kd", w, v[t]) - p, axis=1)
    assert hit.distance_m[0] == pytest.approx(d.min(), abs=1e-12)
    assert np.allclose(hit.barycentric.sum(axis=1), 1.0) and hit.barycentric.min() >= -1e-12


def test_closest_point_regions():
    a, b, c = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    cases = {
        (-1, -1, 0): (1, 0, 0),
        (2, -0.1, 0): (0, 1, 0),
        (0.5, -1, 3): (0.5, 0.5, 0),
        (0.2, 0.2, 1): (0.6, 0.2, 0.2),
    }
    for p, w in cases.items():
        got = closest_point_on_triangles(np.array([p], float), a, b, c)[0]
        assert np.allclose(got, w), (p, got)


@pytest.mark.parametrize("offset_m", [0.0, 1000.0])
def test_the_bvh_engine_finds_the_exact_closest_point(offset_m):
    """The Warp engine's float32 BVH only lists candidates: its answer is the exact float64 one
    (brute force over every triangle), for points on, near and far from a soup of small, thin and
    degenerate triangles, also 1 km from the origin where float32 spacing is 61 um."""
    rng = np.random.default_rng(7)
    centres = rng.uniform(-0.05, 0.05, (300, 3))
    v = (centres[:, None, :] + rng.normal(0.0, 0.004, (300, 3, 3))).reshape(-1, 3)
    v[3:30:3] = v[4:31:3]  # repeated corners
    t = np.arange(900).reshape(300, 3)
    t[40:50, 2] = t[40:50, 1]  # segments
    v = v + offset_m
    on = np.einsum("kj,kjd->kd", rng.dirichlet(np.ones(3), 200), v[t[rng.integers(0, 300, 200)]])
    p = np.concatenate([on, on + rng.normal(0.0, 1e-4, on.shape), offset_m + rng.uniform(-0.2, 0.2, (200, 3))])
    p = np.concatenate([p, [[offset_m + 50.0, 0.0, 0.0]]])
    hit = SurfaceQuery(v, t, engine="bvh").closest(p)
    w = closest_point_on_triangles(np.repeat(p, len(t), 0), *(np.tile(v[t[:, j]], (len(p), 1)) for j in range(3)))
    d = np.linalg.norm(np.einsum("kj,kjd->kd", w, np.tile(v[t], (len(p), 1, 1))) - np.repeat(p, len(t), 0), axis=1)
    best = d.reshape(len(p), len(t)).min(axis=1)
    assert np.allclose(hit.distance_m, best, rtol=1e-12, atol=1e-12 * (1 + offset_m))
    assert np.allclose(np.linalg.norm(hit.point_m - p, axis=1), hit.distance_m, atol=1e-12 * (1 + offset_m))
    assert np.allclose(hit.barycentric.sum(axis=1), 1.0) and hit.barycentric.min() >= -1e-12
    kd = SurfaceQuery(v, t).closest(p)
    assert np.allclose(hit.point_m, kd.point_m, rtol=0, atol=1e-12 * (1 + offset_m))


def test_the_engines_refuse_what_they_cannot_do():
    v, t = _SPHERE
    with pytest.raises(ValueError, match="unknown engine 'octree'"):
        SurfaceQuery(v, t, engine="octree")
    empty = _BVH_QUERY.closest(np.zeros((0, 3)))
    assert empty.triangle.shape == (0,) and empty.point_m.shape == (0, 3)
    with pytest.raises(ValueError, match="NaN"):
        _BVH_QUERY.closest(np.array([[0.0, np.inf, 0.0]]))


def test_closest_rejects_nan():
    with pytest.raises(ValueError, match="NaN"):
        _QUERY.closest(np.array([[np.nan, 0, 0]]))


def test_boundary_faces_of_a_box_are_outward():
    x, t = _box(3)
    f = boundary_faces(t)
    assert len(f) == 6 * 9 * 2
    centre = x.mean(axis=0)
    n = triangle_normals(x, f)
    assert np.all(np.einsum("ij,ij->i", n, x[f].mean(axis=1) - centre) > 0)


def test_quality_of_regular_and_box_tets():
    assert volume_ratio_quality(REGULAR, np.array([[0, 1, 2, 3]]))[0] == pytest.approx(1.0, abs=1e-12)
    assert dihedral_angles_deg(REGULAR, np.array([[0, 1, 2, 3]])) == pytest.approx(np.degrees(np.arccos(1 / 3)))
    x, t = _box(2)
    q = quality_report(x, t)
    assert q.inverted == 0
    assert q.min_dihedral_deg == pytest.approx(45.0) and q.max_dihedral_deg == pytest.approx(90.0)  # Kuhn tets


@pytest.mark.parametrize("suffix", [".vtu", ".msh"])
def test_meshio_round_trip(tmp_path, suffix):
    x, t = _box(2)
    cell = {"muscle_id": [np.arange(len(t), dtype=np.int32)]}
    path = write_tet_mesh(tmp_path / f"box{suffix}", x, t, cell_data=cell)
    x2, t2, _ = read_tet_mesh(path)
    assert np.allclose(x2, x) and np.array_equal(np.sort(t2, axis=1), np.sort(t, axis=1))


def test_read_reorients_and_reports(tmp_path):
    x, t = _box(1)
    path = write_tet_mesh(tmp_path / "flip.vtu", x, t[:, [0, 2, 1, 3]])
    x2, t2, _ = read_tet_mesh(path)
    assert quality_report(x2, t2).inverted == 0
    with pytest.raises(FileNotFoundError):
        read_tet_mesh(tmp_path / "missing.vtu")
    import meshio

    meshio.write(tmp_path / "tri.vtu", meshio.Mesh(x, [("triangle", t[:, :3])]))
    with pytest.raises(ValueError, match="no tetrahedra"):
        read_tet_mesh(tmp_path / "tri.vtu")


def test_count_inverted_counts_the_non_positive_signed_volumes():
    """The Warp count against numpy's signed volumes: inverted, flattened (exactly zero volume) and
    positive tets of a perturbed grid."""
    from types import SimpleNamespace

    x, t = _box(4)
    rng = np.random.default_rng(2)
    y = x + rng.normal(scale=0.12, size=x.shape)  # inverts some tets
    model = SimpleNamespace(tets=t.astype(np.int64))  # any integer type
    expected = int(np.count_nonzero(signed_volumes(y, t) <= 0.0))
    assert 0 < expected < len(t)
    assert count_inverted(model, y) == expected
    flat = x.copy()
    flat[t[0, 3]] = flat[t[0, 0]]  # a collapsed tet: zero volume counts
    assert count_inverted(model, flat) == int(np.count_nonzero(signed_volumes(flat, t) <= 0.0)) >= 1
    assert count_inverted(model, x) == 0
    assert count_inverted(SimpleNamespace(tets=np.zeros((0, 4), int)), x) == 0


def test_signed_surfaces_of_the_same_triangles_share_their_topology():
    """``SignedSurface`` keeps what the triangles alone fix (edge ids, open boundary, vertices in use)
    per distinct triangle array, since contact rebuilds the lips' surfaces at new positions on every
    evaluation: a surface built with the cached topology equals one built from scratch, field by field
    and query by query; different triangles of the same count get their own; the cache is bounded
    and its arrays are read-only."""
    from wface.mesh import signed_distance as sd
    from wface.testing.models import box_model

    box = box_model((3, 2, 2))
    tri = boundary_faces(box.tets)
    rng = np.random.default_rng(7)
    x = box.rest_positions_m
    y = x @ np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 1.2]]) + 0.003 * rng.standard_normal(x.shape)
    q = np.concatenate(
        [y[np.unique(tri)] + 1e-3 * rng.standard_normal((len(np.unique(tri)), 3)), rng.random((50, 3)) * 0.05]
    )
    for t in (tri, tri[1:], tri[:-1]):  # closed, and two open surfaces of the same size
        sd._TOPOLOGY_CACHE.clear()
        fresh = sd.SignedSurface(y, t, orient=False)
        sd.SignedSurface(x, t, orient=False)  # the same triangles at other positions: a cache hit
        cached = sd.SignedSurface(y, t, orient=False)
        assert len(sd._TOPOLOGY_CACHE) == 1
        for name in ("edge_normals", "boundary_edge", "boundary_vertex", "lower_m", "upper_m", "_edge_of"):
            assert np.array_equal(getattr(cached, name), getattr(fresh, name)), name
        assert cached.closed == fresh.closed == (len(t) == len(tri))
        a, b = cached.signed(q), fresh.signed(q)
        for name in ("phi_m", "normal", "triangle", "barycentric", "on_boundary", "feature", "edge_direction"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
    sd._TOPOLOGY_CACHE.clear()
    first, second = sd.SignedSurface(y, tri[1:], orient=False), sd.SignedSurface(y, tri[:-1], orient=False)
    assert not np.array_equal(first.boundary_vertex, second.boundary_vertex)  # each its own hole
    with pytest.raises(ValueError):
        first._edge_of[0, 0] = 1  # shared: read-only
    for k in range(sd._TOPOLOGY_CACHE_SIZE + 5):
        sd.SignedSurface(y, np.roll(tri, k + 1, axis=0), orient=False)
    assert len(sd._TOPOLOGY_CACHE) == sd._TOPOLOGY_CACHE_SIZE
