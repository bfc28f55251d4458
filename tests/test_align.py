"""Similarity fits, surface alignment with projection, head-motion removal; AnimFace on ICT."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.conftest import data_path
from wface.mesh.align import Similarity, align_to_surface, embed_markers, remove_head_motion, tangent_frame, umeyama

_EXACT = 1e-9  # float64 round-off on O(1) coordinates


def _random_similarity(rng) -> Similarity:
    return Similarity(float(rng.uniform(0.3, 3.0)), Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), k=st.integers(3, 40))
def test_umeyama_recovers_exact_transform(seed, k):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(k, 3))
    if np.linalg.matrix_rank(x - x.mean(0)) < 2:
        return
    tf = _random_similarity(rng)
    got = umeyama(x, tf.apply(x))
    np.testing.assert_allclose(got.apply(x), tf.apply(x), atol=_EXACT * tf.scale * 10)
    assert np.linalg.det(got.rotation) == pytest.approx(1.0)
    assert got.scale == pytest.approx(tf.scale, rel=1e-9)


def test_umeyama_weights_nan_and_rigid():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(10, 3))
    tf = _random_similarity(rng)
    y = tf.apply(x)
    y[3] = np.nan  # missing marker: ignored
    y[5] += 100.0  # outlier with zero weight: ignored
    w = np.ones(10)
    w[5] = 0
    got = umeyama(x, y, weights=w)
    np.testing.assert_allclose(got.apply(x[:3]), tf.apply(x[:3]), atol=1e-9)
    rigid = umeyama(x, Similarity(1.0, tf.rotation, tf.translation_m).apply(x), with_scale=False)
    assert rigid.scale == 1.0
    np.testing.assert_allclose(rigid.rotation, tf.rotation, atol=1e-9)
    with pytest.raises(ValueError, match="at least 3"):
        umeyama(x[:2], x[:2])
    # inverse and composition
    np.testing.assert_allclose(tf.inverse().apply(tf.apply(x)), x, atol=1e-12)
    np.testing.assert_allclose(tf.compose(tf.inverse()).as_matrix(), np.eye(4), atol=1e-12)


def _sphere(n_lat=24, n_lon=48, radius=0.1):
    th = np.linspace(0.15, np.pi - 0.15, n_lat)
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    v = radius * np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    # an ellipsoid so that the fit is unique up to symmetry
    v *= [1.0, 0.7, 1.3]
    tris = []
    for i in range(n_lat - 1):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            c, d = a + n_lon, b + n_lon
            tris += [(a, c, b), (b, c, d)]
    return v, np.array(tris)


def test_align_to_surface_recovers_pose_with_landmarks():
    v, tris = _sphere()
    rng = np.random.default_rng(2)
    ids = rng.choice(len(v), 30, replace=False)
    markers_model = v[ids]
    tf = _random_similarity(rng)  # model -> capture
    capture = tf.apply(markers_model)
    capture[4] = np.nan
    res = align_to_surface(capture, v, tris, landmark_vertices=ids)
    ok = np.isfinite(capture).all(axis=1)
    np.testing.assert_allclose(res.aligned_m[ok], markers_model[ok], atol=1e-7)
    assert res.distance_m[ok].max() < 1e-7 and np.isnan(res.distance_m[4])
    assert res.embedding.triangle[4] == -1
    # embedding reproduces the marker on the undeformed surface
    np.testing.assert_allclose(res.embedding.marker_positions(v, tris)[ok], markers_model[ok], atol=1e-6)


def test_align_without_landmarks_uses_principal_axes():
    v, tris = _sphere()
    rng = np.random.default_rng(5)
    ids = rng.choice(len(v), 200, replace=False)
    tf = Similarity(2.0, Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix(), np.array([1.0, 2, 3]))
    res = align_to_surface(tf.apply(v[ids]), v, tris)
    assert res.rms_history_m[-1] < 1e-4  # on the surface up to the facet error
    assert res.rms_history_m[-1] <= res.rms_history_m[0]


def test_embedding_normal_offset():
    v, tris = _sphere()
    from wface.mesh.surface import vertex_normals

    n = vertex_normals(v, tris)
    p = v[[100, 200]] + 0.005 * n[[100, 200]]
    emb = embed_markers(p, v, tris)
    np.testing.assert_allclose(emb.normal_offset_m, 0.005, atol=2e-4)  # facets vs smooth normal
    np.testing.assert_allclose(emb.marker_positions(v, tris), p, atol=2e-4)


def test_marker_positions_on_the_ring_equal_the_whole_surface():
    """Normals summed over the triangles touching the markers' triangles alone are the whole
    surface's at those vertices, bit for bit, on a deformed surface too."""
    v, tris = _sphere()
    rng = np.random.default_rng(3)
    from wface.mesh.surface import vertex_normals

    n = vertex_normals(v, tris)
    picks = rng.choice(len(v), 12, replace=False)
    emb = embed_markers(v[picks] + 0.004 * n[picks], v, tris)
    ring = emb.ring_triangles(tris)
    assert 0 < len(ring) < len(tris) // 4
    moved = v * np.array([1.2, 0.9, 1.05]) + 0.01 * np.sin(7.0 * v[:, [1, 2, 0]])
    whole = emb.surface_points(moved, tris)
    normals = vertex_normals(moved, tris)
    tri = tris[emb.triangle]
    nm = np.einsum("kj,kjd->kd", emb.barycentric, normals[tri])
    nm /= np.linalg.norm(nm, axis=1, keepdims=True)
    whole += emb.normal_offset_m[:, None] * nm
    t1, t2 = tangent_frame(moved[tri], nm)
    whole += emb.tangent_offset_m[:, :1] * t1 + emb.tangent_offset_m[:, 1:] * t2
    np.testing.assert_array_equal(emb.marker_positions(moved, tris, ring=ring), whole)
    np.testing.assert_array_equal(emb.marker_positions(moved, tris), whole)


def test_markers_off_a_ridge_sit_at_rest_and_turn_with_the_skin():
    """A marker far off a coarse, curved surface has its closest point on an edge or a vertex, so
    part of its offset is not along the interpolated normal: the embedding keeps that part in the
    triangle's tangent frame, puts every marker exactly at its rest place and carries it rigidly."""
    v, tris = _sphere()
    rng = np.random.default_rng(11)
    p = rng.normal(size=(20, 3))
    p *= (0.12 + 0.02 * rng.random(20))[:, None] / np.linalg.norm(p, axis=1, keepdims=True)  # 0-2 cm off
    emb = embed_markers(p, v, tris)
    assert np.linalg.norm(emb.tangent_residual_m, axis=1).max() > 1e-4  # off the normal somewhere
    np.testing.assert_allclose(emb.marker_positions(v, tris), p, rtol=0, atol=1e-14)
    dropped = embed_markers(p, v, tris)
    dropped.tangent_offset_m = None  # the normal part alone misses by the tangent residual
    miss = np.linalg.norm(dropped.marker_positions(v, tris) - p, axis=1)
    np.testing.assert_allclose(miss, np.linalg.norm(emb.tangent_residual_m, axis=1), rtol=1e-9, atol=1e-15)
    rot = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
    shift = np.array([0.01, -0.02, 0.03])
    np.testing.assert_allclose(emb.marker_positions(v @ rot.T + shift, tris), p @ rot.T + shift, rtol=0, atol=1e-14)


def test_remove_head_motion_rigid():
    rng = np.random.default_rng(3)
    rest = rng.normal(scale=0.05, size=(12, 3))
    frames = []
    for f in range(5):
        tf = Similarity(1.0, Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))
        local = rest.copy()
        local[6:] += 0.003 * f  # deforming (non-stable) markers
        frames.append(tf.apply(local))
    out, tfs = remove_head_motion(np.array(frames), [0, 1, 2, 3], reference_frame=0)
    ref = frames[0]
    for f in range(5):
        np.testing.assert_allclose(out[f, :4], ref[:4], atol=1e-9)
    # the deformation survives (expressed in frame 0's pose)
    d = out[3, 6:] - out[0, 6:]
    assert np.allclose(np.linalg.norm(d, axis=1), 0.003 * 3 * np.sqrt(3), atol=1e-9)


def test_animface_first_frames_fit_ict_landmarks():
    """The landmark file places all 41 AnimFace markers within a few mm of a similarity fit."""
    ezc3d_path = data_path("animface", "JawMoCap.c3d")
    ict = data_path("ict-facekit", "ict_expressions.npz")
    from wface.basis.landmarks import load_ict_animface_landmarks
    from wface.io.mocap import read_c3d

    lm = load_ict_animface_landmarks()
    neutral = np.load(ict)["neutral"].astype(np.float64) * 0.01
    for name in ("JawMoCap.c3d", "CheeksMoCap.c3d", "EyebrowsMoCap.c3d", "NoseMoCap.c3d"):
        take = read_c3d(ezc3d_path.with_name(name))
        assert set(take.marker_names) == set(lm)
        target = neutral[[lm[n] for n in take.marker_names]]
        tf = umeyama(take.positions_m[0], target)
        resid_mm = np.linalg.norm(tf.apply(take.positions_m[0]) - target, axis=1) * 1e3
        # Person-to-person shape differences plus marker stand-off: a few mm, never a wrong feature.
        assert np.sqrt(np.mean(resid_mm**2)) < 4.0, name
        assert resid_mm.max() < 8.0, name
        assert 0.9 < tf.scale < 1.1


def test_landmark_file_is_reproducible_from_its_derivation():
    """wface/data/ict_animface_landmarks.json is what derive_landmarks gives on JawMoCap frame 0."""
    import json

    from wface.basis import load_basis
    from wface.basis.landmarks import ANIMFACE_DLIB_SEEDS, derive_landmarks, load_ict_animface_landmarks
    from wface.io.mocap import read_c3d

    ict_dir = data_path("ict-facekit", "vertex_indices.json").parent
    basis = load_basis(ict_dir / "ict_expressions.npz")
    dlib = json.loads((ict_dir / "vertex_indices.json").read_text())["idx_to_landmark_verts"]
    take = read_c3d(data_path("animface", "JawMoCap.c3d"))
    tris = basis.triangles[(basis.triangles < 9409).all(axis=1)]  # ICT face region
    seeds = {k: dlib[v] for k, v in ANIMFACE_DLIB_SEEDS.items()}
    derived, dist = derive_landmarks(take.marker_names, take.positions_m[0], basis.neutral_m, tris, seeds)
    assert derived == load_ict_animface_landmarks()
    assert np.sqrt(np.mean(dist**2)) < 0.003  # ~2.4 mm: marker stand-off plus face-shape differences
