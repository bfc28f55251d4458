"""Calibrating a muscle against a reference displacement field recovers a known muscle."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from wface.waters.calibrate import calibrate_muscle, mirror_name, relative_error
from wface.waters.layout import MuscleLayout
from wface.waters.muscles import LinearMuscle, SphincterMuscle
from wface.waters.rig import WatersRig


def _skin() -> np.ndarray:
    g = np.linspace(-0.06, 0.06, 49)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), 0.01 * np.cos(6 * x.ravel())], axis=1)


def _layout(zyg: LinearMuscle) -> MuscleLayout:
    mirror = replace(
        zyg, name="zygomaticus_major_r", bone_m=zyg.bone_m * [-1, 1, 1], insertion_m=zyg.insertion_m * [-1, 1, 1]
    )
    ring = SphincterMuscle("orbicularis_oris_upper", [0, -0.02, -0.01], [1, 0, 0], [0, 1, 0], [0.03, 0.02, 0.03], 0.3)
    return MuscleLayout("cal", [zyg, mirror, ring])


def test_mirror_names():
    assert mirror_name("risorius_l") == "risorius_r" and mirror_name("risorius_r") == "risorius_l"
    assert mirror_name("procerus") is None


def test_calibration_recovers_a_perturbed_linear_muscle():
    x = _skin()
    truth = LinearMuscle(
        "zygomaticus_major_l",
        [0.05, 0.03, -0.01],
        [0.015, -0.02, 0.0],
        zone_deg=25.0,
        fall_start_m=0.055,
        fall_finish_m=0.08,
        spring_constant_m=0.008,
    )
    ref = WatersRig(_layout(truth), x).deform({"zygomaticus_major_l": 1.0}) - x
    start = replace(truth, bone_m=truth.bone_m + [0.006, -0.004, 0.0], zone_deg=35.0, spring_constant_m=0.005)
    res = calibrate_muscle(
        _layout(start), x, ref, muscle="zygomaticus_major_l", action_units={"AU12L": 1.0}, max_evaluations=1500
    )
    assert res.error_before > 0.1
    assert res.error_after < 0.02 * res.error_before
    fitted = res.layout.muscle("zygomaticus_major_l")
    d = WatersRig(res.layout, x).deform({"zygomaticus_major_l": 1.0}) - x
    assert relative_error(d, ref) == pytest.approx(res.error_after, rel=1e-9)
    # the mirror partner follows
    np.testing.assert_allclose(res.layout.muscle("zygomaticus_major_r").bone_m, fitted.bone_m * [-1, 1, 1])


def test_calibration_of_a_sphincter_and_errors():
    x = _skin()
    lay = _layout(LinearMuscle("zygomaticus_major_l", [0.05, 0.03, -0.01], [0.015, -0.02, 0.0]))
    ref = WatersRig(lay, x).deform({"orbicularis_oris_upper": 1.0}) - x
    weak = replace(lay, muscles=[*lay.muscles[:2], replace(lay.muscles[2], tension=0.1)])
    res = calibrate_muscle(weak, x, ref, muscle="orbicularis_oris_upper", action_units={"AU23": 1.0})
    assert res.error_after < 0.05 * res.error_before
    with pytest.raises(ValueError, match="do not contract"):
        calibrate_muscle(lay, x, ref, muscle="risorius_l", action_units={"AU12": 1.0})
    with pytest.raises(ValueError, match="reference has shape"):
        calibrate_muscle(lay, x, ref[:5], muscle="zygomaticus_major_l", action_units={"AU12": 1.0})
