"""`wface demo` and `wface track` end to end on tiny inputs; the real AnimFace jaw take when present."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.conftest import data_path
from wface.cli import main
from wface.physics.penalty import TRACKING_SMOOTHING_M

REPORT_KEYS = (
    "frames markers tets nodes device solver marker_rms_mm marker_rms_mm_mean marker_max_mm seconds_per_frame "
    "seconds_per_frame_median gauss_newton_steps quasistatic_solves linear_solves cg_iterations "
    "activation_bound_violation_max inverted_elements muscle_identifiability"
).split()
TRUTH_KEYS = ("activation_rms_error", "activation_rms_error_all", "truth_marker_rms_mm", "jaw_angle_error_deg")


@pytest.mark.slow
def test_demo_writes_everything(tmp_path):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--tets", "2000", "--frames", "3", "--no-movie"]) == 0
    report = json.loads((out / "report.json").read_text())
    for key in (*REPORT_KEYS, *TRUTH_KEYS):
        assert key in report, key
    assert report["frames"] == 3 and len(report["marker_rms_mm"]) == 3
    assert report["truth_marker_rms_mm"] < 1.0 and report["inverted_elements"] == 0
    usage = report["usage_prior"]  # what the data chose, per muscle by name, and what the fits cost
    assert set(usage["activation_sd"]) == set(report["muscle_identifiability"]) and usage["noise_mm"] > 0
    _check_usage_passes(report)
    for name in ("controls.npz", "controls.csv", "animation.usdc", "report.html", "activations.png"):
        assert (out / name).exists(), name
    assert len(list((out / "frames").glob("frame_*.npz"))) == 3
    header = (out / "controls.csv").read_text().splitlines()[0]
    assert header.startswith("frame,") and "jaw_opening_deg" in header
    assert "-0.0," not in (out / "controls.csv").read_text().replace("\n", ",")  # no negative zeros


def test_demo_with_lip_contact(tmp_path):
    """--contact lips: ground truth and tracking both solve with lip contact (Jacobians included)."""
    out = tmp_path / "demo_contact"
    args = ["demo", "--out", str(out), "--tets", "1500", "--frames", "2", "--no-pictures", "--contact", "lips"]
    assert main(args) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["contact"] == "lips" and report["frames"] == 2
    assert report["contact_smoothing_mm"] == pytest.approx(1e3 * TRACKING_SMOOTHING_M)  # the default ramp
    assert report["truth_marker_rms_mm"] < 1.0 and report["inverted_elements"] == 0
    usage = report["usage_prior"]  # what the data chose, per muscle by name, and what the fits cost
    assert set(usage["activation_sd"]) == set(report["muscle_identifiability"]) and usage["noise_mm"] > 0
    _check_usage_passes(report)


def _check_usage_passes(report) -> None:
    """One usage pass, or all three when the first moved the activations by more than the refit test's 0.15."""
    from wface.tracking.estimator import TrackOptions

    changes = report["usage_pass_activation_change_rms"]
    refit = changes[0] > TrackOptions.prior_refit_change
    assert len(changes) == len(report["usage_prior_fit_seconds"]) == (3 if refit else 1), changes


def test_track_a_csv_file(tmp_path):
    from wface.faces.builtin import build_face
    from wface.io.mocap import MocapTake, write_mocap
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import embed_model_markers
    from wface.tracking.synthetic import synthesize_performance

    model = build_face(2000)
    perf = synthesize_performance(FaceRig(model), embed_model_markers(model), frames=3, seed=4)
    # Frame 0 is the neutral face (the alignment embeds markers at the first frame of the range).
    rest = embed_model_markers(model).positions(model.rest_positions_m)[None]
    # An actor 1.25 times the face's size: the capture comes in at scale 0.8, errors also in its own mm.
    take = MocapTake(1.25 * np.concatenate([rest, perf.clean_markers_m]), list(model.marker_names), 30.0)
    write_mocap(take, tmp_path / "take.csv")
    out = tmp_path / "run"
    assert (
        main(
            [
                "track",
                "--mocap",
                str(tmp_path / "take.csv"),
                "--tets",
                "2000",
                "--out",
                str(out),
                "--frames",
                "0:3",
                "--no-pictures",
            ]
        )
        == 0
    )
    report = json.loads((out / "report.json").read_text())
    assert report["frames"] == 3 and report["marker_rms_mm_mean"] < 0.1
    assert report["capture_to_model_scale"] == pytest.approx(0.8, rel=1e-6)
    assert report["marker_rms_capture_mm_mean"] == pytest.approx(report["marker_rms_mm_mean"] / 0.8, rel=1e-9)
    assert sorted(p.name for p in (out / "frames").glob("*.npz"))[-1] == "frame_000002.npz"


def test_neutral_frame_outside_the_range_anchors_the_embedding(tmp_path, capsys):
    """Tracking frames 1:3 of a take whose neutral face is frame 0: with --neutral-frame 0 the
    activations come back; embedding at frame 1 instead reads frame 1 as the neutral face."""
    from wface.faces.builtin import build_face
    from wface.io.mocap import MocapTake, write_mocap
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import embed_model_markers
    from wface.tracking.synthetic import synthesize_performance

    model = build_face(2000)
    perf = synthesize_performance(FaceRig(model), embed_model_markers(model), frames=2, seed=5)
    rest = embed_model_markers(model).positions(model.rest_positions_m)[None]
    write_mocap(
        MocapTake(np.concatenate([rest, perf.clean_markers_m]), list(model.marker_names), 30.0), tmp_path / "t.csv"
    )
    errors = {}
    for neutral in (["--neutral-frame", "0"], []):
        out = tmp_path / f"run{len(neutral)}"
        args = ["track", "--mocap", str(tmp_path / "t.csv"), "--tets", "2000", "--out", str(out), "--frames", "1:3"]
        assert main([*args, "--no-pictures", *neutral]) == 0
        got = np.load(out / "controls.npz")["activations"]
        errors[bool(neutral)] = float(np.sqrt(np.mean((got - perf.activations) ** 2)))
    assert errors[True] < 0.05 < errors[False]
    assert (
        main(["track", "--mocap", str(tmp_path / "t.csv"), "--out", str(tmp_path / "x"), "--neutral-frame", "9"]) == 1
    )
    assert "--neutral-frame 9" in capsys.readouterr().err


def test_track_reports_bad_input(tmp_path, capsys):
    assert main(["track", "--mocap", str(tmp_path / "missing.c3d"), "--out", str(tmp_path / "o")]) == 1
    assert "missing.c3d" in capsys.readouterr().err


@pytest.mark.slow
def test_real_jaw_capture_on_the_builtin_face(tmp_path):
    path = data_path("animface", "JawMoCap.c3d")
    out = tmp_path / "jaw"
    assert (
        main(["track", "--mocap", str(path), "--tets", "2000", "--out", str(out), "--frames", "0:4", "--no-pictures"])
        == 0
    )
    report = json.loads((out / "report.json").read_text())
    assert report["markers"] == 41 and report["frames"] == 4
    assert report["marker_rms_mm_mean"] < 6.0  # a different person's face: shape mismatch remains
    assert np.all(np.isfinite(report["jaw_opening_deg"])) and report["inverted_elements"] == 0


def test_per_marker_rms_skips_missing_samples_and_never_seen_markers():
    """A marker missing in every frame gets null (valid JSON), not NaN and a numpy warning."""
    import warnings

    from wface.tracking.report import _per_marker_rms_mm

    err = np.array([[1.0, np.nan, 2.0], [3.0, np.nan, np.nan]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rms = _per_marker_rms_mm(err, ["a", "b", "c"])
    assert rms == {"a": pytest.approx(np.sqrt(5.0)), "b": None, "c": pytest.approx(2.0)}
    json.dumps(rms, allow_nan=False)


def test_every_sth_frame_keeps_the_capture_numbers_and_rate(tmp_path, capsys):
    """`--frames 1:7:3` tracks capture frames 1 and 4 (a Python slice):
    controls.npz, the frame files and the USD time codes carry the capture's numbers at its rate, so the
    take plays at its true speed; the same frames tracked one by one give the same activations."""
    from pxr import Usd

    from wface.faces.builtin import build_face
    from wface.io.mocap import MocapTake, write_mocap
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import embed_model_markers
    from wface.tracking.synthetic import synthesize_performance

    model = build_face(2000)
    perf = synthesize_performance(FaceRig(model), embed_model_markers(model), frames=6, seed=6)
    rest = embed_model_markers(model).positions(model.rest_positions_m)[None]
    markers = np.concatenate([rest, perf.clean_markers_m])  # 7 frames, frame 0 neutral
    write_mocap(MocapTake(markers, list(model.marker_names), 60.0), tmp_path / "t.csv")
    base = ["track", "--mocap", str(tmp_path / "t.csv"), "--tets", "2000", "--neutral-frame", "0", "--no-movie"]
    out = tmp_path / "strided"
    assert main([*base, "--out", str(out), "--frames", "1:7:3"]) == 0
    with np.load(out / "controls.npz") as c:
        assert c["frames"].tolist() == [1, 4] and float(c["fps"]) == 60.0
        strided = c["activations"]
    assert sorted(p.name for p in (out / "frames").glob("*.npz")) == ["frame_000001.npz", "frame_000004.npz"]
    stage = Usd.Stage.Open(str(out / "animation.usdc"))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()) == (1.0, 4.0, 60.0)
    report = json.loads((out / "report.json").read_text())
    assert report["frames"] == 2
    assert json.loads((out / "provenance.json").read_text())["source"]["frames"] == "1:7:3"
    # the same capture frames, consecutive in their own file: the same fit
    write_mocap(MocapTake(markers[[0, 1, 4]], list(model.marker_names), 20.0), tmp_path / "picked.csv")
    picked = tmp_path / "picked"
    args = ["track", "--mocap", str(tmp_path / "picked.csv"), "--tets", "2000", "--neutral-frame", "0"]
    assert main([*args, "--no-pictures", "--out", str(picked), "--frames", "1:3"]) == 0
    np.testing.assert_allclose(strided, np.load(picked / "controls.npz")["activations"], atol=1e-6)
    capsys.readouterr()


@pytest.mark.parametrize("text, parsed", [("0:300", (0, 300, 1)), ("0:300:5", (0, 300, 5)), ("100::2", (100, None, 2))])
def test_frame_ranges_take_a_step(text, parsed):
    from wface.cli.validate import frame_range

    assert frame_range(text) == parsed


@pytest.mark.parametrize("text", ["0:300:0", "0:300:-2", "0:300:x", "1:2:3:4", "5:3"])
def test_bad_frame_ranges_are_usage_errors(text):
    import argparse

    from wface.cli.validate import frame_range

    with pytest.raises(argparse.ArgumentTypeError):
        frame_range(text)
