"""``wface bench --suite track`` reports what a frame costs and how close it comes to its limit."""

from __future__ import annotations

import numpy as np
import pytest

from wface.bench.track import bench_size, peak_rss_mb
from wface.solvers.linear import direct_backend


@pytest.mark.skipif(direct_backend() is None, reason="the limit is a factorisation: needs a direct backend")
def test_track_bench_reports_the_breakdown_the_counts_and_the_limit():
    from wface.tracking.estimator import TrackOptions

    r = bench_size(1000, frames=3, repeat=1, options=TrackOptions(prior="temporal"))  # one pass: a frame's own work
    assert r["prior"] == "temporal" and "pass1_seconds_per_frame" not in r
    assert r["frames"] == 3 and r["seconds_per_frame"] > 0
    assert set(r["breakdown_seconds_per_frame"]) == {"quasistatic_solves", "jacobians", "gauss_newton_system"}
    # a warm frame: one solve, at most one factorisation (kept factors and Jacobians: often none, and
    # no Jacobian columns; wface.tracking.adaptive)
    assert r["factorizations_per_frame"] <= 1.0 and r["quasistatic_solves_per_frame"] == 1.0
    assert r["limit"]["columns"] == 48  # 35 muscles, the pressure, 12 jaw numbers
    limit = r["limit"]
    assert r["limit_seconds"] == pytest.approx(limit["numeric_factor_seconds"] + limit["back_solve_columns_seconds"])
    assert r["limit_ratio"] == pytest.approx(r["seconds_per_frame"] / r["limit_seconds"])
    assert 0 < r["peak_rss_mb"] <= peak_rss_mb() + 1.0
    acc = r["accuracy"]
    assert all(np.isfinite(acc[k]) for k in ("activation_rms_error_all", "truth_marker_rms_mm", "jaw_angle_error_deg"))
    assert acc["truth_marker_rms_mm"] < acc["input_noise_rms_mm"]  # the fit filters the 0.5 mm noise


@pytest.mark.skipif(direct_backend() is None, reason="the limit is a factorisation: needs a direct backend")
def test_track_bench_reports_each_pass_of_the_usage_prior():
    """With the usage prior each warm frame is tracked once per pass: the bench reports each pass's median
    alone, the first equal to ``pass1_seconds_per_frame``; over two warm frames the medians are means, so
    the passes add up to the frame (every pass run: no refit test)."""
    from wface.tracking.estimator import TrackOptions

    r = bench_size(1000, frames=3, repeat=1, options=TrackOptions(prior_passes=2, prior_refit_change=0.0))
    passes = r["pass_seconds_per_frame"]
    assert len(passes) == 3 and all(p > 0 for p in passes)
    assert r["prior_passes_run"] == 2 and len(r["activation_change_rms"]) == 2
    assert passes[0] == pytest.approx(r["pass1_seconds_per_frame"])
    assert sum(passes) == pytest.approx(r["seconds_per_frame"], rel=1e-9)
