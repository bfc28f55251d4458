"""Optical motion capture: read and write C3D, TRC and CSV marker takes.

Everything is held in metres: each reader converts from the file's declared units (mm, cm, dm,
m). Gaps are NaN. In C3D a point is invalid when its residual is negative or all three
coordinates are exactly zero (the usual "not seen" convention of capture systems).

CSV layout (written and read here): comment lines ``# key: value`` (``units``, required unless
given to ``read_csv``; ``rate_hz``), then a header ``frame,time_s,<marker>_x,<marker>_y,<marker>_z,...``
and one row per frame; an empty cell is a gap. ``frame`` and ``time_s`` columns are optional on
read. ``read_csv`` also reads the CSV exports of Vicon Nexus and OptiTrack Motive
(``wface.io.mocap_vendor``), recognised by their first line.

Units are read from the file (C3D ``POINT:UNITS``, TRC ``Units``, the CSV units line or row) and
a file whose units are missing or unknown is refused, never guessed. Subject-prefixed labels
(``Face:Chin``, as Vicon and Motive write them) lose their prefix when one subject's markers are
read, with a notice in ``take.meta["notices"]`` (``strip_subject_prefix``).
"""

from __future__ import annotations

import csv
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wface.io.mocap_vendor import is_motive, is_vicon, parse_motive, parse_vicon

__all__ = [
    "MocapTake",
    "UNITS_TO_M",
    "read_c3d",
    "read_csv",
    "read_mocap",
    "read_trc",
    "strip_subject_prefix",
    "write_c3d",
    "write_csv",
    "write_mocap",
    "write_trc",
]

#: Length unit name -> metres.
UNITS_TO_M: dict[str, float] = {"mm": 1e-3, "cm": 1e-2, "dm": 1e-1, "m": 1.0}
_UNIT_ALIASES = {
    "millimeters": "mm",
    "millimetres": "mm",
    "centimeters": "cm",
    "centimetres": "cm",
    "decimeters": "dm",
    "decimetres": "dm",
    "meters": "m",
    "metres": "m",
}
FORMATS_READ = (
    "C3D (.c3d), TRC (.trc), and CSV (.csv): the wface layout ('# units: mm' line, then "
    "<marker>_x,<marker>_y,<marker>_z columns), a Vicon Nexus trajectories export or an OptiTrack Motive export"
)


def _unit_scale(units: str, path: Path | str) -> float:
    key = str(units).strip().lower()
    key = _UNIT_ALIASES.get(key, key)
    if key not in UNITS_TO_M:
        known = ", ".join([*UNITS_TO_M, *_UNIT_ALIASES])
        raise ValueError(f"{path}: unknown length units {units!r} (known: {known})")
    return UNITS_TO_M[key]


def strip_subject_prefix(names: list[str]) -> tuple[list[str], str | None]:
    """(names without a shared ``Subject:`` prefix, a notice or None).

    The prefix goes only when every prefixed name has the same subject and the stripped names stay
    unique; with several subjects the names keep their prefixes (and the notice says so).
    """
    prefixed = [n for n in names if ":" in n]
    if not prefixed:
        return list(names), None
    subjects = sorted({n.split(":", 1)[0] for n in prefixed})
    if len(subjects) > 1:
        return list(names), f"markers of {len(subjects)} subjects ({', '.join(subjects)}): names keep their prefixes"
    stripped = [n.split(":", 1)[1] if ":" in n else n for n in names]
    if len(set(stripped)) != len(stripped):
        return list(names), f"subject prefix '{subjects[0]}:' kept: without it marker names would repeat"
    return stripped, f"stripped the subject prefix '{subjects[0]}:' from {len(prefixed)} marker names"


def _named(take: MocapTake) -> MocapTake:
    """The take with subject prefixes stripped (``strip_subject_prefix``), the notice in meta."""
    names, note = strip_subject_prefix(take.marker_names)
    if note is None:
        return take
    take.marker_names = names
    take.meta.setdefault("notices", []).append(note)
    return take


@dataclass
class MocapTake:
    """A marker take.

    Attributes:
        positions_m: (frames, markers, 3) float64 positions in metres; NaN = gap.
        marker_names: marker labels, one per marker.
        rate_hz: frame rate in Hz.
        source: file it was read from ("" when built in memory).
        first_frame: index of the first frame in the original file (kept by slicing).
        meta: free-form facts from the file (e.g. its units).
        start_time_s: time of the first frame (default first_frame / rate_hz).
    """

    positions_m: np.ndarray
    marker_names: list[str]
    rate_hz: float
    source: str = ""
    first_frame: int = 0
    meta: dict = field(default_factory=dict)
    start_time_s: float | None = None

    def __post_init__(self):
        p = np.asarray(self.positions_m, dtype=np.float64)
        if p.ndim != 3 or p.shape[2] != 3:
            raise ValueError(f"{self.source or 'MocapTake'}: positions must be (frames, markers, 3), got {p.shape}")
        if p.shape[1] != len(self.marker_names):
            raise ValueError(
                f"{self.source or 'MocapTake'}: {p.shape[1]} marker columns but {len(self.marker_names)} names"
            )
        if len(set(self.marker_names)) != len(self.marker_names):
            raise ValueError(f"{self.source or 'MocapTake'}: duplicate marker names")
        if not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise ValueError(f"{self.source or 'MocapTake'}: frame rate must be positive, got {self.rate_hz}")
        p = p.copy()
        p[~np.isfinite(p).all(axis=2)] = np.nan  # a gap in any coordinate voids the point
        self.positions_m = p
        if self.start_time_s is None:
            self.start_time_s = self.first_frame / self.rate_hz
        self.marker_names = [str(n) for n in self.marker_names]

    @property
    def n_frames(self) -> int:
        return self.positions_m.shape[0]

    @property
    def n_markers(self) -> int:
        return self.positions_m.shape[1]

    @property
    def times_s(self) -> np.ndarray:
        """(frames,) time of each frame in seconds."""
        return self.start_time_s + np.arange(self.n_frames) / self.rate_hz

    def marker_index(self, name: str) -> int:
        try:
            return self.marker_names.index(name)
        except ValueError:
            raise KeyError(f"{self.source or 'take'}: no marker named {name!r}") from None

    def frames(self, start: int | None = None, stop: int | None = None, step: int = 1) -> MocapTake:
        """Frame slice ``[start:stop:step]`` (Python slice rules); the rate divides by ``step``."""
        if step < 1:
            raise ValueError(f"frames(): step must be >= 1, got {step}")
        sl = slice(start, stop, step)
        first = range(self.n_frames)[sl]
        if len(first) == 0:
            raise ValueError(f"{self.source or 'take'}: frame slice [{start}:{stop}:{step}] is empty")
        return MocapTake(
            self.positions_m[sl].copy(),
            list(self.marker_names),
            self.rate_hz / step,
            self.source,
            self.first_frame + first[0],
            dict(self.meta),
            float(self.times_s[first[0]]),
        )

    def select(self, names: list[str]) -> MocapTake:
        """The take restricted to (and reordered as) ``names``."""
        idx = [self.marker_index(n) for n in names]
        return MocapTake(
            self.positions_m[:, idx],
            list(names),
            self.rate_hz,
            self.source,
            self.first_frame,
            dict(self.meta),
            self.start_time_s,
        )


# ---------------------------------------------------------------------------------------- C3D


def _check_file(path: Path) -> None:
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such motion-capture file")
    if path.is_dir():
        raise ValueError(f"{path}: is a directory, expected a motion-capture file")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: file is empty")


def read_c3d(path: str | Path) -> MocapTake:
    """Read the 3-D points of a C3D file (ezc3d).

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unreadable / truncated file, no points, unknown units.
    """
    try:
        import ezc3d
    except ImportError as exc:  # pragma: no cover
        raise ImportError("reading C3D needs ezc3d: pip install 'wface[mocap]'") from exc
    path = Path(path)
    _check_file(path)
    try:
        c = ezc3d.c3d(str(path))
    except Exception as exc:  # ezc3d raises RuntimeError / IOError with terse messages
        raise ValueError(f"{path}: not a readable C3D file ({exc})") from exc
    params = c["parameters"]["POINT"]
    names = [str(n).strip() for n in params["LABELS"]["value"]]
    pts = np.asarray(c["data"]["points"], dtype=np.float64)  # (4, markers, frames)
    if pts.ndim != 3 or pts.shape[1] == 0 or len(names) == 0:
        raise ValueError(f"{path}: C3D file holds no 3-D points (markers)")
    if pts.shape[2] == 0:
        raise ValueError(f"{path}: C3D file holds no frames")
    _check_c3d_size(c, path)
    names = names[: pts.shape[1]]
    if len(names) < pts.shape[1]:
        names += [f"marker_{i}" for i in range(len(names), pts.shape[1])]
    if not params.get("UNITS", {}).get("value"):
        raise ValueError(f"{path}: C3D file has no POINT:UNITS parameter, so its length unit is unknown")
    units = params["UNITS"]["value"][0]
    scale = _unit_scale(units, path)
    rate = float(params["RATE"]["value"][0])
    xyz = pts[:3].transpose(2, 1, 0).copy()
    invalid = np.all(xyz == 0.0, axis=2) | ~np.isfinite(xyz).all(axis=2)
    res = c["data"]["meta_points"].get("residuals") if "meta_points" in c["data"] else None
    if res is not None and np.size(res):
        invalid |= np.asarray(res, dtype=np.float64)[0].T < 0
    xyz[invalid] = np.nan
    first = int(c["header"]["points"]["first_frame"])
    return _named(MocapTake(xyz * scale, names, rate, str(path), first, {"units": units, "format": "c3d"}))


def _check_c3d_size(c, path: Path) -> None:
    """Raise when the file holds fewer frames than its raw header declares.

    ezc3d reads a truncated file without complaint (and rewrites its frame counts to what it
    found), so the declared first/last frame are read from the 512-byte header here.
    """

    with path.open("rb") as fh:
        head = fh.read(512)
        if len(head) < 12:
            raise ValueError(f"{path}: C3D header is truncated")
        fh.seek(max(head[0] - 1, 0) * 512 + 3)
        proc = fh.read(1)
    endian = ">" if proc and proc[0] == 86 else "<"  # 84 Intel, 85 DEC (little-endian ints), 86 MIPS
    first, last = struct.unpack(endian + "HH", head[6:10])
    if last == 0xFFFF:  # long files keep the count in parameters only
        return
    declared = last - first + 1
    got = c["data"]["points"].shape[2]
    if got < declared:
        raise ValueError(f"{path}: C3D file is truncated ({got} of {declared} declared frames present)")


def write_c3d(take: MocapTake, path: str | Path, *, units: str = "mm") -> None:
    """Write a take as C3D (gaps as residual -1 and zero coordinates)."""
    import ezc3d

    scale = _unit_scale(units, path)
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(take.rate_hz)]
    c["parameters"]["POINT"]["LABELS"]["value"] = list(take.marker_names)
    c["parameters"]["POINT"]["UNITS"]["value"] = [units]
    xyz = take.positions_m / scale
    gap = ~np.isfinite(xyz).all(axis=2)
    pts = np.ones((4, take.n_markers, take.n_frames))
    pts[:3] = np.where(gap[..., None], 0.0, xyz).transpose(2, 1, 0)
    c["data"]["points"] = pts
    res = np.where(gap, -1.0, 0.0).T[None]
    c["data"]["meta_points"]["residuals"] = res
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, take.n_markers, take.n_frames), dtype=bool)
    c.write(str(path))


# ---------------------------------------------------------------------------------------- TRC


def read_trc(path: str | Path) -> MocapTake:
    """Read a TRC (OpenSim / Motion Analysis track row column) marker file."""
    path = Path(path)
    _check_file(path)
    lines = path.read_text(encoding="utf-8-sig", errors="replace").splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise ValueError(f"{path}: not a TRC file (first line should start with 'PathFileType', need 5 header lines)")
    keys = lines[1].split("\t")
    vals = lines[2].split("\t")
    if len(vals) < len(keys):
        raise ValueError(f"{path}: TRC header line 3 has {len(vals)} values for {len(keys)} keys")
    header = {k.strip(): v.strip() for k, v in zip(keys, vals, strict=False)}
    try:
        rate = float(header["DataRate"])
        n_markers = int(header["NumMarkers"])
        n_frames = int(header["NumFrames"])
        units = header["Units"]
    except (KeyError, ValueError) as exc:
        raise ValueError(f"{path}: TRC header lacks or mangles DataRate/NumFrames/NumMarkers/Units ({exc})") from exc
    if n_markers <= 0:
        raise ValueError(f"{path}: TRC file declares no markers")
    scale = _unit_scale(units, path)
    name_cells = lines[3].split("\t")[2:]
    names = [n.strip() for n in name_cells if n.strip()]
    if len(names) != n_markers:
        raise ValueError(f"{path}: TRC header names {len(names)} markers but NumMarkers is {n_markers}")
    rows = [ln for ln in lines[5:] if ln.strip()]
    if len(rows) != n_frames:
        raise ValueError(f"{path}: TRC file has {len(rows)} data rows but NumFrames is {n_frames} (truncated?)")
    data = np.full((n_frames, n_markers * 3), np.nan)
    for i, row in enumerate(rows):
        cells = row.split("\t")[2:]
        if len(cells) > n_markers * 3 or len(cells) < n_markers * 3 - 2:
            # trailing empty cells may be stripped; anything else is a broken row
            if len(cells) > n_markers * 3 and not any(c.strip() for c in cells[n_markers * 3 :]):
                cells = cells[: n_markers * 3]
            else:
                raise ValueError(
                    f"{path}: TRC data row {i + 1} has {len(cells)} coordinate columns, expected {n_markers * 3}"
                )
        for j, cell in enumerate(cells):
            cell = cell.strip()
            if cell:
                try:
                    data[i, j] = float(cell)
                except ValueError:
                    raise ValueError(f"{path}: TRC data row {i + 1}, column {j + 3}: not a number: {cell!r}") from None
    take = MocapTake(data.reshape(n_frames, n_markers, 3) * scale, names, rate, str(path), 0, {"units": units})
    return _named(take)


def write_trc(take: MocapTake, path: str | Path, *, units: str = "mm") -> None:
    """Write a take as TRC (tab separated; gaps as empty cells)."""
    path = Path(path)
    scale = _unit_scale(units, path)
    f, k = take.n_frames, take.n_markers
    out = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{take.rate_hz:g}\t{take.rate_hz:g}\t{f}\t{k}\t{units}\t{take.rate_hz:g}\t{take.first_frame + 1}\t{f}",
        "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in take.marker_names).rstrip("\t"),
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(k)),
        "",
    ]
    xyz = take.positions_m / scale
    for i in range(f):
        cells = ["" if not np.isfinite(v) else repr(float(v)) for v in xyz[i].ravel()]
        out.append(f"{take.first_frame + i + 1}\t{take.times_s[i]:.6f}\t" + "\t".join(cells))
    path.write_text("\n".join(out) + "\n")


# ---------------------------------------------------------------------------------------- CSV


#: capture rates a CSV's rounded time column is snapped to (``_csv_rate``)
COMMON_RATES_HZ = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 100.0, 120.0, 150.0, 200.0, 240.0, 250.0, 500.0)


def read_csv(path: str | Path, *, units: str | None = None, rate_hz: float | None = None) -> MocapTake:
    """Read a CSV take: the wface layout, a Vicon Nexus or an OptiTrack Motive export (module docstring).

    Args:
        path: file.
        units: length units of a wface-layout file without a ``# units:`` line (no default: a
            file whose units are unknown is refused).
        rate_hz: frame rate when the file has no ``# rate_hz:`` line and no ``time_s`` column.

    Raises:
        ValueError: a layout none of the readers knows (the message names the formats read), unknown
            or missing units, a broken row.
    """
    path = Path(path)
    _check_file(path)
    with path.open(newline="", encoding="utf-8-sig", errors="replace") as fh:  # -sig: Excel's byte-order mark
        lines = fh.read().splitlines()
    for sniff, parse in ((is_vicon, parse_vicon), (is_motive, parse_motive)):
        if sniff(lines):
            xyz, names, rate, unit, meta = parse(lines, str(path))
            scale = _unit_scale(unit, path)
            return _named(MocapTake(xyz * scale, names, rate, str(path), 0, {"units": unit, **meta}))
    return _named(_read_wface_csv(path, lines, units=units, rate_hz=rate_hz))


def _read_wface_csv(path: Path, lines: list[str], *, units: str | None, rate_hz: float | None) -> MocapTake:
    """The wface CSV layout (module docstring)."""
    meta: dict[str, str] = {}
    body, line_no = [], []  # the header and data rows, and their line numbers in the file
    for n, ln in enumerate(lines, start=1):
        if ln.startswith("#"):
            if ":" in ln:
                k, v = ln[1:].split(":", 1)
                meta[k.strip().lower()] = v.strip()
        elif ln.strip():
            body.append(ln)
            line_no.append(n)
    if not body:
        raise ValueError(f"{path}: CSV has no header row")
    rows = list(csv.reader(body))
    header = [h.strip() for h in rows[0]]
    skip = [i for i, h in enumerate(header) if h.lower() in ("frame", "time_s", "time")]
    coords = [i for i in range(len(header)) if i not in skip]
    if not coords:
        raise ValueError(
            f"{path}: CSV has no marker columns (expected <name>_x,<name>_y,<name>_z). Read: {FORMATS_READ}"
        )
    if len(coords) % 3:
        raise ValueError(
            f"{path}: CSV has {len(coords)} coordinate columns, not a multiple of 3: not a layout wface reads. "
            f"Read: {FORMATS_READ}"
        )
    names = []
    for a in range(0, len(coords), 3):
        trip = [header[coords[a + j]] for j in range(3)]
        base = [t[:-2] for t in trip]
        if [t[-2:].lower() for t in trip] != ["_x", "_y", "_z"] or len(set(base)) != 1:
            raise ValueError(f"{path}: CSV columns {trip} are not <name>_x,<name>_y,<name>_z. Read: {FORMATS_READ}")
        names.append(base[0])
    data = np.full((len(rows) - 1, len(coords)), np.nan)
    if len(rows) < 2:
        raise ValueError(f"{path}: CSV has a header but no frames")
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise ValueError(f"{path}: CSV line {line_no[i + 1]} has {len(row)} columns, the header {len(header)}")
        for j, c in enumerate(coords):
            cell = row[c].strip()
            if cell and cell.lower() != "nan":
                try:
                    data[i, j] = float(cell)
                except ValueError:
                    raise ValueError(
                        f"{path}: CSV line {line_no[i + 1]}, column {header[c]!r}: not a number: {cell!r}"
                    ) from None
    unit = meta.get("units", units)
    if unit is None:
        raise ValueError(
            f"{path}: CSV gives no length units: add a line '# units: mm' (or cm, m) before the header "
            "(in Python: read_csv(path, units=...))"
        )
    scale = _unit_scale(unit, path)
    rate = _csv_rate(path, meta, rate_hz, header, skip, rows, line_no)
    return MocapTake(data.reshape(len(rows) - 1, len(names), 3) * scale, names, rate, str(path), 0, {"units": unit})


def _csv_rate(path, meta, rate_hz, header, skip, rows, line_no) -> float:
    """The frame rate of a wface CSV: its ``# rate_hz:`` line, the caller's, or its time column's span over its
    frames (not the median step: times written to the millisecond make a 60 Hz take 58.8 Hz that way), snapped
    to a common capture rate when one lies within what the times' rounding allows."""
    if "rate_hz" in meta:
        try:
            return float(meta["rate_hz"])
        except ValueError:
            raise ValueError(f"{path}: '# rate_hz: {meta['rate_hz']}' is not a number of frames per second") from None
    if rate_hz is not None:
        return float(rate_hz)
    tcol = [i for i in skip if header[i].lower() in ("time_s", "time")]
    fix = "add a line '# rate_hz: 60' (your rate) before the header (in Python: read_csv(path, rate_hz=...))"
    if not tcol or len(rows) < 3:
        raise ValueError(f"{path}: CSV gives no frame rate (no '# rate_hz:' line, no time_s column): {fix}")
    try:
        t = np.array([float(r[tcol[0]]) for r in rows[1:]])
    except ValueError:
        raise ValueError(f"{path}: CSV column {header[tcol[0]]!r} holds a value that is not a time: {fix}") from None
    good = np.isfinite(t) & np.concatenate([[True], np.diff(t) > 0])  # (F,): a finite time after its predecessor
    if not good.all():
        bad = int(np.argmin(good)) + 1  # the first bad data row, in line_no (whose 0 is the header)
        raise ValueError(
            f"{path}: CSV column {header[tcol[0]]!r} does not increase at line {line_no[bad]} "
            f"(times rounded too coarsely for the rate?): {fix}"
        )
    span, n = float(t[-1] - t[0]), len(t) - 1
    decimals = max(len(r[tcol[0]].strip().partition(".")[2].rstrip()) for r in rows[1:])
    res = 10.0**-decimals  # the times' resolution as written: the span is known to +- res
    lo, hi = n / (span + res), (n / (span - res) if span > res else np.inf)
    common = [r for r in COMMON_RATES_HZ if lo <= r <= hi]
    return float(min(common, key=lambda r: abs(r - n / span))) if common else n / span


def write_csv(take: MocapTake, path: str | Path, *, units: str = "mm") -> None:
    """Write a take in the CSV layout of this module."""
    scale = _unit_scale(units, path)
    xyz = take.positions_m / scale
    with Path(path).open("w", newline="") as fh:
        fh.write(f"# units: {units}\n# rate_hz: {take.rate_hz:.17g}\n")
        w = csv.writer(fh)
        w.writerow(["frame", "time_s"] + [f"{n}_{a}" for n in take.marker_names for a in "xyz"])
        for i in range(take.n_frames):
            vals = ["" if not np.isfinite(v) else repr(float(v)) for v in xyz[i].ravel()]
            w.writerow([take.first_frame + i, f"{take.times_s[i]:.6f}"] + vals)


# ------------------------------------------------------------------------------------ dispatch

_READERS = {".c3d": read_c3d, ".trc": read_trc, ".csv": read_csv}
_WRITERS = {".c3d": write_c3d, ".trc": write_trc, ".csv": write_csv}


def read_mocap(path: str | Path) -> MocapTake:
    """Read a C3D, TRC or CSV take (``FORMATS_READ``), chosen by the file suffix."""
    path = Path(path)
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        raise ValueError(f"{path}: unknown motion-capture format {path.suffix!r}. Read: {FORMATS_READ}")
    return reader(path)


def write_mocap(take: MocapTake, path: str | Path, *, units: str = "mm") -> None:
    """Write a take as C3D, TRC or CSV, chosen by the file suffix."""
    path = Path(path)
    writer = _WRITERS.get(path.suffix.lower())
    if writer is None:
        raise ValueError(f"{path}: unknown motion-capture format {path.suffix!r} (use .c3d, .trc or .csv)")
    writer(take, path, units=units)
