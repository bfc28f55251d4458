"""Where poses come from: named expressions, inline action-unit / muscle specs, tracked takes.

Expression specs (``expression_pose``):
- a preset of ``wface.facs.EXPRESSIONS`` (``happy``, ``surprise``, ...; ``smile`` is ``happy``);
- inline items ``KEY=VALUE`` separated by commas, each KEY an action unit (``AU12``, ``AU6L``), a
  muscle of the model (``zygomaticus_major_l``) or ``jaw_open`` (degrees): ``"AU12=1,AU6=0.5"``;
- a preset with extras: ``"happy,AU26=0.5"``.
Action units use the model's own FACS table (``FaceModel.facs``) when it has one (so imported
faces map AUs to their muscles), the shared ``wface.facs`` table otherwise; jaw openings come
from ``wface.facs.ACTION_UNITS``. Contributions to a muscle combine by maximum, as in ``wface.facs``.

Tracked takes (``load_take``): the directory written by ``wface track`` / ``wface demo`` (or by
``wface edit``): ``controls.npz`` (activations, 24 bone parameters per frame, muscle names; see
``wface.tracking.report.write_controls``), else the per-frame files ``frames/frame_NNNNNN.npz`` of
``wface.tracking.sequence``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from wface.editing.pose import Pose, Take, bone_projection_error_m, clamp_jaw, pose_from_controls
from wface.facs import ACTION_UNITS, EXPRESSIONS, action_unit_muscles, expression_action_units, parse_action_unit
from wface.model import FaceModel

__all__ = ["EXPRESSION_ALIASES", "expression_names", "expression_pose", "load_take", "save_controls"]

EXPRESSION_ALIASES = {"smile": "happy", "joy": "happy", "surprised": "surprise", "angry": "anger", "sadness": "sad"}
DEFAULT_FPS = 30.0


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
    for key, value in items:
        if not 0.0 <= value <= 1.0 and key != "jaw_open":
            raise ValueError(f"{key}={value}: values must lie in [0, 1]")
        if key == "jaw_open":
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
        jaw_deg = max(jaw_deg, ACTION_UNITS[au].jaw_open_deg * v)
        for name, w in _au_muscles(model, au, side).items():
            i = model.muscle_index(name)
            act[i] = max(act[i], min(1.0, w * v))
    for name, v in muscles.items():
        act[model.muscle_index(name)] = v
    return clamp_jaw(Pose(act, jaw_opening_deg=jaw_deg), model.jaw_joint)


def _read_fps(path: Path) -> float | None:
    for name in ("controls.npz",):
        p = path / name
        if p.exists():
            with np.load(p) as d:
                if "fps" in d:
                    return float(d["fps"])
    for name in ("animation.usdc", "animation.usda", "animation.usd"):
        p = path / name
        if p.exists():
            try:
                from pxr import Usd

                stage = Usd.Stage.Open(str(p))
                return float(stage.GetTimeCodesPerSecond())
            except Exception:  # noqa: BLE001 - the rate is a convenience; fall back to the default
                return None
    return None


def load_take(path: str | Path, model: FaceModel, *, fps: float | None = None) -> Take:
    """A tracked (or edited) take from its output directory, as poses of ``model``.

    Args:
        path: directory of ``wface track`` / ``wface demo`` / ``wface edit`` output.
        model: the face it was tracked on (muscle names and node count are checked).
        fps: frame rate; default: the one stored with the take (``controls.npz`` or the USD
            stage's timeCodesPerSecond), else 30.

    Returns:
        A ``Take``; ``info["bone_projection_error_mm"]`` is the largest attached-node distance
        between the tracked bones and their rigid / on-joint projection in the poses.
    """
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(
            f"take directory {path} does not exist (give the --out of `wface track` or `wface demo`)"
        )
    report = path / "report.json"
    if report.exists():
        nodes = json.loads(report.read_text()).get("nodes")
        if nodes is not None and int(nodes) != model.n_nodes:
            raise ValueError(
                f"{path} was made on a face with {nodes} nodes, this model has {model.n_nodes}: "
                "pass the same --model (or --tets) it was tracked with"
            )
    npz = path / "controls.npz"
    scale = None
    if npz.exists():
        with np.load(npz) as d:
            names = [str(s) for s in d["muscle_names"]]
            frames = np.asarray(d["frames"])
            C = np.concatenate([d["activations"], d["bones"]], axis=1)
            if "force_length_scale" in d:
                scale = np.asarray(d["force_length_scale"], dtype=np.float64)
    else:
        files = sorted((path / "frames").glob("frame_*.npz")) if (path / "frames").is_dir() else []
        files = [f for f in files if ".part" not in f.name]
        if not files:
            raise FileNotFoundError(f"{path} holds no controls.npz and no frames/frame_*.npz: not a tracked take")
        names = list(model.muscle_names)
        rows = []
        for f in files:
            with np.load(f) as d:
                rows.append((int(d["frame"]), np.asarray(d["controls"], dtype=np.float64)))
        rows.sort(key=lambda r: r[0])
        frames = np.array([r[0] for r in rows])
        C = np.stack([r[1] for r in rows])
    if names != list(model.muscle_names):
        raise ValueError(
            f"{path} has muscles {', '.join(names)}; the model has {', '.join(model.muscle_names)}: "
            "pass the --model it was tracked with"
        )
    poses, err = [], 0.0
    for k, c in enumerate(C):
        s = None if scale is None or np.all(scale[k] == 1.0) else scale[k]
        pose = pose_from_controls(model, c, force_length_scale=s)
        err = max(err, bone_projection_error_m(model, c, pose))
        poses.append(pose)
    rate = fps or _read_fps(path) or DEFAULT_FPS
    info = {"frames": frames.tolist(), "bone_projection_error_mm": err * 1e3}
    return Take(poses, rate, list(model.muscle_names), str(path), info)


def save_controls(out_dir: str | Path, model: FaceModel, take: Take) -> Path:
    """``controls.npz`` in the tracking format (+ fps and per-frame force-length scales), so
    ``load_take`` reads an edit back and edits chain."""
    from wface.controls import jaw_to_intuitive

    out = Path(out_dir) / "controls.npz"
    B = np.stack([p.bones(model.jaw_joint) for p in take.poses])
    jaw = [jaw_to_intuitive(model.jaw_joint, b[12:]) for b in B]
    scale = take.force_length_scales
    np.savez(
        out,
        frames=np.arange(len(take.poses)),
        activations=take.activations,
        bones=B,
        muscle_names=np.array(model.muscle_names),
        force_length_scale=scale,
        fps=np.float64(take.fps),
        jaw_opening_deg=np.array([j["opening_deg"] for j in jaw]),
        jaw_protrusion_m=np.array([j["protrusion_m"] for j in jaw]),
        jaw_lateral_deg=np.array([j["lateral_deg"] for j in jaw]),
    )
    return out
