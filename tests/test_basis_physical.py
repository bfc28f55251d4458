"""A physically derived basis from the FEM face (issue 6, point 1c): shapes, analysis and retargeting."""

from __future__ import annotations

import numpy as np
import pytest

from wface.basis.analysis import MarkerBasis, analyze
from wface.basis.physical import basis_from_face
from wface.basis.retarget import retarget
from wface.faces.builtin import build_face

MUSCLES = ["zygomaticus_major_l", "zygomaticus_major_r", "orbicularis_oris_lower", "frontalis_medial_l", "mentalis_l"]


@pytest.fixture(scope="module")
def bases():
    a = build_face(1500)
    b = build_face(2500)
    return a, basis_from_face(a, muscles=MUSCLES), basis_from_face(b, muscles=MUSCLES)


def test_shapes_follow_anatomy(bases):
    model, basis, _ = bases
    assert list(basis.names) == MUSCLES and basis.n_vertices == len(np.unique(model.skin_triangles))
    corner = model.marker_positions_m[model.marker_names.index("Mouth_Lend")]
    v = int(np.argmin(np.linalg.norm(basis.neutral_m - corner, axis=1)))
    d = basis.shapes_m[0, v]  # zygomaticus major left at the left mouth corner
    assert d[1] > 0.001 and d[0] > 0  # up and outward, millimetres
    assert np.abs(basis.shapes_m[1, v]).max() < np.abs(d).max()  # the right muscle barely moves the left corner


def test_analysis_recovers_contractions_and_retargets(bases):
    model, basis, other = bases
    mk = [int(np.argmin(np.linalg.norm(basis.neutral_m - p, axis=1))) for p in model.marker_positions_m]
    mb = MarkerBasis(np.transpose(basis.shapes_m[:, mk], (1, 2, 0)), list(model.marker_names), list(MUSCLES))
    truth = np.array([[0.6, 0.1, 0.4, 0.0, 0.8], [0.2, 0.9, 0.0, 0.5, 0.3]])
    result = analyze(mb, mb.predict(truth))
    assert np.allclose(result.contractions, truth, atol=1e-6)  # exact data, box-feasible truth
    out = retarget(result.contractions, MUSCLES, other, synthesize=True)
    assert np.allclose(out.contractions, truth, atol=1e-6)
    assert out.positions_m.shape == (2, other.n_vertices, 3)


def test_unknown_muscle_is_named():
    with pytest.raises(KeyError, match="unknown muscle"):
        basis_from_face(build_face(1500), muscles=["zygomaticus"])


@pytest.fixture(scope="module")
def cli_basis(tmp_path_factory):
    from wface.cli import main

    out = tmp_path_factory.mktemp("from_face") / "fem_basis.npz"
    assert main(["basis", "from-face", "--tets", "1500", "--out", str(out)]) == 0
    return out


def test_cli_from_face(cli_basis):
    from wface.basis.core import load_basis

    basis = load_basis(cli_basis)
    # 35 muscles and the intra-oral pressure's two shapes (puff, suction: a basis weight is >= 0)
    assert basis.n_elements == 37 and np.abs(basis.shapes_m).max() > 1e-3
    assert basis.names[-2:] == ["intraoral_pressure", "intraoral_pressure_suction"]


def _capture_of(model, basis, truth, *, scale: float, angle_deg: float, offset_m):
    """A take of the model's markers under ``basis`` contractions ``truth`` (frames, B) after rest,
    seen by a capture system whose frame is the model's scaled, turned about x and moved."""
    from wface.io.mocap import MocapTake

    vert = [basis.landmarks[n] for n in model.marker_names]
    frames = np.vstack([np.zeros((1, basis.n_elements)), truth])
    pos = basis.synthesize(frames)[:, vert]
    a = np.radians(angle_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return MocapTake(scale * pos @ rot.T + np.asarray(offset_m), list(model.marker_names), 100.0)


def test_a_basis_from_a_face_knows_its_markers(bases, tmp_path):
    """`wface basis analyze` on a basis made by `basis from-face` failed on the AnimFace takes ("aligns
    at scale 0.06"): without landmarks the capture's frame was guessed by closest points alone. The
    basis now carries the model's markers (name -> nearest skin vertex, saved with it), and a take
    with those names aligns from them, here from a frame turned 70 degrees and scaled 1.1."""
    from wface.basis.core import load_basis
    from wface.basis.pipeline import analyze_take

    model, basis, _ = bases
    assert set(basis.landmarks) == set(model.marker_names)
    corner = basis.landmarks["Mouth_Lend"]
    d = np.linalg.norm(basis.neutral_m - model.marker_positions_m[model.marker_names.index("Mouth_Lend")], axis=1)
    assert corner == int(np.argmin(d))
    basis.save(tmp_path / "b.npz")
    assert load_basis(tmp_path / "b.npz").landmarks == basis.landmarks

    truth = np.array([[0.6, 0.1, 0.4, 0.0, 0.8], [0.2, 0.9, 0.0, 0.0, 0.3]])  # frontalis moves the stable markers
    take = _capture_of(model, basis, truth, scale=1.1, angle_deg=70.0, offset_m=[0.3, -0.2, 1.4])
    res = analyze_take(basis, take)
    assert res.layout.alignment_rms_m < 1e-6
    np.testing.assert_allclose(res.analysis.contractions[1:], truth, atol=0.02)  # stable markers move a little

    bare = load_basis(tmp_path / "b.npz")
    bare.landmarks = None  # as before: closest points alone, which land about 0.5 mm off here
    off = analyze_take(bare, take)
    assert off.layout.alignment_rms_m > 1e-4
    assert np.abs(off.analysis.contractions[1:] - truth).max() > 0.05


def test_an_animface_take_analyses_on_a_basis_from_the_face(cli_basis, tmp_path):
    """The review's case: `basis analyze` of NoseMoCap on a `basis from-face` basis stopped with
    "aligns to the basis at scale 0.0605" and left an output folder holding only provenance.json."""
    from conftest import data_path

    from wface.cli import main

    mocap = data_path("animface", "NoseMoCap.c3d")
    out = tmp_path / "an"
    args = ["basis", "analyze", "--basis", str(cli_basis), "--mocap", str(mocap), "--frames", "0:60:20"]
    assert main([*args, "--no-plot", "--no-progress", "--out", str(out)]) == 0
    report = __import__("json").loads((out / "report.json").read_text())
    assert report["marker_rms_mm_mean"] < 3.0


def test_from_face_and_refine_do_not_replace_files_unasked(cli_basis, tmp_path, capsys):
    """`basis from-face --out victim.npz` replaced a face model, `basis refine --out v3.npz` an earlier basis
    and its v3.npz.report.json; each is refused before any work unless --overwrite."""
    from wface.cli import main

    victim = tmp_path / "victim.npz"
    victim.write_bytes(b"a face model")
    assert main(["basis", "from-face", "--tets", "1500", "--out", str(victim)]) == 2
    err = capsys.readouterr().err
    assert f"--out {victim} exists" in err and "--overwrite" in err, err
    refine = ["basis", "refine", "--basis", str(cli_basis), "--train", str(tmp_path / "none.c3d")]
    report = tmp_path / "v3.npz.report.json"
    report.write_text("{}")
    assert main([*refine, "--out", str(tmp_path / "v3.npz")]) == 2  # the report alone is there
    err = capsys.readouterr().err
    assert f"{report} exists" in err and "--overwrite" in err, err
    assert main([*refine, "--out", str(victim)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert victim.read_bytes() == b"a face model" and report.read_text() == "{}"
