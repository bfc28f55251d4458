"""argparse ``type=`` checkers: a bad option value is a usage error (exit code 2) that says what was expected.

Each checker takes the option's text and returns the parsed value or raises
``argparse.ArgumentTypeError``, which argparse turns into ``wface CMD: error: argument --x: ...``.

Example::

    p.add_argument("--outliers", type=probability, default=0.02)
    p.add_argument("--frames", type=positive_int, default=30)
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from wface.cli.errors import UsageError
from wface.faces.builtin.face import MAX_TETS, MIN_TETS

__all__ = [
    "UsageError",
    "angle_deg",
    "finite_float",
    "frame_range",
    "non_negative_float",
    "non_negative_int",
    "positive_float",
    "positive_fraction",
    "positive_int",
    "probability",
    "options_given",
    "refuse_existing",
    "unit_interval",
]


def _float(text: str) -> float:
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _int(text: str) -> int:
    try:
        return int(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def finite_float(text: str) -> float:
    """Any finite number (not nan, not inf)."""
    return _float(text)


def positive_float(text: str) -> float:
    """A finite number > 0 (rates, sizes, tolerances, stiffnesses)."""
    v = _float(text)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return v


def non_negative_float(text: str) -> float:
    """A finite number >= 0 (noise levels, weights, cut-offs where 0 means off)."""
    v = _float(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def probability(text: str) -> float:
    """A fraction in [0, 1]."""
    v = _float(text)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a fraction between 0 and 1, got {text!r}")
    return v


def positive_fraction(text: str) -> float:
    """A fraction in (0, 1] (an activation that is divided by, a share that must not be empty)."""
    v = _float(text)
    if not 0.0 < v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], got {text!r}")
    return v


unit_interval = probability  # activations, intensities: the same range, a clearer name where it reads better


def positive_int(text: str) -> int:
    """A whole number >= 1 (counts: frames, tets, workers, repeats, substeps)."""
    v = _int(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return v


def non_negative_int(text: str) -> int:
    """A whole number >= 0 (frame numbers, seeds, fades where 0 means none)."""
    v = _int(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return v


def face_tets(text: str) -> int:
    """A size of the built-in face in tets, within what ``build_face`` makes (checked before any work)."""
    v = _int(text)
    if not MIN_TETS <= v <= MAX_TETS:
        raise argparse.ArgumentTypeError(f"the built-in face is made with {MIN_TETS} to {MAX_TETS} tets, got {text!r}")
    return v


def holdout_spec(text: str) -> str:
    """``--holdout``'s type: N >= 2 (every Nth marker by height) or marker names; the names are checked
    against the capture later."""
    t = str(text).strip()
    if t.isdigit() and int(t) < 2:
        raise argparse.ArgumentTypeError(f"hiding every Nth marker needs N >= 2, got {text!r}")
    if not t or not any(n.strip() for n in t.split(",")):
        raise argparse.ArgumentTypeError("expected N (every Nth marker by height) or marker names, got nothing")
    return t


def npz_file(text: str) -> str:
    """An output file name ending in .npz (checked before the work, not after it)."""
    if not str(text).lower().endswith(".npz"):
        raise argparse.ArgumentTypeError(f"expected a file name ending in .npz, got {text!r}")
    return text


def options_given(args: argparse.Namespace, defaults: dict) -> list[str]:
    """The options among ``defaults`` ({dest: default}) that ``args`` sets otherwise, as flags ("--max-step-ms")."""
    return ["--" + k.replace("_", "-") for k, v in defaults.items() if getattr(args, k, v) != v]


def refuse_existing(*outputs: tuple[str, str | Path | None], overwrite: bool) -> None:
    """Output files are checked before the work: a directory in a file's place is refused, and an existing
    file is not replaced unless ``overwrite`` (--overwrite). ``outputs``: (what names it, e.g. "--vtu", path);
    a None path is skipped."""
    for what, path in outputs:
        if path is None:
            continue
        if Path(path).is_dir():
            raise UsageError(f"{what} {path} is a directory: give a file name")
        if Path(path).exists() and not overwrite:
            raise UsageError(f"{what} {path} exists: choose another file, or pass --overwrite to replace it")


TET_MESH_SUFFIXES = (".vtu", ".vtk", ".msh", ".xdmf", ".inp", ".mesh")  # meshio formats that hold tetrahedra


def tet_mesh_file(text: str) -> str:
    """An output file name whose suffix names a format that holds a tet mesh (``TET_MESH_SUFFIXES``)."""
    if not str(text).lower().endswith(TET_MESH_SUFFIXES):
        raise argparse.ArgumentTypeError(
            f"expected a tet mesh file ({', '.join(TET_MESH_SUFFIXES)}), got {text!r} (that format holds no tets)"
        )
    return text


def frame_range(text: str) -> tuple[int | None, int | None, int]:
    """``A:B`` or ``A:B:S`` (either end may be empty; a Python slice of the file's frames, A < B when both
    given; S >= 1 keeps every S-th frame)."""
    parts = str(text).split(":")
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(
            f"expected a frame range A:B or A:B:S (e.g. 0:300, 100: or 0:300:5), got {text!r}"
        )
    try:
        a, b = (int(p) if p.strip() else None for p in parts[:2])
        step = int(parts[2]) if len(parts) == 3 and parts[2].strip() else 1
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frame range A:B[:S] of whole numbers, got {text!r}") from None
    if a is not None and b is not None and (a >= 0) == (b >= 0) and a >= b:
        raise argparse.ArgumentTypeError(f"frame range {text!r} is empty (A must be below B)")
    if step < 1:
        raise argparse.ArgumentTypeError(f"frame range {text!r}: the step S must be >= 1")
    return a, b, step


def angle_deg(lo: float, hi: float):
    """A checker for an angle in degrees within [lo, hi] (joint limits)."""

    def check(text: str) -> float:
        v = _float(text)
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"expected an angle in [{lo:g}, {hi:g}] degrees, got {text!r}")
        return v

    check.__name__ = f"angle_deg[{lo:g},{hi:g}]"
    return check
