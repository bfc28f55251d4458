"""Frame files of a take: one tracked frame each, written as soon as it is done (docs/design.md, "Takes").

``frames/frame_NNNNNN.npz`` holds a ``FrameRecord``: the frame number, the controls, the world and
cranium-frame node positions, the simulated markers and their errors, the frame's stats, the
tracker's carried state (so a resumed run continues bit for bit) and the frame's provenance
(``wface.takes.provenance``). Files are written atomically (``wface.files``); ``verified_frames``
decides which files ``--resume`` may reuse and says why the others are redone. ``wface.takes.store``
owns the rest of the take directory and re-exports these names.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wface.files import FileFormatError, atomic_path, is_temporary, load_npz, save_npz
from wface.takes.provenance import explain_mismatch, frame_fingerprint

__all__ = [
    "FRAMES_DIR",
    "REFINE_DIR_PREFIX",
    "SURVEY_DIR",
    "FrameRecord",
    "ResumePlan",
    "decode_json",
    "frame_numbers_on_disk",
    "frame_path",
    "json_bytes",
    "link_frame",
    "load_frame_records",
    "read_frame",
    "resume_plan",
    "verified_frames",
    "write_frame",
]

FRAMES_DIR = "frames"
SURVEY_DIR = "survey"  # the first pass of a two-pass tracking run (``wface.tracking.sequence``)
REFINE_DIR_PREFIX = "refine"  # refine2, refine3, ..: the passes between the first and the last


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
    state: dict = field(default_factory=dict)  # name -> array: what the tracker carries to the next frame
    provenance: dict | None = None  # {"run": run provenance, "frame": f, "fingerprint": ...}


def frame_path(out_dir: str | Path, frame: int, *, folder: str = FRAMES_DIR) -> Path:
    """``out_dir/frames/frame_NNNNNN.npz`` of a frame number (``folder``: another folder of the take)."""
    return Path(out_dir) / folder / f"frame_{int(frame):06d}.npz"


def json_bytes(obj) -> np.ndarray:
    return np.frombuffer(json.dumps(obj).encode(), dtype=np.uint8)


def write_frame(out_dir: str | Path, rec: FrameRecord, *, folder: str = FRAMES_DIR) -> Path:
    """Write one frame file atomically (a temporary file renamed into place, ``wface.files``)."""
    extra = {f"state/{k}": np.asarray(v) for k, v in rec.state.items()}
    if rec.provenance is not None:
        extra["provenance_json"] = json_bytes(rec.provenance)
    return save_npz(
        frame_path(out_dir, rec.frame, folder=folder),
        frame=rec.frame,
        controls=rec.controls,
        x_m=rec.x_m,
        y_m=rec.y_m,
        markers_m=rec.markers_m,
        marker_error_m=rec.marker_error_m,
        stats_json=json_bytes(rec.stats),
        **extra,
    )


_FRAME_KEYS = ("frame", "controls", "x_m", "y_m", "markers_m", "marker_error_m", "stats_json")


def link_frame(out_dir: str | Path, rec: FrameRecord, *, source: str, folder: str = FRAMES_DIR) -> Path:
    """Put ``rec``'s frame file, already written under the take's ``source`` folder, under ``folder`` as
    well: a hard link, so the two folders share one file on disk (a later rewrite of either replaces
    its own entry, atomically, and leaves the other's), or a fresh write of ``rec`` where the file
    system has no hard links or the source is gone."""
    src = frame_path(out_dir, rec.frame, folder=source)
    dst = frame_path(out_dir, rec.frame, folder=folder)
    try:
        with atomic_path(dst) as tmp:
            os.link(src, tmp)
        return dst
    except OSError:
        return write_frame(out_dir, rec, folder=folder)


def decode_json(d: dict, key: str, path: Path):
    try:
        return json.loads(bytes(d[key]).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(f"{path}: corrupted {key} ({exc})") from None


def read_frame(path: str | Path) -> FrameRecord:
    """One frame file back into a ``FrameRecord`` (``FileFormatError`` naming the file when it is
    empty, truncated, corrupted or not a frame file)."""
    path = Path(path)
    d = load_npz(path, what="a tracked frame file", required=_FRAME_KEYS)
    return FrameRecord(
        int(d["frame"]),
        d["controls"],
        d["x_m"],
        d["y_m"],
        d["markers_m"],
        d["marker_error_m"],
        decode_json(d, "stats_json", path),
        {k.split("/", 1)[1]: v for k, v in d.items() if k.startswith("state/")},
        decode_json(d, "provenance_json", path) if "provenance_json" in d else None,
    )


def frame_numbers_on_disk(out_dir: str | Path, *, folder: str = FRAMES_DIR) -> list[int]:
    """Frame numbers of the frame files under ``out_dir/frames`` (sorted; temporaries of unfinished
    writes and files not named ``frame_<number>.npz`` are ignored)."""
    where = Path(out_dir) / folder
    if not where.is_dir():
        return []
    out = []
    for p in where.glob("frame_*.npz"):
        tail = p.stem.split("_", 1)[1]
        if not is_temporary(p) and ".part" not in p.name and tail.isdigit():
            out.append(int(tail))
    return sorted(out)


def load_frame_records(out_dir: str | Path, frames) -> dict[int, FrameRecord]:
    """Frame records already written under ``out_dir`` for the given frame numbers (a torn or
    unreadable file, or one that holds another frame, is left out). No provenance check: for
    reading a take; ``verified_frames`` is the check ``--resume`` makes."""
    found = {}
    for f in frames:
        p = frame_path(out_dir, int(f))
        if p.exists():
            try:
                rec = read_frame(p)
            except (FileFormatError, OSError):
                continue
            if rec.frame == int(f):
                found[int(f)] = rec
    return found


def verified_frames(
    out_dir: str | Path, frames, targets_m, run: dict, *, folder: str = FRAMES_DIR, extra: str | None = None
) -> tuple[dict[int, FrameRecord], dict[int, str]]:
    """The frame files under ``out_dir`` that this run may reuse, and why the others present may not.

    Args:
        out_dir: the take directory.
        frames: frame numbers wanted.
        targets_m: (len(frames), k, 3) the marker data of those frames (the frame fingerprints cover it).
        run: the run's provenance (``wface.takes.provenance.run_provenance``).
        folder: the folder of frame files (``frames``, or ``survey`` for a first pass).
        extra: what else the frames depend on (``wface.takes.provenance.frame_fingerprint``).

    Returns:
        ({frame: record} reusable, {frame: reason} present but to be tracked again).
    """
    ok: dict[int, FrameRecord] = {}
    redo: dict[int, str] = {}
    for f, target in zip(frames, targets_m, strict=True):
        f = int(f)
        p = frame_path(out_dir, f, folder=folder)
        if not p.exists():
            continue
        try:
            rec = read_frame(p)
        except (FileFormatError, OSError):
            redo[f] = "unreadable (torn or corrupted) file"
            continue
        prov = rec.provenance or {}
        if rec.frame != f:
            redo[f] = f"the file holds frame {rec.frame}"
        elif not prov:
            redo[f] = "no provenance recorded"
        elif prov.get("fingerprint") != frame_fingerprint(run, f, target, extra=extra):
            why = explain_mismatch(run, prov.get("run"))
            if why == "another fingerprint":
                why = "another take-wide prior" if prov.get("extra") != extra else "other marker data for this frame"
            redo[f] = why
        else:
            ok[f] = rec
    return ok, redo


@dataclass
class ResumePlan:
    """What ``--resume`` found: frames reused and frames present but redone (with the reason).

    For a two-pass run (``first_pass``) the frames are the first pass's; ``second_on_disk`` counts the
    second pass's frame files, reused only if the take-wide prior fitted to the first pass comes out
    the same (checked by fingerprint once it is fitted)."""

    wanted: int
    reused: list[int]
    redo: dict[int, str]
    first_pass: bool = False
    second_on_disk: int = 0

    def summary(self) -> str:
        """One line, e.g. "resume: reusing 7 of 10 frames; redoing 2 (2 another face model); 1 still to track"."""
        left = self.wanted - len(self.reused) - len(self.redo)
        head = "resume (first pass)" if self.first_pass else "resume"
        text = f"{head}: reusing {len(self.reused)} of {self.wanted} frames"
        if self.redo:
            why = Counter(self.redo.values())
            text += f"; redoing {len(self.redo)} (" + ", ".join(f"{n} {r}" for r, n in why.most_common()) + ")"
        if left:
            text += f"; {left} still to track"
        if self.first_pass:
            text += (
                f"; {self.second_on_disk} second-pass frames on disk, reused if the take-wide prior comes out the same"
            )
        return text


def resume_plan(
    out_dir: str | Path,
    frames,
    targets_m,
    run: dict,
    *,
    folder: str = FRAMES_DIR,
    extra: str | None = None,
    two_pass: bool = False,
) -> ResumePlan:
    """The ``ResumePlan`` of a run over ``frames`` with marker data ``targets_m`` (see ``verified_frames``);
    ``two_pass``: a two-pass tracking run (``TrackOptions.prior == "auto"``), whose first pass is checked."""
    frames = [int(f) for f in frames]
    if two_pass:
        ok, redo = verified_frames(out_dir, frames, targets_m, run, folder=SURVEY_DIR)
        second = len(set(frame_numbers_on_disk(out_dir)) & set(frames))
        return ResumePlan(len(frames), sorted(ok), redo, first_pass=True, second_on_disk=second)
    ok, redo = verified_frames(out_dir, frames, targets_m, run, folder=folder, extra=extra)
    return ResumePlan(len(frames), sorted(ok), redo)
