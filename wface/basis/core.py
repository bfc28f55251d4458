"""The linear actuation basis of Choe & Ko (2001): E = E0 + sum_i x_i e_i.

E0 is the neutral surface (n, 3) and e_i the displacement field of element i acting alone at
full contraction (x_i = 1). A basis can come from a set of OBJ files (neutral + one per element),
from the ICT-FaceKit expression npz (centimetres), from any displacement fields (e.g. an FEM face
with one muscle at a time), or from this module's own npz format.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wface.files import load_npz, save_npz

__all__ = ["ActuationBasis", "FORMAT_VERSION", "load_basis", "polygons_to_triangles"]

FORMAT_VERSION = 1


def polygons_to_triangles(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Fan-triangulate USD-style polygons.

    Args:
        counts: (p,) vertices per polygon (>= 3).
        indices: (sum(counts),) vertex ids, polygon after polygon.

    Returns:
        (t, 3) int64 triangles, t = sum(counts - 2).
    """
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if counts.sum() != len(indices):
        raise ValueError(f"polygon counts sum to {counts.sum()} but there are {len(indices)} indices")
    if np.any(counts < 3):
        raise ValueError("polygons need at least 3 vertices")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    n_tri = counts - 2
    owner = np.repeat(np.arange(len(counts)), n_tri)
    k = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)  # fan index within polygon
    s = starts[owner]
    return np.stack([indices[s], indices[s + k + 1], indices[s + k + 2]], axis=1)


@dataclass
class ActuationBasis:
    """Neutral surface plus one displacement shape per actuation element.

    Attributes:
        neutral_m: (n, 3) float64 neutral vertex positions, metres.
        shapes_m: (B, n, 3) float64 displacement of each element at full contraction, metres.
        names: B element names (unique).
        face_counts: (p,) vertices per polygon.
        face_indices: (sum(face_counts),) polygon vertex ids.
        skin_vertices: vertex ids markers may be attached to and refinement may move (default:
            all vertices).
        source: where the basis came from.
        landmarks: {marker name: vertex} the basis knows its markers by (a basis made from a face
            model: the model's markers at their nearest skin vertices), or None. Capture
            alignment starts from them when no landmarks are given.
    """

    neutral_m: np.ndarray
    shapes_m: np.ndarray
    names: list[str]
    face_counts: np.ndarray
    face_indices: np.ndarray
    skin_vertices: np.ndarray | None = None
    source: str = ""
    landmarks: dict[str, int] | None = None
    _triangles: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        self.neutral_m = np.asarray(self.neutral_m, dtype=np.float64)
        self.shapes_m = np.asarray(self.shapes_m, dtype=np.float64)
        self.names = [str(n) for n in self.names]
        self.face_counts = np.asarray(self.face_counts, dtype=np.int64)
        self.face_indices = np.asarray(self.face_indices, dtype=np.int64)
        n = self.neutral_m.shape[0]
        if self.neutral_m.shape != (n, 3):
            raise ValueError(f"basis neutral must be (n, 3), got {self.neutral_m.shape}")
        if self.shapes_m.ndim != 3 or self.shapes_m.shape[1:] != (n, 3):
            raise ValueError(f"basis shapes must be (B, {n}, 3), got {self.shapes_m.shape}")
        if len(self.names) != self.shapes_m.shape[0]:
            raise ValueError(f"basis has {self.shapes_m.shape[0]} shapes but {len(self.names)} names")
        if len(set(self.names)) != len(self.names):
            raise ValueError("basis element names must be unique")
        if len(self.face_indices) and (self.face_indices.min() < 0 or self.face_indices.max() >= n):
            raise ValueError("basis polygons reference vertices out of range")
        if self.skin_vertices is not None:
            self.skin_vertices = np.asarray(self.skin_vertices, dtype=np.int64)
        if self.landmarks is not None:
            self.landmarks = {str(k): int(v) for k, v in self.landmarks.items()}
            bad = {k: v for k, v in self.landmarks.items() if not 0 <= v < n}
            if bad:
                raise ValueError(f"basis landmarks name vertices outside its {n} vertices: {bad}")

    # ------------------------------------------------------------------ properties and synthesis
    @property
    def n_elements(self) -> int:
        return self.shapes_m.shape[0]

    @property
    def n_vertices(self) -> int:
        return self.neutral_m.shape[0]

    @property
    def triangles(self) -> np.ndarray:
        """(t, 3) fan triangulation of the polygons."""
        if self._triangles is None:
            self._triangles = polygons_to_triangles(self.face_counts, self.face_indices)
        return self._triangles

    @property
    def skin_triangles(self) -> np.ndarray:
        """Triangles whose three vertices are all skin vertices."""
        tri = self.triangles
        if self.skin_vertices is None:
            return tri
        mask = np.zeros(self.n_vertices, dtype=bool)
        mask[self.skin_vertices] = True
        return tri[mask[tri].all(axis=1)]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"basis has no element named {name!r}") from None

    def synthesize(self, contractions: np.ndarray) -> np.ndarray:
        """Vertex positions E0 + sum_i x_i e_i.

        Args:
            contractions: (B,) or (frames, B).

        Returns:
            (n, 3) or (frames, n, 3) positions in metres.
        """
        x = np.asarray(contractions, dtype=np.float64)
        if x.shape[-1] != self.n_elements:
            raise ValueError(f"synthesize: got {x.shape[-1]} contractions for {self.n_elements} elements")
        flat = self.shapes_m.reshape(self.n_elements, -1)
        return self.neutral_m + (x @ flat).reshape(*x.shape[:-1], self.n_vertices, 3)

    def vertex_shapes(self, vertices: Sequence[int] | np.ndarray) -> np.ndarray:
        """(k, 3, B) displacement of vertex j, coordinate c, under element i."""
        v = np.asarray(vertices, dtype=np.int64)
        return self.shapes_m[:, v, :].transpose(1, 2, 0).copy()

    def subset(self, names: Sequence[str]) -> ActuationBasis:
        """The basis restricted to (and ordered as) ``names``."""
        idx = [self.index(n) for n in names]
        return ActuationBasis(
            self.neutral_m,
            self.shapes_m[idx],
            list(names),
            self.face_counts,
            self.face_indices,
            self.skin_vertices,
            self.source,
            self.landmarks,
        )

    # ------------------------------------------------------------------------------- builders
    @classmethod
    def from_displacements(
        cls,
        neutral_m: np.ndarray,
        shapes_m: np.ndarray,
        names: Sequence[str],
        *,
        triangles: np.ndarray | None = None,
        face_counts: np.ndarray | None = None,
        face_indices: np.ndarray | None = None,
        skin_vertices: np.ndarray | None = None,
        source: str = "displacements",
        landmarks: dict[str, int] | None = None,
    ) -> ActuationBasis:
        """Basis from displacement fields, e.g. an FEM face with each muscle activated alone.

        Args:
            neutral_m: (n, 3) rest surface, metres.
            shapes_m: (B, n, 3) displacement of each element at full contraction, metres.
            names: B element names.
            triangles: (t, 3) surface triangles (or give ``face_counts`` + ``face_indices``).
        """
        if triangles is not None:
            tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
            face_counts, face_indices = np.full(len(tri), 3), tri.ravel()
        if face_counts is None or face_indices is None:
            raise ValueError("from_displacements: give triangles or face_counts and face_indices")
        return cls(neutral_m, shapes_m, list(names), face_counts, face_indices, skin_vertices, source, landmarks)

    @classmethod
    def from_ict_npz(
        cls, path: str | Path, *, names: Sequence[str] | None = None, skin_only: bool = True
    ) -> ActuationBasis:
        """Basis from ICT-FaceKit's ``ict_expressions.npz`` (centimetres -> metres).

        Args:
            path: the npz (keys neutral, face_vertex_counts, face_vertex_indices, names, deltas).
            names: keep only these expression shapes (default all 57).
            skin_only: markers attach to, and refinement moves, only the face and head skin
                (ICT vertices 0-11247: face 0-9408, head and neck 9409-11247).
        """
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such ICT expression file")
        with np.load(path) as d:
            missing = {"neutral", "face_vertex_counts", "face_vertex_indices", "names", "deltas"} - set(d.files)
            if missing:
                raise ValueError(f"{path}: not an ICT expression npz, missing {sorted(missing)}")
            all_names = [str(n) for n in d["names"]]
            deltas = d["deltas"]
            neutral = d["neutral"].astype(np.float64) * 0.01
            counts, indices = d["face_vertex_counts"], d["face_vertex_indices"]
        keep = list(range(len(all_names))) if names is None else [all_names.index(n) for n in names]
        shapes = deltas[keep].astype(np.float64) * 0.01
        skin = np.arange(11248) if skin_only and len(neutral) > 11248 else None
        return cls(neutral, shapes, [all_names[i] for i in keep], counts, indices, skin, str(path))

    @classmethod
    def from_obj_files(
        cls,
        neutral_path: str | Path,
        element_paths: dict[str, str | Path] | Sequence[str | Path],
        *,
        units_to_m: float = 1.0,
    ) -> ActuationBasis:
        """Basis from OBJ files: the neutral and one posed mesh per element (same topology).

        Args:
            neutral_path: neutral OBJ.
            element_paths: {name: OBJ} or a list of OBJs (named by file stem).
            units_to_m: length unit of the files in metres (0.01 for centimetres).
        """
        if not isinstance(element_paths, dict):
            element_paths = {Path(p).stem: p for p in element_paths}
        v0, counts, indices = _read_obj(neutral_path)
        shapes = []
        for name, p in element_paths.items():
            v, c, _ = _read_obj(p)
            if v.shape != v0.shape:
                raise ValueError(f"{p}: {len(v)} vertices, the neutral {neutral_path} has {len(v0)} (element {name!r})")
            shapes.append(v - v0)
        return cls(v0 * units_to_m, np.array(shapes) * units_to_m, list(element_paths), counts, indices, None,
                   str(neutral_path))  # fmt: skip

    # ------------------------------------------------------------------------------ save/load
    def save(self, path: str | Path) -> None:
        """Write a compressed npz (metres, float64) that :func:`load_basis` reads back exactly."""
        extra = {} if self.skin_vertices is None else {"skin_vertices": self.skin_vertices}
        if self.landmarks:
            extra["landmark_names"] = np.array(list(self.landmarks))
            extra["landmark_vertices"] = np.array(list(self.landmarks.values()), dtype=np.int64)
        save_npz(
            path, compressed=True, format="wface.actuation_basis", format_version=FORMAT_VERSION,
            neutral_m=self.neutral_m, shapes_m=self.shapes_m, names=np.array(self.names), face_counts=self.face_counts,
            face_indices=self.face_indices, source=self.source, **extra,
        )  # fmt: skip


def _read_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (n, 3) and polygons (counts, indices) of an OBJ file (v and f records only)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such OBJ file")
    verts, counts, idx = [], [], []
    with path.open() as fh:
        for ln, line in enumerate(fh, 1):
            if line.startswith("v "):
                parts = line.split()
                if len(parts) < 4:
                    raise ValueError(f"{path}:{ln}: vertex line needs 3 coordinates")
                try:
                    verts.append([float(p) for p in parts[1:4]])
                except ValueError:
                    raise ValueError(f"{path}:{ln}: vertex coordinates are not numbers: {line.strip()!r}") from None
            elif line.startswith("f "):
                ids = [int(p.split("/")[0]) for p in line.split()[1:]]
                ids = [i - 1 if i > 0 else len(verts) + i for i in ids]
                counts.append(len(ids))
                idx.extend(ids)
    if not verts:
        raise ValueError(f"{path}: OBJ file has no vertices")
    return np.array(verts, dtype=np.float64), np.array(counts, dtype=np.int64), np.array(idx, dtype=np.int64)


def load_basis(path: str | Path) -> ActuationBasis:
    """Load a basis from this module's npz, or straight from an ICT-FaceKit expression npz."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such basis file")
    d = load_npz(path, what="an actuation basis (.npz)")  # named errors for empty, truncated, corrupted files
    files = set(d)
    if "format" in files and str(d["format"]) == "wface.actuation_basis":
        version = int(d["format_version"])
        if version > FORMAT_VERSION:
            raise ValueError(f"{path}: basis format version {version} is newer than this wface ({FORMAT_VERSION})")
        skin = d["skin_vertices"] if "skin_vertices" in files else None
        landmarks = None
        if "landmark_names" in files:
            landmarks = dict(zip([str(n) for n in d["landmark_names"]], d["landmark_vertices"].tolist(), strict=True))
        return ActuationBasis(
            d["neutral_m"],
            d["shapes_m"],
            [str(n) for n in d["names"]],
            d["face_counts"],
            d["face_indices"],
            skin,
            str(d["source"]),
            landmarks,
        )
    if {"neutral", "deltas", "names"} <= files:
        return ActuationBasis.from_ict_npz(path)
    raise ValueError(f"{path}: neither a wface actuation basis nor an ICT expression npz (keys: {sorted(files)})")
