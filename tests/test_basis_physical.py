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


def test_cli_from_face(tmp_path):
    from wface.basis.core import load_basis
    from wface.cli import main

    out = tmp_path / "fem_basis.npz"
    assert main(["basis", "from-face", "--tets", "1500", "--out", str(out)]) == 0
    basis = load_basis(out)
    # 35 muscles and the intra-oral pressure's two shapes (puff, suction: a basis weight is >= 0)
    assert basis.n_elements == 37 and np.abs(basis.shapes_m).max() > 1e-3
    assert basis.names[-2:] == ["intraoral_pressure", "intraoral_pressure_suction"]
