"""The sphincters of AU6, AU7 and AU18 on a synthetic head (no data needed): direction and size.

The packaged ICT layout fitted to the ellipsoid head by its landmarks. Expectations from FACS and
the ICT-FaceKit shapes the layout was calibrated on (examples/waters_sphincters_ict.py): the
cheek raiser lifts the cheek by millimetres and hardly moves the brow, the lid tightener lifts
the lower lid, and the lip pucker pushes both lips forward. Switching the new ring features off
(no protrusion, a symmetric ellipse) shows what they add.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from wface.testing.synthetic_head import synthetic_head, synthetic_landmarks
from wface.waters.expressions import pose_from_action_units
from wface.waters.fit import fit_layout
from wface.waters.layout import load_layout
from wface.waters.muscles import SphincterMuscle
from wface.waters.rig import WatersRig


@pytest.fixture(scope="module")
def head():
    base = load_layout("ict")
    mesh = synthetic_head(60, 120)
    lay = fit_layout(
        base, synthetic_landmarks(base), target_vertices_m=mesh.vertices_m, target_triangles=mesh.triangles()
    )
    return lay, mesh.vertices_m


def _moves(layout, x, au, marker):
    """Displacement (3,) in mm of the vertex nearest ``marker`` under action unit ``au`` at full intensity."""
    rig = WatersRig(layout, x)
    v = int(np.argmin(np.linalg.norm(x - layout.landmarks_m[marker], axis=1)))
    pose = pose_from_action_units({au: 1.0}, rig.muscle_names)
    return (rig.deform(pose.contractions)[v] - x[v]) * 1e3


def _classic(layout):
    """The layout with every sphincter back to Waters' in-plane symmetric ring."""
    return replace(layout, muscles=[replace(m, protrusion_m=0.0, lower_semi_axis_m=0.0)
                                    if isinstance(m, SphincterMuscle) else m for m in layout.muscles])  # fmt: skip


def test_cheek_raiser_lifts_the_cheek_not_the_brow(head):
    lay, x = head
    cheek, brow = _moves(lay, x, "AU6L", "Lcheek_Up"), _moves(lay, x, "AU6L", "Leyebrow_M")
    assert cheek[1] > 2.0  # measured 3.3 mm up
    assert abs(brow[1]) < 0.5 * cheek[1]  # measured 0.7 mm down
    assert _moves(_classic(lay), x, "AU6L", "Lcheek_Up")[1] < 0.5 * cheek[1]  # the egg reaches the cheek


def test_lid_tightener_lifts_the_lower_lid_toward_the_inner_corner(head):
    lay, x = head
    lid = _moves(lay, x, "AU7L", "Leye_Down")
    assert lid[1] > 1.0 and lid[0] < 0  # measured 1.9 mm up, 1.3 mm medial (subject's left eye: -x)
    assert abs(_moves(lay, x, "AU7L", "Lcheek_Up")[1]) < 0.5 * _moves(lay, x, "AU6L", "Lcheek_Up")[1]  # not AU6


def test_lip_pucker_pushes_the_lips_forward(head):
    lay, x = head
    for marker in ("Mouth_Up", "Mouth_Down"):
        d = _moves(lay, x, "AU18", marker)
        assert d[2] > 2.0, marker  # measured 2.9 and 3.6 mm forward
        assert _moves(_classic(lay), x, "AU18", marker)[2] < 0.25 * d[2]  # an in-plane ring cannot pucker
