"""The take store: the one module that owns a take's files on disk.

A take directory (what ``wface track``, ``wface demo``, ``wface edit`` and ``wface resim`` write)::

    provenance.json           what made the take (``wface.takes.provenance``), written when a run
                              claims the directory (``claim_take_dir``)
    frames/frame_NNNNNN.npz   one tracked frame each (``FrameRecord``: frame number, controls, world
                              and cranium-frame node positions, simulated markers, marker errors,
                              stats, the tracker's carried state, the frame's provenance), written
                              atomically as soon as the frame is done
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

Every file is written through ``wface.files`` (a temporary file renamed into place: a kill leaves the
old file or the new one, never a torn one) and every read error names the file. controls.npz and
report.json carry the run's provenance; ``--resume`` reuses a frame file only when its fingerprint
matches the run's (``verified_frames``), and a directory holding another take is not written unless
asked (``claim_take_dir``).
"""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import numpy as np

from wface.controls import IDENTITY_BONES, jaw_to_intuitive
from wface.files import FileFormatError, load_npz, read_json, save_npz, write_csv, write_json
from wface.model import FaceModel
from wface.takes.dynamic import ResimResult
from wface.takes.frames import (
    FRAMES_DIR,
    REFINE_DIR_PREFIX,
    SURVEY_DIR,
    FrameRecord,
    ResumePlan,
    decode_json,
    frame_numbers_on_disk,
    frame_path,
    json_bytes,
    link_frame,
    load_frame_records,
    read_frame,
    resume_plan,
    verified_frames,
    write_frame,
)
from wface.takes.pose import bone_projection_error_m
from wface.takes.provenance import describe_source, explain_mismatch, same_take
from wface.takes.take import Take

__all__ = [
    "CONTROLS",
    "DEFAULT_FPS",
    "FRAMES_DIR",
    "PROVENANCE",
    "SURVEY_DIR",
    "REPORT",
    "USD",
    "FrameRecord",
    "ResumePlan",
    "TakeDirectoryError",
    "claim_take_dir",
    "frame_numbers_on_disk",
    "frame_path",
    "link_frame",
    "load_frame_records",
    "load_take",
    "require_take_dir",
    "read_fps",
    "read_frame",
    "read_report",
    "recorded_run",
    "resume_plan",
    "take_from_records",
    "verified_frames",
    "write_controls",
    "write_frame",
    "write_report",
    "write_resim_npz",
]

CONTROLS = "controls.npz"
REPORT = "report.json"
USD = "animation.usdc"
PROVENANCE = "provenance.json"
DEFAULT_FPS = 30.0
# what a take directory's results are (cleared by --overwrite or a restart of the same take)
TAKE_FILES = (CONTROLS, "controls.csv", REPORT, USD, "resim.npz", "truth.npz", "report.html")


class TakeDirectoryError(ValueError):
    """An output directory holds another take's results (or cannot hold a take)."""


# ---------------------------------------------------------------------- the take directory
def recorded_run(out_dir: str | Path) -> dict | None:
    """The provenance of the run that owns ``out_dir``: provenance.json, else report.json's or
    controls.npz's ``provenance``, else a frame file's; None when nothing records one."""
    out = Path(out_dir)
    try:
        if (out / PROVENANCE).exists():
            return read_json(out / PROVENANCE, what="a take's provenance")
        report = read_report(out)
        if report and report.get("provenance"):
            return report["provenance"]
        if (out / CONTROLS).exists():
            d = load_npz(out / CONTROLS, what="a take's controls")
            if "provenance_json" in d:
                return decode_json(d, "provenance_json", out / CONTROLS)
    except FileFormatError:
        return None
    for f in frame_numbers_on_disk(out)[:1]:
        try:
            prov = read_frame(frame_path(out, f)).provenance
        except (FileFormatError, OSError):
            return None
        return (prov or {}).get("run")
    return None


def _has_results(out: Path) -> bool:
    frames = frame_numbers_on_disk(out) or frame_numbers_on_disk(out, folder=SURVEY_DIR)
    return any((out / name).exists() for name in (*TAKE_FILES, PROVENANCE)) or bool(frames)


def _pass_dirs(out: Path) -> list[Path]:
    """The frame directories of every tracking pass in ``out`` (survey, refine passes, final frames)."""
    names = (SURVEY_DIR, *sorted(p.name for p in out.glob(f"{REFINE_DIR_PREFIX}*")), FRAMES_DIR)
    return [out / n for n in names if (out / n).is_dir()]


def _clear_results(out: Path) -> None:
    for name in (*TAKE_FILES, PROVENANCE):
        if (out / name).is_file():
            (out / name).unlink()
    for d in _pass_dirs(out):
        shutil.rmtree(d)


def claim_take_dir(out_dir: str | Path, run: dict, *, resume: bool = False, overwrite: bool = False) -> str:
    """Make ``out_dir`` the directory of this run's take, or refuse.

    A directory that holds another take's results (another kind of run, model or input, or results
    without provenance) is refused unless ``overwrite``, which clears them first. The same take
    again is continued with ``resume`` (frames are then reused only where their fingerprints match,
    ``verified_frames``); without it, it is refused while it holds finished frames (a plain rerun
    after Ctrl-C threw hours of frames away; ``wface track`` resumes the very same run by itself)
    and started again otherwise, its old results cleared so that no stale frame survives. Writes
    provenance.json.

    Returns:
        A line saying what was found and done ("" for a new directory).

    Raises:
        TakeDirectoryError: another take is there, or ``out_dir`` is a file.
        PermissionError: ``out_dir`` cannot be written.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise TakeDirectoryError(f"{out}: is a file, not a directory: give --out a directory")
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK | os.X_OK):
        raise PermissionError(f"{out}: directory is not writable")
    note = ""
    if _has_results(out):
        found = recorded_run(out)
        if overwrite:
            _clear_results(out)
            note = f"--overwrite: removed the earlier results in {out} ({describe_source(found)})"
        elif not same_take(found, run):
            raise TakeDirectoryError(
                f"{out} holds another take's results ({describe_source(found)}; this run is "
                f"{describe_source(run)}; {explain_mismatch(run, found)}): choose another --out, or pass "
                "--overwrite to replace them"
            )
        elif not resume:
            kept = [(d.name, sum(1 for _ in d.glob("*.npz"))) for d in _pass_dirs(out)]
            if any(n for _, n in kept):  # finished work is not thrown away unasked (a rerun after Ctrl-C)
                done = ", ".join(f"{n} in {name}/" for name, n in kept if n)
                why = explain_mismatch(run, found) if (found or {}).get("fingerprint") != run.get("fingerprint") else ""
                raise TakeDirectoryError(
                    f"{out} holds this take's finished frames ({done}{'; ' + why if why else ''}): pass --resume "
                    "to continue from them (frames made otherwise are redone), or --overwrite to start again"
                )
            _clear_results(out)
            note = f"starting this take again in {out} (it held no finished frames)"
    for where in (out, out / FRAMES_DIR, out / SURVEY_DIR):
        for tmp in where.glob(".*.part-*") if where.is_dir() else ():
            tmp.unlink(missing_ok=True)  # a killed writer's temporary file
    write_json(out / PROVENANCE, run)
    return note


def take_from_records(model: FaceModel, records, *, fps: float = DEFAULT_FPS, source: str = "tracked") -> Take:
    """The ``Take`` of tracked frame records (controls c = (a, b) per frame; positions as reference)."""
    C = np.array([r.controls for r in records])
    M = model.n_muscles
    return Take(
        activations=model.clip_activations(C[:, :M]),
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
    run = _directory_run(out_dir)
    if run is not None:
        extra["provenance_json"] = json_bytes(run)
    npz = save_npz(
        out_dir / CONTROLS,
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
    header = [
        "frame",
        *model.muscle_names,
        "jaw_opening_deg",
        "jaw_protrusion_mm",
        "jaw_lateral_deg",
        *[f"cranium_{k}" for k in range(12)],
    ]
    rows = (
        [
            int(fr),
            *(np.round(a, 6) + 0.0),  # + 0.0: no "-0.0" cells (a value rounded to zero from below)
            round(j["opening_deg"], 4) + 0.0,
            round(j["protrusion_m"] * 1e3, 4) + 0.0,
            round(j["lateral_deg"], 4) + 0.0,
            *(np.round(b[:12], 6) + 0.0),
        ]
        for fr, a, b, j in zip(take.frames, take.activations, bones, jaw, strict=True)
    )
    path = write_csv(out_dir / "controls.csv", header, rows)
    return npz, path


def _directory_run(out_dir: Path) -> dict | None:
    """provenance.json of a take directory (what ``claim_take_dir`` wrote), or None."""
    path = Path(out_dir) / PROVENANCE
    try:
        return read_json(path, what="a take's provenance") if path.exists() else None
    except FileFormatError:
        return None


def write_report(out_dir: str | Path, report: dict) -> Path:
    """report.json (indented, with a final newline, written atomically); it records the directory's
    provenance (provenance.json) under ``provenance`` unless the report already has one."""
    run = _directory_run(Path(out_dir))
    if run is not None and "provenance" not in report:
        report = {**report, "provenance": run}
    return write_json(Path(out_dir) / REPORT, report)


def read_report(out_dir: str | Path) -> dict | None:
    """report.json of a take directory, or None when there is none (``FileFormatError`` naming the
    file when it is empty or not JSON)."""
    path = Path(out_dir) / REPORT
    if not path.exists():
        return None
    return read_json(path, what="a take's report.json")


def read_fps(path: str | Path) -> float | None:
    """The frame rate stored with a take: controls.npz's ``fps``, else the USD stage's
    timeCodesPerSecond, else None."""
    path = Path(path)
    controls = path / CONTROLS
    if controls.exists():
        try:
            d = load_npz(controls, what="a take's controls")
        except FileFormatError:
            d = {}
        if "fps" in d:
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
    """(frames, activations, bones, scale or None, provenance or None) of controls.npz."""
    d = load_npz(path, what="a take's controls.npz", required=("frames", "activations", "bones"))
    if "muscle_names" in d and [str(s) for s in d["muscle_names"]] != list(model.muscle_names):
        names = ", ".join(str(s) for s in d["muscle_names"])
        raise ValueError(
            f"{path}: muscle names differ from the model's (was it tracked on another face?): the take has "
            f"{names}; the model has {', '.join(model.muscle_names)}: pass the --model it was tracked with"
        )
    scale = np.asarray(d["force_length_scale"], dtype=np.float64) if "force_length_scale" in d else None
    run = decode_json(d, "provenance_json", path) if "provenance_json" in d else None
    return np.asarray(d["frames"]), d["activations"], d["bones"], scale, run


def require_take_dir(path: str | Path) -> Path:
    """``path`` as a Path if it is a take directory (controls.npz or frame files in it: what
    ``load_take`` reads) or a take's controls.npz (its directory is returned), else FileNotFoundError
    saying what it is not. Cheap: commands call it before
    they build or load a face."""
    path = Path(path)
    if path.is_file() and path.name == CONTROLS:  # the take's controls.npz itself: its directory is the take
        path = path.parent
    if path.is_file():
        raise FileNotFoundError(
            f"{path} is a file, not a take directory (give the --out of `wface track`, `wface demo` or `wface edit`)"
        )
    if not path.is_dir():
        raise FileNotFoundError(
            f"take directory {path} does not exist (give the --out of `wface track`, `wface demo` or `wface edit`)"
        )
    if not (path / CONTROLS).exists() and not frame_numbers_on_disk(path):
        raise FileNotFoundError(
            f"{path}: no controls.npz and no frames/frame_*.npz: not a tracking output directory "
            "(give the --out of `wface track`, `wface demo` or `wface edit`)"
        )
    return path


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
    path = require_take_dir(path)
    try:
        report = read_report(path)
    except FileFormatError as exc:
        warnings.warn(f"{exc}; reading the take without it", stacklevel=2)
        report = None
    if report is not None and report.get("nodes") is not None and int(report["nodes"]) != model.n_nodes:
        raise ValueError(
            f"{path} was made on a face with {report['nodes']} nodes, this model has {model.n_nodes}: "
            "pass the same --model (or --tets) it was tracked with"
        )
    controls = path / CONTROLS
    on_disk = frame_numbers_on_disk(path)
    records = load_frame_records(path, on_disk) if on_disk and (reference or not controls.exists()) else {}
    scale = run = None
    if controls.exists():
        try:
            numbers, acts, bones, scale, run = _read_controls(controls, model)
        except FileFormatError as exc:
            if not on_disk:
                raise
            warnings.warn(f"{exc}; reading the take from its frame files instead", stacklevel=2)
            records = records or load_frame_records(path, on_disk)
            controls = path / "frames"  # read below from the records
    if not controls.exists() or controls.is_dir():
        if not records:
            raise FileNotFoundError(
                f"{path}: no readable controls.npz and no readable frames/frame_*.npz: not a tracking output directory"
            )
        if len(records) < len(on_disk):
            bad = sorted(set(on_disk) - set(records))
            warnings.warn(
                f"{path}: {len(bad)} frame files are unreadable (first {frame_path(path, bad[0]).name}); "
                "the take is read without those frames",
                stacklevel=2,
            )
        numbers = np.array(sorted(records))
        C = np.array([records[f].controls for f in numbers])
        acts, bones = C[:, : model.n_muscles], C[:, model.n_muscles :]
    if acts.shape[1] != model.n_muscles or bones.shape[1] != 24:
        raise ValueError(
            f"{path}: controls have {acts.shape[1]} activations and {bones.shape[1]} bone parameters per frame; "
            f"the model has {model.n_muscles} muscles (and 24 bone parameters)"
        )
    tracked = None
    mine = (run or {}).get("fingerprint")
    foreign = [f for f in numbers if mine and int(f) in records and _frame_run(records[int(f)]) not in (None, mine)]
    if foreign:
        warnings.warn(
            f"{path}: {len(foreign)} frame files (first {frame_path(path, foreign[0]).name}) were made by another "
            "run than controls.npz; their tracked positions are not used as the reference",
            stacklevel=2,
        )
        records = {}
    if reference and records and all(int(f) in records for f in numbers):
        tracked = np.array([records[int(f)].x_m for f in numbers])
        if tracked.shape[1] != model.n_nodes:
            raise ValueError(
                f"{path}: tracked frames have {tracked.shape[1]} nodes, the model {model.n_nodes}: wrong model?"
            )
    rows = np.arange(len(numbers))[frames or slice(None)]
    if not len(rows):
        f = frames or slice(None)
        raise ValueError(
            f"{path}: the frame range {'' if f.start is None else f.start}:{'' if f.stop is None else f.stop} "
            f"selects none of the take's {len(numbers)} frames (positions 0 to {len(numbers) - 1})"
        )
    take = Take(
        activations=model.clip_activations(acts[rows]),
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


def _frame_run(rec: FrameRecord) -> str | None:
    """The run fingerprint a frame file records (None without provenance)."""
    return ((rec.provenance or {}).get("run") or {}).get("fingerprint")


def write_resim_npz(path: str | Path, result: ResimResult, *, reference_positions_m: np.ndarray | None = None) -> Path:
    """resim.npz of a dynamic replay (``wface.takes.dynamic.ResimResult``): positions_m (T, n, 3), fps,
    scheme, the per-frame stats (and the quasistatic reference)."""
    path = Path(path)
    arrays = {
        "positions_m": result.positions_m,
        "fps": np.float64(result.fps),
        "kinetic_energy_j": result.kinetic_energy_j,
        "newton_iterations": result.newton_iterations,
        "residual_rel": result.residual_rel,
        "inverted_elements": result.inverted_elements,
        "summary_json": json_bytes({k: v for k, v in result.summary().items() if not isinstance(v, list)}),
    }
    if reference_positions_m is not None:
        arrays["reference_positions_m"] = reference_positions_m
    return save_npz(path, **arrays)
