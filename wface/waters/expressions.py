"""FACS action units and expression presets driving Waters muscles (through the shared ``wface.facs`` table).

An action-unit set ``{"AU12": 1.0, "AU26": 0.5, ...}`` becomes muscle contractions (the layout's
muscles only) and a jaw angle with ``wface.facs.muscle_activations``. Presets are
``wface.facs.EXPRESSIONS``; two presets blend linearly in action-unit space.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from wface.facs import expression_action_units, interpolate_action_units, muscle_activations, parse_action_unit

__all__ = ["Pose", "expression_pose", "interpolate_poses", "parse_au_assignments", "pose_from_action_units"]


@dataclass(frozen=True)
class Pose:
    """Muscle contractions (name -> [0, 1]) and a jaw opening in degrees, plus the action units behind them."""

    action_units: dict[str, float]
    contractions: dict[str, float]
    jaw_opening_deg: float


def pose_from_action_units(action_units: Mapping[str, float], muscle_names: list[str] | None = None) -> Pose:
    """Contractions and jaw angle for action-unit intensities (unknown AU names raise KeyError).

    Args:
        action_units: ``{"AU12": 1.0, "AU6L": 0.5}``, intensities in [0, 1].
        muscle_names: the layout's muscles (others are dropped); None keeps every canonical muscle.
    """
    aus = {}
    for key, value in action_units.items():
        v = float(value)
        if not np.isfinite(v):
            raise ValueError(f"action unit {key!r} intensity is not finite: {value!r}")
        parse_action_unit(key)  # clear KeyError for unknown names
        aus[key] = v
    contractions, jaw = muscle_activations(aus, muscle_names=muscle_names)
    return Pose(dict(aus), contractions, float(jaw))


def parse_au_assignments(items: list[str] | None) -> dict[str, float]:
    """``["AU12=0.8", "AU26=1"]`` -> ``{"AU12": 0.8, "AU26": 1.0}`` (command-line form)."""
    out: dict[str, float] = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"action unit {item!r} must be written AU=VALUE, e.g. AU12=0.8")
        key, _, value = item.partition("=")
        try:
            v = float(value)
        except ValueError:
            raise ValueError(f"action unit {key!r}: value {value!r} is not a number") from None
        parse_action_unit(key)
        out[key.strip().upper()] = v
    return out


def expression_pose(
    name: str,
    *,
    intensity: float = 1.0,
    extra_action_units: Mapping[str, float] | None = None,
    muscle_names: list[str] | None = None,
) -> Pose:
    """Pose of a preset (``wface.facs.EXPRESSIONS``) scaled by ``intensity``; an extra AU sets its intensity in place
    of the preset's, on one side with an L / R suffix (``AU12R=0`` keeps the preset's smile on the left only)."""
    if not (0.0 <= float(intensity) <= 1.0):
        raise ValueError(f"intensity must lie in [0, 1], got {intensity}")
    aus = {k: float(intensity) * v for k, v in expression_action_units(name).items()}
    for key, value in (extra_action_units or {}).items():
        au, side = parse_action_unit(key)
        if side == "both":  # the AU on both sides: the preset's sided entries go
            aus.pop(au + "L", None), aus.pop(au + "R", None)
        elif au in aus:  # one side of a preset's AU on both sides: split it, then set that side
            both = aus.pop(au)
            aus.setdefault(au + "L", both), aus.setdefault(au + "R", both)
        aus[au if side == "both" else au + side.upper()] = value
    return pose_from_action_units(aus, muscle_names)


def interpolate_poses(
    a: str | Mapping[str, float], b: str | Mapping[str, float], t: float, *, muscle_names: list[str] | None = None
) -> Pose:
    """Blend two presets (names) or action-unit sets at t in [0, 1] (t=0 gives a, t=1 gives b)."""
    if not (0.0 <= float(t) <= 1.0):
        raise ValueError(f"interpolation parameter t must lie in [0, 1], got {t}")
    aus_a = expression_action_units(a) if isinstance(a, str) else dict(a)
    aus_b = expression_action_units(b) if isinstance(b, str) else dict(b)
    return pose_from_action_units(interpolate_action_units(aus_a, aus_b, float(t)), muscle_names)
