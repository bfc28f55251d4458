"""Muscle layouts: named Waters muscles, a jaw region and landmarks for one face, as JSON.

File format (``"format": "wface.waters.layout"``, ``"version": 1``)::

    {
      "format": "wface.waters.layout", "version": 1, "name": "ict-facekit",
      "units": "cm",                      # every length below is in these units ("m", "cm", "mm")
      "max_displacement": 1.5,            # per-vertex cap on the combined muscle displacement
      "overlap_factor": 1.5,              # ... and at most this times the vertex's strongest single pull
      "mesh": {"vertex_count": 26719, "muscle_vertices": [[0, 11248]]},   # optional, see below
      "landmarks": {"Chin": [x, y, z], ...},                              # for fitting (model coords)
      "jaw": {"pivot": [x, y, z], "axis": [1, 0, 0], "max_open_deg": 30,
              "planes": [{"point": [..], "normal": [..], "width": 0.01, "width_per_lateral": 0.43,
                          "lateral_start": 0.0, "curvature": 0.04}]},
      "muscles": [
        {"name": "zygomaticus_major_l", "type": "linear", "bone": [..], "insertion": [..],
         "zone_deg": 25, "fall_start": 6.0, "fall_finish": 8.5, "spring_constant": 1.2,
         "elasticity": 1.0, "region": "any"},
        {"name": "orbicularis_oris_upper", "type": "sphincter", "centre": [..],
         "horizontal": [1, 0, 0], "vertical": [0, 1, 0], "semi_axes": [a, b, c],
         "tension": 0.3, "elasticity": 1.0, "region": "upper",
         "protrusion": 0.0, "lower_semi_axis": 0.0}        # optional, see wface.waters.muscles
      ]
    }

Lengths are converted to metres on read; in memory everything is SI. ``mesh.muscle_vertices``
(half-open index ranges) restricts the muscles to the skin of the mesh the layout was made for
(e.g. not the eyeballs and teeth of the ICT head); it applies only to a mesh with exactly
``vertex_count`` vertices. Muscle names must be canonical names from ``wface.facs``.

Jaw region: vertex weight w = prod over planes of smoothstep(s / width(p) + 1/2) where, with the
lateral distance l = |(p - pivot) . axis|, s = (p - point) . normal - curvature l^2 is the signed
distance along the plane's normal (which points into the jaw side; ``curvature`` bends the lip line
toward the jaw at the mouth corners) and width(p) = width + width_per_lateral max(l - lateral_start, 0)
(a sharp lip line in the middle that widens into a soft blend over the cheeks). Plane keys:
"point", "normal", "width", optional "width_per_lateral", "lateral_start", "curvature" (1/units).
AU26 rotates x by w times the jaw angle about the axis through the pivot (positive = opening).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from wface.facs import all_muscle_names
from wface.files import read_json, write_json
from wface.mesh.surface_fields import edge_graph
from wface.waters.muscles import LinearMuscle, SphincterMuscle

__all__ = [
    "FORMAT",
    "UNITS",
    "VERSION",
    "JawPlane",
    "JawRegion",
    "MuscleLayout",
    "builtin_layout_path",
    "layout_from_dict",
    "layout_to_dict",
    "load_layout",
    "save_layout",
]

FORMAT = "wface.waters.layout"
VERSION = 1
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
_BUILTIN = {"ict": "waters_ict.json", "builtin": "waters_builtin.json"}


def _v3(where: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{where} must be 3 finite numbers, got {value!r}")
    return a


def _unit(where: str, value) -> np.ndarray:
    a = _v3(where, value)
    n = np.linalg.norm(a)
    if n == 0:
        raise ValueError(f"{where} is a zero vector")
    return a if abs(n - 1.0) < 1e-14 else a / n  # already unit: keep bits (exact JSON round trip)


@dataclass
class JawPlane:
    """One half-space of the jaw region: ``normal`` points into the part that follows the jaw."""

    point_m: np.ndarray
    normal: np.ndarray
    width_m: float
    width_per_lateral: float = 0.0
    lateral_start_m: float = 0.0
    curvature_per_m: float = 0.0

    def __post_init__(self) -> None:
        self.point_m = _v3("jaw plane point", self.point_m)
        self.normal = _unit("jaw plane normal", self.normal)
        if not (self.width_m > 0 and np.isfinite(self.width_m)):
            raise ValueError(f"jaw plane width must be > 0, got {self.width_m}")
        if not (self.width_per_lateral >= 0 and np.isfinite(self.width_per_lateral)):
            raise ValueError(f"jaw plane width_per_lateral must be >= 0, got {self.width_per_lateral}")
        if not (self.lateral_start_m >= 0 and np.isfinite(self.lateral_start_m)):
            raise ValueError(f"jaw plane lateral_start must be >= 0, got {self.lateral_start_m}")
        if not np.isfinite(self.curvature_per_m):
            raise ValueError(f"jaw plane curvature must be finite, got {self.curvature_per_m}")


@dataclass
class JawRegion:
    """Jaw pivot, rotation axis (unit, +x: opening is a positive rotation) and region planes."""

    pivot_m: np.ndarray
    axis: np.ndarray
    planes: list[JawPlane]
    max_open_deg: float = 30.0

    def __post_init__(self) -> None:
        self.pivot_m = _v3("jaw pivot", self.pivot_m)
        self.axis = _unit("jaw axis", self.axis)
        if not self.planes:
            raise ValueError("jaw region needs at least one plane")

    def weights(self, points_m: np.ndarray) -> np.ndarray:
        """(n,) weight in [0, 1] of each point's jaw following (1 = rigidly with the jaw)."""
        p = np.asarray(points_m, dtype=np.float64)
        lateral = np.abs((p - self.pivot_m) @ self.axis)
        w = np.ones(len(p))
        for plane in self.planes:
            s = (p - plane.point_m) @ plane.normal - plane.curvature_per_m * lateral**2
            width = plane.width_m + plane.width_per_lateral * np.maximum(lateral - plane.lateral_start_m, 0.0)
            t = np.clip(s / width + 0.5, 0.0, 1.0)
            w *= t * t * (3.0 - 2.0 * t)
        return w

    def weights_on_mesh(self, points_m: np.ndarray, triangles: np.ndarray, *, band_m: float = 0.005) -> np.ndarray:
        """``weights`` made to respect the mesh's mouth: within ``band_m`` of the first plane (the mouth line)
        the weights are harmonic on the mesh's edge graph, held to the planes' weights beyond it.

        The planes alone split by position: where the lips meet, an upper lip hanging below the mouth line
        went with the jaw while its neighbours stayed (a tear from the philtrum to the lower lip on the
        ICT-FaceKit head at any jaw opening). On the mesh the two lips join only at the mouth's corners, so
        the harmonic weights keep each lip with its own side (no edge of the ICT head then jumps by more
        than 0.5; 108 did)."""
        p = np.asarray(points_m, dtype=np.float64)
        w = self.weights(p)
        tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        plane = self.planes[0]
        lateral = np.abs((p - self.pivot_m) @ self.axis)
        free = np.abs((p - plane.point_m) @ plane.normal - plane.curvature_per_m * lateral**2) < band_m
        free[np.setdiff1d(np.arange(len(p)), tri)] = False  # a vertex on no triangle keeps its weight
        if not free.any() or free.all():
            return w
        a = edge_graph(p, tri)
        a.data[:] = 1.0  # the uniform (graph) Laplacian: adjacency, not lengths
        lap = (sp.diags(np.asarray(a.sum(axis=1)).ravel()) - a).tocsr()
        fi, xi = np.flatnonzero(free), np.flatnonzero(~free)
        k = lap[fi][:, fi].tocsc() + sp.identity(len(fi), format="csc") * 1e-12  # a part with no fixed vertex
        w[fi] = np.clip(spsolve(k, -(lap[fi][:, xi] @ w[xi])), 0.0, 1.0)
        return w

    def rotation(self, angle_deg: float) -> np.ndarray:
        """(3, 3) rotation by ``angle_deg`` about the jaw axis (Rodrigues)."""
        th = np.radians(float(angle_deg))
        k = self.axis
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        return np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * (kx @ kx)


@dataclass
class MuscleLayout:
    """Named Waters muscles, jaw region and landmarks for one face, in metres."""

    name: str
    muscles: list[LinearMuscle | SphincterMuscle]
    jaw: JawRegion | None = None
    landmarks_m: dict[str, np.ndarray] = field(default_factory=dict)
    max_displacement_m: float = 0.015
    overlap_factor: float = 1.5
    mesh_vertex_count: int | None = None
    muscle_vertex_ranges: list[tuple[int, int]] = field(default_factory=list)
    notes: str = ""

    def __post_init__(self) -> None:
        known = set(all_muscle_names())
        seen: set[str] = set()
        for m in self.muscles:
            if m.name not in known:
                raise KeyError(f"layout {self.name!r}: unknown muscle {m.name!r}; use canonical names from wface.facs")
            if m.name in seen:
                raise ValueError(f"layout {self.name!r}: muscle {m.name!r} appears twice")
            seen.add(m.name)
        if not (self.max_displacement_m > 0 and np.isfinite(self.max_displacement_m)):
            raise ValueError(f"max_displacement must be > 0, got {self.max_displacement_m}")
        if not (self.overlap_factor >= 1.0 and np.isfinite(self.overlap_factor)):
            raise ValueError(f"overlap_factor must be >= 1, got {self.overlap_factor}")
        self.landmarks_m = {str(k): _v3(f"landmark {k}", v) for k, v in self.landmarks_m.items()}
        self.muscle_vertex_ranges = [(int(a), int(b)) for a, b in self.muscle_vertex_ranges]
        for a, b in self.muscle_vertex_ranges:
            if not (0 <= a < b):
                raise ValueError(f"muscle_vertices range [{a}, {b}) is empty or negative")

    @property
    def muscle_names(self) -> list[str]:
        return [m.name for m in self.muscles]

    def muscle(self, name: str) -> LinearMuscle | SphincterMuscle:
        """The muscle called ``name``; a KeyError lists the layout's muscles."""
        for m in self.muscles:
            if m.name == name:
                return m
        raise KeyError(f"layout {self.name!r} has no muscle {name!r}; it has: {', '.join(self.muscle_names)}")

    def muscle_vertex_mask(self, n_vertices: int) -> np.ndarray | None:
        """(n,) bool mask of vertices the muscles may move, or None for all of them."""
        if not self.muscle_vertex_ranges or self.mesh_vertex_count != n_vertices:
            return None
        mask = np.zeros(n_vertices, dtype=bool)
        for a, b in self.muscle_vertex_ranges:
            mask[a : min(b, n_vertices)] = True
        return mask


# ----------------------------------------------------------------------------- dict <-> layout
def _muscle_from_dict(d: dict, scale: float) -> LinearMuscle | SphincterMuscle:
    name = d.get("name")
    if not name:
        raise ValueError(f"muscle entry without a name: {d!r}")
    kind = d.get("type", "linear")
    common = {"elasticity": float(d.get("elasticity", 1.0)), "region": d.get("region", "any")}
    try:
        if kind == "linear":
            return LinearMuscle(
                name,
                bone_m=_v3(f"{name}.bone", d["bone"]) * scale,
                insertion_m=_v3(f"{name}.insertion", d["insertion"]) * scale,
                zone_deg=float(d.get("zone_deg", 35.0)),
                fall_start_m=float(d.get("fall_start", 0.0)) * scale,
                fall_finish_m=float(d.get("fall_finish", 0.0)) * scale,
                spring_constant_m=float(d["spring_constant"]) * scale,
                **common,
            )
        if kind == "sphincter":
            return SphincterMuscle(
                name,
                centre_m=_v3(f"{name}.centre", d["centre"]) * scale,
                horizontal=d.get("horizontal", [1, 0, 0]),
                vertical=d.get("vertical", [0, 1, 0]),
                semi_axes_m=_v3(f"{name}.semi_axes", d["semi_axes"]) * scale,
                tension=float(d["tension"]),
                protrusion_m=float(d.get("protrusion", 0.0)) * scale,
                lower_semi_axis_m=float(d.get("lower_semi_axis", 0.0)) * scale,
                **common,
            )
    except KeyError as exc:
        raise ValueError(f"muscle {name!r}: missing field {exc.args[0]!r}") from None
    raise ValueError(f"muscle {name!r}: unknown type {kind!r} (linear or sphincter)")


def layout_from_dict(d: dict) -> MuscleLayout:
    """Build a layout from its JSON object (lengths in ``d["units"]``, converted to metres)."""
    if d.get("format") != FORMAT:
        raise ValueError(f"not a Waters layout: format is {d.get('format')!r}, expected {FORMAT!r}")
    if int(d.get("version", 0)) > VERSION:
        raise ValueError(f"layout version {d.get('version')} is newer than this reader ({VERSION})")
    units = d.get("units", "m")
    if units not in UNITS:
        raise ValueError(f"unknown layout units {units!r}; known: {', '.join(UNITS)}")
    s = UNITS[units]
    jaw = None
    if d.get("jaw"):
        j = d["jaw"]
        jaw = JawRegion(
            pivot_m=_v3("jaw.pivot", j["pivot"]) * s,
            axis=j.get("axis", [1, 0, 0]),
            planes=[
                JawPlane(
                    point_m=_v3("jaw plane point", p["point"]) * s,
                    normal=p["normal"],
                    width_m=float(p["width"]) * s,
                    width_per_lateral=float(p.get("width_per_lateral", 0.0)),
                    lateral_start_m=float(p.get("lateral_start", 0.0)) * s,
                    curvature_per_m=float(p.get("curvature", 0.0)) / s,
                )
                for p in j.get("planes", [])
            ],
            max_open_deg=float(j.get("max_open_deg", 30.0)),
        )
    mesh = d.get("mesh") or {}
    return MuscleLayout(
        name=str(d.get("name", "layout")),
        muscles=[_muscle_from_dict(m, s) for m in d.get("muscles", [])],
        jaw=jaw,
        landmarks_m={k: _v3(f"landmark {k}", v) * s for k, v in (d.get("landmarks") or {}).items()},
        max_displacement_m=float(d.get("max_displacement", 0.015 / s)) * s,
        overlap_factor=float(d.get("overlap_factor", 1.5)),
        mesh_vertex_count=mesh.get("vertex_count"),
        muscle_vertex_ranges=[tuple(r) for r in mesh.get("muscle_vertices", [])],
        notes=str(d.get("notes", "")),
    )


def _l(a: np.ndarray, inv: float) -> list[float]:
    return [float(x) for x in (np.asarray(a) * inv if inv != 1.0 else np.asarray(a))]


def layout_to_dict(layout: MuscleLayout, *, units: str = "m") -> dict:
    """The JSON object of a layout; ``units="m"`` (default) round-trips bit-exactly."""
    if units not in UNITS:
        raise ValueError(f"unknown units {units!r}; known: {', '.join(UNITS)}")
    inv = 1.0 / UNITS[units]
    muscles = []
    for m in layout.muscles:
        if isinstance(m, LinearMuscle):
            muscles.append(
                {
                    "name": m.name,
                    "type": "linear",
                    "bone": _l(m.bone_m, inv),
                    "insertion": _l(m.insertion_m, inv),
                    "zone_deg": m.zone_deg,
                    "fall_start": m.fall_start_m * inv,
                    "fall_finish": m.fall_finish_m * inv,
                    "spring_constant": m.spring_constant_m * inv,
                    "elasticity": m.elasticity,
                    "region": m.region,
                }
            )
        else:
            muscles.append(
                {
                    "name": m.name,
                    "type": "sphincter",
                    "centre": _l(m.centre_m, inv),
                    "horizontal": _l(m.horizontal, 1.0),
                    "vertical": _l(m.vertical, 1.0),
                    "semi_axes": _l(m.semi_axes_m, inv),
                    "tension": m.tension,
                    "elasticity": m.elasticity,
                    "region": m.region,
                }
            )
            if m.protrusion_m:
                muscles[-1]["protrusion"] = m.protrusion_m * inv
            if m.lower_semi_axis_m:
                muscles[-1]["lower_semi_axis"] = m.lower_semi_axis_m * inv
    out: dict = {"format": FORMAT, "version": VERSION, "name": layout.name, "units": units}
    if layout.notes:
        out["notes"] = layout.notes
    out["max_displacement"] = layout.max_displacement_m * inv
    out["overlap_factor"] = layout.overlap_factor
    if layout.mesh_vertex_count is not None:
        out["mesh"] = {
            "vertex_count": int(layout.mesh_vertex_count),
            "muscle_vertices": [list(r) for r in layout.muscle_vertex_ranges],
        }
    if layout.landmarks_m:
        out["landmarks"] = {k: _l(v, inv) for k, v in layout.landmarks_m.items()}
    if layout.jaw is not None:
        j = layout.jaw
        out["jaw"] = {
            "pivot": _l(j.pivot_m, inv),
            "axis": _l(j.axis, 1.0),
            "max_open_deg": j.max_open_deg,
            "planes": [
                {
                    "point": _l(p.point_m, inv),
                    "normal": _l(p.normal, 1.0),
                    "width": p.width_m * inv,
                    "width_per_lateral": p.width_per_lateral,
                    "lateral_start": p.lateral_start_m * inv,
                    "curvature": p.curvature_per_m / inv,
                }
                for p in j.planes
            ],
        }
    out["muscles"] = muscles
    return out


def builtin_layout_path(name: str) -> Path:
    """Path of a packaged layout: ``"ict"`` (ICT-FaceKit neutral head) or ``"builtin"`` (wface's face)."""
    if name not in _BUILTIN:
        raise KeyError(f"unknown packaged layout {name!r}; known: {', '.join(_BUILTIN)}")
    return Path(str(resources.files("wface") / "data" / _BUILTIN[name]))


def load_layout(path_or_name: str | Path) -> MuscleLayout:
    """Read a layout file, or a packaged layout by name (``"ict"``, ``"builtin"``)."""
    if isinstance(path_or_name, str) and path_or_name in _BUILTIN:
        path = builtin_layout_path(path_or_name)
    else:
        path = Path(path_or_name)
    if not path.is_file():
        raise FileNotFoundError(f"layout file not found: {path} (packaged layouts: {', '.join(sorted(_BUILTIN))})")
    return layout_from_dict(read_json(path, what="a Waters muscle layout (JSON)"))


def save_layout(layout: MuscleLayout, path: str | Path, *, units: str = "m") -> Path:
    """Write a layout as JSON (lengths in ``units``)."""
    path = Path(path)
    write_json(path, layout_to_dict(layout, units=units), indent=1)
    return path
