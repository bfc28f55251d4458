"""Issue 9 point 2: each Badin muscle alone moves the skin as anatomy says (real data, quasistatic FEM).

Markers are read on the deformed skin through their barycentric coordinates on the rest skin. All
bilateral muscles are activated on both sides at full activation; the jaw is opened by rotation
about the condyle axis. Every equilibrium must converge with no inverted tet. Thresholds are a
fraction of what the solve gives (in comments), so the tests check direction, not exact numbers.
"""

from __future__ import annotations

import numpy as np
import pytest

from wface.mesh.closest import SurfaceQuery

pytestmark = pytest.mark.slow
TOL = 1e-4  # relative force residual: enough for millimetre-scale marker motion


@pytest.fixture(scope="module")
def setup(badin_model):
    from wface.physics.simulator import Simulator

    model = badin_model
    sim = Simulator(model)
    hit = SurfaceQuery(model.rest_positions_m, model.skin_triangles).closest(model.marker_positions_m)
    tri = model.skin_triangles[hit.triangle]

    def markers(x):
        p = np.einsum("kj,kjd->kd", hit.barycentric, x[tri])
        return dict(zip(model.marker_names, p, strict=True))

    return model, sim, markers


def _solve(setup, muscle=None, jaw_deg=0.0):
    from wface.controls import attached_positions_from_affines, jaw_opening_affine

    model, sim, markers = setup
    acts = {n: 1.0 for n in model.muscle_names if muscle and n.rsplit("_", 1)[0] == muscle}
    targets = attached_positions_from_affines(model, jaw=jaw_opening_affine(model, jaw_deg)) if jaw_deg else None
    res = sim.solve(activations=acts, attached_positions=targets, tol=TOL)
    assert res.converged and res.inverted_elements == 0, (muscle, jaw_deg, res.residual_rel, res.inverted_elements)
    rest, moved = markers(model.rest_positions_m), markers(res.x)
    return {k: (moved[k] - rest[k]) * 1e3 for k in rest}, rest  # displacements in mm


def test_oop_purses_the_lips(setup):
    d, rest = _solve(setup, "OOP")
    # corners move toward the midline (about 4 mm each side)
    assert d["Mouth_Lend"][0] < -1.5 and d["Mouth_Rend"][0] > 1.5
    assert np.isclose(d["Mouth_Lend"][0], -d["Mouth_Rend"][0], atol=0.5)  # symmetric


def test_ris_pulls_the_corners_sideways(setup):
    d, _ = _solve(setup, "RIS")
    # corners move outward (about 3.6 mm) and back
    assert d["Mouth_Lend"][0] > 1.5 and d["Mouth_Rend"][0] < -1.5
    assert d["Mouth_Lend"][2] < 0


def test_lls_raises_the_upper_lip(setup):
    d, _ = _solve(setup, "LLS")
    # the upper lip under the insertion (lateral to the midline) goes up, about 3 mm
    assert d["Mouth_UpL"][1] > 1.5 and d["Mouth_UpR"][1] > 1.5
    assert d["Mouth_UpL"][1] > abs(d["Mouth_DownL"][1])  # more than the lower lip moves


def test_zyg_pulls_the_corners_up_and_out(setup):
    d, _ = _solve(setup, "ZYG")
    # smile: corners up about 4 mm and out about 3 mm
    assert d["Mouth_Lend"][1] > 2.0 and d["Mouth_Rend"][1] > 2.0
    assert d["Mouth_Lend"][0] > 1.0 and d["Mouth_Rend"][0] < -1.0


def test_dao_pulls_the_corners_down(setup):
    d, _ = _solve(setup, "DAO")
    # corners down about 3.8 mm
    assert d["Mouth_Lend"][1] < -2.0 and d["Mouth_Rend"][1] < -2.0


def test_ment_raises_chin_and_lower_lip(setup):
    d, _ = _solve(setup, "MENT")
    # chin soft tissue up about 3.6 mm, lower lip up about 1.8 mm; the upper lip barely moves
    assert d["Chin"][1] > 1.5 and d["Mouth_Down"][1] > 0.7
    assert abs(d["Mouth_Up"][1]) < 0.5 * d["Mouth_Down"][1]


def test_jaw_opening_drops_the_lower_lip(setup):
    d, _ = _solve(setup, jaw_deg=15.0)
    # 15 degrees about the condyles: lower lip down about 17 mm, upper lip a few mm
    assert d["Mouth_Down"][1] < -8.0 and d["Chin"][1] < -8.0
    assert d["Mouth_Up"][1] > 0.5 * d["Mouth_Down"][1]
