"""Polygon surface meshes from files (OBJ, PLY, STL, OFF, ...), read by maintained libraries, and OBJ out.

One ``SurfaceMesh`` serves every user of a head mesh: a render mesh bound to the FEM face
(``wface.faces.render_mesh``), the target of template fitting (``wface.faces.fit``) and the Waters
tools (``wface.waters``). A TD's head carries more than positions, and the mesh keeps it all,
face-varying, in the source's vertex and polygon order, so a posed mesh drops back onto the
artist's rig and shaders:

- OBJ goes through tinyobjloader (the maintained reference OBJ parser): polygons as authored
  (quads and triangles, no triangulation), per-corner texture coordinates and normals with their
  own indices (the UV seams of an artist's layout: the ICT-FaceKit head has 26,719 vertices and
  28,911 UVs), the ``usemtl`` material of every face, the ``mtllib`` name and the diffuse colours
  the ``.mtl`` defines. Materials named by ``usemtl`` but missing from the ``.mtl`` (or with no
  ``.mtl``, or no ``mtllib`` line at all) keep their names: the parser gets a stub library that
  defines them. trimesh was measured first and left out: on the ICT head it triangulated the
  quads, split the vertices into 12 meshes and dropped the UVs because the ``.mtl`` is absent.
- Every other format goes through meshio (positions and polygons only).
- ``write_obj`` writes the file units (``# units: cm``), ``mtllib``, ``usemtl`` groups, ``vt`` and
  ``vn`` with ``f v/vt/vn`` corners, atomically. The USD writers of a ``SurfaceMesh`` live in
  ``wface.io.usd`` (``write_surface_mesh``; a render mesh's layer in ``wface.io.usd.render_mesh``).

``points`` are in the file's units and ``meters_per_unit`` says what they are (``points_m`` in
metres; ``vertices_m`` is the same array, the name the Waters tools use), read from the extent
unless given: a head is about 0.25 m tall, so a largest extent under 3 is metres, under 150
centimetres, else millimetres. A posed mesh (``with_vertices``) keeps the layout and gets normals
of its own shape (area-weighted per vertex) when the source had normals.
"""

from __future__ import annotations

import contextlib
import io
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import meshio
import numpy as np
import tinyobjloader

from wface.files import write_text
from wface.mesh.surface import vertex_normals

__all__ = ["UNITS", "SurfaceMesh", "guess_meters_per_unit", "read_surface_mesh", "write_obj"]

#: unit name -> metres per unit
UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "in": 0.0254}


@dataclass
class SurfaceMesh:
    """A polygon mesh as authored (USD-style flat topology, module docstring).

    Attributes:
        points: (n, 3) float64 vertex positions in the file's units.
        face_vertex_counts: (p,) int32 corners per face (3 or more).
        face_vertex_indices: (sum counts,) int32 vertex ids, corners in order.
        meters_per_unit: metres per file unit (0.01 for centimetres).
        uv: (u, 2) float64 texture coordinates, or None.
        uv_indices: (sum counts,) int32 index into ``uv`` per face corner (faceVarying), or None.
        normals: (j, 3) unit normals, or None; ``normal_indices`` (sum counts,) per corner.
        face_groups: {material name: (f,) int32 face ids} in file order; empty without materials.
        material_library: the ``mtllib`` file name of the source, or None.
        material_colors: {material name: (3,) diffuse colour} that the ``.mtl`` file defines.
        source: the file it came from.
    """

    points: np.ndarray
    face_vertex_counts: np.ndarray
    face_vertex_indices: np.ndarray
    meters_per_unit: float = 1.0
    uv: np.ndarray | None = None
    uv_indices: np.ndarray | None = None
    normals: np.ndarray | None = None
    normal_indices: np.ndarray | None = None
    face_groups: dict[str, np.ndarray] = field(default_factory=dict)
    material_library: str | None = None
    material_colors: dict = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64)
        self.face_vertex_counts = np.asarray(self.face_vertex_counts, dtype=np.int32).reshape(-1)
        self.face_vertex_indices = np.asarray(self.face_vertex_indices, dtype=np.int32).reshape(-1)
        where = f"{self.source}: " if self.source else ""
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"{where}vertices must have shape (n, 3), got {self.points.shape}")
        if not np.all(np.isfinite(self.points)):
            raise ValueError(f"{where}vertices contain NaN or inf")
        if np.any(self.face_vertex_counts < 3):
            raise ValueError(f"{where}a face has fewer than 3 corners")
        idx = self.face_vertex_indices
        if self.face_vertex_counts.sum() != idx.size:
            raise ValueError(f"{where}face_vertex_counts must sum to the number of face vertex indices")
        if idx.size and (idx.min() < 0 or idx.max() >= len(self.points)):
            raise ValueError(f"{where}face indices outside the {len(self.points)} vertices")
        if not (np.isfinite(self.meters_per_unit) and self.meters_per_unit > 0):
            raise ValueError(f"meters per unit must be a positive number, got {self.meters_per_unit}")
        self.meters_per_unit = float(self.meters_per_unit)
        for values, ids, width, label in (
            ("uv", "uv_indices", 2, "texture coordinates"),
            ("normals", "normal_indices", 3, "normals"),
        ):
            v = getattr(self, values)
            if v is None:
                setattr(self, ids, None)
                continue
            v = np.asarray(v, dtype=np.float64).reshape(-1, width)
            i = np.asarray(getattr(self, ids), dtype=np.int32).reshape(-1)
            if i.size != idx.size or (i.size and (i.min() < 0 or i.max() >= len(v))):
                raise ValueError(f"{where}{label}: one index per face corner into {len(v)} values is needed")
            setattr(self, values, v)
            setattr(self, ids, i)
        groups = {str(k): np.asarray(f, dtype=np.int32).reshape(-1) for k, f in self.face_groups.items()}
        for name, f in groups.items():
            if f.size and (f.min() < 0 or f.max() >= self.n_faces):
                raise ValueError(f"{where}material {name!r}: face ids outside [0, {self.n_faces})")
        self.face_groups = groups

    @classmethod
    def from_triangles(cls, vertices_m: np.ndarray, triangles: np.ndarray) -> SurfaceMesh:
        """A triangle mesh in metres, without UVs or materials."""
        t = np.asarray(triangles, dtype=np.int32).reshape(-1, 3)
        return cls(vertices_m, np.full(len(t), 3, np.int32), t.ravel())

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    n_vertices = n_points

    @property
    def n_faces(self) -> int:
        return int(self.face_vertex_counts.shape[0])

    @property
    def points_m(self) -> np.ndarray:
        """(n, 3) vertex positions in metres (file frame)."""
        return self.points * self.meters_per_unit

    vertices_m = points_m

    @property
    def units(self) -> str | None:
        """The file's unit name ("cm", ...) when ``meters_per_unit`` is one of ``UNITS``, else None."""
        return next((k for k, v in UNITS.items() if np.isclose(v, self.meters_per_unit, rtol=1e-12, atol=0)), None)

    @property
    def material_names(self) -> list[str]:
        """The material groups' names, in file order."""
        return list(self.face_groups)

    @property
    def face_materials(self) -> np.ndarray | None:
        """(p,) int32 index into ``material_names`` per face (-1: none), or None without materials."""
        if not self.face_groups:
            return None
        out = np.full(self.n_faces, -1, dtype=np.int32)
        for k, f in enumerate(self.face_groups.values()):
            out[f] = k
        return out

    def triangles(self) -> np.ndarray:
        """(t, 3) int32 fan triangulation of the polygons (``triangle_faces`` names each one's face)."""
        counts = self.face_vertex_counts.astype(np.int64)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        n_tri = counts - 2
        face = self.triangle_faces()
        k = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)  # fan index within its face
        s = starts[face]
        idx = self.face_vertex_indices
        return np.stack([idx[s], idx[s + k + 1], idx[s + k + 2]], axis=1).astype(np.int32)

    def triangle_faces(self) -> np.ndarray:
        """(t,) int32 face id of each triangle of ``triangles()``."""
        return np.repeat(np.arange(self.n_faces), self.face_vertex_counts.astype(np.int64) - 2).astype(np.int32)

    def faces_of(self, groups) -> np.ndarray:
        """Sorted face ids of the named material groups (KeyError naming the known groups)."""
        ids = []
        for g in groups:
            if g not in self.face_groups:
                raise KeyError(
                    f"{self.source}: no material group {g!r}; it has {', '.join(self.face_groups) or 'none'}"
                )
            ids.append(self.face_groups[g])
        return np.unique(np.concatenate(ids)) if ids else np.zeros(0, dtype=np.int32)

    def with_vertices(self, vertices_m: np.ndarray) -> SurfaceMesh:
        """The same mesh (topology, UVs, materials, units) with new vertex positions (n, 3) in metres;
        normals, when the source has them, are those of the new shape (one per vertex)."""
        v = np.asarray(vertices_m, dtype=np.float64)
        if v.shape != self.points.shape:
            raise ValueError(f"new vertices have shape {v.shape}, expected {self.points.shape}")
        out = replace(self, points=v / self.meters_per_unit)
        if self.normals is not None:
            out = replace(out, normals=vertex_normals(v, self.triangles()), normal_indices=self.face_vertex_indices)
        return out


def guess_meters_per_unit(points: np.ndarray) -> float:
    """Metres per unit of a head-sized mesh from its largest bounding-box extent (module docstring)."""
    extent = float(np.max(np.ptp(np.asarray(points, dtype=np.float64), axis=0)))
    if extent < 3.0:
        return UNITS["m"]
    if extent < 150.0:
        return UNITS["cm"]
    return UNITS["mm"]


def _meters_per_unit(units: str | float, points: np.ndarray) -> float:
    if units == "auto":
        return guess_meters_per_unit(points)
    if isinstance(units, str):
        if units not in UNITS:
            raise ValueError(f"unknown units {units!r}; known: auto, {', '.join(UNITS)}")
        return UNITS[units]
    if not (np.isfinite(units) and units > 0):
        raise ValueError(f"meters per unit must be a positive number, got {units}")
    return float(units)


def _material_text(path: Path, text: str) -> tuple[str, str, str | None, set[str]]:
    """(the OBJ text for the parser, the .mtl text: the source's library plus a stub for every other
    ``usemtl`` name, the library's file name, the names the library defines)."""
    lib = re.search(r"^\s*mtllib\s+(.+?)\s*$", text, re.M)
    mtl = ""
    if lib and (path.parent / lib.group(1)).is_file():
        mtl = (path.parent / lib.group(1)).read_text(errors="replace")
    defined = set(re.findall(r"^\s*newmtl\s+(\S+)", mtl, re.M))
    used = dict.fromkeys(re.findall(r"^\s*usemtl\s+(\S+)", text, re.M))
    stubs = "".join(f"\nnewmtl {name}\n" for name in used if name not in defined)
    if used and not lib:
        text = "mtllib stub.mtl\n" + text  # the parser reads the library only where the file asks for one
    return text, mtl + stubs, lib.group(1) if lib else None, defined


def _check_obj_vertices(path: Path, text: str) -> None:
    """Refuse ``v`` lines whose position is not 3 finite numbers: tinyobjloader reads ``nan``, a missing
    coordinate or a word as 0, which would put the vertex at the origin without a word."""
    for number, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts or parts[0] != "v":
            continue
        try:
            xyz = [float(p) for p in parts[1:4]]
        except ValueError:
            xyz = []
        if len(xyz) < 3 or not all(math.isfinite(c) for c in xyz):
            raise ValueError(f"{path}:{number}: a vertex needs 3 finite coordinates, got {line.strip()!r}")


def _read_obj(path: Path) -> dict:
    """The pieces of an OBJ file, in the file's units, via tinyobjloader (polygons kept)."""
    raw = path.read_text(errors="replace")
    _check_obj_vertices(path, raw)
    text, mtl, library, defined = _material_text(path, raw)
    reader = tinyobjloader.ObjReader()
    config = tinyobjloader.ObjReaderConfig()
    config.triangulate = False
    if not reader.ParseFromString(text, mtl, config):
        raise ValueError(f"{path}: not a readable OBJ file ({reader.Error().strip()})")
    attrib = reader.GetAttrib()
    shapes = [s.mesh for s in reader.GetShapes()]
    if sum(len(m.num_face_vertices) for m in shapes) == 0:
        raise ValueError(f"{path}: the OBJ file has no faces")
    # the list accessors: the numpy_* views of tinyobjloader 2.0.0rc13 misread their dtypes
    counts = np.concatenate([np.asarray(m.num_face_vertices, dtype=np.int32) for m in shapes])
    corner = {
        key: np.concatenate([np.asarray(getattr(m, f"{key}_indices")(), dtype=np.int64) for m in shapes])
        for key in ("vertex", "texcoord", "normal")
    }
    face_mat = np.concatenate([np.asarray(m.material_ids, dtype=np.int64) for m in shapes])
    out = {"v": np.asarray(attrib.vertices, dtype=np.float64).reshape(-1, 3), "counts": counts}
    out["indices"], out["library"] = corner["vertex"], library
    uv = np.asarray(attrib.texcoords, dtype=np.float64).reshape(-1, 2)
    if len(uv) and np.all(corner["texcoord"] >= 0):
        out["uv"], out["uv_indices"] = uv, corner["texcoord"]
    vn = np.asarray(attrib.normals, dtype=np.float64).reshape(-1, 3)
    if len(vn) and np.all(corner["normal"] >= 0):
        out["normals"], out["normal_indices"] = vn, corner["normal"]
    materials = reader.GetMaterials()
    groups = {m.name: np.flatnonzero(face_mat == k).astype(np.int32) for k, m in enumerate(materials)}
    out["groups"] = {k: v for k, v in groups.items() if v.size}
    out["colors"] = {m.name: tuple(m.diffuse) for m in materials if m.name in defined and m.name in out["groups"]}
    return out


def _read_meshio(path: Path) -> dict:
    try:
        said = io.StringIO()  # meshio prints its complaints
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            mesh = meshio.read(path)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - any reader failure; meshio's ply reader calls exit(1)
        why = " ".join(said.getvalue().split()) or str(exc)
        raise ValueError(f"{path}: not a readable surface mesh ({why})") from None
    counts, idx = [], []
    for block in mesh.cells:
        if block.type in ("triangle", "quad"):
            data = np.asarray(block.data, dtype=np.int64)
            counts.append(np.full(len(data), data.shape[1], dtype=np.int32))
            idx.append(data.ravel())
        elif block.type.startswith("polygon"):
            for poly in block.data:
                counts.append(np.array([len(poly)], dtype=np.int32))
                idx.append(np.asarray(poly, dtype=np.int64))
    if not counts:
        raise ValueError(f"{path}: no triangles, quads or polygons in the file")
    return {
        "v": np.asarray(mesh.points, dtype=np.float64)[:, :3],
        "counts": np.concatenate(counts),
        "indices": np.concatenate(idx),
    }


def read_surface_mesh(path: str | Path, *, units: str | float = "auto") -> SurfaceMesh:
    """Read a surface mesh: OBJ with its UVs, normals and materials (tinyobjloader); PLY, STL, OFF, ...
    through meshio.

    Args:
        path: the mesh file.
        units: "auto" (from the extent, module docstring), a unit name ("m", "cm", "mm", ...) or
            metres per unit.

    Returns:
        A ``SurfaceMesh`` in the file's units, with ``meters_per_unit`` set.

    Raises:
        FileNotFoundError: no such file.
        ValueError: unreadable file, no faces, or indices out of range.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    parts = _read_obj(path) if path.suffix.lower() == ".obj" else _read_meshio(path)
    points = parts["v"]
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{path}: vertices contain NaN or inf")
    return SurfaceMesh(
        points=points,
        face_vertex_counts=parts["counts"],
        face_vertex_indices=parts["indices"],
        meters_per_unit=_meters_per_unit(units, points),
        uv=parts.get("uv"),
        uv_indices=parts.get("uv_indices"),
        normals=parts.get("normals"),
        normal_indices=parts.get("normal_indices"),
        face_groups=parts.get("groups", {}),
        material_library=parts.get("library"),
        material_colors=parts.get("colors", {}),
        source=str(path),
    )


def write_obj(path: str | Path, mesh: SurfaceMesh, *, units: str | None = None) -> Path:
    """Write an OBJ in the mesh's units (or ``units``, a name of ``UNITS``): ``mtllib``, ``usemtl``
    groups, ``vt``, ``vn`` and ``f v/vt/vn`` corners as the mesh has them, polygons as given.

    Returns:
        The path written (atomically: a temporary file renamed into place).
    """
    if units is not None and units not in UNITS:
        raise ValueError(f"unknown units {units!r}; known: {', '.join(UNITS)}")
    scale = 1.0 if units is None else mesh.meters_per_unit / UNITS[units]
    name = units or mesh.units
    lines = [f"# wface, units: {name}" if name else f"# wface, meters per unit: {mesh.meters_per_unit:.12g}"]
    if mesh.material_library:
        lines.append(f"mtllib {mesh.material_library}")
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mesh.points * scale]
    if mesh.uv is not None:
        lines += [f"vt {u:.9g} {v:.9g}" for u, v in mesh.uv]
    if mesh.normals is not None:
        lines += [f"vn {x:.7g} {y:.7g} {z:.7g}" for x, y, z in mesh.normals]
    ends = np.cumsum(mesh.face_vertex_counts)[:-1]
    corners = [mesh.face_vertex_indices + 1]
    corners.append(mesh.uv_indices + 1 if mesh.uv is not None else None)
    corners.append(mesh.normal_indices + 1 if mesh.normals is not None else None)
    v_idx, t_idx, n_idx = (None if c is None else np.split(c, ends) for c in corners)
    face_materials, names, current = mesh.face_materials, mesh.material_names, -1
    for f, face in enumerate(v_idx):
        if face_materials is not None and face_materials[f] != current:
            current = face_materials[f]
            if current >= 0:  # OBJ cannot take a material back: a face without one keeps the one before
                lines.append(f"usemtl {names[current]}")
        if t_idx is None and n_idx is None:
            lines.append("f " + " ".join(map(str, face.tolist())))
            continue
        t = t_idx[f].tolist() if t_idx is not None else [""] * len(face)
        n = n_idx[f].tolist() if n_idx is not None else None
        cells = [
            f"{a}/{b}" + (f"/{n[k]}" if n is not None else "") for k, (a, b) in enumerate(zip(face, t, strict=True))
        ]
        lines.append("f " + " ".join(cells))
    return write_text(path, "\n".join(lines) + "\n")
