"""Expression editing in activation space (wface.takes, ``wface edit``) on a tiny built-in face, float64."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from wface.controls import jaw_joint_values, jaw_limits
from wface.takes import (
    Pose,
    Take,
    blend,
    exaggerate,
    expression_pose,
    interpolate,
    layer,
    load_take,
    retime,
    simulate_poses,
)

_ROUND_OFF = 1e-12  # float64 round-off of rotation compositions and linear mixes
_SOLVE_M = 1e-9  # two solves of the same pose from the same start agree far below their 1e-6 residual


@pytest.fixture(scope="module")
def model():
    from wface.faces.builtin import build_face

    return build_face(3000)


@pytest.fixture(scope="module")
def model_path(model, tmp_path_factory):
    from wface.model import save_model

    return save_model(model, tmp_path_factory.mktemp("face") / "face.npz")


@pytest.fixture(scope="module")
def smile(model):
    return expression_pose(model, "smile")


@pytest.fixture(scope="module")
def surprise(model):
    return expression_pose(model, "surprise")


def _moved(pose: Pose, rotvec, t_m, jaw) -> Pose:
    from dataclasses import replace

    R = Rotation.from_rotvec(rotvec).as_matrix()
    return replace(pose, cranium_rotation=R, cranium_translation_m=np.asarray(t_m, float)).with_jaw(jaw)


def _corner_mm(model, X: np.ndarray) -> np.ndarray:
    """Displacement (mm) of the left mouth-corner marker from rest for positions X (F, n, 3)."""
    from wface.tracking.sequence import embed_model_markers

    mm = embed_model_markers(model)
    k = model.marker_names.index("Mouth_Lend")
    rest = mm.positions(model.rest_positions_m)[k]
    return np.array([np.linalg.norm(mm.positions(x)[k] - rest) * 1e3 for x in X])


# ---------------------------------------------------------------------- poses and sources
def test_expressions_map_to_muscles_and_jaw(model, smile, surprise):
    zyg = [model.muscle_index(n) for n in ("zygomaticus_major_l", "zygomaticus_major_r")]
    assert np.all(smile.activations[zyg] == 1.0)  # AU12 at 1.0
    assert surprise.jaw_opening_deg == pytest.approx(12.0)  # AU26 at 1.0 opens the jaw 12 deg
    inline = expression_pose(model, "AU12=1,AU6=0.8,AU25=0.4")
    np.testing.assert_array_equal(inline.activations, smile.activations)
    assert expression_pose(model, "zygomaticus_major_l=0.3").activations[zyg[0]] == 0.3
    with pytest.raises(KeyError, match="known: .*happy"):
        expression_pose(model, "grin")
    with pytest.raises(KeyError, match="zygomaticus_major_l"):
        expression_pose(model, "zygomaticus_mayor_l=0.5")
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        expression_pose(model, "AU12=1.5")
    assert expression_pose(model, "jaw_open=20").jaw_opening_deg == 20.0
    for wide in ("jaw_open=90", "jaw_open=-10"):  # were clamped to 35 and the closed limit without a word
        with pytest.raises(ValueError, match="the jaw opens from -2.29 to 35 degrees"):
            expression_pose(model, wide)


# ---------------------------------------------------------------------- interpolate and blend
def test_interpolation_endpoints_reproduce_poses_and_equilibria(model, smile, surprise):
    j = model.jaw_joint
    a = _moved(smile, [0.05, -0.1, 0.02], [0.001, 0.0, -0.002], (3.0, 0.002, 1.0))
    b = _moved(surprise, [-0.08, 0.12, 0.0], [0.0, 0.003, 0.001], (10.0, 0.006, -2.0))
    for t, ref in ((0.0, a), (1.0, b)):
        got = interpolate(a, b, t, joint=j)
        np.testing.assert_allclose(got.controls(model), ref.controls(model), rtol=0, atol=_ROUND_OFF)
    x_ref = simulate_poses(model, [a, b]).x_m
    x_got = simulate_poses(model, [interpolate(a, b, 0.0, joint=j), interpolate(a, b, 1.0, joint=j)]).x_m
    np.testing.assert_allclose(x_got, x_ref, rtol=0, atol=_SOLVE_M)
    with pytest.raises(ValueError):
        interpolate(a, b, 1.5)


def test_midpoint_bones_are_rigid_and_the_jaw_stays_on_its_joint(model, smile, surprise):
    j = model.jaw_joint
    lim = jaw_limits(j)
    # b yaws the jaw to its limit: a straight line in (yaw, protrusion) leaves the joint unless clamped
    a = _moved(smile, [0.3, 0.0, 0.1], [0.0, 0.0, 0.0], (0.0, 0.0, 0.0))
    b = _moved(surprise, [-0.2, 0.4, 0.0], [0.01, 0.0, 0.0], (20.0, 0.006, lim["lateral_deg"]))
    angle = np.linalg.norm(Rotation.from_matrix(a.cranium_rotation.T @ b.cranium_rotation).as_rotvec())
    for t in (0.25, 0.5, 0.75):
        pose = interpolate(a, b, t, joint=j)
        bones = pose.bones(j)
        for M in (bones[:9].reshape(3, 3), bones[12:21].reshape(3, 3)):
            np.testing.assert_allclose(M.T @ M, np.eye(3), rtol=0, atol=_ROUND_OFF)
            assert np.linalg.det(M) == pytest.approx(1.0, abs=_ROUND_OFF)
        psi = jaw_joint_values(j, bones[12:])
        np.testing.assert_allclose(psi[:3], 0.0, atol=_ROUND_OFF)
        assert np.all(psi[3:5] >= -_ROUND_OFF) and np.all(psi[3:5] <= j.track_length_m + _ROUND_OFF)
        assert -j.max_opening_sine - _ROUND_OFF <= psi[5] <= _ROUND_OFF
        # slerp: the rotation moves a fraction t of the way along the geodesic
        part = Rotation.from_matrix(a.cranium_rotation.T @ pose.cranium_rotation).as_rotvec()
        assert np.linalg.norm(part) == pytest.approx(t * angle, abs=_ROUND_OFF)
        assert np.all((pose.activations >= 0) & (pose.activations <= 1))


def test_blend_is_a_validated_convex_combination(model, smile, surprise):
    a = _moved(smile, [0.1, 0.0, 0.0], [0.0, 0.0, 0.0], (2.0, 0.001, 0.0))
    b = _moved(surprise, [0.0, 0.2, 0.0], [0.0, 0.002, 0.0], (8.0, 0.003, 0.0))
    mid, ref = blend([0.5, 0.5], [a, b]), interpolate(a, b, 0.5)
    np.testing.assert_allclose(mid.activations, ref.activations, atol=_ROUND_OFF)
    np.testing.assert_allclose(mid.cranium_rotation, ref.cranium_rotation, atol=_ROUND_OFF)
    np.testing.assert_allclose(mid.jaw, ref.jaw, atol=_ROUND_OFF)
    np.testing.assert_allclose(blend([1.0], [a]).controls(model), a.controls(model), atol=_ROUND_OFF)
    for weights in ([-0.1, 1.1], [0.5, 0.6], [np.nan, 1.0], [1.0]):
        with pytest.raises(ValueError):
            blend(weights, [a, b])


# ---------------------------------------------------------------------- exaggerate
def test_exaggerate_keeps_activations_in_range(model, smile, surprise):
    assert exaggerate(smile, 1.0) is smile  # factor 1 is the identity
    for f in (0.0, 0.5, 1.5, 2.0, 3.0):
        for neutral in (None, surprise):
            for mode in ("muscle", "global"):
                p = exaggerate(smile, f, neutral, joint=model.jaw_joint, scale_mode=mode)
                assert np.all((p.activations >= 0) & (p.activations <= 1))
                if p.force_length_scale is not None:
                    assert np.all(p.force_length_scale >= 1)
                e_n = 0.0 if neutral is None else neutral.drive
                np.testing.assert_allclose(p.drive, np.maximum(0, e_n + f * (smile.drive - e_n)), atol=_ROUND_OFF)
    assert not np.any(exaggerate(smile, 0.0).activations)
    wide = exaggerate(surprise, 4.0, joint=model.jaw_joint)  # 48 deg asked, the joint allows 35
    assert wide.jaw_opening_deg == pytest.approx(jaw_limits(model.jaw_joint)["opening_deg"][1])
    for bad in (-0.5, np.nan, np.inf):
        with pytest.raises(ValueError):
            exaggerate(smile, bad)
    with pytest.raises(ValueError):
        exaggerate(smile, 1.5, scale_mode="bogus")


def test_exaggerated_smile_moves_the_mouth_corner_further(model, smile):
    j = model.jaw_joint
    factors = (0.5, 1.0, 1.5, 2.0)
    poses = [exaggerate(smile, f, joint=j) for f in factors]
    zyg = model.muscle_index("zygomaticus_major_l")
    assert poses[2].activations[zyg] == 1.0 and poses[2].force_length_scale[zyg] == 1.5  # past 1: the curve scales
    poses.append(exaggerate(smile, 1.5, joint=j, scale_mode="global"))
    res = simulate_poses(model, poses)
    assert res.converged
    corner = _corner_mm(model, res.x_m)
    assert np.all(np.diff(corner[:4]) > 0.5), corner  # monotone, by clearly more than the solve tolerance
    # global and per-muscle scales give the same forces, hence the same face
    np.testing.assert_allclose(res.x_m[4], res.x_m[2], rtol=0, atol=1e-7)


def test_per_muscle_force_length_scale_matches_scaled_activations():
    from wface.physics import Simulator
    from wface.testing.models import box_model

    model = box_model((3, 2, 2), muscles=2)
    x = model.rest_positions_m + 0.002 * np.random.default_rng(3).normal(size=model.rest_positions_m.shape)
    plain, scaled = Simulator(model), Simulator(model, force_length_scale=np.array([2.0, 0.5]))
    tol = 1e-12 * np.abs(plain.forces(x, [1.0, 1.0])).max()
    np.testing.assert_allclose(scaled.forces(x, [0.4, 1.0]), plain.forces(x, [0.8, 0.5]), rtol=0, atol=tol)
    np.testing.assert_allclose(
        scaled.muscle_forces(x), plain.muscle_forces(x) * np.array([2.0, 0.5])[:, None, None], rtol=0, atol=tol
    )
    scaled.force_length_scale = 1.0  # back to a scalar: the original behaviour
    np.testing.assert_array_equal(scaled.forces(x, [0.4, 1.0]), plain.forces(x, [0.4, 1.0]))
    for bad in (np.array([1.0, np.nan]), np.array([1.0, -1.0]), np.ones(3), -1.0):
        with pytest.raises(ValueError):
            scaled.force_length_scale = bad


# ---------------------------------------------------------------------- takes: layer and retime
def _take(model, smile, surprise, n=24) -> Take:
    a = _moved(smile, [0.0, 0.0, 0.0], [0, 0, 0], (0.0, 0.0, 0.0))
    b = _moved(surprise, [0.1, 0.3, 0.0], [0.0, 0.01, 0.0], (15.0, 0.004, 2.0))
    poses = [interpolate(a, b, t, joint=model.jaw_joint) for t in np.linspace(0, 1, n) ** 2]
    return Take.from_poses(poses, 30.0, list(model.muscle_names), model.jaw_joint, source="test")


def test_retime_speed_one_is_identity_and_speed_two_halves_the_frames(model, smile, surprise):
    take = _take(model, smile, surprise)
    same = retime(take)
    assert len(same) == len(take) and all(p is q for p, q in zip(same.poses, take.poses, strict=True))
    fast = retime(take, speed=2.0)
    assert len(fast) == 12 and fast.fps == 30.0
    assert all(p is q for p, q in zip(fast.poses, take.poses[::2], strict=True))
    fine = retime(take, fps_out=60.0)
    assert len(fine) == 2 * len(take) - 1 and fine.fps == 60.0
    mid = interpolate(take.poses[3], take.poses[4], 0.5, joint=model.jaw_joint)
    np.testing.assert_allclose(fine.poses[7].controls(model), mid.controls(model), atol=_ROUND_OFF)
    for kwargs in ({"speed": 0.0}, {"speed": np.nan}, {"fps_out": -1.0}):
        with pytest.raises(ValueError):
            retime(take, **kwargs)


def test_layer_adds_within_bounds(model, smile, surprise):
    j = model.jaw_joint
    take = _take(model, smile, surprise, n=6)
    same = layer(take, smile, 0.0, joint=j)
    for p, q in zip(same.poses, take.poses, strict=True):
        np.testing.assert_allclose(p.controls(model), q.controls(model), atol=_ROUND_OFF)
    lim = jaw_limits(j)
    for w in (1.0, 5.0, -3.0):
        out = layer(take, surprise, w, joint=j)
        for p in out.poses:
            assert np.all((p.activations >= 0) & (p.activations <= 1)) and p.force_length_scale is None
            assert lim["opening_deg"][0] <= p.jaw_opening_deg <= lim["opening_deg"][1]
    zyg = model.muscle_index("zygomaticus_major_l")
    half = layer(take, smile, 0.5)
    assert half.poses[0].activations[zyg] == 1.0  # already full: clamped
    assert half.poses[-1].activations[zyg] == pytest.approx(0.5)  # surprise + half a smile
    with pytest.raises(ValueError):
        layer(take, smile, np.ones(3))  # an envelope needs one weight per frame


# ---------------------------------------------------------------------- tracked takes on disk
def test_load_take_reads_tracking_outputs(model, smile, surprise, tmp_path):
    from wface.takes.store import FrameRecord, take_from_records, write_controls, write_frame

    M = model.n_muscles
    take = _take(model, smile, surprise, n=3)
    C = np.stack([p.controls(model) for p in take.poses])
    C[1, M : M + 9] *= 1.0 + 1e-4  # a tracked cranium is rigid only up to its penalty
    C[2, :M] = np.clip(C[2, :M] + 1e-9, None, 1.0 + 1e-9)  # and activations may stray by round-off
    n = model.n_nodes
    recs = [
        FrameRecord(f, c, np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((0, 3)), np.zeros(0), {})
        for f, c in enumerate(C)
    ]
    (tmp_path / "npz").mkdir()
    write_controls(tmp_path / "npz", model, take_from_records(model, recs))
    for rec in recs:
        write_frame(tmp_path / "frames_only", rec)
    for d in ("npz", "frames_only"):
        got = load_take(tmp_path / d, model)
        assert len(got) == 3 and got.fps == 30.0
        np.testing.assert_allclose(got.activations, np.clip(C[:, :M], 0, 1), atol=_ROUND_OFF)
        np.testing.assert_allclose(got.poses[2].jaw, take.poses[2].jaw, atol=1e-9)
        assert 0 < got.info["bone_projection_error_mm"] < 0.05  # the 1e-4 scale of frame 1, projected away
    with pytest.raises(FileNotFoundError):
        load_take(tmp_path / "missing", model)
    (tmp_path / "npz" / "report.json").write_text(json.dumps({"nodes": 12}))
    with pytest.raises(ValueError, match="12 nodes"):
        load_take(tmp_path / "npz", model)


# ---------------------------------------------------------------------- CLI
def test_cli_blend_labels_its_panels_by_blend_weight(model_path, tmp_path, monkeypatch):
    """The contact sheet's panels of ``edit blend`` are blend weights (0..1), not times: "blend 0.50"."""
    from wface.cli import main
    from wface.takes import output

    seen = {}
    monkeypatch.setattr(output, "write_contact_sheet", lambda path, model, result, labels: seen.update(labels=labels))
    argv = ["edit", "blend", "--from", "smile", "--to", "surprise", "--frames", "3", "--model", str(model_path)]
    assert main([*argv, "--mesh-only", "--out", str(tmp_path / "b")]) == 0
    assert seen["labels"] == ["blend 0.00", "blend 0.50", "blend 1.00"]


def test_cli_blend_then_chained_edits_write_valid_usd(model_path, tmp_path, capsys):
    from wface.cli import main
    from wface.io.usd import assert_stage_valid, read_take

    base = ["--model", str(model_path), "--no-pictures"]
    blend_dir = tmp_path / "blend"
    rc = main(["edit", "blend", "--from", "smile", "--to", "surprise", "--frames", "4", "--out", str(blend_dir), *base])
    assert rc == 0
    assert_stage_valid(blend_dir / "animation.usdc")
    usd = read_take(blend_dir / "animation.usdc")
    assert usd["n_frames"] == 4 and usd["fps"] == 30.0 and usd["skin_points_m"].shape[0] == 4
    with np.load(blend_dir / "controls.npz") as d:
        np.testing.assert_allclose(usd["activations"], d["activations"], atol=1e-7)  # USD floats
    rep = json.loads((blend_dir / "report.json").read_text())
    assert rep["frames"] == 4 and rep["converged"] and 0.0 <= rep["activation_min"] <= rep["activation_max"] <= 1.0
    lo, hi = rep["intraoral_pressure_range"]  # the signed pressure apart from the muscles' [0, 1]
    assert -1.0 <= lo <= hi <= 1.0
    x_dir = tmp_path / "x"
    argv = ["edit", "exaggerate", "--take", str(blend_dir), "--factor", "2", "--mesh-only", "--out", str(x_dir)]
    assert main([*argv, *base]) == 0
    assert_stage_valid(x_dir / "animation.usdc")  # the skin alone, through write_mesh_animation
    rep = json.loads((x_dir / "report.json").read_text())
    assert rep["activation_max"] <= 1.0 and rep["force_length_scale_max"] == pytest.approx(2.0)
    assert rep["scaled_muscles"]
    r_dir = tmp_path / "r"
    assert main(["edit", "retime", "--take", str(x_dir), "--speed", "2", "--usda", "--out", str(r_dir), *base]) == 0
    assert_stage_valid(r_dir / "animation.usda")
    assert json.loads((r_dir / "report.json").read_text())["frames"] == 2
    capsys.readouterr()


@pytest.mark.parametrize(
    ("argv", "message", "code"),
    [
        (["exaggerate", "--expression", "grin", "--factor", "1.5"], "known: ", 1),
        (["exaggerate", "--expression", "smile", "--factor", "nan"], "finite", 2),  # a usage error (argparse type)
        (["exaggerate", "--expression", "smile", "--factor", "-1"], ">= 0", 1),
        (["layer", "--take", "/nonexistent/take", "--add", "happy"], "does not exist", 1),
        (["blend", "--from", "smile", "--to", "AU12=1,buccinator_x=1"], "buccinator_l", 1),
        (["blend", "--from", "smile", "--to", "happy", "--tets", "2000"], "--tets does nothing with --model", 2),
    ],
)
def test_cli_errors_are_one_line(model_path, tmp_path, capsys, argv, message, code):
    from wface.cli import main

    rc = main(["edit", *argv, "--model", str(model_path), "--no-pictures", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == code and message in err and "Traceback" not in err


def test_unedited_take_resimulates_to_the_rig_equilibria(model, smile, surprise, tmp_path):
    """Loading a take and re-simulating it unchanged gives the tracker's rig positions (same conventions)."""
    from wface.takes.store import FrameRecord, write_frame
    from wface.tracking.rig import FaceRig

    rig = FaceRig(model)
    take = _take(model, smile, surprise, n=3)
    for f, pose in enumerate(take.poses):
        state = rig.equilibrium(pose.controls(model))
        write_frame(tmp_path, FrameRecord(f, state.controls, state.x_m, state.y_m, np.zeros((0, 3)), np.zeros(0), {}))
    loaded = load_take(tmp_path, model)
    res = simulate_poses(model, loaded.with_poses([exaggerate(p, 1.0) for p in loaded.poses]))
    ref = np.stack([np.load(tmp_path / "frames" / f"frame_{f:06d}.npz")["x_m"] for f in range(3)])
    # 1 um: both are 1e-6-residual solves, one warm- and one cold-started (measured 6e-8 m)
    np.testing.assert_allclose(res.x_m, ref, rtol=0, atol=1e-6)


def test_retime_of_a_strided_take_keeps_its_true_timing(model, smile, surprise):
    """A take of every 2nd capture frame at 30 fps (frames 10, 12, ...) is the same motion as its poses
    at 15 fps: retimed to 30 fps it gains one interpolated frame between each two, and at 15 fps it is
    the poses themselves. An edit in place (layer) keeps its frame numbers."""
    take = _take(model, smile, surprise, n=6)
    strided = Take.from_poses(
        take.poses, 30.0, list(model.muscle_names), model.jaw_joint, source="test", frames=10 + 2 * np.arange(6)
    )
    at_15 = retime(strided, fps_out=15.0)
    assert len(at_15) == 6 and all(p is q for p, q in zip(at_15.poses, take.poses, strict=True))
    at_30 = retime(strided)
    assert len(at_30) == 11 and at_30.fps == 30.0
    mid = interpolate(take.poses[2], take.poses[3], 0.5, joint=model.jaw_joint)
    np.testing.assert_allclose(at_30.poses[5].controls(model), mid.controls(model), atol=_ROUND_OFF)
    assert layer(strided, smile, 0.5, joint=model.jaw_joint).frames.tolist() == strided.frames.tolist()
    with pytest.raises(ValueError, match="frame numbers must increase"):
        Take(activations=take.activations, fps=30.0, frames=np.array([0, 2, 2, 3, 4, 5]))


def test_a_fade_longer_than_the_take_is_refused():
    """A layer faded in and out over more than half the take never reached its weight, without a word."""
    from wface.cli.edit import _envelope

    assert _envelope(11, 5).max() == 1.0 and _envelope(12, 0).min() == 1.0
    with pytest.raises(ValueError, match="--fade 5: a fade in and out needs at least 11 frames, the take has 10"):
        _envelope(10, 5)
