"""write_take_figures + write_html_report: the whole picture set of a take, end to end."""

from __future__ import annotations

import re

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")
pytest.importorskip("matplotlib")

from wface.viz.figures import comparison_frame, peak_frame, write_take_figures  # noqa: E402


def _can_render_off_screen() -> bool:
    try:
        plotter = pv.Plotter(off_screen=True, window_size=(32, 32))
        plotter.add_mesh(pv.Sphere())
        plotter.screenshot(return_img=True)
        plotter.close()
        return True
    except Exception:  # noqa: BLE001 - no OpenGL context (no EGL / OSMesa / display)
        return False


pytestmark = pytest.mark.skipif(not _can_render_off_screen(), reason="VTK cannot render off-screen here")
from wface.testing.synthetic_face import synthetic_face, synthetic_take  # noqa: E402
from wface.viz.report import write_html_report  # noqa: E402


def test_take_figures_and_report(tmp_path):
    model = synthetic_face(nx=6, ny=6, nz=1)
    take = synthetic_take(model, n_frames=5, fps=10.0)
    images = write_take_figures(
        tmp_path,
        model=model,
        node_positions_m=take["node_positions_m"],
        fps=take["fps"],
        activations=take["activations"],
        captured_markers_m=take["captured_markers_m"],
        simulated_markers_m=take["simulated_markers_m"],
        cranium_affines=take["cranium_affines"],
        jaw_affines=take["jaw_affines"],
        truth_activations=take["activations"],
        truth_jaw_angle_deg=take["jaw_angle_deg"],
        movie_max_frames=3,
        panel_size=(240, 260),
    )
    names = {p.name for p in images.values()}
    assert names == {
        "expression.png",
        "muscles.png",
        "before_after.png",
        "activations.png",
        "marker_error.png",
        "jaw_opening.png",
        "take.mp4",
    }
    assert all(p.stat().st_size > 1000 for p in images.values())
    report = {"frames": 5, "marker_rms_mm": [0.4, 0.5, 0.6, 0.5, 0.4], "marker_rms_mm_mean": 0.48}
    html = write_html_report(tmp_path, report, images).read_text()
    assert len(re.findall(r'src="data:image/png;base64,', html)) == 6
    assert html.count('src="data:video/mp4;base64,') == 1


def test_peak_frame():
    rest = np.zeros((4, 3))
    x = np.zeros((3, 4, 3))
    x[2] += 0.01
    assert peak_frame(x, rest) == 2
    assert peak_frame(x, rest, np.array([[0.0, 1.0], [1.0, 1.0], [0.2, 0.0]])) == 1


def test_before_after_never_shows_one_frame_twice():
    assert comparison_frame(2, 5) == 2  # the peak beside the first frame
    assert comparison_frame(0, 5) == 4  # a take peaking at its first frame: the last one instead
    assert comparison_frame(0, 1) == 0  # one frame: nothing else to show
