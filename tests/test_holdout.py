"""Held-out markers (wface.tracking.holdout): which markers hide, their errors per frame and per
marker, and `wface demo --holdout` end to end (report.json, HTML, plot)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wface.cli import main
from wface.takes.store import FrameRecord
from wface.tracking.holdout import hide, holdout_report, select_holdout

_TOL_MM = 1e-9  # float64 round-off on millimetre errors


def test_every_nth_marker_by_height_or_by_name():
    names = [f"m{i}" for i in range(10)]
    ref = np.zeros((10, 3))
    ref[:, 1] = np.arange(10)[::-1] * 0.01  # m0 highest ... m9 lowest
    ref[3] = np.nan  # missing at the reference: sorts last
    # top to bottom: m0 m1 m2 m4 m5 m6 m7 m8 m9 m3 -> every 3rd: m2, m6, m9
    assert select_holdout("3", names, ref).tolist() == [2, 6, 9]
    assert select_holdout("m4, m1", names, ref).tolist() == [1, 4]
    with pytest.raises(ValueError, match="unknown marker"):
        select_holdout("nose", names, ref)
    with pytest.raises(ValueError, match="N >= 2"):
        select_holdout("1", names, ref)
    with pytest.raises(ValueError, match="keep at least 3"):
        select_holdout(",".join(names[:8]), names, ref)


def test_hidden_errors_per_frame_and_per_marker():
    rng = np.random.default_rng(0)
    F, k = 4, 6
    targets = rng.normal(size=(F, k, 3))
    offsets = np.zeros((F, k, 3))
    offsets[:, 1, 0] = [1e-3, 2e-3, 3e-3, 4e-3]  # marker 1 off by 1..4 mm
    offsets[:, 4, 2] = 2e-3  # marker 4 off by 2 mm
    targets[2, 4] = np.nan  # marker 4 missing in frame 2
    records = [
        FrameRecord(f, np.zeros(3), None, None, np.nan_to_num(targets[f]) + offsets[f], None, {}) for f in range(F)
    ]
    rep = holdout_report(records, targets, np.array([1, 4]), [f"m{i}" for i in range(k)])
    assert rep["holdout_markers"] == ["m1", "m4"]
    expect = [np.sqrt((1 + 4) / 2), np.sqrt((4 + 4) / 2), 3.0, np.sqrt((16 + 4) / 2)]
    np.testing.assert_allclose(rep["holdout_rms_mm"], expect, atol=_TOL_MM)
    assert rep["holdout_rms_mm_per_marker"]["m1"] == pytest.approx(np.sqrt((1 + 4 + 9 + 16) / 4), abs=_TOL_MM)
    assert rep["holdout_rms_mm_per_marker"]["m4"] == pytest.approx(2.0, abs=_TOL_MM)
    assert rep["holdout_max_mm"] == pytest.approx(4.0, abs=_TOL_MM)
    hidden = hide(targets, [1, 4])
    assert np.isnan(hidden[:, [1, 4]]).all() and np.array_equal(hidden[:, 0], targets[:, 0])


def test_demo_with_held_out_markers(tmp_path):
    out = tmp_path / "demo"
    rc = main(
        ["demo", "--out", str(out), "--tets", "2000", "--frames", "2", "--holdout", "6", "--no-movie",
         "--noise-mm", "0", "--outliers", "0", "--dropout", "0"]
    )  # fmt: skip
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    hidden = rep["holdout_markers"]
    assert len(hidden) == len(rep["marker_rms_mm_per_marker"]) // 6 and len(rep["holdout_rms_mm"]) == 2
    assert all(rep["marker_rms_mm_per_marker"][n] is None for n in hidden)  # never fitted
    assert 0 < rep["holdout_rms_mm_mean"] < 5.0  # predicted, not fitted: small but not zero on clean data
    assert (out / "holdout.png").stat().st_size > 0
    assert "holdout_rms_mm_per_marker" in (out / "report.html").read_text()
    # --dropout 0: the capture lacks nothing; the hidden samples are counted apart, not as missing
    assert rep["missing_samples"] == 0 and rep["holdout_samples"] == 2 * len(hidden)
    assert "held-out marker RMS" in (out / "report.html").read_text()
    # so in each marker's row too (it read "seen 0, missing 2")
    for n, st in rep["marker_stats"].items():
        assert (st["seen"], st["missing"], st["held_out"]) == ((0, 0, 2) if n in hidden else (2, 0, 0)), n
