"""Off-screen pictures and movies: the colours say what they should, the camera clips nothing."""

from __future__ import annotations

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")
imageio = pytest.importorskip("imageio")

from wface.viz import render  # noqa: E402


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

_SIZE = (320, 360)


@pytest.fixture(scope="module")
def face():
    return synthetic_face(nx=8, ny=8, nz=2)


@pytest.fixture(scope="module")
def take(face):
    return synthetic_take(face, n_frames=6, fps=24.0)


def _img(path):
    return np.asarray(imageio.v3.imread(path))[..., :3].astype(int)


def _count(img, cond):
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(np.count_nonzero(cond(r, g, b)))


def _red(r, g, b):
    return (r > 170) & (g < 70) & (b < 70)


def _green(r, g, b):
    return (g > 120) & (r < 90) & (b < 90)


def _yellow(r, g, b):
    return (r > 170) & (g > 140) & (b < 90)


def _border_is_background(img, width=3):
    edges = [img[:width], img[-width:], img[:, :width], img[:, -width:]]
    return all(np.all(e >= 250) for e in edges)


def test_markers_red_and_green_and_nothing_clipped(tmp_path, face, take):
    f = 3
    out = render.render_expression(
        face,
        take["node_positions_m"][f],
        tmp_path / "m.png",
        captured_markers_m=take["captured_markers_m"][f],
        simulated_markers_m=take["simulated_markers_m"][f],
        panel_size=_SIZE,
    )
    img = _img(out)
    assert img.shape[:2] == (_SIZE[1], _SIZE[0])
    assert _count(img, _red) > 20 and _count(img, _green) > 20
    assert _border_is_background(img), "geometry touches the image border: the camera fit clips it"
    assert np.count_nonzero(img.sum(axis=2) < 700) > 0.1 * img.shape[0] * img.shape[1]  # a face, not a blank page


def test_without_markers_there_is_no_red_or_green(tmp_path, face):
    img = _img(render.render_expression(face, face.rest_positions_m, tmp_path / "n.png", panel_size=_SIZE))
    assert _count(img, _red) == 0 and _count(img, _green) == 0


@pytest.mark.parametrize("shown", [("captured",), ("simulated",), ("captured", "simulated")])
def test_the_marker_legend_names_the_markers_shown(tmp_path, face, take, shown):
    """Red and green balls without a word on which is which (a user read red as the error)."""
    f = 3
    kw = {f"{k}_markers_m": take[f"{k}_markers_m"][f] for k in shown}
    img = _img(render.render_expression(face, take["node_positions_m"][f], tmp_path / "l.png", panel_size=_SIZE, **kw))
    corner = img[: int(0.12 * _SIZE[1]), : int(0.35 * _SIZE[0])]  # the legend's band, above the head
    assert (_count(corner, _red) > 0) == ("captured" in shown)
    assert (_count(corner, _green) > 0) == ("simulated" in shown)
    assert _border_is_background(img)


def test_muscle_colours_follow_activation(tmp_path, face):
    M = face.n_muscles
    off = _img(
        render.render_expression(
            face,
            face.rest_positions_m,
            tmp_path / "off.png",
            activations=np.zeros(M),
            style="muscles",
            panel_size=_SIZE,
        )
    )
    on = _img(
        render.render_expression(
            face, face.rest_positions_m, tmp_path / "on.png", activations=np.ones(M), style="muscles", panel_size=_SIZE
        )
    )
    assert _count(off, _red) > 200 and _count(off, _yellow) < 0.1 * _count(off, _red)  # inactive: red
    assert _count(on, _yellow) > 200 and _count(on, _red) < 0.1 * _count(on, _yellow)  # active: yellow
    skin = _img(
        render.render_expression(
            face, face.rest_positions_m, tmp_path / "s.png", activations=np.ones(M), style="skin", panel_size=_SIZE
        )
    )
    assert _count(skin, _yellow) > 200


def test_before_after_is_two_panels(tmp_path, face, take):
    out = render.render_before_after(
        face,
        render.Panel(face.rest_positions_m),
        render.Panel(take["node_positions_m"][2], take["activations"][2]),
        tmp_path / "ba.png",
        panel_size=_SIZE,
    )
    img = _img(out)
    assert img.shape[:2] == (_SIZE[1], 2 * _SIZE[0])
    left, right = img[:, : _SIZE[0]], img[:, _SIZE[0] :]
    assert _count(right, _yellow) > _count(left, _yellow)


def test_movie_has_one_frame_per_take_frame(tmp_path, face, take):
    out = render.render_take_movie(
        face,
        take["node_positions_m"],
        tmp_path / "take.mp4",
        fps=take["fps"],
        activations=take["activations"],
        captured_markers_m=take["captured_markers_m"],
        simulated_markers_m=take["simulated_markers_m"],
        window_size=(330, 250),
    )
    frames = list(imageio.v3.imiter(out))
    assert len(frames) == take["node_positions_m"].shape[0]
    assert frames[0].shape[:2] == (240, 320)  # rounded down to multiples of 16 for H.264
    assert not np.array_equal(frames[0], frames[3])


def test_render_errors(tmp_path, face, take):
    with pytest.raises(ValueError, match="node_positions_m must have shape"):
        render.render_expression(face, face.rest_positions_m[:5], tmp_path / "x.png")
    with pytest.raises(ValueError, match="style"):
        render.render_expression(face, face.rest_positions_m, tmp_path / "x.png", style="cartoon")
    with pytest.raises(ValueError, match="activations has 2 frames"):
        render.render_take_movie(face, take["node_positions_m"], tmp_path / "x.mp4", activations=np.zeros((2, 3)))


@pytest.mark.parametrize("style", ["skin", "muscles"])
def test_builtin_face_is_framed_whole(tmp_path, style):
    builtin = pytest.importorskip("wface.faces.builtin")
    model = builtin.build_face(target_tets=2000)
    a = np.zeros(model.n_muscles)
    a[[i for i, n in enumerate(model.muscle_names) if n.startswith("zygomaticus_major")]] = 1.0
    mk = model.marker_positions_m
    img = _img(
        render.render_expression(
            model,
            model.rest_positions_m,
            tmp_path / f"{style}.png",
            activations=a,
            captured_markers_m=mk + [0.004, 0.0, 0.0],
            simulated_markers_m=mk,
            style=style,
            panel_size=_SIZE,
        )
    )
    assert _border_is_background(img), "the built-in face touches the image border"
    assert _count(img, _yellow) > 100 and _count(img, _green) > 20 and _count(img, _red) > 20
    covered = np.count_nonzero(img.sum(axis=2) < 720) / (img.shape[0] * img.shape[1])
    assert covered > 0.25, f"the face fills only {covered:.0%} of the picture"


def test_panel_bone_affines_compose_the_jaw_onto_the_cranium():
    from wface.testing.synthetic_face import rotation_about

    c = np.hstack([rotation_about((0, 1, 0), 0.3), [[0.01], [0.02], [0.0]]])
    j = np.hstack([rotation_about((1, 0, 0), 0.2), [[0.0], [-0.005], [0.001]]])
    bones = render.Panel(np.zeros((1, 3)), cranium_affine=c, jaw_affine=j).bone_affines()
    p = np.array([0.03, -0.05, 0.08])
    np.testing.assert_allclose(
        bones["jaw"][:, :3] @ p + bones["jaw"][:, 3], c[:, :3] @ (j[:, :3] @ p + j[:, 3]) + c[:, 3]
    )
    np.testing.assert_allclose(bones["cranium"], c)


def test_headless_render_prints_no_vtk_warning(tmp_path):
    """On a machine without a display VTK logs "bad X server connection" and renders anyway;
    wface keeps VTK's log to errors, so users see nothing (a fresh process: VTK warns once)."""
    import subprocess
    import sys

    code = (
        "from wface.viz.offscreen import offscreen_pyvista\n"
        "pv = offscreen_pyvista()\n"
        "p = pv.Plotter(off_screen=True, window_size=(32, 32))\n"
        "p.add_mesh(pv.Sphere())\n"
        f"p.screenshot({str(tmp_path / 's.png')!r})\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "X server" not in run.stderr and "WARN" not in run.stderr
    assert (tmp_path / "s.png").stat().st_size > 100


@pytest.mark.parametrize("affines_given", [True, False])
def test_an_open_mouth_shows_a_dark_cavity_not_the_background(tmp_path, affines_given):
    """The built-in face has no oral cavity (no tongue, palate or throat): with the jaw open, the
    picture showed the white background through the mouth. The flesh's inner surfaces, the bones and
    a backdrop behind the teeth are drawn dark now, so no background is enclosed by the face. The head
    turned and the jaw open: without the bones' affines (an edit's contact sheet) the teeth and the
    backdrop follow the attached nodes (they stood at rest, and the mouth showed the background)."""
    from scipy.ndimage import binary_fill_holes

    from wface.controls import jaw_opening_affine
    from wface.faces.builtin import build_face
    from wface.physics.simulator import Simulator

    model = build_face(target_tets=2000)
    jaw = jaw_opening_affine(model, 15.0)
    x = Simulator(model).solve(np.zeros(model.n_muscles), _opened(model, jaw)).x
    c, s = np.cos(np.radians(20.0)), np.sin(np.radians(20.0))
    head = np.array([[c, 0.0, s, 0.004], [0.0, 1.0, 0.0, -0.003], [-s, 0.0, c, 0.002]])  # turned 20 deg, moved
    x = x @ head[:, :3].T + head[:, 3]
    given = {"cranium_affine": head, "jaw_affine": jaw} if affines_given else {}
    img = _img(render.render_expression(model, x, tmp_path / "open.png", panel_size=_SIZE, **given))
    face = img[: int(0.8 * img.shape[0])]  # above the colour bar (its lettering has holes of its own)
    fg = face.sum(axis=2) < 750
    holes = binary_fill_holes(fg) & ~fg
    assert np.count_nonzero(holes) == 0, f"{np.count_nonzero(holes)} background pixels seen through the face"


def _opened(model, jaw):
    """Bone-attached nodes' targets with the jaw's nodes moved by the (3, 4) affine ``jaw``."""
    targets = model.rest_positions_m.copy()
    on_jaw = model.nodes_of_bone("jaw")
    targets[on_jaw] = targets[on_jaw] @ jaw[:, :3].T + jaw[:, 3]
    return targets[model.attached_nodes]
