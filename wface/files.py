"""Atomic writes and named read errors: the one place every writer and reader of wface's files goes through.

Writes: the content goes to a hidden temporary file in the destination's folder (same suffix, so
format-by-extension writers such as numpy, matplotlib and USD keep working), is flushed to disk and
renamed over the destination (``os.replace``, atomic on POSIX and Windows). A crash or a kill
leaves either the old file or the new one under the real name, never a torn or empty one; the
temporary file of an interrupted write is removed when the writer raises, and ``.part-`` files of
a killed process are ignored by every reader (they do not carry the real name).

Reads: ``FileFormatError`` (a ``ValueError``) names the file and what is wrong with it: empty (an
interrupted write of an older version), truncated, a bad checksum, not the format it should be,
keys missing. npz archives are read eagerly inside the check, so a corrupted member fails here with
the file's name instead of later as a bare ``zipfile`` or ``EOFError``.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import math
import os
import secrets
import zipfile
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

__all__ = [
    "FileFormatError",
    "atomic_path",
    "file_sha256",
    "is_temporary",
    "load_npz",
    "read_json",
    "read_landmarks",
    "save_layer",
    "save_npz",
    "write_bytes",
    "write_csv",
    "write_json",
    "without_timings",
    "write_text",
]

_PART = ".part-"


class FileFormatError(ValueError):
    """A file exists but cannot be read as what it should be; the message names the file and the problem."""


def is_temporary(path: str | Path) -> bool:
    """True for the temporary file of an unfinished atomic write (never a result)."""
    return _PART in Path(path).name


def _check_destination(path: Path) -> None:
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, cannot write a file there")
    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise NotADirectoryError(f"{parent}: is a file, not a directory (cannot write {path.name} into it)")
    parent.mkdir(parents=True, exist_ok=True)
    if not os.access(parent, os.W_OK):
        raise PermissionError(f"{parent}: directory is not writable (cannot write {path.name})")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix) to write to; on success it is renamed over
    ``path``, on an exception it is removed and ``path`` is left as it was.

    Example::

        with atomic_path(out / "plot.png") as tmp:
            fig.savefig(tmp)
    """
    path = Path(path)
    _check_destination(path)
    tmp = path.with_name(f".{path.stem}{_PART}{os.getpid()}-{secrets.token_hex(3)}{path.suffix}")
    try:
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(f"{path}: the writer produced no file")
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically. Returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically. Returns the path."""
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | Path, obj, *, indent: int | None = 2) -> Path:
    """Write ``obj`` as JSON (with a final newline) atomically. Returns the path."""
    return write_text(path, json.dumps(obj, indent=indent) + "\n")


def write_csv(path: str | Path, header: list[str], rows: Iterable[Iterable]) -> Path:
    """Write a CSV file (one header row, then ``rows``) atomically. Returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def save_npz(path: str | Path, *, compressed: bool = False, **arrays) -> Path:
    """``np.savez`` (``np.savez_compressed`` with ``compressed``) to ``path`` atomically. Returns the path."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"{path}: npz archives must end in .npz")
    with atomic_path(path) as tmp:
        (np.savez_compressed if compressed else np.savez)(tmp, **arrays)
    return path


def save_layer(layer, path: str | Path) -> Path:
    """Save a USD layer (``pxr.Sdf.Layer``, e.g. ``stage.GetRootLayer()``) to ``path`` atomically: the layer
    is exported to a temporary file of the same format and renamed into place. Returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        if not layer.Export(str(tmp)):
            raise OSError(f"{path}: USD could not write the stage")
    return path


def _size_problem(path: Path, what: str) -> None:
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file ({what})")
    if path.is_dir():
        raise FileFormatError(f"{path}: is a directory, expected {what}")
    if path.stat().st_size == 0:
        raise FileFormatError(f"{path}: file is empty (0 bytes; an interrupted write?), expected {what}")


def load_npz(path: str | Path, *, what: str = "an .npz archive", required: Iterable[str] = ()) -> dict[str, np.ndarray]:
    """Read every array of an .npz archive (eagerly; no pickles).

    Args:
        path: the archive.
        what: what the file should be, for messages (e.g. "a tracked frame file").
        required: keys that must be present.

    Returns:
        {name: array}.

    Raises:
        FileNotFoundError: no file at ``path``.
        FileFormatError: empty, truncated, a bad checksum, not an npz archive, or a required key missing.
    """
    path = Path(path)
    _size_problem(path, what)
    if not zipfile.is_zipfile(path):
        raise FileFormatError(f"{path}: not {what} (not an .npz archive: no zip directory; truncated or other format?)")
    try:
        with np.load(path, allow_pickle=False) as data:
            out = {k: data[k] for k in data.files}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
        text = str(exc) or type(exc).__name__
        kind = "corrupted (bad checksum)" if "CRC" in text else "truncated or corrupted"
        raise FileFormatError(f"{path}: {kind}, not readable as {what} ({text})") from None
    missing = [k for k in required if k not in out]
    if missing:
        raise FileFormatError(f"{path}: not {what}: missing {', '.join(missing)}")
    return out


def _unique_keys(pairs: list) -> dict:
    """A JSON object's dict, refusing a key given twice (``json`` keeps the last one without a word)."""
    out = {}
    for key, value in pairs:
        if key in out:
            raise FileFormatError(f"the key {key!r} is given twice")
        out[key] = value
    return out


def read_json(path: str | Path, *, what: str = "a JSON file", unique_keys: bool = False):
    """Parse a JSON file; errors name the file, the line and the column (``unique_keys``: and a key
    that an object gives twice)."""
    path = Path(path)
    _size_problem(path, what)
    try:
        return json.loads(path.read_text(encoding="utf-8"), object_pairs_hook=_unique_keys if unique_keys else None)
    except FileFormatError as exc:
        raise FileFormatError(f"{path}: {exc}; expected {what}") from None
    except UnicodeDecodeError as exc:
        raise FileFormatError(f"{path}: not {what}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise FileFormatError(
            f"{path}: not valid JSON at line {exc.lineno}, column {exc.colno} ({exc.msg}); expected {what}"
        ) from None


def read_landmarks(path: str | Path, *, n_vertices: int | None = None, points: bool = False) -> dict:
    """A landmark file: a JSON object {name: vertex index} (or, with ``points``, {name: [x, y, z]} in the
    mesh's units as well). Errors name the file, the landmark and what was expected.

    Args:
        path: the JSON file.
        n_vertices: vertex indices must lie in [0, n_vertices) when given.
        points: also accept a point [x, y, z] per name.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"landmark file not found: {path}")
    form = "{name: vertex index}" + (" or {name: [x, y, z]}" if points else "")
    data = read_json(path, what=f"a landmark JSON file {form}", unique_keys=True)
    if not isinstance(data, dict):
        raise FileFormatError(f"{path}: expected a JSON object {form}, got a {type(data).__name__}")
    if not data:
        raise FileFormatError(f"{path}: holds no landmarks (expected {form})")
    out = {}
    for name, v in data.items():
        if isinstance(v, int) and not isinstance(v, bool):
            if v < 0 or (n_vertices is not None and v >= n_vertices):
                top = f"[0, {n_vertices})" if n_vertices is not None else ">= 0"
                raise FileFormatError(f"{path}: landmark {name!r}: vertex index {v} is not in {top}")
            out[str(name)] = v
        elif points and isinstance(v, list) and len(v) == 3 and all(isinstance(c, int | float) for c in v):
            if not all(math.isfinite(c) for c in v):  # json reads NaN and Infinity
                raise FileFormatError(f"{path}: landmark {name!r}: the point {v!r} is not 3 finite numbers")
            out[str(name)] = [float(c) for c in v]
        else:
            raise FileFormatError(f"{path}: landmark {name!r}: {v!r} is not a vertex index (expected {form})")
    return out


def file_sha256(path: str | Path, *, chunk_bytes: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(chunk_bytes), b""):
            h.update(block)
    return h.hexdigest()


def without_timings(report):
    """A report as a model's metadata keeps it: every "seconds" entry (wall-clock time, at any depth)
    left out, so the same inputs make the same model and ``model_sha256`` (a take's provenance)."""
    if isinstance(report, dict):
        return {k: without_timings(v) for k, v in report.items() if k != "seconds"}
    if isinstance(report, list):
        return [without_timings(v) for v in report]
    return report
