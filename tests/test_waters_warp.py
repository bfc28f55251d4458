"""The Warp kernel evaluates the same Waters muscles as the numpy rig (float64, CPU)."""

from __future__ import annotations

import numpy as np
import pytest

from wface.testing.synthetic_head import synthetic_head, synthetic_landmarks
from wface.waters.expressions import expression_pose
from wface.waters.fit import fit_layout
from wface.waters.layout import load_layout
from wface.waters.rig import WatersRig

pytest.importorskip("warp")


@pytest.fixture(scope="module")
def head_rig():
    base = load_layout("ict")
    head = synthetic_head(60, 120)
    lay = fit_layout(
        base, synthetic_landmarks(base), target_vertices_m=head.vertices_m, target_triangles=head.triangles()
    )
    return lay, head, WatersRig(lay, head.vertices_m)


@pytest.mark.parametrize("name", ["happy", "anger", "disgust", "fear"])
def test_warp_kernel_matches_the_numpy_rig(head_rig, name):
    from wface.waters.warp_backend import WarpWaters

    lay, head, rig = head_rig
    pose = expression_pose(name, muscle_names=rig.muscle_names)
    warp_d = WarpWaters(lay, device="cpu").muscle_displacement(
        head.vertices_m, pose.contractions, jaw_weights=rig.jaw_weights
    )
    np.testing.assert_allclose(warp_d, rig.muscle_displacement(pose.contractions), atol=1e-12)
    assert np.abs(warp_d).max() > 1e-4


def test_warp_kernel_on_moved_points_matches_a_fresh_rig(head_rig):
    from wface.waters.warp_backend import WarpWaters

    lay, head, _ = head_rig
    moved = head.vertices_m + 0.002 * np.sin(40 * head.vertices_m)  # a different "rest" shape
    c = np.linspace(0.0, 1.0, len(lay.muscles))
    fresh = WatersRig(lay, moved)
    got = WarpWaters(lay, device="cpu").muscle_displacement(moved, c)
    np.testing.assert_allclose(got, fresh.muscle_displacement(c), atol=1e-12)
    with pytest.raises(ValueError, match="contraction"):
        WarpWaters(lay, device="cpu").muscle_displacement(moved, np.full(len(lay.muscles), 2.0))


def test_warp_kernel_without_a_jaw_matches_the_rig(head_rig):
    from dataclasses import replace

    from wface.waters.warp_backend import WarpWaters

    lay, head, _ = head_rig
    no_jaw = replace(lay, jaw=None)
    c = np.full(len(lay.muscles), 0.5)
    got = WarpWaters(no_jaw, device="cpu").muscle_displacement(head.vertices_m, c)
    np.testing.assert_allclose(got, WatersRig(no_jaw, head.vertices_m).muscle_displacement(c), atol=1e-12)


def test_warp_kernel_matches_the_rig_for_protruding_egg_shaped_rings(head_rig):
    """AU6, AU7 and AU18 use the sphincter protrusion and lower semi-axis: the kernel has them too."""
    from wface.waters.expressions import pose_from_action_units
    from wface.waters.muscles import SphincterMuscle
    from wface.waters.warp_backend import WarpWaters

    lay, head, rig = head_rig
    rings = [m for m in lay.muscles if isinstance(m, SphincterMuscle)]
    assert any(m.protrusion_m > 0 for m in rings) and any(m.lower_semi_axis_m > 0 for m in rings)
    pose = pose_from_action_units({"AU6": 1.0, "AU7": 1.0, "AU18": 1.0}, rig.muscle_names)
    got = WarpWaters(lay, device="cpu").muscle_displacement(
        head.vertices_m, pose.contractions, jaw_weights=rig.jaw_weights
    )
    np.testing.assert_allclose(got, rig.muscle_displacement(pose.contractions), atol=1e-12)
    assert np.abs(got[:, 2]).max() > 1e-3  # the pucker pushes forward by millimetres
