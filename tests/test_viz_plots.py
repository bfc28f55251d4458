"""Plots and the numbers behind them: marker errors, jaw opening angle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from wface.testing.synthetic_face import rotation_about  # noqa: E402
from wface.viz import plots  # noqa: E402


def test_marker_errors_mm_with_missing_markers():
    sim = np.zeros((3, 4, 3))
    cap = sim.copy()
    cap[0, :, 0] = 0.001  # every marker 1 mm off
    cap[1, 0] = [0.0, 0.003, 0.004]  # one marker 5 mm off, others exact
    cap[1, 1] = np.nan  # missing
    cap[2] = np.nan  # all missing
    rms, mx = plots.marker_errors_mm(cap, sim)
    np.testing.assert_allclose(rms[:2], [1.0, 5.0 / np.sqrt(3)])
    np.testing.assert_allclose(mx[:2], [1.0, 5.0])
    assert np.isnan(rms[2]) and np.isnan(mx[2])
    with pytest.raises(ValueError, match="both be"):
        plots.marker_errors_mm(cap[:, :2], sim)


def test_jaw_opening_recovers_angles_under_head_motion():
    angles = np.array([0.0, 5.0, 12.5, -3.0])
    u = np.array([1.0, 0.0, 0.0])
    jaw, cran = [], []
    for k, a in enumerate(angles):
        Rh = rotation_about((0.2, 1.0, 0.1), np.radians(10.0 * k))
        Rj = Rh @ rotation_about(u, np.radians(a))
        cran.append(np.hstack([Rh, np.full((3, 1), 0.01 * k)]))
        jaw.append(np.hstack([Rj, np.zeros((3, 1))]))
    got = plots.jaw_opening_deg(np.array(jaw), cranium_affines=np.array(cran), jaw_frame="world")
    np.testing.assert_allclose(got, angles, atol=1e-10)
    with pytest.raises(ValueError, match="differ in shape"):
        plots.jaw_opening_deg(np.array(jaw), cranium_affines=np.array(cran)[:2], jaw_frame="world")
    with pytest.raises(ValueError, match="needs cranium_affines"):
        plots.jaw_opening_deg(np.array(jaw), jaw_frame="world")


def test_jaw_opening_matches_the_intuitive_jaw_controls():
    controls = pytest.importorskip("wface.controls")
    from wface.model import JawJoint

    joint = JawJoint(
        u=(1.0, 0.0, 0.0),
        v=(0.0, -0.6, 0.8),
        midpoint_m=(0.0, -0.02, 0.0),
        condyle_distance_m=0.1,
        track_length_m=0.012,
        max_opening_sine=0.6,
    )
    openings = [0.0, 7.5, 20.0, 30.0]
    jaw = []
    for k, a in enumerate(openings):
        p = controls.jaw_from_intuitive(joint, opening_deg=a, protrusion_m=0.002 * k, lateral_deg=0.0)
        M, t = controls.affine_from_params(p)
        jaw.append(np.hstack([M, t[:, None]]))
    np.testing.assert_allclose(plots.jaw_opening_deg(np.array(jaw), joint), openings, atol=1e-9)


@pytest.mark.parametrize("n_muscles", [3, 20])
def test_activation_plot(tmp_path, n_muscles):
    rng = np.random.default_rng(0)
    a = rng.random((30, n_muscles))
    out = plots.plot_activations(a, [f"m{i}" for i in range(n_muscles)], tmp_path / "a.png", fps=30, truth=a * 0.9)
    img = plt_image(out)
    assert img.shape[0] > 200 and img.std() > 10
    with pytest.raises(ValueError, match="activations must have shape"):
        plots.plot_activations(a, ["x"], tmp_path / "b.png")


def test_error_and_jaw_plots(tmp_path):
    t = np.linspace(0, 1, 40)
    out1 = plots.plot_marker_error(1 + t, tmp_path / "e.png", marker_max_mm=2 + t, fps=40)
    out2 = plots.plot_jaw_opening(10 * t, tmp_path / "j.png", truth_deg=10 * t + 0.5)
    for out in (out1, out2):
        assert plt_image(out).std() > 10
    with pytest.raises(ValueError, match="frames"):
        plots.plot_jaw_opening(t, tmp_path / "k.png", truth_deg=t[:3])


def plt_image(path):
    import matplotlib.image as mpimg

    return (np.asarray(mpimg.imread(path))[..., :3] * 255).astype(int)


def test_activation_colors_chunked_equals_direct():
    from wface.viz.muscles import activation_colors

    rng = np.random.default_rng(3)
    w, a = rng.random((50, 4)), rng.random((7, 4))
    va, rgb = activation_colors(w, a)
    np.testing.assert_allclose(va, np.max(w[None] * a[:, None, :], axis=2))
    for f in range(7):
        va1, rgb1 = activation_colors(w, a[f])
        np.testing.assert_allclose(va1, va[f])
        np.testing.assert_allclose(rgb1, rgb[f])
    assert np.all((rgb >= 0) & (rgb <= 1))


def _drawn_figure(monkeypatch):
    """Keep the figure a plot function saves (its axes are what the tests read)."""
    kept = {}

    def keep(fig, out_path):
        kept["fig"] = fig
        return Path(out_path)

    monkeypatch.setattr(plots, "_save", keep)
    return kept


@pytest.mark.parametrize("n_muscles", [3, 12])
def test_activation_plot_shows_negative_pressure(monkeypatch, tmp_path, n_muscles):
    a = np.full((20, n_muscles), 0.5)
    a[:, -1] = np.linspace(-1.0, 1.0, 20)  # intraoral_pressure: suction is negative
    kept = _drawn_figure(monkeypatch)
    plots.plot_activations(a, [f"m{i}" for i in range(n_muscles - 1)] + ["intraoral_pressure"], tmp_path / "a.png")
    fig = kept["fig"]
    lo, hi = fig.axes[0].get_ylim()
    assert lo <= -1.0 and hi >= 1.0
    labels = [ax.get_ylabel() for ax in fig.axes] + [fig._supylabel.get_text() if fig._supylabel else ""]
    assert plots.ACTIVATION_AXIS_LABEL in labels and "-1 to 1" in plots.ACTIVATION_AXIS_LABEL
    assert plots.activation_ylim(np.full((2, 1), 0.5))[0] == pytest.approx(-0.03)  # muscles alone: 0..1


def test_marker_error_plot_keeps_outliers_apart(monkeypatch, tmp_path):
    """The truth error and the inliers' RMS and max on top; the max counting outliers (26 mm) in its own
    panel, so that the curves above keep their scale."""
    rng = np.random.default_rng(1)
    sim = rng.normal(size=(10, 6, 3)) * 0.01
    clean = sim + 1e-4
    cap = clean + rng.normal(size=sim.shape) * 2e-4
    cap[::2, 0] += 0.026  # an injected outlier every other frame
    rms, mx = plots.marker_errors_mm(cap, sim, outlier_mm=3.0)
    assert np.nanmax(mx) < 3.0 and np.nanmax(plots.marker_errors_mm(cap, sim)[1]) > 20.0
    kept = _drawn_figure(monkeypatch)
    plots.plot_marker_error(
        rms,
        tmp_path / "e.png",
        marker_max_mm=mx,
        truth_rms_mm=plots.marker_errors_mm(clean, sim)[0],
        outlier_mm=3.0,
        max_all_mm=plots.marker_errors_mm(cap, sim)[1],
    )
    top, bottom = kept["fig"].axes
    assert top.get_ylim()[1] < 3.0 and bottom.get_ylim()[1] > 20.0
    labels = [line.get_label() for line in top.get_lines()]
    assert labels[0].startswith("vs truth") and any("RMS of inliers" in s for s in labels)
    assert any("incl. outliers" in line.get_label() for line in bottom.get_lines())


def test_jaw_plot_draws_the_joint_limits(monkeypatch, tmp_path):
    ang = np.r_[np.full(10, -2.3), np.linspace(-2.3, 20.0, 10)]  # flat on the closed limit, then opening
    kept = _drawn_figure(monkeypatch)
    plots.plot_jaw_opening(ang, tmp_path / "j.png", limits_deg=(-2.3, 22.0))
    (ax,) = kept["fig"].axes
    limits = {line.get_label(): line.get_ydata()[0] for line in ax.get_lines() if "joint limit" in line.get_label()}
    assert sorted(limits.values()) == [-2.3, 22.0]
    kept.clear()
    plots.plot_jaw_opening(ang, tmp_path / "k.png", limits_deg=(-2.3, 80.0))  # the open limit far above: left out
    assert [s for s in (line.get_label() for line in kept["fig"].axes[0].get_lines()) if "joint" in s] == [
        "joint limit, closed (-2.3 deg)"
    ]
