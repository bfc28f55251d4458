"""Waters layouts (format, round trip, errors) and the compiled rig (overlap limit, regions, jaw, determinism)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wface.facs import all_muscle_names
from wface.waters.layout import (
    JawPlane,
    JawRegion,
    MuscleLayout,
    layout_from_dict,
    layout_to_dict,
    load_layout,
    save_layout,
)
from wface.waters.muscles import LinearMuscle, SphincterMuscle
from wface.waters.rig import WatersRig, direct_displacement


def _grid(n: int = 41, half_m: float = 0.08) -> np.ndarray:
    """A flat (n*n, 3) patch of 'skin' in the z = 0 plane."""
    g = np.linspace(-half_m, half_m, n)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def _layout(**kw) -> MuscleLayout:
    muscles = [
        LinearMuscle(
            "zygomaticus_major_l", [0.06, 0.03, -0.01], [0.02, -0.03, 0.0], zone_deg=30, spring_constant_m=0.008
        ),
        LinearMuscle("risorius_l", [0.07, -0.03, -0.01], [0.02, -0.03, 0.0], zone_deg=20, spring_constant_m=0.008),
        LinearMuscle(
            "depressor_labii_inferioris_l",
            [0.02, -0.07, -0.005],
            [0.01, -0.04, 0.0],
            spring_constant_m=0.005,
            region="lower",
        ),
        LinearMuscle("frontalis_medial_l", [0.015, 0.09, -0.005], [0.015, 0.05, 0.0], spring_constant_m=0.005),
        SphincterMuscle(
            "orbicularis_oris_upper",
            [0.0, -0.03, -0.01],
            [1, 0, 0],
            [0, 1, 0],
            [0.03, 0.02, 0.03],
            tension=0.3,
            region="upper",
        ),
    ]
    jaw = JawRegion(
        pivot_m=[0.0, 0.03, -0.09],
        axis=[1, 0, 0],
        planes=[JawPlane([0.0, -0.034, 0.0], [0, -1, 0], width_m=0.002, width_per_lateral=0.3)],
    )
    base = dict(name="test", muscles=muscles, jaw=jaw, landmarks_m={"Chin": [0, -0.06, 0.0]})
    base.update(kw)
    return MuscleLayout(**base)


# ------------------------------------------------------------------------------------------ layout
def test_layout_json_round_trip_is_exact(tmp_path):
    lay = _layout()
    path = save_layout(lay, tmp_path / "l.json")
    again = load_layout(path)
    assert layout_to_dict(again) == layout_to_dict(lay)


def test_layout_units_convert_to_metres():
    d = layout_to_dict(_layout(), units="cm")
    assert d["units"] == "cm"
    lay = layout_from_dict(d)
    np.testing.assert_allclose(lay.muscles[0].bone_m, [0.06, 0.03, -0.01], atol=1e-15)
    assert lay.muscles[0].spring_constant_m == pytest.approx(0.008, rel=1e-14)


def test_packaged_layouts_use_canonical_names_and_are_big_enough():
    lay = load_layout("ict")
    assert len(lay.muscles) >= 20
    assert set(lay.muscle_names) <= set(all_muscle_names())
    assert lay.jaw is not None and len(lay.landmarks_m) == 41
    # stored in centimetres, read in metres: the head is ~25 cm tall
    span = np.ptp(np.stack(list(lay.landmarks_m.values())), axis=0)
    assert 0.05 < span[1] < 0.3


def test_layout_errors_name_the_problem(tmp_path):
    with pytest.raises(KeyError, match="unknown muscle 'smile_muscle'"):
        _layout(muscles=[LinearMuscle("smile_muscle", [0, 0, 0], [1, 0, 0])])
    d = layout_to_dict(_layout())
    d["muscles"][0].pop("insertion")
    with pytest.raises(ValueError, match="missing field 'insertion'"):
        layout_from_dict(d)
    with pytest.raises(ValueError, match="units"):
        layout_from_dict({**layout_to_dict(_layout()), "units": "furlong"})
    with pytest.raises(ValueError, match="format"):
        layout_from_dict({"muscles": []})
    with pytest.raises(FileNotFoundError, match="layout file not found"):
        load_layout(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_layout(tmp_path / "bad.json")
    d = layout_to_dict(_layout())
    d["muscles"].append(dict(d["muscles"][0]))
    with pytest.raises(ValueError, match="appears twice"):
        layout_from_dict(d)
    json.dumps(layout_to_dict(_layout()))  # JSON-ready


# --------------------------------------------------------------------------------------------- rig
def test_rig_equals_direct_formulas_for_unmasked_muscles():
    lay = _layout(jaw=None)
    x = _grid()
    rig = WatersRig(lay, x)
    c = {"zygomaticus_major_l": 0.7, "frontalis_medial_l": 0.4}
    np.testing.assert_allclose(rig.muscle_displacement(c, limit=False), direct_displacement(lay, x, c), atol=1e-15)


def test_single_muscle_is_never_clamped():
    lay = _layout()
    rig = WatersRig(lay, _grid())
    for name in lay.muscle_names:
        for c in (0.3, 1.0):
            a = rig.muscle_displacement({name: c})
            np.testing.assert_array_equal(a, rig.muscle_displacement({name: c}, limit=False))


def test_overlap_is_limited_per_vertex():
    lay = _layout(overlap_factor=1.2)
    rig = WatersRig(lay, _grid(61))
    both = {"zygomaticus_major_l": 1.0, "risorius_l": 1.0}
    raw = np.linalg.norm(rig.muscle_displacement(both, limit=False), axis=1)
    lim = np.linalg.norm(rig.muscle_displacement(both), axis=1)
    strongest = np.maximum(
        np.linalg.norm(rig.muscle_displacement({"zygomaticus_major_l": 1.0}), axis=1),
        np.linalg.norm(rig.muscle_displacement({"risorius_l": 1.0}), axis=1),
    )
    assert np.any(raw > 1.2 * strongest + 1e-6)  # the two pulls do overlap here
    assert np.all(lim <= 1.2 * strongest * (1 + 1e-12) + 1e-15)
    assert np.all(lim <= raw + 1e-15)
    # the global cap too
    capped = WatersRig(_layout(max_displacement_m=0.002), _grid(61))
    assert np.max(np.linalg.norm(capped.muscle_displacement(both), axis=1)) <= 0.002 * (1 + 1e-12)
    over = np.flatnonzero(np.linalg.norm(capped.muscle_displacement(both, limit=False), axis=1) > 0.002)
    assert len(over) and np.array_equal(capped.vertices_at_cap(both), over)
    assert len(rig.vertices_at_cap({})) == 0


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=5, max_size=5))
def test_limit_holds_for_any_contractions(c):
    rig = _RIG
    d = np.linalg.norm(rig.muscle_displacement(np.array(c)), axis=1)
    assert np.all(d <= rig.vertex_limit_m * (1 + 1e-12) + 1e-18)


_RIG = WatersRig(_layout(), _grid(31))


def test_rig_is_deterministic():
    a = WatersRig(_layout(), _grid())
    b = WatersRig(_layout(), _grid())
    c = np.array([0.3, 0.9, 0.5, 0.2, 1.0])
    assert (a.basis != b.basis).nnz == 0
    np.testing.assert_array_equal(a.deform(c, jaw_opening_deg=7.0), b.deform(c, jaw_opening_deg=7.0))


def test_regions_split_the_lips():
    lay = _layout()
    x = _grid(81)
    rig = WatersRig(lay, x)
    w = rig.jaw_weights
    up = np.linalg.norm(rig.muscle_displacement({"orbicularis_oris_upper": 1.0}), axis=1)
    low = np.linalg.norm(rig.muscle_displacement({"depressor_labii_inferioris_l": 1.0}), axis=1)
    assert np.all(up[w >= 1.0] == 0.0) and up.max() > 0
    assert np.all(low[w <= 0.0] == 0.0) and low.max() > 0


def test_jaw_rotates_the_jaw_region_rigidly_about_the_pivot():
    lay = _layout()
    x = _grid(41)
    rig = WatersRig(lay, x)
    y = rig.deform(None, jaw_opening_deg=12.0)
    w = rig.jaw_weights
    full, none = w >= 1.0, w <= 0.0
    assert full.any() and none.any()
    np.testing.assert_array_equal(y[none], x[none])
    r0 = np.linalg.norm(x[full] - lay.jaw.pivot_m, axis=1)
    r1 = np.linalg.norm(y[full] - lay.jaw.pivot_m, axis=1)
    np.testing.assert_allclose(r1, r0, rtol=1e-12)
    a, b = (x[full] - lay.jaw.pivot_m)[:, 1:], (y[full] - lay.jaw.pivot_m)[:, 1:]  # across the +x axis
    ang = np.degrees(
        np.arccos(np.clip(np.einsum("ij,ij->i", a, b) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1), -1, 1))
    )
    np.testing.assert_allclose(ang, 12.0, atol=1e-6)
    # opening moves the chin down (positive angle about +x)
    assert np.all(y[full][:, 1] <= x[full][:, 1] + 1e-15)


def test_rig_errors_name_the_problem():
    rig = WatersRig(_layout(), _grid(11))
    with pytest.raises(KeyError, match="unknown muscle 'mentalis_l'"):
        rig.deform({"mentalis_l": 0.5})
    with pytest.raises(ValueError, match="expected \\(5,\\)"):
        rig.deform(np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        rig.deform(np.full(5, np.nan))
    with pytest.raises(ValueError, match="out of range: risorius_l"):
        rig.deform({"risorius_l": 1.5})
    with pytest.raises(ValueError, match="outside"):
        rig.deform(None, jaw_opening_deg=80.0)
    with pytest.raises(ValueError, match="no jaw region"):
        WatersRig(_layout(jaw=None), _grid(11)).deform(None, jaw_opening_deg=5.0)
    with pytest.raises(ValueError, match="shape"):
        WatersRig(_layout(), np.zeros((5, 2)))


def test_without_a_jaw_region_the_lip_regions_do_not_apply():
    rig = WatersRig(_layout(jaw=None), _grid(41))
    low = np.linalg.norm(rig.muscle_displacement({"depressor_labii_inferioris_l": 1.0}), axis=1)
    assert low.max() > 0.001


def test_given_jaw_weights_override_the_planes():
    x = _grid(21)
    w = np.clip((0.02 - x[:, 1]) / 0.04, 0.0, 1.0)
    rig = WatersRig(_layout(), x, jaw_weights=w)
    np.testing.assert_array_equal(rig.jaw_weights, w)
    y = rig.deform(None, jaw_opening_deg=10.0)
    np.testing.assert_array_equal(y[w == 0], x[w == 0])
    assert np.all(np.linalg.norm(y[w == 1] - x[w == 1], axis=1) > 0)
    with pytest.raises(ValueError, match="jaw_weights must lie"):
        WatersRig(_layout(), x, jaw_weights=w + 1)
    with pytest.raises(ValueError, match="jaw_weights must be"):
        WatersRig(_layout(), x, jaw_weights=w[:3])


def test_sphincter_extensions_round_trip_and_default_to_the_classic_ring(tmp_path):
    ring = SphincterMuscle("incisivus_labii_superioris", [0, -0.03, 0.1], [1, 0, 0], [0, 1, 0], [0.03, 0.02, 0.02],
                           0.2, protrusion_m=0.008, lower_semi_axis_m=0.03)  # fmt: skip
    lay = _layout(muscles=[ring])
    again = load_layout(save_layout(lay, tmp_path / "l.json", units="cm"))
    assert again.muscles[0].protrusion_m == pytest.approx(0.008, rel=1e-14)
    assert again.muscles[0].lower_semi_axis_m == pytest.approx(0.03, rel=1e-14)
    d = layout_to_dict(_layout())
    assert all("protrusion" not in m and "lower_semi_axis" not in m for m in d["muscles"])  # old files unchanged
    assert all(m.protrusion_m == 0 and m.lower_semi_axis_m == 0 for m in layout_from_dict(d).muscles
               if isinstance(m, SphincterMuscle))  # fmt: skip
