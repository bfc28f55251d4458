"""Where poses come from: named expressions, inline action-unit / muscle specs, tracked takes.

Expression specs (``expression_pose``):
- a preset of ``wface.facs.EXPRESSIONS`` (``happy``, ``surprise``, ...; ``smile`` is ``happy``);
- inline items ``KEY=VALUE`` separated by commas, each KEY an action unit (``AU12``, ``AU6L``), a
  muscle of the model (``zygomaticus_major_l``) or ``jaw_open`` (degrees): ``"AU12=1,AU6=0.5"``;
- a preset with extras: ``"happy,AU26=0.5"``.
Action units use the model's own FACS table (``FaceModel.facs``) when it has one (so imported
faces map AUs to their muscles), the shared ``wface.facs`` table otherwise; jaw openings come
from ``wface.facs.ACTION_UNITS``. Contributions to a muscle combine by maximum, as in ``wface.facs``.

Tracked takes are read by ``wface.takes.store.load_take``.
"""

from __future__ import annotations

import numpy as np

from wface.controls import jaw_limits
from wface.facs import (
    ACTION_UNITS,
    EXPRESSIONS,
    action_unit_muscles,
    combine_contributions,
    expression_action_units,
    parse_action_unit,
)
from wface.model import FaceModel
from wface.takes.pose import Pose, clamp_jaw

__all__ = ["EXPRESSION_ALIASES", "expression_names", "expression_pose"]

EXPRESSION_ALIASES = {"smile": "happy", "joy": "happy", "surprised": "surprise", "angry": "anger", "sadness": "sad"}


def expression_names() -> list[str]:
    """Valid preset names (``wface.facs.EXPRESSIONS`` and aliases)."""
    return sorted(set(EXPRESSIONS) | set(EXPRESSION_ALIASES))


def _au_muscles(model: FaceModel, au: str, side: str) -> dict[str, float]:
    """{model muscle: weight at intensity 1} of one action unit on one side."""
    if model.facs:
        table = dict(model.facs.get(au, {}))
        if side != "both":
            table = {m: w for m, w in table.items() if not m.endswith(("_l", "_r")) or m.endswith("_" + side)}
        return table
    return action_unit_muscles(au, side, muscle_names=model.muscle_names)


def _parse_items(spec: str) -> tuple[str | None, list[tuple[str, float]]]:
    preset, items = None, []
    for raw in (s.strip() for s in spec.split(",")):
        if not raw:
            continue
        key, sep, value = raw.partition("=")
        key = key.strip()
        if not sep:
            if preset is not None:
                raise ValueError(f"expression {spec!r}: two presets ({preset!r}, {key!r}); blend them instead")
            preset = key
            continue
        try:
            items.append((key, float(value)))
        except ValueError:
            raise ValueError(f"expression {spec!r}: {value!r} is not a number") from None
    return preset, items


def expression_pose(model: FaceModel, spec: str, *, intensity: float = 1.0) -> Pose:
    """A pose of ``model`` from an expression spec (module docstring), scaled by ``intensity`` in [0, 1].

    Raises:
        KeyError: unknown expression, action unit or muscle (the message lists the valid ones).
        ValueError: malformed spec or values outside [0, 1].
    """
    if not 0.0 <= float(intensity) <= 1.0:
        raise ValueError(f"intensity must lie in [0, 1], got {intensity} (use exaggerate to go further)")
    preset, items = _parse_items(spec)
    aus: dict[str, float] = {}
    if preset is not None:
        name = EXPRESSION_ALIASES.get(preset.lower(), preset.lower())
        if name not in EXPRESSIONS:
            raise KeyError(f"unknown expression {preset!r}; known: {', '.join(expression_names())}")
        aus = {k: float(intensity) * v for k, v in expression_action_units(name).items()}
    act = np.zeros(model.n_muscles)
    jaw_deg = 0.0
    muscles: dict[str, float] = {}
    signed = set(model.pressure_actuators)
    for key, value in items:
        if key in signed:
            if not -1.0 <= value <= 1.0:
                raise ValueError(f"{key}={value}: a pressure actuator's value must lie in [-1, 1] (suction..pressure)")
        elif not 0.0 <= value <= 1.0 and key != "jaw_open":
            raise ValueError(f"{key}={value}: values must lie in [0, 1]")
        if key == "jaw_open":
            lo, hi = jaw_limits(model.jaw_joint)["opening_deg"]
            if not lo <= value <= hi:  # the clamp below would change it without a word
                raise ValueError(f"jaw_open={value:g}: the jaw opens from {lo:.3g} to {hi:.3g} degrees")
            jaw_deg = max(jaw_deg, value)
        elif key.upper().startswith("AU") and key[2:3].isdigit():
            parse_action_unit(key)  # clear KeyError listing the action units
            aus[key] = value
        elif key in model.muscle_names:
            muscles[key] = value
        else:
            raise KeyError(
                f"{key!r} is neither an action unit nor a muscle of this model; muscles: "
                f"{', '.join(model.muscle_names)}; action units: {', '.join(ACTION_UNITS)}"
            )
    for key, v in aus.items():
        au, side = parse_action_unit(key)
        jaw_deg = max(jaw_deg, ACTION_UNITS[au].jaw_opening_deg * v)
        for name, w in _au_muscles(model, au, side).items():
            i = model.muscle_index(name)
            act[i] = combine_contributions(act[i], float(np.clip(w * v, -1.0, 1.0)))
    for name, v in muscles.items():
        act[model.muscle_index(name)] = v
    return clamp_jaw(Pose(act, jaw_opening_deg=jaw_deg), model.jaw_joint)
