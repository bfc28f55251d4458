"""What a tracked take leaves on disk: USD without pictures, --no-usd, the closing lines, the report's headline."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wface.cli import main
from wface.tracking.report import _marker_stats, add_capture_units
from wface.viz.report import headline_cards


def test_usd_is_written_without_pictures_and_skipped_with_no_usd(tmp_path, capsys):
    pytest.importorskip("pxr")
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--tets", "1500", "--frames", "2", "--no-pictures"]) == 0
    closing = capsys.readouterr().out
    for name in ("controls.npz", "controls.csv", "report.json", "truth.npz", "animation.usdc", "report.html"):
        assert (out / name).exists(), name
        assert f"  {name}" in closing, name  # the closing lines name every file
    assert "frames/ (2 frame files" in closing
    summary = next(ln for ln in closing.splitlines() if "=" in ln)
    assert summary.startswith("truth_marker_rms_mm=") and "marker_rms_mm_inliers=" in summary  # headline first
    assert not list(out.glob("*.png")) and not (out / "take.mp4").exists()
    report = json.loads((out / "report.json").read_text())
    assert report["marker_samples"] == 2 * report["markers"]
    assert set(report["marker_stats"]["Chin"]) == {
        "seen", "missing", "held_out", "outliers", "rms_mm", "inlier_rms_mm", "max_mm"
    }  # fmt: skip
    html = (out / "report.html").read_text()
    assert "marker RMS error vs the clean truth" in html and "<h2>Files</h2>" in html
    # the page lists what the closing lines list: provenance.json and the per-frame folder too
    assert "<code>provenance.json</code>" in html and "<code>frames/</code>" in html

    (out / "animation.usdc").unlink()
    assert (
        main(["demo", "--out", str(out), "--tets", "1500", "--frames", "2", "--no-pictures", "--no-usd", "--resume"])
        == 0
    )
    assert not (out / "animation.usdc").exists()
    assert "animation.usdc" not in capsys.readouterr().out


def test_marker_stats_separate_outliers_and_missing_samples():
    err = np.array([[0.3, 5.0, np.nan], [0.4, 0.2, np.nan], [0.5, 0.1, 1.0]])  # mm
    stats, totals = _marker_stats(err, ["a", "b", "c"], 3.0)
    assert totals["outlier_samples"] == 1 and totals["missing_samples"] == 2 and totals["marker_samples"] == 9
    inliers = np.array([0.3, 0.4, 0.5, 0.2, 0.1, 1.0])
    assert totals["marker_rms_mm_inliers"] == pytest.approx(np.sqrt(np.mean(inliers**2)))
    assert stats["b"] == {
        "seen": 3,
        "missing": 0,
        "held_out": 0,
        "outliers": 1,
        "rms_mm": pytest.approx(np.sqrt((25.0 + 0.04 + 0.01) / 3)),  # every sample seen: the outlier shows
        "inlier_rms_mm": pytest.approx(np.sqrt(0.025)),
        "max_mm": 5.0,
    }
    assert stats["c"]["missing"] == 2 and stats["c"]["rms_mm"] == pytest.approx(1.0)
    _, plain = _marker_stats(err, ["a", "b", "c"], None)  # plain least squares: no outliers
    assert plain["outlier_samples"] == 0


def test_headline_is_the_error_a_person_should_read():
    real = {"marker_rms_mm_mean": 2.3, "marker_rms_mm_inliers": 0.4, "outlier_samples": 7, "missing_samples": 3}
    real |= {"marker_samples": 400, "outlier_threshold_mm": 3.0, "frames": 10}
    cards = headline_cards(real)
    # every fitted sample first: on a take the face cannot follow the inlier error measures the cut-off
    assert cards[0] == ("2.3", "mm", "marker RMS, every fitted sample (outliers included)")
    assert cards[1] == ("0.4", "mm", "inlier RMS (error <= 3 mm; 2 % of fitted samples over it)")  # 7 of 397
    assert cards[2] == ("7 / 3", "", "outlier / missing samples of 400")
    held = headline_cards({**real, "holdout_rms_mm_mean": 2.9, "holdout_samples": 47})
    assert [c[0] for c in held[:3]] == ["2.3", "2.9", "0.4"] and "2 % of fitted" in held[2][2]  # 7 of 350
    synthetic = {**real, "truth_marker_rms_mm": 0.24}
    assert headline_cards(synthetic)[0] == ("0.24", "mm", "marker RMS error vs the clean truth")
    assert all("2.3" != c[0] for c in headline_cards(synthetic))  # the outlier-corrupted RMS is not a headline
    scaled = add_capture_units({**real}, 0.9)  # a face 0.9 times the actor's size: the actor's mm shown too
    assert scaled["marker_rms_capture_mm_mean"] == pytest.approx(2.3 / 0.9)
    assert scaled["marker_rms_capture_mm_inliers"] == pytest.approx(0.4 / 0.9)
    assert ("2.556", "mm", "marker RMS in the capture's mm (face = 0.9 x actor)") in headline_cards(scaled)
    assert not any("capture" in c[2] for c in headline_cards(add_capture_units({**real}, 1.0)))
    with pytest.raises(ValueError, match="capture_to_model_scale"):
        add_capture_units({}, 0.0)


def test_markers_set_aside_in_most_frames_are_named():
    """The headline counts inliers: a marker the robust fit ignores in most frames is said by name."""
    from wface.cli.track import _warn_rejected_markers

    stats = {
        "Chin": {"seen": 20, "outliers": 17, "max_mm": 11.8},
        "NoseTop": {"seen": 20, "outliers": 2, "max_mm": 3.4},
        "Hidden": {"seen": 0, "outliers": 0, "max_mm": None},
    }
    with pytest.warns(UserWarning, match=r"most frames .*: Chin \(17 of 20 frames, up to 11.8 mm\); the face"):
        _warn_rejected_markers({"marker_stats": stats})
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _warn_rejected_markers({"marker_stats": {"NoseTop": stats["NoseTop"]}})
