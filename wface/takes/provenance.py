"""Provenance of a take's files: what made each frame and output, as a fingerprint (docs/design.md, "Takes").

A *run* is described by a small JSON-able dict (``run_provenance``):

    kind            "track", "demo", "edit", "resim", ... (what wrote the directory)
    model_sha256    ``wface.model.model_sha256`` of the face
    source          where the input came from: a capture file's name, SHA-256, frame range and
                    neutral frame; a synthetic take's seed, size and corruption; an edit's inputs
    options         everything that changes the result: tracking options, solver, tolerance,
                    device, contact, the marker embedding's digest
    wface_version   ``wface.__version__``
    fingerprint     SHA-256 (16 hex digits) of all of the above

Two runs are *the same take* when kind, model and source agree (``same_take``): a directory that
holds one take's results is not written by another unless the user asks (``--overwrite``). A frame
file records the run and its own fingerprint, which also covers the frame number and the bytes of
that frame's marker data (``frame_fingerprint``), so ``--resume`` reuses a frame only when all of
it matches, and ``explain_mismatch`` says in words why another was redone.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from wface import __version__
from wface.model import model_sha256

__all__ = [
    "array_sha256",
    "command_provenance",
    "explain_mismatch",
    "frame_fingerprint",
    "run_provenance",
    "same_take",
    "describe_source",
]

_DIGITS = 16


def _digest(obj) -> str:
    text = json.dumps(obj, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:_DIGITS]


def array_sha256(*arrays: np.ndarray) -> str:
    """Hex SHA-256 of arrays' dtypes, shapes and bytes (NaN patterns included)."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def run_provenance(*, kind: str, model_sha256: str, source: dict, options: dict) -> dict:
    """The provenance dict of a run (see module docstring), with its ``fingerprint``."""
    body = {
        "kind": str(kind),
        "model_sha256": str(model_sha256),
        "source": json.loads(json.dumps(source, sort_keys=True, default=str)),
        "options": json.loads(json.dumps(options, sort_keys=True, default=str)),
        "wface_version": __version__,
    }
    body["fingerprint"] = _digest(body)
    return body


def frame_fingerprint(run: dict, frame: int, target_m: np.ndarray | None, *, extra: str | None = None) -> str:
    """Fingerprint of one frame of a run: the run's fingerprint, the frame number and the bytes of
    that frame's marker data ((k, 3) metres, or None where a frame has no data of its own); ``extra``:
    what else the frame depends on (e.g. the digest of a prior fitted over the whole take)."""
    data = "none" if target_m is None else array_sha256(np.asarray(target_m, dtype=np.float64))
    body = {"run": run["fingerprint"], "frame": int(frame), "data": data}
    if extra is not None:
        body["extra"] = str(extra)
    return _digest(body)


def same_take(a: dict | None, b: dict | None) -> bool:
    """True when two runs made the same take (kind, model and source agree; options may differ)."""
    if not a or not b:
        return False
    return all(a.get(k) == b.get(k) for k in ("kind", "model_sha256", "source"))


def describe_source(run: dict | None) -> str:
    """A short human description of what made a run ("wface track of JawMoCap.c3d frames 0:300 on model 1a2b...")."""
    if not run:
        return "results without provenance (written by an older wface or by hand)"
    src = run.get("source") or {}
    take = src.get("take")
    if isinstance(take, dict):  # a --take input, named by its path (and its own fingerprint, not shown)
        take = take.get("path")
    what = src.get("file") or (f"synthetic seed {src['seed']}" if "seed" in src else None) or take
    frames = src.get("frames")
    kind = run.get("kind", "?")
    text = f"wface {kind}"
    if what:
        text += f" of {what}"
    if frames is not None:  # a capture's frame range (track, demo) or the command's own --frames option
        text += f" frames {frames}" if kind in ("track", "demo") else f" (--frames {frames})"
    return text + f" on model {str(run.get('model_sha256', '?'))[:12]}"


def explain_mismatch(expected: dict, found: dict | None) -> str:
    """Why a recorded run differs from the expected one, in a few words (the first difference that
    matters: model, source, options, version)."""
    if not found:
        return "no provenance recorded"
    if found.get("kind") != expected.get("kind"):
        return f"made by wface {found.get('kind')}"
    if found.get("model_sha256") != expected.get("model_sha256"):
        return "another face model"
    if found.get("source") != expected.get("source"):
        a, b = found.get("source") or {}, expected.get("source") or {}
        keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        return "another input (" + ", ".join(keys) + " differ)"
    if found.get("options") != expected.get("options"):
        a, b = found.get("options") or {}, expected.get("options") or {}
        keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        return "other options (" + ", ".join(keys[:4]) + (", ..." if len(keys) > 4 else "") + ")"
    if found.get("wface_version") != expected.get("wface_version"):
        return f"another wface version ({found.get('wface_version')})"
    return "another fingerprint"


_NOT_OPTIONS = (
    "func",
    "out",
    "overwrite",
    "resume",
    "debug",
    "command",
    "json",
    "no_pictures",
    "no_movie",
    "no_usd",
    "dynamic_option_defaults",
    "contact_option_defaults",
)  # parser bookkeeping (the defaults that say which options were given), not options
_SOURCE_KEYS = (
    "take", "model", "tets", "mocap", "from_", "to", "mix", "expression", "add", "activation", "frames", "gesture",
    "speech_dir",
)  # fmt: skip


def command_provenance(kind: str, model, args) -> dict:
    """The provenance of a command run from its parsed arguments (``argparse.Namespace``): the inputs
    (take, model, expressions, ...) are its source, the other options its options. A ``--take``
    input is named by its own recorded fingerprint where it has one."""
    values = {k: v for k, v in sorted(vars(args).items()) if k not in _NOT_OPTIONS and not callable(v)}
    source = {k: values.pop(k) for k in _SOURCE_KEYS if k in values}
    take = source.get("take")
    if take:
        try:
            recorded = json.loads((Path(take) / "provenance.json").read_text())
            source["take"] = {"path": str(take), "fingerprint": recorded.get("fingerprint")}
        except (OSError, ValueError):
            source["take"] = {"path": str(take)}
    return run_provenance(kind=kind, model_sha256=model_sha256(model), source=source, options=values)
