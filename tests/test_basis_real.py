"""The actuation basis on real data: ICT-FaceKit shapes, AnimFace performances (skipped without data)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.conftest import data_path
from wface.basis import (
    MarkerLayout,
    analyze,
    interpolate_to_mesh,
    load_basis,
    refine_marker_basis,
    retarget,
    stabilise_capture,
)
from wface.basis.landmarks import load_ict_animface_landmarks

TAKES = ("JawMoCap.c3d", "CheeksMoCap.c3d", "EyebrowsMoCap.c3d", "NoseMoCap.c3d")


@pytest.fixture(scope="module")
def ict():
    return load_basis(data_path("ict-facekit", "ict_expressions.npz"))


@pytest.fixture(scope="module")
def takes():
    from wface.io.mocap import read_c3d

    return {n: read_c3d(data_path("animface", n)) for n in TAKES}


@pytest.fixture(scope="module")
def layout(ict, takes):
    jaw = takes["JawMoCap.c3d"]
    return MarkerLayout.from_frame(ict, jaw.marker_names, jaw.positions_m[0], landmarks=load_ict_animface_landmarks())


def test_ict_basis_in_metres(ict):
    assert ict.shapes_m.shape == (57, 26719, 3) and "jawOpen" in ict.names
    assert 0.15 < np.ptp(ict.neutral_m[:9409], axis=0).max() < 0.35  # a head, in metres
    jaw = ict.shapes_m[ict.index("jawOpen")]
    assert 0.005 < np.abs(jaw).max() < 0.05  # jaw opening moves the chin by centimetres


def test_layout_alignment_is_close(layout):
    # markers sit a few mm off the ICT skin (marker stand-off and a different person's face)
    assert layout.alignment_rms_m < 0.004
    assert np.all(layout.embedding.triangle >= 0)


def test_analysis_explains_most_of_the_motion(ict, takes, layout):
    mb = layout.marker_basis(ict)
    for name, take in takes.items():
        cap = stabilise_capture(take.frames(0, None, 6), layout)
        an = analyze(mb, cap.displacements_m)
        assert an.contractions.min() >= 0 and an.contractions.max() <= 1
        disp = np.sqrt(np.mean(np.sum(cap.displacements_m**2, axis=2)))
        assert an.total_rms_m < 0.6 * disp, name  # the basis explains most of the displacement
        assert cap.head_rms_m.max() < 0.006  # stable markers really are nearly rigid


def test_refinement_generalises_to_held_out_take(ict, takes, layout):
    """Refine on three takes (subsampled), test on the fourth: the held-out error must drop."""
    mb = layout.marker_basis(ict)
    disp = {n: stabilise_capture(t, layout).displacements_m for n, t in takes.items()}
    test = "EyebrowsMoCap.c3d"  # the hardest fold: brows barely appear in the training takes
    train = [disp[n][::12] for n in TAKES if n != test]
    res = refine_marker_basis(mb, train, regularization=1.0, max_iterations=4, rel_tol=1e-4)
    assert res.errors_m[-1] < 0.7 * res.errors_m[0]
    assert all(
        b <= a * (1 + 1e-9) for a, b in zip(res.errors_m, res.errors_m[1:], strict=False)
    )  # fixed point descends
    held = disp[test][::6]
    before = analyze(mb, held).total_rms_m
    after = analyze(res.basis, held).total_rms_m
    assert after < before
    # carried to the whole mesh, the refined basis reproduces the refined marker shapes closely
    refined = interpolate_to_mesh(ict, layout.surface_m, res.basis.shapes_m - mb.shapes_m)
    mb_mesh = layout.marker_basis(refined)
    gap = np.abs(mb_mesh.shapes_m - res.basis.shapes_m).max()
    change = np.abs(res.basis.shapes_m - mb.shapes_m).max()
    assert gap < 1e-6 * change  # the surface spline is exact at the markers' embedded points
    straight = interpolate_to_mesh(ict, layout.surface_m, res.basis.shapes_m - mb.shapes_m, metric="euclidean")
    assert np.abs(layout.marker_basis(straight).shapes_m - res.basis.shapes_m).max() < 0.25 * change  # close only
    assert analyze(mb_mesh, held).total_rms_m < before
    # far from the face nothing moved
    back = ict.neutral_m[:, 2] < ict.neutral_m[:, 2].min() + 0.05
    np.testing.assert_array_equal(refined.shapes_m[:, back], ict.shapes_m[:, back])
    # retarget the held-out contractions onto the refined face: every element matches by name
    x = analyze(mb, held[:20]).contractions
    r = retarget(x, ict.names, refined, synthesize=True)
    assert not r.match.unmatched_source and r.positions_m.shape == (20, ict.n_vertices, 3)


def test_cli_analyze_and_refine(tmp_path):
    from wface.cli import main

    ict_path = data_path("ict-facekit", "ict_expressions.npz")
    anim = data_path("animface")
    out = tmp_path / "an"
    rc = main(["basis", "analyze", "--basis", str(ict_path), "--mocap", str(anim / "NoseMoCap.c3d"), "--out", str(out),
               "--frames", "0:90", "--no-progress"])  # fmt: skip
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["frames"] == 90 and rep["markers"] == 41 and len(rep["marker_rms_mm"]) == 90
    assert 0 < rep["marker_rms_mm_mean"] < 10
    assert (out / "analysis.png").stat().st_size > 10_000
    x = np.load(out / "contractions.npz")["contractions"]
    assert x.shape == (90, 57)
    refined = tmp_path / "refined.npz"
    rc = main(["basis", "refine", "--basis", str(ict_path), "--train", str(anim / "JawMoCap.c3d"),
               str(anim / "CheeksMoCap.c3d"), "--out", str(refined), "--frames", "0:600:20", "--regularization", "auto",
               "--max-iterations", "2", "--no-progress"])  # fmt: skip
    assert rc == 0
    rep = json.loads(refined.with_name("refined.npz.report.json").read_text())
    assert rep["error_rms_mm_per_iteration"][-1] < rep["error_rms_mm_per_iteration"][0]
    assert rep["regularization"] in (0.03, 0.3, 3.0) and len(rep["regularization_scores_mm"]) == 3
    assert load_basis(refined).n_elements == 57
    rc = main(["basis", "analyze", "--basis", str(refined), "--mocap", str(anim / "NoseMoCap.c3d"), "--out",
               str(tmp_path / "an2"), "--frames", "0:60", "--no-progress", "--no-plot", "--split"])  # fmt: skip
    assert rc == 0
    assert main(["basis", "analyze", "--basis", str(tmp_path / "missing.npz"), "--mocap", "x.c3d", "--out", "o"]) == 1


def test_cli_analyze_refuses_bad_landmarks_a_failed_alignment_and_another_runs_results(tmp_path, capsys):
    """Each used to run to the end: an implausible alignment (scale 0.05) gave a wrong analysis, a landmark
    name the take lacks or a negative vertex id was ignored, a JSON list was an internal error, and another
    run's directory was overwritten."""
    from wface.cli import main

    ict_path = data_path("ict-facekit", "ict_expressions.npz")
    take = str(data_path("animface", "JawMoCap.c3d"))
    base = ["basis", "analyze", "--basis", str(ict_path), "--mocap", take, "--frames", "0:30:10", "--no-progress"]
    for text, words in [
        ('["Chin"]', "expected a JSON object {name: vertex index}, got a list"),
        ('{"Chin": -5}', "landmark 'Chin': vertex index -5 is not in [0, "),
        ('{"Foo": 10}', "none of the landmark names (Foo) is a marker of the take"),
    ]:
        (tmp_path / "lm.json").write_text(text)
        assert main([*base, "--landmarks", str(tmp_path / "lm.json"), "--out", str(tmp_path / "x")]) == 1
        err = capsys.readouterr().err
        assert words in err and "internal error" not in err, err
    far = {"Chin": 0, "ForeHead_M": 1, "NoseTop": 2, "Mouth_Up": 3}  # four vertices side by side: a tiny face
    (tmp_path / "lm.json").write_text(json.dumps(far))
    assert main([*base, "--landmarks", str(tmp_path / "lm.json"), "--out", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err
    assert "aligns to the basis at scale" in err and "plausible: 0.5 to 2" in err, err
    other = tmp_path / "tracked"
    other.mkdir()
    (other / "report.json").write_text('{"frames": 20}')
    assert main([*base, "--out", str(other)]) == 1
    assert "holds another take's results" in capsys.readouterr().err
    assert (other / "report.json").read_text() == '{"frames": 20}'
    assert main([*base, "--out", str(other), "--overwrite"]) == 0


def test_lower_lip_change_leaves_the_upper_lip_on_ict(ict):
    """The ICT lips touch: a lower-lip-only change moves the lower lip, not the upper one."""
    from wface.mesh.surface_fields import surface_distances

    lm = load_ict_animface_landmarks()
    names = list(lm)
    ids = np.array([lm[n] for n in names])
    lower = np.array([n.startswith("Mouth_Down") for n in names])  # Mouth_Down, _DownL, _DownR
    change = np.zeros((len(ids), 3, 1))
    change[lower, 1, 0] = -0.002  # the lower-lip markers 2 mm further down, every other marker still
    one = ict.subset(ict.names[:1])
    tri = one.skin_triangles

    def along(v):  # distances along the skin from vertex v
        t = np.flatnonzero((tri == v).any(axis=1))[0]
        return surface_distances(one.neutral_m, tri, [t], (tri[t] == v).astype(float)[None], limit_m=0.2)

    up, down = lm["Mouth_Up"], lm["Mouth_Down"]
    d_up, d_down = along(up), along(down)
    skin = one.skin_vertices
    straight = np.linalg.norm(one.neutral_m - one.neutral_m[down], axis=1)
    # upper-lip vertices: near the lower-lip marker in space but far from it along the skin
    upper_lip = skin[(d_up[skin] < 0.03) & (d_up[skin] < d_down[skin] - 0.02) & (straight[skin] < 0.03)]
    straight_up = np.linalg.norm(one.neutral_m - one.neutral_m[up], axis=1)
    lower_lip = skin[(d_down[skin] < 0.03) & (d_down[skin] < d_up[skin] - 0.02) & (straight_up[skin] < 0.03)]
    assert len(upper_lip) > 50 and len(lower_lip) > 50
    moved = {}
    for metric in ("surface", "euclidean"):
        out = interpolate_to_mesh(one, one.neutral_m[ids], change, metric=metric)
        move = np.linalg.norm(out.shapes_m[0] - one.shapes_m[0], axis=1)
        np.testing.assert_allclose(move[ids[lower]], 0.002, rtol=1e-6)
        moved[metric] = (move[upper_lip].mean(), move[upper_lip].max(), move[lower_lip].mean())
    up_mean, up_max, low_mean = moved["surface"]
    assert low_mean > 0.0018  # the lower lip follows its markers
    assert up_mean < 0.1e-3 and up_max < 0.4e-3  # measured 0.08 / 0.28 mm of 2 mm (around the corners)
    assert moved["euclidean"][0] > 0.5e-3  # straight distances drag the upper lip (measured 0.67 mm)
