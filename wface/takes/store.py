"""The take store: the one module that owns a take's files on disk.

A take directory (what ``wface track``, ``wface demo``, ``wface edit`` and ``wface resim`` write)::

    frames/frame_NNNNNN.npz   one tracked frame each (``FrameRecord``: frame number, controls, world
                              and cranium-frame node positions, simulated markers, marker errors,
                              stats), written atomically as soon as the frame is done
    controls.npz              the take (``write_controls``): frames (the capture's frame numbers),
                              activations (T, M), bones (T, 24), muscle_names, fps, the jaw in
                              intuitive parameters, and force_length_scale (T, M) for exaggerated edits
    controls.csv              the same per frame, for spreadsheets and DCC scripts
    report.json               what made the take and how well (``write_report`` / ``read_report``)
    animation.usdc            the take as USD (``wface.takes.usd.write_take_usd``)
    resim.npz                 a dynamic replay's positions and per-frame stats (``write_resim_npz``)

``load_take`` reads a directory back into a ``wface.takes.take.Take``: from controls.npz, or from
the frame files of an interrupted run; the tracked world positions of the frame files become the
take's ``reference_positions_m``. The frame rate comes from controls.npz, else from the USD stage's
timeCodesPerSecond (``read_fps``), else 30.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wface.controls import IDENTITY_BONES, jaw_to_intuitive
from wface.model import FaceModel
from wface.takes.dynamic import ResimResult
from wface.takes.pose import bone_projection_error_m
from wface.takes.take import Take

__all__ = [
    "CONTROLS",
    "DEFAULT_FPS",
    "FRAMES_DIR",
    "REPORT",
    "USD",
    "FrameRecord",
    "frame_numbers_on_disk",
    "frame_path",
    "load_frame_records",
    "load_take",
    "read_fps",
    "read_frame",
    "read_report",
    "take_from_records",
    "write_controls",
    "write_frame",
    "write_report",
    "write_resim_npz",
]

FRAMES_DIR = "frames"
CONTROLS = "controls.npz"
REPORT = "report.json"
USD = "animation.usdc"
DEFAULT_FPS = 30.0


# ---------------------------------------------------------------------- frame files
@dataclass
class FrameRecord:
    """What is kept of a tracked frame (also what a frame file holds)."""

    frame: int
    controls: np.ndarray
    x_m: np.ndarray  # (n, 3) world positions
    y_m: np.ndarray  # (n, 3) cranium-frame equilibrium
    markers_m: np.ndarray  # (k, 3)
    marker_error_m: np.ndarray  # (k,)
    stats: dict


def frame_path(out_dir: str | Path, frame: int) -> Path:
    """``out_dir/frames/frame_NNNNNN.npz`` of a frame number."""
    return Path(out_dir) / FRAMES_DIR / f"frame_{int(frame):06d}.npz"


def write_frame(out_dir: str | Path, rec: FrameRecord) -> Path:
    """Write one frame file atomically (a temporary file renamed into place)."""
    path = frame_path(out_dir, rec.frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part.npz")
    np.savez(
        tmp,
        frame=rec.frame,
        controls=rec.controls,
        x_m=rec.x_m,
        y_m=rec.y_m,
        markers_m=rec.markers_m,
        marker_error_m=rec.marker_error_m,
        stats_json=np.frombuffer(json.dumps(rec.stats).encode(), dtype=np.uint8),
    )
    os.replace(tmp, path)
    return path


def read_frame(path: str | Path) -> FrameRecord:
    """One frame file back into a ``FrameRecord``."""
    with np.load(path) as d:
        return FrameRecord(
            int(d["frame"]),
            d["controls"],
            d["x_m"],
            d["y_m"],
            d["markers_m"],
            d["marker_error_m"],
            json.loads(bytes(d["stats_json"]).decode()),
        )


def frame_numbers_on_disk(out_dir: str | Path) -> list[int]:
    """Frame numbers of the complete frame files under ``out_dir/frames`` (sorted)."""
    folder = Path(out_dir) / FRAMES_DIR
    if not folder.is_dir():
        return []
    return sorted(int(p.stem.split("_")[1]) for p in folder.glob("frame_*.npz") if ".part" not in p.name)


def load_frame_records(out_dir: str | Path, frames) -> dict[int, FrameRecord]:
    """Frame records already written under ``out_dir`` for the given frame numbers (a torn or
    unreadable file is left out, so that frame is tracked again)."""
    found = {}
    for f in frames:
        p = frame_path(out_dir, int(f))
        if p.exists():
            try:
                found[int(f)] = read_frame(p)
            except Exception:  # noqa: BLE001 - a torn file is simply redone
                continue
    return found


def take_from_records(model: FaceModel, records, *, fps: float = DEFAULT_FPS, source: str = "tracked") -> Take:
    """The ``Take`` of tracked frame records (controls c = (a, b) per frame; positions as reference)."""
    C = np.array([r.controls for r in records])
    M = model.n_muscles
    return Take(
        activations=np.clip(C[:, :M], 0.0, 1.0),
        fps=fps,
        bones=C[:, M:],
        muscle_names=list(model.muscle_names),
        frames=np.array([r.frame for r in records]),
        source=source,
        joint=model.jaw_joint,
    )


# ---------------------------------------------------------------------- controls and report
def write_controls(out_dir: str | Path, model: FaceModel, take: Take) -> tuple[Path, Path]:
    """controls.npz and controls.csv of a take: per-frame activations, bone parameters and jaw pose.

    The frame rate is stored in controls.npz, so ``wface edit`` and ``wface resim`` replay the take
    at its own rate even when no animation.usdc was written.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    M = model.n_muscles
    if take.n_muscles != M:
        raise ValueError(f"the take has {take.n_muscles} muscles, the model {M}")
    bones = take.bones if take.bones is not None else np.tile(IDENTITY_BONES, (take.n_frames, 1))
    jaw = [jaw_to_intuitive(model.jaw_joint, b[12:]) for b in bones]
    extra = {} if take.force_length_scale is None else {"force_length_scale": take.force_length_scale}
    npz = out_dir / CONTROLS
    np.savez(
        npz,
        **extra,
        fps=np.float64(take.fps),
        frames=take.frames,
        activations=take.activations,
        bones=bones,
        muscle_names=np.array(model.muscle_names),
        jaw_opening_deg=np.array([j["opening_deg"] for j in jaw]),
        jaw_protrusion_m=np.array([j["protrusion_m"] for j in jaw]),
        jaw_lateral_deg=np.array([j["lateral_deg"] for j in jaw]),
    )
    path = out_dir / "controls.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "frame",
                *model.muscle_names,
                "jaw_opening_deg",
                "jaw_protrusion_mm",
                "jaw_lateral_deg",
                *[f"cranium_{k}" for k in range(12)],
            ]
        )
        for fr, a, b, j in zip(take.frames, take.activations, bones, jaw, strict=True):
            w.writerow(
                [
                    int(fr),
                    *np.round(a, 6),
                    round(j["opening_deg"], 4),
                    round(j["protrusion_m"] * 1e3, 4),
                    round(j["lateral_deg"], 4),
                    *np.round(b[:12], 6),
                ]
            )
    return npz, path


def write_report(out_dir: str | Path, report: dict) -> Path:
    """report.json (indented, with a final newline)."""
    path = Path(out_dir) / REPORT
    path.write_text(json.dumps(report, indent=2) + "\n")
    return path


def read_report(out_dir: str | Path) -> dict | None:
    """report.json of a take directory, or None when there is none."""
    path = Path(out_dir) / REPORT
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None


def read_fps(path: str | Path) -> float | None:
    """The frame rate stored with a take: controls.npz's ``fps``, else the USD stage's
    timeCodesPerSecond, else None."""
    path = Path(path)
    controls = path / CONTROLS
    if controls.exists():
        with np.load(controls) as d:
            if "fps" in d.files:
                return float(d["fps"])
    for name in ("animation.usdc", "animation.usda", "animation.usd"):
        p = path / name
        if p.exists():
            try:
                from pxr import Usd

                return float(Usd.Stage.Open(str(p)).GetTimeCodesPerSecond())
            except Exception:  # noqa: BLE001 - the rate is a convenience; fall back to the default
                return None
    return None


# ---------------------------------------------------------------------- a whole take
def _read_controls(path: Path, model: FaceModel):
    """(frames, activations, bones, scale or None) of controls.npz."""
    with np.load(path) as d:
        if "muscle_names" in d.files and [str(s) for s in d["muscle_names"]] != list(model.muscle_names):
            names = ", ".join(str(s) for s in d["muscle_names"])
            raise ValueError(
                f"{path}: muscle names differ from the model's (was it tracked on another face?): the take has "
                f"{names}; the model has {', '.join(model.muscle_names)}: pass the --model it was tracked with"
            )
        scale = np.asarray(d["force_length_scale"], dtype=np.float64) if "force_length_scale" in d.files else None
        return np.asarray(d["frames"]), d["activations"], d["bones"], scale


def load_take(
    path: str | Path,
    model: FaceModel,
    *,
    fps: float | None = None,
    frames: slice | None = None,
    reference: bool = True,
) -> Take:
    """Read the take that ``wface track`` / ``demo`` / ``edit`` wrote under ``path``.

    Args:
        path: the take directory.
        model: the face the take was made on (node count, muscle names and counts are checked).
        fps: frame rate; default: the one stored with the take (``read_fps``), else 30.
        frames: optional slice of the take's frames (e.g. ``slice(0, 60)``).
        reference: also read the tracked positions of the frame files into
            ``reference_positions_m`` (T x n x 3 floats; False skips them when controls.npz is there).

    Returns:
        A ``Take`` with the model's muscle names and jaw joint; activations clipped into [0, 1]
        (a tracker's penalty lets them stray by round-off); ``info["frames"]`` and
        ``info["bone_projection_error_mm"]``: the largest attached-node distance between the take's
        bones and their rigid, on-joint projection in ``take.poses``.
    """
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(
            f"take directory {path} does not exist (give the --out of `wface track`, `wface demo` or `wface edit`)"
        )
    report = read_report(path)
    if report is not None and report.get("nodes") is not None and int(report["nodes"]) != model.n_nodes:
        raise ValueError(
            f"{path} was made on a face with {report['nodes']} nodes, this model has {model.n_nodes}: "
            "pass the same --model (or --tets) it was tracked with"
        )
    controls = path / CONTROLS
    on_disk = frame_numbers_on_disk(path)
    records = load_frame_records(path, on_disk) if on_disk and (reference or not controls.exists()) else {}
    scale = None
    if controls.exists():
        numbers, acts, bones, scale = _read_controls(controls, model)
    elif records:
        numbers = np.array(sorted(records))
        C = np.array([records[f].controls for f in numbers])
        acts, bones = C[:, : model.n_muscles], C[:, model.n_muscles :]
    else:
        raise FileNotFoundError(f"{path}: no controls.npz and no frames/frame_*.npz: not a tracking output directory")
    if acts.shape[1] != model.n_muscles or bones.shape[1] != 24:
        raise ValueError(
            f"{path}: controls have {acts.shape[1]} activations and {bones.shape[1]} bone parameters per frame; "
            f"the model has {model.n_muscles} muscles (and 24 bone parameters)"
        )
    tracked = None
    if reference and records and all(int(f) in records for f in numbers):
        tracked = np.array([records[int(f)].x_m for f in numbers])
        if tracked.shape[1] != model.n_nodes:
            raise ValueError(
                f"{path}: tracked frames have {tracked.shape[1]} nodes, the model {model.n_nodes}: wrong model?"
            )
    rows = np.arange(len(numbers))[frames or slice(None)]
    take = Take(
        activations=np.clip(acts[rows], 0.0, 1.0),
        fps=fps or read_fps(path) or DEFAULT_FPS,
        bones=bones[rows],
        muscle_names=list(model.muscle_names),
        frames=np.asarray(numbers)[rows],
        force_length_scale=None if scale is None else scale[rows],
        reference_positions_m=None if tracked is None else tracked[rows],
        source=str(path),
        joint=model.jaw_joint,
    )
    err = 0.0
    for pose, a, b in zip(take.poses, take.activations, take.bones, strict=True):
        err = max(err, bone_projection_error_m(model, np.concatenate([a, b]), pose))
    take.info.update({"frames": take.frames.tolist(), "bone_projection_error_mm": err * 1e3})
    return take


def write_resim_npz(path: str | Path, result: ResimResult, *, reference_positions_m: np.ndarray | None = None) -> Path:
    """resim.npz of a dynamic replay (``wface.takes.dynamic.ResimResult``): positions_m (T, n, 3), fps,
    scheme, the per-frame stats (and the quasistatic reference)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "positions_m": result.positions_m,
        "fps": np.float64(result.fps),
        "kinetic_energy_j": result.kinetic_energy_j,
        "newton_iterations": result.newton_iterations,
        "residual_rel": result.residual_rel,
        "inverted_elements": result.inverted_elements,
        "summary_json": np.frombuffer(
            json.dumps({k: v for k, v in result.summary().items() if not isinstance(v, list)}).encode(), dtype=np.uint8
        ),
    }
    if reference_positions_m is not None:
        arrays["reference_positions_m"] = reference_positions_m
    np.savez(path, **arrays)
    return path
