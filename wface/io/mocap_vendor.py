"""CSV exports of capture systems: Vicon Nexus (trajectories) and OptiTrack Motive.

Each parser takes the file's lines and returns the raw pieces ``(positions (F, k, 3) in the file's
units, names, rate_hz, units, meta)``; ``wface.io.mocap.read_csv`` turns them into a
``MocapTake`` (units converted, subject prefixes stripped). Gaps (empty cells) are NaN.

Vicon Nexus, "Trajectories" section of a CSV export (other sections, e.g. "Devices" before it or
"Model Outputs" after it, are skipped; a section ends at a blank line)::

    Trajectories
    100                                   <- rate, Hz
    ,,Face:Chin,,,Face:Nose,,,            <- one name per X,Y,Z triple
    Frame,Sub Frame,X,Y,Z,X,Y,Z
    ,,mm,mm,mm,mm,mm,mm                   <- units of each column
    1,0,12.3,45.6,78.9,,,                 <- one row per frame

OptiTrack Motive (format 1.2x and 1.3x)::

    Format Version,1.23,...,Export Frame Rate,120.000000,...,Length Units,Millimeters,...
    (blank)
    ,Type,Marker,Marker,Marker,Rigid Body,...
    ,Name,Face:Chin,Face:Chin,Face:Chin,...
    ,ID,...
    ,Position,Position,Position,Rotation,...
    Frame,Time (Seconds),X,Y,Z,X,...
    0,0.000000,1.1,2.2,3.3,...

Only columns of type "Marker" (labelled markers) are read; rigid bodies, bones, their constraint
markers and unlabelled markers ("Unlabeled 1003") are left out, and ``meta["skipped"]`` says
how many.
"""

from __future__ import annotations

import csv

import numpy as np

__all__ = ["is_motive", "is_vicon", "parse_motive", "parse_vicon"]

_VICON_SECTIONS = ("trajectories", "devices", "model outputs", "joints", "segments")


def _cells(line: str) -> list[str]:
    return next(csv.reader([line]))


def is_vicon(lines: list[str]) -> bool:
    """The first non-blank line names a Vicon Nexus CSV section."""
    first = next((ln for ln in lines if ln.strip()), "")
    return first.split(",")[0].strip().lower() in _VICON_SECTIONS and not any(c.strip() for c in first.split(",")[1:])


def is_motive(lines: list[str]) -> bool:
    """The first line is Motive's "Format Version,..." header."""
    return bool(lines) and lines[0].lstrip("\ufeff").startswith("Format Version")


def _number(cell: str, where: str) -> float:
    cell = cell.strip()
    if not cell:
        return np.nan
    try:
        return float(cell)
    except ValueError:
        raise ValueError(f"{where}: not a number: {cell!r}") from None


def _rows_to_array(rows: list[list[str]], columns: list[int], where: str, first_line: int) -> np.ndarray:
    data = np.full((len(rows), len(columns)), np.nan)
    for i, row in enumerate(rows):
        for j, c in enumerate(columns):
            if c < len(row):
                data[i, j] = _number(row[c], f"{where} line {first_line + i}")
    return data


def parse_vicon(lines: list[str], where: str):
    """The "Trajectories" section of a Vicon Nexus CSV export (module docstring)."""
    starts = [i for i, ln in enumerate(lines) if ln.split(",")[0].strip().lower() == "trajectories"]
    if not starts:
        raise ValueError(f"{where}: Vicon Nexus CSV without a 'Trajectories' section (export the trajectories)")
    s = starts[0]
    if len(lines) < s + 5:
        raise ValueError(f"{where}: Vicon 'Trajectories' section is cut short (needs rate, names, axes and units rows)")
    rate = _number(_cells(lines[s + 1])[0], f"{where} line {s + 2} (frame rate)")
    names_row, axes_row, units_row = (_cells(lines[s + k]) for k in (2, 3, 4))
    triples = [j for j, a in enumerate(axes_row) if a.strip().upper() == "X"]
    names, cols, units = [], [], set()
    for j in triples:
        if axes_row[j + 1 : j + 3] != ["Y", "Z"] or j >= len(names_row) or not names_row[j].strip():
            continue
        names.append(names_row[j].strip())
        cols += [j, j + 1, j + 2]
        units.update(u.strip() for u in units_row[j : j + 3] if u.strip())
    if not names:
        raise ValueError(f"{where}: Vicon 'Trajectories' section names no marker above an X,Y,Z column triple")
    if len(units) != 1:
        raise ValueError(
            f"{where}: Vicon trajectories need one length unit in the units row (line {s + 5}); found {sorted(units)}"
        )
    body = []
    for ln in lines[s + 5 :]:
        if not ln.strip() or not ln.split(",")[0].strip():
            break  # the section ends at a blank line (or a row without a frame number)
        body.append(_cells(ln))
    if not body:
        raise ValueError(f"{where}: Vicon 'Trajectories' section has no frames")
    data = _rows_to_array(body, cols, where, s + 6)
    frames = [int(float(r[0])) for r in body]
    meta = {"format": "vicon-nexus-csv", "first_frame_number": frames[0]}
    return data.reshape(len(body), len(names), 3), names, rate, units.pop(), meta


def _header_value(header: list[str], key: str) -> str | None:
    for i, cell in enumerate(header[:-1]):
        if cell.strip().lower() == key.lower():
            return header[i + 1].strip()
    return None


def parse_motive(lines: list[str], where: str):
    """The labelled markers of an OptiTrack Motive CSV export (module docstring)."""
    header = _cells(lines[0].lstrip("\ufeff"))
    rate_text = _header_value(header, "Export Frame Rate") or _header_value(header, "Capture Frame Rate")
    if rate_text is None:
        raise ValueError(f"{where}: Motive CSV header names no 'Export Frame Rate'")
    rate = _number(rate_text, f"{where} line 1 (frame rate)")
    units = _header_value(header, "Length Units")
    if units is None:
        version = _header_value(header, "Format Version")
        raise ValueError(
            f"{where}: Motive CSV header has no 'Length Units' (format version {version}): export again with the "
            "units in the header, or convert the file to the wface CSV layout with a '# units:' line"
        )
    rows = {}
    axes_at = None
    for i, ln in enumerate(lines[1:40], start=1):
        cells = _cells(ln) if ln.strip() else []
        label = cells[1].strip() if len(cells) > 1 else ""
        if label in ("Type", "Name", "ID", "Position"):
            rows[label] = cells
        elif cells and cells[0].strip() == "Frame":
            rows["axes"], axes_at = cells, i
            break
    if axes_at is None or "Type" not in rows or "Name" not in rows:
        raise ValueError(f"{where}: Motive CSV without the Type / Name / Frame header rows")
    types, names_row, axes = rows["Type"], rows["Name"], rows["axes"]
    names, cols, skipped = [], [], 0
    for j in range(2, len(axes) - 2):
        if axes[j].strip() != "X" or axes[j + 1 : j + 3] != ["Y", "Z"]:
            continue
        kind = types[j].strip() if j < len(types) else ""
        name = names_row[j].strip() if j < len(names_row) else ""
        if kind != "Marker" or not name or name.lower().startswith("unlabeled"):
            skipped += 1
            continue
        names.append(name)
        cols += [j, j + 1, j + 2]
    if not names:
        raise ValueError(f"{where}: Motive CSV holds no labelled marker columns (Type 'Marker' with X,Y,Z)")
    body = [_cells(ln) for ln in lines[axes_at + 1 :] if ln.strip()]
    if not body:
        raise ValueError(f"{where}: Motive CSV has no frames")
    data = _rows_to_array(body, cols, where, axes_at + 2)
    meta = {
        "format": "optitrack-motive-csv",
        "skipped": skipped,
        "format_version": _header_value(header, "Format Version"),
    }
    return data.reshape(len(body), len(names), 3), names, rate, units, meta
