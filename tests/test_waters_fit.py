"""Fitting a layout to another face by landmarks; FACS driving; the synthetic head."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from wface.facs import EXPRESSIONS
from wface.testing.synthetic_head import synthetic_head, synthetic_landmarks
from wface.waters.expressions import expression_pose, interpolate_poses, parse_au_assignments, pose_from_action_units
from wface.waters.fit import fit_layout, landmark_warp, similarity_transform
from wface.waters.layout import layout_to_dict, load_layout
from wface.waters.muscles import LinearMuscle
from wface.waters.rig import WatersRig

S, R, T = 1.37, Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix(), np.array([0.12, -0.4, 0.05])


def _xf(p):
    return S * np.asarray(p) @ R.T + T


def test_similarity_transform_recovers_a_known_one():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(20, 3))
    s, r, t = similarity_transform(a, _xf(a))
    assert s == pytest.approx(S, rel=1e-12)
    np.testing.assert_allclose(r, R, atol=1e-12)
    np.testing.assert_allclose(t, T, atol=1e-12)
    with pytest.raises(ValueError, match="collinear"):
        similarity_transform(np.outer(np.arange(5.0), [1, 2, 3]), np.outer(np.arange(5.0), [1, 2, 3]))


def test_rbf_warp_interpolates_landmarks():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(30, 3))
    b = _xf(a) + 0.05 * rng.normal(size=a.shape)
    warp = landmark_warp(a, b, method="rbf")
    np.testing.assert_allclose(warp(a), b, atol=1e-9)


@pytest.mark.parametrize("method", ["similarity", "affine", "rbf"])
def test_fit_reproduces_layout_under_a_similarity(method):
    lay = load_layout("ict")
    target = {k: _xf(v) for k, v in lay.landmarks_m.items()}
    fitted = fit_layout(lay, target, method=method, snap=False)
    for m0, m1 in zip(lay.muscles, fitted.muscles, strict=True):
        assert m0.name == m1.name
        if isinstance(m0, LinearMuscle):
            np.testing.assert_allclose(m1.bone_m, _xf(m0.bone_m), atol=1e-9)
            np.testing.assert_allclose(m1.insertion_m, _xf(m0.insertion_m), atol=1e-9)
            assert m1.fall_start_m == pytest.approx(S * m0.fall_start_m, rel=1e-9)
            assert m1.fall_finish_m == pytest.approx(S * m0.fall_finish_m, rel=1e-9)
            assert m1.spring_constant_m == pytest.approx(S * m0.spring_constant_m, rel=1e-9)
            assert m1.zone_deg == m0.zone_deg
        else:
            np.testing.assert_allclose(m1.centre_m, _xf(m0.centre_m), atol=1e-9)
            np.testing.assert_allclose(m1.semi_axes_m, S * m0.semi_axes_m, rtol=1e-6)
            np.testing.assert_allclose(m1.horizontal, R @ m0.horizontal, atol=1e-6)
    np.testing.assert_allclose(fitted.jaw.pivot_m, _xf(lay.jaw.pivot_m), atol=1e-9)
    np.testing.assert_allclose(fitted.jaw.axis, R @ lay.jaw.axis, atol=1e-6)
    assert fitted.max_displacement_m == pytest.approx(S * lay.max_displacement_m)
    # the fitted rig deforms the transformed points exactly like the original rig, transformed
    pts = np.stack(list(lay.landmarks_m.values()))
    c = {"zygomaticus_major_l": 0.8, "orbicularis_oris_lower": 0.5, "frontalis_lateral_r": 1.0}
    d0 = WatersRig(lay, pts, muscle_mask=np.ones(len(pts), bool)).deform(c, jaw_opening_deg=8.0)
    d1 = WatersRig(fitted, _xf(pts), muscle_mask=np.ones(len(pts), bool)).deform(c, jaw_opening_deg=8.0)
    np.testing.assert_allclose(d1, _xf(d0), atol=1e-9 * S)


def test_fit_with_snapping_onto_a_transformed_surface_is_reproduced():
    base = load_layout("ict")
    head = synthetic_head(60, 120)
    tri = head.triangles()
    on_head = fit_layout(base, synthetic_landmarks(base), target_vertices_m=head.vertices_m, target_triangles=tri)
    # insertions lie on the surface
    from wface.mesh.closest import SurfaceQuery

    q = SurfaceQuery(head.vertices_m, tri)
    ins = np.stack([m.insertion_m for m in on_head.muscles if isinstance(m, LinearMuscle)])
    assert np.max(q.closest(ins).distance_m) < 1e-12
    moved = fit_layout(
        on_head,
        {k: _xf(v) for k, v in on_head.landmarks_m.items()},
        target_vertices_m=_xf(head.vertices_m),
        target_triangles=tri,
        method="similarity",
    )
    for m0, m1 in zip(on_head.muscles, moved.muscles, strict=True):
        if isinstance(m0, LinearMuscle):
            np.testing.assert_allclose(m1.insertion_m, _xf(m0.insertion_m), atol=1e-9)
            np.testing.assert_allclose(m1.bone_m, _xf(m0.bone_m), atol=1e-9)


def test_fitted_layout_deforms_the_synthetic_head_sensibly():
    base = load_layout("ict")
    head = synthetic_head(80, 160)
    lay = fit_layout(
        base, synthetic_landmarks(base), target_vertices_m=head.vertices_m, target_triangles=head.triangles()
    )
    rig = WatersRig(lay, head.vertices_m)
    pose = expression_pose("happy", muscle_names=rig.muscle_names)
    d = rig.deform(pose.contractions, jaw_opening_deg=pose.jaw_opening_deg) - head.vertices_m
    size = np.linalg.norm(d, axis=1)
    assert 0.002 < size.max() <= lay.max_displacement_m + 0.01  # muscles + a few degrees of jaw
    # a smile pulls the left mouth corner up and out (toward +x, +y)
    corner = lay.landmarks_m["Mouth_Lend"]
    near = np.argmin(np.linalg.norm(head.vertices_m - corner, axis=1))
    assert d[near, 0] > 0 and d[near, 1] > 0


def test_fit_errors_name_the_problem():
    lay = load_layout("ict")
    with pytest.raises(ValueError, match="at least 4 landmarks"):
        fit_layout(lay, {"Chin": [0, 0, 0], "Nope": [1, 1, 1]}, snap=False)
    with pytest.raises(ValueError, match="snap=True needs"):
        fit_layout(lay, dict(lay.landmarks_m))
    with pytest.raises(ValueError, match="unknown warp method"):
        landmark_warp(np.eye(3), np.eye(3), method="spline")


# ------------------------------------------------------------------------------------------- FACS
def test_action_units_map_through_the_shared_facs_table():
    names = load_layout("ict").muscle_names
    pose = pose_from_action_units({"AU12": 1.0, "AU26": 0.5}, names)
    assert pose.contractions == {"zygomaticus_major_l": 1.0, "zygomaticus_major_r": 1.0}
    assert pose.jaw_opening_deg == pytest.approx(6.0)
    one_side = pose_from_action_units({"AU12L": 0.6}, names)
    assert one_side.contractions == {"zygomaticus_major_l": 0.6}
    required = ["AU1", "AU2", "AU4", "AU5", "AU6", "AU7", "AU9", "AU10", "AU12", "AU15", "AU17", "AU20", "AU23", "AU25"]
    for au in required:
        assert pose_from_action_units({au: 1.0}, names).contractions, f"{au} drives no muscle of the ICT layout"
    with pytest.raises(KeyError, match="unknown action unit 'AU99'"):
        pose_from_action_units({"AU99": 1.0}, names)
    with pytest.raises(ValueError, match="outside"):
        pose_from_action_units({"AU12": 2.0}, names)
    assert parse_au_assignments(["au12=0.5", "AU26=1"]) == {"AU12": 0.5, "AU26": 1.0}
    with pytest.raises(ValueError, match="AU=VALUE"):
        parse_au_assignments(["AU12"])


def test_presets_and_interpolation():
    names = load_layout("ict").muscle_names
    assert {"neutral", "happy", "sad", "fear", "anger", "surprise", "disgust"} <= set(EXPRESSIONS)
    with pytest.raises(KeyError, match="unknown expression 'bored'"):
        expression_pose("bored")
    a, b = expression_pose("happy", muscle_names=names), expression_pose("surprise", muscle_names=names)

    def nonzero(pose):
        return {k: v for k, v in pose.contractions.items() if v > 0}

    assert nonzero(interpolate_poses("happy", "surprise", 0.0, muscle_names=names)) == a.contractions
    assert nonzero(interpolate_poses("happy", "surprise", 1.0, muscle_names=names)) == b.contractions
    mid = interpolate_poses("happy", "surprise", 0.5, muscle_names=names)
    # blending happens in action-unit space; the jaw is the largest AU demand (AU26 at 0.5 -> 6 deg)
    assert mid.jaw_opening_deg == pytest.approx(0.5 * 12.0)
    assert mid.action_units["AU26"] == pytest.approx(0.5) and mid.action_units["AU12"] == pytest.approx(0.5)
    assert mid.contractions["zygomaticus_major_l"] == pytest.approx(0.5)
    half = expression_pose("happy", intensity=0.5, muscle_names=names)
    assert half.contractions["zygomaticus_major_l"] == pytest.approx(0.5)


def test_layout_dict_is_stable_after_fit_round_trip(tmp_path):
    from wface.waters.layout import save_layout

    lay = fit_layout(load_layout("ict"), {k: _xf(v) for k, v in load_layout("ict").landmarks_m.items()}, snap=False)
    again = load_layout(save_layout(lay, tmp_path / "fitted.json"))
    assert layout_to_dict(again) == layout_to_dict(lay)


@settings(max_examples=25, deadline=None)
@given(
    st.floats(0.2, 5.0),
    st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
)
def test_fit_under_random_similarities(scale, rotvec, shift):
    lay = load_layout("ict")
    rot = Rotation.from_rotvec(rotvec).as_matrix()

    def xf(p):
        return scale * np.asarray(p) @ rot.T + np.asarray(shift)

    fitted = fit_layout(lay, {k: xf(v) for k, v in lay.landmarks_m.items()}, method="similarity", snap=False)
    for m0, m1 in zip(lay.muscles, fitted.muscles, strict=True):
        p0 = m0.bone_m if isinstance(m0, LinearMuscle) else m0.centre_m
        p1 = m1.bone_m if isinstance(m1, LinearMuscle) else m1.centre_m
        np.testing.assert_allclose(p1, xf(p0), atol=1e-9 * max(1.0, scale))
