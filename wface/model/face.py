"""The face model: tetrahedral flesh, embedded muscles, bones, jaw joint, markers and FACS table.

Everything in SI units (metres, pascals). A ``FaceModel`` is plain data: numpy arrays and small
dataclasses, validated on construction (``validate``) and saved to / loaded from ``.npz`` with a
format version so that a round trip is bit-exact.

Muscles are embedded per tetrahedron as a sparse list of entries (tet, muscle, volume fraction,
unit fibre direction in rest space), sorted by tet. Bones are rigid: nodes attached to a bone
follow it (Dirichlet nodes), and bone surfaces serve contact and rendering.

Actuators: ``muscle_names`` lists every activation channel. Most are fibre muscles, driven in
[0, 1]; a *pressure actuator* (``pressure_actuators``: name -> maximum pressure in Pa) is a
pressure on the surface group of the same name, e.g. the intra-oral pressure on the wall of the
oral vestibule that puffs the cheeks (docs/design.md, "Intra-oral pressure"). Its control is
signed, in [-1, 1] (suction to pressure: ``activation_lower_bounds``), and it has no fibre entries.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from wface.files import FileFormatError, load_npz, save_npz
from wface.model.material import Material, ModelError

__all__ = [
    "BONES",
    "FORMAT_VERSION",
    "BoneMesh",
    "FaceModel",
    "JawJoint",
    "load_model",
    "model_sha256",
    "save_model",
]

# 2: the material may carry mu20_pa or fibre_stress. 3: the model has pressure actuators. 4: the jaw
# joint has a closing range (JawJoint.max_closing_sine > 0). 5: the material names muscles' own fibre
# curves (Material.muscle_curves). 6: the flesh's bulk potential is not the default (Material.bulk_potential
# "quadratic"). A model without these is still written as format 1, byte for byte
# as before, so older wface versions read it; one with any of them is refused by a version that would lose it.
FORMAT_VERSION = 6
BONES = ("cranium", "jaw")  # bone ids 0 and 1 in attachment arrays
FACE_SPAN_M = (0.02, 2.0)  # the rest flesh's largest extent, metres: a lip alone to head and shoulders


@dataclass(frozen=True)
class JawJoint:
    """Temporomandibular joint geometry (Sifakis et al. 2005, section 8; docs/design.md, "Controls and the jaw joint").

    ``u``: unit vector from the right to the left condyle; ``v``: unit vector along the sliding
    tracks, back to front; ``w = v x u``; ``midpoint_m``: condyle midpoint; ``condyle_distance_m``
    (l); ``track_length_m`` (d); ``max_opening_sine`` (s = sin of the largest opening angle);
    ``max_closing_sine`` (sin of the largest angle the jaw may rotate closed past the rest pose: 0 when
    the rest pose has the teeth in occlusion, the freeway space when it is the postural rest with the
    teeth apart; docs/design.md, "Controls and the jaw joint").
    """

    u: tuple[float, float, float]
    v: tuple[float, float, float]
    midpoint_m: tuple[float, float, float]
    condyle_distance_m: float
    track_length_m: float
    max_opening_sine: float
    max_closing_sine: float = 0.0

    @property
    def w(self) -> np.ndarray:
        return np.cross(np.asarray(self.v), np.asarray(self.u))

    def validate(self) -> None:
        u, v = np.asarray(self.u, float), np.asarray(self.v, float)
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(v)) and np.all(np.isfinite(self.midpoint_m))):
            raise ModelError("jaw joint: non-finite axis or midpoint")
        if abs(np.linalg.norm(u) - 1) > 1e-9 or abs(np.linalg.norm(v) - 1) > 1e-9:
            raise ModelError(
                f"jaw joint: u and v must be unit vectors (|u|={np.linalg.norm(u)}, |v|={np.linalg.norm(v)})"
            )
        if abs(u @ v) > 1e-9:
            raise ModelError(f"jaw joint: u and v must be orthogonal (u.v = {u @ v:.3g})")
        if not (self.condyle_distance_m > 0 and self.track_length_m >= 0 and 0 < self.max_opening_sine <= 1):
            raise ModelError("jaw joint: need condyle_distance_m > 0, track_length_m >= 0, 0 < max_opening_sine <= 1")
        if not (np.isfinite(self.max_closing_sine) and 0 <= self.max_closing_sine < 1):
            raise ModelError(f"jaw joint: need 0 <= max_closing_sine < 1, got {self.max_closing_sine}")


@dataclass
class BoneMesh:
    """A rigid triangle surface that moves with a bone (``bone`` is "cranium" or "jaw")."""

    vertices_m: np.ndarray  # (k, 3) float64
    triangles: np.ndarray  # (t, 3) int32
    bone: str


@dataclass
class FaceModel:
    """An anatomical face for the quasistatic FEM (docs/design.md, "Units and the face model").

    Shapes: n nodes, m tets.
    """

    rest_positions_m: np.ndarray  # (n, 3) float64
    tets: np.ndarray  # (m, 4) int32, positively oriented
    skin_triangles: np.ndarray  # (k, 3) int32, outer skin (markers, rendering, contact)
    muscle_names: list[str]
    fibre_tet: np.ndarray  # (e,) int32, sorted
    fibre_muscle: np.ndarray  # (e,) int32 index into muscle_names
    fibre_fraction: np.ndarray  # (e,) float64 in [0, 1]
    fibre_direction: np.ndarray  # (e, 3) float64 unit, rest space
    attached_nodes: np.ndarray  # (a,) int32
    attached_bone: np.ndarray  # (a,) int8, index into BONES
    jaw_joint: JawJoint
    material: Material = field(default_factory=Material)
    muscle_strength: np.ndarray | None = None  # (M,) float64 multiplier of sigma_max, default ones
    bone_meshes: dict[str, BoneMesh] = field(default_factory=dict)
    surface_groups: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (t, 3) int32 triangles
    marker_names: list[str] = field(default_factory=list)
    marker_positions_m: np.ndarray | None = None  # (k, 3) rest positions of the default markers
    facs: dict[str, dict[str, float]] = field(default_factory=dict)  # AU -> {muscle: weight}
    metadata: dict = field(default_factory=dict)
    # actuator name (in muscle_names) -> maximum pressure (Pa) on surface_groups[name], whose
    # triangles are wound outward of the flesh (normals into the cavity); control in [-1, 1]
    pressure_actuators: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rest_positions_m = np.asarray(self.rest_positions_m, dtype=np.float64)
        self.tets = np.asarray(self.tets, dtype=np.int32)
        self.skin_triangles = np.asarray(self.skin_triangles, dtype=np.int32).reshape(-1, 3)
        self.muscle_names = [str(s) for s in self.muscle_names]
        self.fibre_tet = np.asarray(self.fibre_tet, dtype=np.int32)
        self.fibre_muscle = np.asarray(self.fibre_muscle, dtype=np.int32)
        self.fibre_fraction = np.asarray(self.fibre_fraction, dtype=np.float64)
        self.fibre_direction = np.asarray(self.fibre_direction, dtype=np.float64).reshape(-1, 3)
        self.attached_nodes = np.asarray(self.attached_nodes, dtype=np.int32)
        self.attached_bone = np.asarray(self.attached_bone, dtype=np.int8)
        if self.muscle_strength is None:
            self.muscle_strength = np.ones(len(self.muscle_names))
        self.muscle_strength = np.asarray(self.muscle_strength, dtype=np.float64)
        if self.marker_positions_m is None:
            self.marker_positions_m = np.zeros((0, 3))
        self.marker_positions_m = np.asarray(self.marker_positions_m, dtype=np.float64).reshape(-1, 3)
        self.marker_names = [str(s) for s in self.marker_names]
        self.pressure_actuators = {str(k): float(v) for k, v in self.pressure_actuators.items()}
        self._derived: dict[str, np.ndarray] = {}

    # ------------------------------------------------------------------ sizes and derived data
    @property
    def n_nodes(self) -> int:
        return int(self.rest_positions_m.shape[0])

    @property
    def n_tets(self) -> int:
        return int(self.tets.shape[0])

    @property
    def n_muscles(self) -> int:
        """Activation channels: the muscles and any pressure actuator (the built-in face's intraoral_pressure)."""
        return len(self.muscle_names)

    def muscle_index(self, name: str) -> int:
        """Index of a muscle by name; a clear KeyError lists the known names."""
        try:
            return self.muscle_names.index(name)
        except ValueError:
            raise KeyError(f"unknown muscle {name!r}; this model has: {', '.join(self.muscle_names)}") from None

    @property
    def activation_lower_bounds(self) -> np.ndarray:
        """(M,) lower bound of each activation channel: 0 for a muscle, -1 for a pressure actuator
        (suction); every upper bound is 1."""
        lo = np.zeros(self.n_muscles)
        for name in self.pressure_actuators:
            lo[self.muscle_names.index(name)] = -1.0
        return lo

    def clip_activations(self, a: np.ndarray) -> np.ndarray:
        """(..., M) activations clipped to each channel's range (``activation_lower_bounds``, 1)."""
        return np.clip(a, self.activation_lower_bounds, 1.0)

    def activation_vector(self, activations: dict[str, float] | np.ndarray | None = None) -> np.ndarray:
        """Activations as an (M,) float64 vector from a {name: value} dict or an array; values in [0, 1]
        ([-1, 1] for a pressure actuator)."""
        a = np.zeros(self.n_muscles)
        if activations is None:
            return a
        if isinstance(activations, dict):
            for name, value in activations.items():
                a[self.muscle_index(name)] = float(value)
        else:
            raw = np.asarray(activations)
            if raw.dtype.kind not in "biuf" or raw.shape != (self.n_muscles,):
                raise ValueError(
                    f"activation vector must be ({self.n_muscles},) numbers, got shape {raw.shape} of {raw.dtype}"
                )
            a = raw.astype(np.float64)
        if not np.all(np.isfinite(a)):
            raise ValueError("activations contain NaN or inf")
        lo = self.activation_lower_bounds if self.pressure_actuators else 0.0
        if np.any(a < lo) or np.any(a > 1):
            bad = [self.muscle_names[i] for i in np.flatnonzero((a < lo) | (a > 1))]
            ranges = " ([-1, 1] for the pressure actuators)" if self.pressure_actuators else ""
            raise ValueError(f"activations must lie in [0, 1]{ranges}; out of range: {', '.join(bad)}")
        return a

    def nodes_of_bone(self, bone: str) -> np.ndarray:
        """Node ids attached to ``bone`` ("cranium" or "jaw")."""
        if bone not in BONES:
            raise KeyError(f"unknown bone {bone!r}; known: {BONES}")
        return self.attached_nodes[self.attached_bone == BONES.index(bone)]

    @property
    def free_nodes(self) -> np.ndarray:
        """Node ids not attached to a bone."""
        mask = np.ones(self.n_nodes, dtype=bool)
        mask[self.attached_nodes] = False
        return np.flatnonzero(mask).astype(np.int32)

    def _edge_matrices(self, x: np.ndarray) -> np.ndarray:
        p = x[self.tets]
        return np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)  # columns

    @property
    def rest_volume_m3(self) -> np.ndarray:
        """(m,) rest volume of each tet."""
        if "vol" not in self._derived:
            self._derived["vol"] = np.linalg.det(self._edge_matrices(self.rest_positions_m)) / 6.0
        return self._derived["vol"]

    @property
    def dm_inv(self) -> np.ndarray:
        """(m, 3, 3) inverse rest edge matrices Dm^-1 (columns x1-x0, x2-x0, x3-x0)."""
        if "dminv" not in self._derived:
            self._derived["dminv"] = np.linalg.inv(self._edge_matrices(self.rest_positions_m))
        return self._derived["dminv"]

    def muscle_volume_m3(self) -> np.ndarray:
        """(M,) volume of each muscle: sum of fraction x tet volume."""
        return np.bincount(
            self.fibre_muscle,
            weights=self.fibre_fraction * self.rest_volume_m3[self.fibre_tet],
            minlength=self.n_muscles,
        )

    # ------------------------------------------------------------------ validation
    def validate(self, *, volume_tol: float = 1e-9) -> FaceModel:
        """Check consistency; raise ``ModelError`` naming the first problem found. Returns self.

        Args:
            volume_tol: a tet whose volume is below ``volume_tol`` x the median volume is degenerate.
        """
        x, t = self.rest_positions_m, self.tets
        n = x.shape[0] if x.ndim == 2 else 0
        if x.ndim != 2 or x.shape[1] != 3 or n == 0:
            raise ModelError(f"rest_positions_m must have shape (n, 3) with n > 0, got {x.shape}")
        bad = np.flatnonzero(~np.all(np.isfinite(x), axis=1))
        if bad.size:
            raise ModelError(f"rest_positions_m has NaN/inf at {bad.size} node(s), first ids {bad[:5].tolist()}")
        if t.ndim != 2 or t.shape[1] != 4 or t.shape[0] == 0:
            raise ModelError(f"tets must have shape (m, 4) with m > 0, got {t.shape}")
        out = np.flatnonzero(np.any((t < 0) | (t >= n), axis=1))
        if out.size:
            raise ModelError(
                f"tets reference nodes outside [0, {n}): {out.size} tet(s), first tet {out[0]} = {t[out[0]].tolist()}"
            )
        rep = np.flatnonzero(np.sort(t, axis=1)[:, 1:] == np.sort(t, axis=1)[:, :-1])
        if rep.size:
            raise ModelError(f"tet {int(rep[0])} repeats a node: {t[rep[0]].tolist()}")
        vol = np.linalg.det(self._edge_matrices(x)) / 6.0
        inv = np.flatnonzero(vol <= 0)
        if inv.size:
            raise ModelError(
                f"{inv.size} tet(s) have non-positive volume (inverted or flat), first ids {inv[:5].tolist()} "
                f"with volumes {vol[inv[:3]].tolist()} m^3"
            )
        tiny = np.flatnonzero(vol < volume_tol * np.median(vol))
        if tiny.size:
            raise ModelError(
                f"{tiny.size} tet(s) have near-zero volume (< {volume_tol:g} x median), first ids {tiny[:5].tolist()}"
            )
        st = self.skin_triangles
        if st.size and (st.min() < 0 or st.max() >= n):
            raise ModelError(f"skin_triangles reference nodes outside [0, {n})")
        for name, tri in self.surface_groups.items():
            if tri.size and (tri.min() < 0 or tri.max() >= n):
                raise ModelError(f"surface group {name!r} references nodes outside [0, {n})")
        self._validate_muscles()
        an, ab = self.attached_nodes, self.attached_bone
        if an.shape != ab.shape:
            raise ModelError(f"attached_nodes {an.shape} and attached_bone {ab.shape} differ in shape")
        if an.size and (an.min() < 0 or an.max() >= n):
            raise ModelError(f"attached_nodes reference nodes outside [0, {n})")
        if np.unique(an).size != an.size:
            raise ModelError("a node is attached twice (attached_nodes has duplicates)")
        if ab.size and (ab.min() < 0 or ab.max() >= len(BONES)):
            raise ModelError(f"attached_bone must be 0 (cranium) or 1 (jaw); found {sorted(set(ab.tolist()))}")
        for bname, mesh in self.bone_meshes.items():
            if mesh.bone not in BONES:
                raise ModelError(f"bone mesh {bname!r} follows unknown bone {mesh.bone!r}; known: {BONES}")
            if not np.all(np.isfinite(mesh.vertices_m)):
                raise ModelError(f"bone mesh {bname!r} has NaN/inf vertices")
            if mesh.triangles.size and (mesh.triangles.min() < 0 or mesh.triangles.max() >= len(mesh.vertices_m)):
                raise ModelError(f"bone mesh {bname!r} triangles reference vertices out of range")
        self.material.validate()
        self.jaw_joint.validate()
        if len(self.marker_names) != len(self.marker_positions_m):
            raise ModelError(f"{len(self.marker_names)} marker names but {len(self.marker_positions_m)} positions")
        if len(set(self.marker_names)) != len(self.marker_names):
            raise ModelError("marker names are not unique")
        if not np.all(np.isfinite(self.marker_positions_m)):
            raise ModelError("marker_positions_m has NaN/inf")
        self._validate_pressure_actuators()
        known = set(self.muscle_names)
        for au, table in self.facs.items():
            unknown = [m for m in table if m not in known]
            if unknown:
                raise ModelError(f"FACS entry {au} names unknown muscle(s) {unknown}")
        return self

    def _validate_muscles(self) -> None:
        m = self.n_tets
        e = self.fibre_tet.shape[0]
        names = self.muscle_names
        if len(set(names)) != len(names):
            raise ModelError("muscle names are not unique")
        for arr, label in ((self.fibre_muscle, "fibre_muscle"), (self.fibre_fraction, "fibre_fraction")):
            if arr.shape != (e,):
                raise ModelError(f"{label} has shape {arr.shape}, expected ({e},) like fibre_tet")
        if self.fibre_direction.shape != (e, 3):
            raise ModelError(f"fibre_direction has shape {self.fibre_direction.shape}, expected ({e}, 3)")
        if e:
            if self.fibre_tet.min() < 0 or self.fibre_tet.max() >= m:
                raise ModelError(f"fibre_tet references tets outside [0, {m})")
            if np.any(np.diff(self.fibre_tet) < 0):
                raise ModelError("fibre entries must be sorted by tet (fibre_tet non-decreasing)")
            if self.fibre_muscle.min() < 0 or self.fibre_muscle.max() >= len(names):
                raise ModelError(f"fibre_muscle references muscles outside [0, {len(names)})")
            f = self.fibre_fraction
            bad = np.flatnonzero(~np.isfinite(f) | (f < 0) | (f > 1))
            if bad.size:
                raise ModelError(
                    f"volume fractions outside [0, 1] at {bad.size} entr(ies), first: tet {self.fibre_tet[bad[0]]}, "
                    f"muscle {names[self.fibre_muscle[bad[0]]]!r}, fraction {f[bad[0]]}"
                )
            norms = np.linalg.norm(self.fibre_direction, axis=1)
            bad = np.flatnonzero(~np.isfinite(norms) | (np.abs(norms - 1.0) > 1e-6))
            if bad.size:
                raise ModelError(
                    f"fibre directions must be unit vectors: {bad.size} are not, first: tet {self.fibre_tet[bad[0]]}, "
                    f"muscle {names[self.fibre_muscle[bad[0]]]!r}, |d| = {norms[bad[0]]}"
                )
        if self.muscle_strength.shape != (len(names),):
            raise ModelError(f"muscle_strength has shape {self.muscle_strength.shape}, expected ({len(names)},)")
        if np.any(~np.isfinite(self.muscle_strength)) or np.any(self.muscle_strength < 0):
            raise ModelError("muscle_strength must be finite and non-negative")
        unknown = sorted({m for m, _ in self.material.muscle_curves} - set(names))
        if unknown:
            raise ModelError(f"material: muscle_curves names {unknown}, which are not muscles of this model")

    def _validate_pressure_actuators(self) -> None:
        for name, max_pa in self.pressure_actuators.items():
            if name not in self.muscle_names:
                raise ModelError(f"pressure actuator {name!r} is not an activation channel (muscle_names)")
            if name not in self.surface_groups or self.surface_groups[name].size == 0:
                raise ModelError(f"pressure actuator {name!r} has no surface group of its name to act on")
            if not (np.isfinite(max_pa) and max_pa > 0):
                raise ModelError(
                    f"pressure actuator {name!r}: maximum pressure must be finite and > 0 Pa, got {max_pa}"
                )
            if np.any(self.fibre_muscle == self.muscle_names.index(name)):
                raise ModelError(f"pressure actuator {name!r} has fibre entries (a channel is a muscle or a pressure)")

    def with_material(self, material: Material) -> FaceModel:
        """A copy with another material (arrays shared)."""
        return replace(self, material=material)


# ---------------------------------------------------------------------- save / load
_HEADER_KEYS = ("muscle_names", "marker_names", "jaw_joint", "material", "bones", "surface_groups", "facs", "metadata")
_ARRAY_FIELDS = (
    "rest_positions_m",
    "tets",
    "skin_triangles",
    "fibre_tet",
    "fibre_muscle",
    "fibre_fraction",
    "fibre_direction",
    "attached_nodes",
    "attached_bone",
    "muscle_strength",
    "marker_positions_m",
)


def _material_header(material: Material) -> dict:
    """The material's fields, each of mu20_pa, fibre_stress, muscle_curves and bulk_potential left out at its default,
    so files and ``model_sha256`` of models without them are those written before they existed; a
    file without them loads with the defaults."""
    defaults = Material()
    late = ("mu20_pa", "fibre_stress", "muscle_curves", "bulk_potential")
    return {
        f.name: getattr(material, f.name)
        for f in fields(Material)
        if f.name not in late or getattr(material, f.name) != getattr(defaults, f.name)
    }


def _model_arrays(model: FaceModel) -> tuple[dict[str, np.ndarray], dict]:
    """(arrays, header) of a model: what ``save_model`` writes and ``model_sha256`` hashes."""
    arrays = {name: getattr(model, name) for name in _ARRAY_FIELDS}
    for name, mesh in model.bone_meshes.items():
        arrays[f"bone/{name}/vertices_m"] = mesh.vertices_m
        arrays[f"bone/{name}/triangles"] = mesh.triangles
    for name, tri in model.surface_groups.items():
        arrays[f"surface/{name}"] = tri
    header = {
        "format": "wface.FaceModel",
        "format_version": _format_version(model),
        "muscle_names": model.muscle_names,
        "marker_names": model.marker_names,
        "bones": {name: mesh.bone for name, mesh in model.bone_meshes.items()},
        "surface_groups": list(model.surface_groups),
        "jaw_joint": {  # without a closing range, as formats 1-3 wrote it
            f.name: getattr(model.jaw_joint, f.name)
            for f in fields(JawJoint)
            if f.name != "max_closing_sine" or model.jaw_joint.max_closing_sine
        },
        "material": _material_header(model.material),
        "facs": model.facs,
        "metadata": model.metadata,
    }
    if model.pressure_actuators:  # absent otherwise: files and hashes of models without them unchanged
        header["pressure_actuators"] = model.pressure_actuators
    return arrays, header


def _format_version(model: FaceModel) -> int:
    """The oldest format that holds everything the model has (see FORMAT_VERSION)."""
    if model.material.bulk_potential != "log":
        return 6
    if model.material.muscle_curves:
        return 5
    if model.jaw_joint.max_closing_sine:
        return 4
    if model.pressure_actuators:
        return 3
    return 2 if model.material.mu20_pa or model.material.fibre_stress != "uniaxial" else 1


def model_sha256(model: FaceModel) -> str:
    """Hex SHA-256 of a model's content (every array's dtype, shape and bytes, and the header), the same
    for a model and its ``save_model`` / ``load_model`` round trip; the fingerprint takes record."""
    arrays, header = _model_arrays(model)
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    h.update(json.dumps(header, sort_keys=True, default=str).encode())
    return h.hexdigest()


def save_model(model: FaceModel, path: str | Path, *, validate: bool = True) -> Path:
    """Write a model to ``.npz`` (uncompressed arrays: bit-exact round trip; written to a temporary
    file renamed into place, ``wface.files``). Returns the path. ``validate``: refuse, with
    ``ModelError``, a model ``load_model`` would refuse (NaN nodes, bad tets, ...) before writing."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"face models are saved as .npz, got {path.name!r}")
    if validate:
        model.validate()
    arrays, header = _model_arrays(model)
    arrays["header_json"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    return save_npz(path, **arrays)


def _material_from_header(path: Path, values: dict) -> Material:
    known = {f.name for f in fields(Material)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ModelError(f"{path}: the face model's material has unknown field(s) {unknown} (newer wface?)")
    try:
        return Material(**values)
    except ModelError as exc:
        raise ModelError(f"{path}: {exc}") from None


def load_model(path: str | Path, *, validate: bool = True) -> FaceModel:
    """Read a model written by ``save_model``. A newer format version is refused; an unreadable,
    truncated or corrupted file raises ``ModelError`` naming the file."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"face model file not found: {path}")
    try:
        data = load_npz(path, what="a wface face model (.npz)")
    except FileFormatError as exc:
        raise ModelError(str(exc)) from None
    if "header_json" not in data:
        raise ModelError(f"{path}: not a wface face model (no header)")
    try:
        header = json.loads(bytes(data["header_json"]).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelError(f"{path}: the face model's header is corrupted ({exc})") from None
    version = int(header.get("format_version", -1))
    if header.get("format") != "wface.FaceModel":
        raise ModelError(f"{path}: not a wface face model (format {header.get('format')!r})")
    if version > FORMAT_VERSION:
        raise ModelError(
            f"{path}: written by a newer wface (model format {version}; this version reads up to "
            f"{FORMAT_VERSION}). Upgrade wface to load it."
        )
    missing = [k for k in _ARRAY_FIELDS if k not in data] + [f"header {k}" for k in _HEADER_KEYS if k not in header]
    missing += [f"bone/{n}/vertices_m" for n in header.get("bones", {}) if f"bone/{n}/vertices_m" not in data]
    missing += [f"surface/{n}" for n in header.get("surface_groups", []) if f"surface/{n}" not in data]
    if missing:
        raise ModelError(f"{path}: the face model lacks {', '.join(missing)} (truncated or not written by wface?)")
    arrays = {name: data[name] for name in _ARRAY_FIELDS}
    bones = {
        name: BoneMesh(data[f"bone/{name}/vertices_m"], data[f"bone/{name}/triangles"], bone)
        for name, bone in header["bones"].items()
    }
    surfaces = {name: data[f"surface/{name}"] for name in header["surface_groups"]}
    jj = header["jaw_joint"]
    model = FaceModel(
        **arrays,
        muscle_names=header["muscle_names"],
        marker_names=header["marker_names"],
        jaw_joint=JawJoint(**{k: tuple(v) if isinstance(v, list) else v for k, v in jj.items()}),
        material=_material_from_header(path, header["material"]),
        bone_meshes=bones,
        surface_groups=surfaces,
        facs=header["facs"],
        metadata=header["metadata"],
        pressure_actuators=header.get("pressure_actuators", {}),
    )
    if not validate:
        return model
    try:
        model.validate()
        span = float(np.ptp(model.rest_positions_m, axis=0).max())
        if not FACE_SPAN_M[0] <= span <= FACE_SPAN_M[1]:  # a file's units: mm saved as m, say (files only)
            raise ModelError(
                f"the flesh spans {span:.3g} m, where a face spans {FACE_SPAN_M[0]:g} to {FACE_SPAN_M[1]:g} m"
            )
    except ModelError as exc:
        raise ModelError(f"{path}: {exc}") from None
    return model
