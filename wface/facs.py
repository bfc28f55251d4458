"""FACS action units, canonical muscle names and expression presets, shared by every face in wface.

One table serves the FEM face, the actuation basis and the Waters vector muscles, so an action
unit means the same muscles everywhere. Muscle names are snake_case anatomical names; bilateral
muscles carry a side suffix ``_l`` (the subject's left, +x) or ``_r``. Midline muscles have no suffix.

Action unit values are intensities in [0, 1] (FACS A..E mapped to 0.2..1.0). ``jaw_opening_deg`` is
the jaw rotation an action unit asks for: AU26/AU27 act through the jaw, not through a muscle.

References: Ekman & Friesen, Facial Action Coding System (1978); Waters (1987) for the muscle
set of the vector-muscle model.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "ACTION_UNITS",
    "ACTUATORS",
    "BILATERAL_MUSCLES",
    "EXPRESSIONS",
    "MIDLINE_MUSCLES",
    "STAND_INS",
    "ActionUnit",
    "action_unit_muscles",
    "all_muscle_names",
    "combine_contributions",
    "expand_muscle",
    "expression_action_units",
    "interpolate_action_units",
    "muscle_activations",
    "parse_action_unit",
]

# Bilateral muscles: one per side, named base + "_l" / "_r".
BILATERAL_MUSCLES: tuple[str, ...] = (
    "frontalis_medial",
    "frontalis_lateral",
    "corrugator",
    "orbicularis_oculi",
    "orbicularis_oculi_palpebral",
    "orbicularis_oculi_palpebral_superior",
    "levator_palpebrae",
    "nasalis",
    "levator_labii_superioris_alaeque_nasi",
    "levator_labii_superioris",
    "zygomaticus_major",
    "zygomaticus_minor",
    "levator_anguli_oris",
    "risorius",
    "buccinator",
    "depressor_anguli_oris",
    "depressor_labii_inferioris",
    "mentalis",
    "platysma",
)
# Midline muscles: a single muscle across the midline.
MIDLINE_MUSCLES: tuple[str, ...] = (
    "procerus",
    "orbicularis_oris_upper",
    "orbicularis_oris_lower",
    "incisivus_labii_superioris",
    "incisivus_labii_inferioris",
)
# Actuators that are not muscles: the intra-oral pressure (``wface.physics.pressure``; its channel
# is signed, suction to pressure). An action unit may drive it with a negative weight (AU35).
ACTUATORS: tuple[str, ...] = ("intraoral_pressure",)
# Finer muscles and the coarser muscle that stands in for them, at a weight factor, on a face that
# lacks them (followed down the chain): ``orbicularis_oculi`` is the whole ring (its orbital part,
# AU6) where a face has no separate palpebral part (AU7); the palpebral part of the upper lid, which
# lowers it over the eye (AU43), falls back on the palpebral ring at half (AU43 before it existed);
# the incisivii (AU18, lip pucker; one ring per lip in the vector-muscle model) fall back on
# orbicularis oris. Faces with only the coarse muscles get the
# activations they had before the finer muscles existed.
STAND_INS: dict[str, tuple[str, float]] = {
    "orbicularis_oculi_palpebral_superior": ("orbicularis_oculi_palpebral", 0.5),
    "orbicularis_oculi_palpebral": ("orbicularis_oculi", 1.0),
    "incisivus_labii_superioris": ("orbicularis_oris_upper", 0.8),
    "incisivus_labii_inferioris": ("orbicularis_oris_lower", 0.8),
}


def all_muscle_names() -> list[str]:
    """Every canonical muscle name (bilateral ones with both sides), and the other actuators."""
    names = [f"{base}_{side}" for base in BILATERAL_MUSCLES for side in ("l", "r")]
    return names + list(MIDLINE_MUSCLES) + list(ACTUATORS)


def expand_muscle(base: str, side: str = "both") -> list[str]:
    """Full muscle names for a base name: ``expand_muscle("risorius")`` -> ``["risorius_l", "risorius_r"]``."""
    if base in MIDLINE_MUSCLES or base in ACTUATORS:
        return [base]
    if base not in BILATERAL_MUSCLES:
        known = BILATERAL_MUSCLES + MIDLINE_MUSCLES + ACTUATORS
        raise KeyError(f"unknown muscle {base!r}; known: {', '.join(known)}")
    sides = {"both": ("l", "r"), "l": ("l",), "r": ("r",)}[side]
    return [f"{base}_{s}" for s in sides]


@dataclass(frozen=True)
class ActionUnit:
    """One FACS action unit: the muscles it contracts (weights at full intensity) and jaw opening."""

    number: int
    name: str
    muscles: Mapping[str, float] = field(default_factory=dict)  # base muscle name -> activation at intensity 1
    # (negative only for a signed actuator: AU35 drives the intra-oral pressure to suction)
    jaw_opening_deg: float = 0.0


ACTION_UNITS: dict[str, ActionUnit] = {
    f"AU{au.number}": au
    for au in (
        ActionUnit(1, "Inner brow raiser", {"frontalis_medial": 1.0}),
        ActionUnit(2, "Outer brow raiser", {"frontalis_lateral": 1.0}),
        ActionUnit(4, "Brow lowerer", {"corrugator": 1.0, "procerus": 0.6}),
        ActionUnit(5, "Upper lid raiser", {"levator_palpebrae": 1.0}),
        ActionUnit(6, "Cheek raiser", {"orbicularis_oculi": 0.7}),
        ActionUnit(7, "Lid tightener", {"orbicularis_oculi_palpebral": 1.0}),
        ActionUnit(9, "Nose wrinkler", {"levator_labii_superioris_alaeque_nasi": 1.0, "nasalis": 0.5, "procerus": 0.4}),
        ActionUnit(10, "Upper lip raiser", {"levator_labii_superioris": 1.0}),
        ActionUnit(11, "Nasolabial deepener", {"zygomaticus_minor": 1.0}),
        ActionUnit(12, "Lip corner puller", {"zygomaticus_major": 1.0}),
        ActionUnit(13, "Sharp lip puller", {"levator_anguli_oris": 1.0}),
        ActionUnit(14, "Dimpler", {"buccinator": 1.0}),
        ActionUnit(15, "Lip corner depressor", {"depressor_anguli_oris": 1.0}),
        ActionUnit(16, "Lower lip depressor", {"depressor_labii_inferioris": 1.0}),
        ActionUnit(17, "Chin raiser", {"mentalis": 1.0}),
        ActionUnit(18, "Lip pucker", {"incisivus_labii_superioris": 1.0, "incisivus_labii_inferioris": 1.0}),
        ActionUnit(20, "Lip stretcher", {"risorius": 1.0, "platysma": 0.4}),
        ActionUnit(22, "Lip funneler", {"orbicularis_oris_upper": 0.6, "orbicularis_oris_lower": 0.6}),
        ActionUnit(23, "Lip tightener", {"orbicularis_oris_upper": 1.0, "orbicularis_oris_lower": 1.0}),
        ActionUnit(24, "Lip pressor", {"orbicularis_oris_upper": 0.9, "orbicularis_oris_lower": 0.9, "mentalis": 0.3}),
        ActionUnit(25, "Lips part", {"depressor_labii_inferioris": 0.4}, jaw_opening_deg=2.0),
        ActionUnit(26, "Jaw drop", {}, jaw_opening_deg=12.0),
        ActionUnit(27, "Mouth stretch", {"platysma": 0.3}, jaw_opening_deg=25.0),
        ActionUnit(28, "Lip suck", {"orbicularis_oris_upper": 1.0, "orbicularis_oris_lower": 1.0}),
        ActionUnit(
            34, "Puff", {"intraoral_pressure": 1.0, "orbicularis_oris_upper": 0.3, "orbicularis_oris_lower": 0.3}
        ),
        ActionUnit(35, "Cheek suck", {"intraoral_pressure": -1.0, "buccinator": 0.5}),
        ActionUnit(43, "Eyes closed", {"orbicularis_oculi_palpebral_superior": 1.0}),
    )
}

# Expression presets as action units with intensities (after Ekman & Friesen's prototypes).
EXPRESSIONS: dict[str, dict[str, float]] = {
    "neutral": {},
    "happy": {"AU6": 0.8, "AU12": 1.0, "AU25": 0.4},
    "sad": {"AU1": 0.9, "AU4": 0.6, "AU15": 0.9, "AU17": 0.4},
    "fear": {"AU1": 0.9, "AU2": 0.8, "AU4": 0.5, "AU5": 0.9, "AU20": 0.8, "AU26": 0.6},
    "anger": {"AU4": 1.0, "AU5": 0.6, "AU7": 0.8, "AU23": 0.9},
    "surprise": {"AU1": 1.0, "AU2": 1.0, "AU5": 0.8, "AU26": 1.0},
    "disgust": {"AU9": 1.0, "AU10": 0.6, "AU15": 0.5, "AU16": 0.4},
}


def parse_action_unit(key: str) -> tuple[str, str]:
    """Split ``"AU12"``, ``"AU12L"`` or ``"au12r"`` into (``"AU12"``, side in {"both", "l", "r"})."""
    k = key.strip().upper()
    side = "both"
    if k.endswith(("L", "R")) and k[:-1] in ACTION_UNITS:
        side, k = k[-1].lower(), k[:-1]
    if k not in ACTION_UNITS:
        raise KeyError(f"unknown action unit {key!r}; known: {', '.join(ACTION_UNITS)}")
    return k, side


def action_unit_muscles(au: str, side: str = "both", *, muscle_names: Iterable[str] | None = None) -> dict[str, float]:
    """{muscle name: weight at intensity 1} of one action unit on one side of a face.

    A muscle the face lacks is replaced by its stand-in (``STAND_INS``) when the face has that,
    else dropped; ``muscle_names=None`` keeps every canonical muscle (no stand-ins).

    Args:
        au: ``"AU7"`` (no side suffix; see :func:`parse_action_unit`).
        side: "both", "l" or "r" (midline muscles act on both sides).
        muscle_names: the muscles the face has.
    """
    keep = None if muscle_names is None else set(muscle_names)
    out: dict[str, float] = {}
    for base, weight in ACTION_UNITS[au].muscles.items():
        names = expand_muscle(base, side if base not in MIDLINE_MUSCLES else "both")
        while keep is not None and base in STAND_INS and not any(n in keep for n in names):
            stand_in, factor = STAND_INS[base]
            base, weight = stand_in, weight * factor
            names = expand_muscle(base, side if base not in MIDLINE_MUSCLES else "both")
        for name in names:
            if keep is None or name in keep:
                out[name] = combine_contributions(out.get(name, 0.0), weight)
    return out


def muscle_activations(
    action_units: Mapping[str, float], *, muscle_names: Iterable[str] | None = None
) -> tuple[dict[str, float], float]:
    """Turn action-unit intensities into muscle activations and a jaw opening.

    Contributions to one muscle combine by maximum (an AU never adds beyond full activation; for the
    signed intra-oral pressure, by largest magnitude).

    Args:
        action_units: ``{"AU12": 1.0, "AU6L": 0.5, ...}``, intensities in [0, 1].
        muscle_names: the muscles a face has; muscles it lacks are dropped, or driven through
            their stand-in (``STAND_INS``) when the face has that. ``None`` keeps all.

    Returns:
        (``{muscle name: activation in [0, 1]}``, jaw opening in degrees).
    """
    names = None if muscle_names is None else list(muscle_names)
    out: dict[str, float] = {}
    jaw_deg = 0.0
    for key, value in action_units.items():
        v = float(value)
        if not (0.0 <= v <= 1.0):
            raise ValueError(f"action unit {key!r} intensity {v} is outside [0, 1]")
        au_key, side = parse_action_unit(key)
        jaw_deg = max(jaw_deg, ACTION_UNITS[au_key].jaw_opening_deg * v)
        for name, weight in action_unit_muscles(au_key, side, muscle_names=names).items():
            out[name] = combine_contributions(out.get(name, 0.0), float(np.clip(weight * v, -1.0, 1.0)))
    return out, jaw_deg


def combine_contributions(a: float, b: float) -> float:
    """Two contributions to one channel: the larger in magnitude (the maximum for muscles, whose
    weights are >= 0; a signed actuator keeps its strongest push or pull)."""
    return a if abs(a) >= abs(b) else b


def expression_action_units(name: str) -> dict[str, float]:
    """Action units of a preset expression.

    Presets: ``neutral``, ``happy``, ``sad``, ``fear``, ``anger``, ``surprise``, ``disgust``.
    """
    try:
        return dict(EXPRESSIONS[name.lower()])
    except KeyError:
        raise KeyError(f"unknown expression {name!r}; known: {', '.join(EXPRESSIONS)}") from None


def interpolate_action_units(a: Mapping[str, float], b: Mapping[str, float], t: float) -> dict[str, float]:
    """Linear blend (1 - t) a + t b of two action-unit sets (missing units count as 0)."""
    keys = set(a) | set(b)
    return {k: (1.0 - t) * float(a.get(k, 0.0)) + t * float(b.get(k, 0.0)) for k in sorted(keys)}
