"""The shared FACS table: finer muscles and their stand-ins on faces that lack them."""

from __future__ import annotations

import pytest

from wface.facs import ACTION_UNITS, STAND_INS, action_unit_muscles, all_muscle_names, muscle_activations

COARSE = [n for n in all_muscle_names() if not n.startswith(("orbicularis_oculi_palpebral", "incisivus"))]


def test_fine_muscles_drive_the_action_units_that_fits_them():
    everything = all_muscle_names()
    assert action_unit_muscles("AU6", muscle_names=everything) == {
        "orbicularis_oculi_l": 0.7,
        "orbicularis_oculi_r": 0.7,
    }
    assert action_unit_muscles("AU7", "l", muscle_names=everything) == {"orbicularis_oculi_palpebral_l": 1.0}
    assert action_unit_muscles("AU18", "r", muscle_names=everything) == {
        "incisivus_labii_superioris": 1.0,
        "incisivus_labii_inferioris": 1.0,
    }  # midline muscles act on both sides


@pytest.mark.parametrize(("au", "before"), [
    ("AU7", {"orbicularis_oculi_l": 1.0, "orbicularis_oculi_r": 1.0}),
    ("AU43", {"orbicularis_oculi_l": 0.5, "orbicularis_oculi_r": 0.5}),
    ("AU18", {"orbicularis_oris_upper": 0.8, "orbicularis_oris_lower": 0.8}),
])  # fmt: skip
def test_faces_without_the_fine_muscles_get_the_activations_they_had(au, before):
    """The stand-ins reproduce the table as it was before the finer muscles (FEM faces, older layouts)."""
    acts, _ = muscle_activations({au: 1.0}, muscle_names=COARSE)
    assert acts == pytest.approx(before)
    assert action_unit_muscles(au, muscle_names=[]) == {}  # a face with neither drops the action unit


def test_stand_ins_are_canonical_and_used():
    names = set(all_muscle_names())
    bases = {b for au in ACTION_UNITS.values() for b in au.muscles}
    for fine, (coarse, factor) in STAND_INS.items():
        assert fine in bases and 0 < factor <= 1
        assert any(n.startswith(coarse) for n in names)


def test_au43_falls_back_down_the_stand_in_chain():
    """AU43 drives the upper lid's palpebral part where a face has it, else the palpebral ring at half
    (AU43 before the lid muscle), else the whole orbicularis oculi ring at half (the FEM face)."""
    lid = ["orbicularis_oculi_palpebral_superior_l", "orbicularis_oculi_palpebral_superior_r"]
    ring = ["orbicularis_oculi_palpebral_l", "orbicularis_oculi_palpebral_r"]
    whole = ["orbicularis_oculi_l", "orbicularis_oculi_r"]
    assert action_unit_muscles("AU43", muscle_names=lid + ring + whole) == dict.fromkeys(lid, 1.0)
    assert action_unit_muscles("AU43", muscle_names=ring + whole) == dict.fromkeys(ring, 0.5)
    assert action_unit_muscles("AU43", muscle_names=whole) == dict.fromkeys(whole, 0.5)
