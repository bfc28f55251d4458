"""The face a command that reads a take works on: ``--model``, ``--tets``, else the one the take was made on.

``wface track`` and ``wface demo`` record it in report.json (``face_model``: the model file's absolute
path, or the built-in face's ``--tets``), so ``wface resim --take`` and ``wface edit ... --take`` need
neither option again (they said "pass the same --model (or --tets)" after building a face of the
wrong size).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from wface.faces.builtin import build_face
from wface.model import load_model
from wface.takes.store import REPORT

__all__ = ["DEFAULT_TETS", "face_for_take", "face_record"]

DEFAULT_TETS = 5000


def face_record(args) -> dict:
    """What report.json records of the face a run used (module docstring)."""
    if getattr(args, "model", None):
        return {"path": str(Path(args.model).resolve())}
    return {"builtin_tets": int(args.tets)}


def face_for_take(args, *, progress: bool = False):
    """The face model for ``args`` (module docstring); says on stderr when the take chose it."""
    if args.model:
        return load_model(args.model)
    if args.tets is not None or not getattr(args, "take", None):
        return build_face(DEFAULT_TETS if args.tets is None else args.tets, progress=progress)
    try:
        record = json.loads((Path(args.take) / REPORT).read_text()).get("face_model") or {}
    except (OSError, ValueError):
        record = {}
    if "path" in record and Path(record["path"]).is_file():
        print(f"face model from the take: {record['path']} (--model or --tets to choose another)", file=sys.stderr)
        return load_model(record["path"])
    if "builtin_tets" in record:
        tets = int(record["builtin_tets"])
        print(f"face from the take: the built-in face at --tets {tets} (--model or --tets to choose another)",
              file=sys.stderr)  # fmt: skip
        return build_face(tets, progress=progress)
    return build_face(DEFAULT_TETS, progress=progress)
