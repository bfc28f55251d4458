"""Polygon surface meshes for the Waters tools: read, write OBJ and USD, keeping what the source mesh has.

A TD's head mesh carries more than positions: texture coordinates (often indexed apart from the
vertices, so seams split them: the ICT-FaceKit head has 26,719 vertices and 28,911 UVs), normals,
material groups (``usemtl``; 12 on the ICT head) and a length unit. ``SurfaceMesh`` keeps them all,
face-varying, in the source's vertex and polygon order, so a posed mesh drops back onto the
artist's rig and shaders:

- OBJ is read by tinyobjloader (the maintained reference OBJ parser, polygons kept as they are);
  materials named by ``usemtl`` but missing from the ``.mtl`` (or with no ``.mtl`` at all) keep
  their names. trimesh was measured first and left out: on the ICT head it triangulated the quads,
  split the vertices into 12 meshes of 9,409-26,719 vertices each and dropped the UVs because the
  ``.mtl`` file is absent. Other formats are read through meshio (positions and polygons only).
- ``write_obj`` writes the source units (``# units: cm``), ``mtllib``, ``usemtl`` groups, ``vt`` and
  ``vn`` with ``f v/vt/vn`` corners; ``write_usd`` writes points in the source units with
  ``metersPerUnit`` set from them, ``primvars:st`` (face-varying, indexed), normals, and one
  ``GeomSubset`` per material bound to a ``UsdPreviewSurface`` material of that name.

Positions are metres in memory (``vertices_m``); ``units`` is the source's unit (given, or "auto":
guessed from the bounding box of a head-sized object, < 2 -> m, < 100 -> cm, else mm). A posed mesh
keeps the source normals' layout but gets normals of its own shape (area-weighted per vertex).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import meshio
import numpy as np
import tinyobjloader

from wface.io.usd import write_mesh_animation
from wface.mesh.surface import vertex_normals

__all__ = ["UNITS_M", "SurfaceMesh", "guess_units", "read_surface", "write_obj", "write_usd"]

UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}


@dataclass
class SurfaceMesh:
    """A polygon mesh: (n, 3) vertices in metres, USD-style flat polygon topology, and optional
    face-varying texture coordinates, normals and material groups (module docstring).

    Attributes:
        vertices_m: (n, 3) positions, metres.
        face_vertex_counts: (p,) vertices per polygon.
        face_vertex_indices: (sum counts,) vertex ids, polygon by polygon.
        uv: (k, 2) texture coordinates, or None; ``uv_indices`` (sum counts,) says which each corner uses.
        normals: (j, 3) unit normals, or None; ``normal_indices`` (sum counts,) per corner.
        face_materials: (p,) index into ``material_names`` per polygon (-1: none), or None.
        material_names: the material names (``usemtl``).
        material_library: the ``mtllib`` file name of the source, or None.
        material_colors: {material: (3,) diffuse colour} from the ``.mtl`` file when it was found.
        units: the source's length unit ("m", "cm" or "mm"), used when writing.
    """

    vertices_m: np.ndarray
    face_vertex_counts: np.ndarray  # (p,) int32
    face_vertex_indices: np.ndarray  # (sum counts,) int32
    uv: np.ndarray | None = None
    uv_indices: np.ndarray | None = None
    normals: np.ndarray | None = None
    normal_indices: np.ndarray | None = None
    face_materials: np.ndarray | None = None
    material_names: list[str] = field(default_factory=list)
    material_library: str | None = None
    material_colors: dict = field(default_factory=dict)
    units: str = "m"

    def __post_init__(self) -> None:
        self.vertices_m = np.asarray(self.vertices_m, dtype=np.float64)
        self.face_vertex_counts = np.asarray(self.face_vertex_counts, dtype=np.int32).reshape(-1)
        self.face_vertex_indices = np.asarray(self.face_vertex_indices, dtype=np.int32).reshape(-1)
        if self.vertices_m.ndim != 2 or self.vertices_m.shape[1] != 3:
            raise ValueError(f"vertices must have shape (n, 3), got {self.vertices_m.shape}")
        if not np.all(np.isfinite(self.vertices_m)):
            raise ValueError("mesh vertices contain NaN or inf")
        if np.any(self.face_vertex_counts < 3) or self.face_vertex_counts.sum() != self.face_vertex_indices.size:
            raise ValueError("face_vertex_counts must be >= 3 and sum to the number of face vertex indices")
        idx = self.face_vertex_indices
        if idx.size and (idx.min() < 0 or idx.max() >= len(self.vertices_m)):
            raise ValueError(f"faces reference vertices outside [0, {len(self.vertices_m)})")
        if self.units not in UNITS_M:
            raise ValueError(f"unknown units {self.units!r}; use one of {', '.join(UNITS_M)}")
        for values, ids, width, label in (
            ("uv", "uv_indices", 2, "texture coordinates"),
            ("normals", "normal_indices", 3, "normals"),
        ):
            v = getattr(self, values)
            if v is None:
                continue
            v = np.asarray(v, dtype=np.float64).reshape(-1, width)
            i = np.asarray(getattr(self, ids), dtype=np.int32).reshape(-1)
            if i.size != idx.size or (i.size and (i.min() < 0 or i.max() >= len(v))):
                raise ValueError(f"{label}: one index per face corner into {len(v)} values is needed")
            setattr(self, values, v)
            setattr(self, ids, i)
        if self.face_materials is not None:
            fm = np.asarray(self.face_materials, dtype=np.int32).reshape(-1)
            if fm.size != self.face_vertex_counts.size or fm.max(initial=-1) >= len(self.material_names):
                raise ValueError("face_materials must hold one index into material_names per polygon")
            self.face_materials = fm

    @classmethod
    def from_triangles(cls, vertices_m: np.ndarray, triangles: np.ndarray) -> SurfaceMesh:
        t = np.asarray(triangles, dtype=np.int32).reshape(-1, 3)
        return cls(vertices_m, np.full(len(t), 3, np.int32), t.ravel())

    @property
    def n_vertices(self) -> int:
        return int(self.vertices_m.shape[0])

    def triangles(self) -> np.ndarray:
        """(t, 3) int32 fan triangulation of the polygons (vectorised)."""
        counts = self.face_vertex_counts
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        n_tri = counts - 2
        owner = np.repeat(np.arange(len(counts)), n_tri)
        k = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)
        s = starts[owner]
        idx = self.face_vertex_indices
        return np.stack([idx[s], idx[s + k + 1], idx[s + k + 2]], axis=1).astype(np.int32)

    def with_vertices(self, vertices_m: np.ndarray) -> SurfaceMesh:
        """The same mesh (topology, UVs, materials, units) with new vertex positions (n, 3); normals,
        when the source has them, are those of the new shape (one per vertex)."""
        v = np.asarray(vertices_m, dtype=np.float64)
        if v.shape != self.vertices_m.shape:
            raise ValueError(f"new vertices have shape {v.shape}, expected {self.vertices_m.shape}")
        out = replace(self, vertices_m=v)
        if self.normals is not None:
            out = replace(out, normals=vertex_normals(v, self.triangles()), normal_indices=self.face_vertex_indices)
        return out


def guess_units(vertices: np.ndarray) -> str:
    """Guess the length unit of a head-sized mesh from its bounding-box diagonal."""
    ext = float(np.linalg.norm(np.ptp(np.asarray(vertices, dtype=np.float64), axis=0)))
    return "m" if ext < 2.0 else "cm" if ext < 100.0 else "mm"


def _material_text(path: Path, text: str) -> tuple[str, str | None, set[str]]:
    """(.mtl text for the parser: the source's library plus a stub for every other ``usemtl`` name,
    the library's file name, the names the library defines)."""
    lib = re.search(r"^mtllib\s+(.+?)\s*$", text, re.M)
    mtl = ""
    if lib and (path.parent / lib.group(1)).is_file():
        mtl = (path.parent / lib.group(1)).read_text(errors="replace")
    defined = set(re.findall(r"^newmtl\s+(\S+)", mtl, re.M))
    used = dict.fromkeys(re.findall(r"^usemtl\s+(\S+)", text, re.M))
    stubs = "".join(f"\nnewmtl {name}\n" for name in used if name not in defined)
    return mtl + stubs, lib.group(1) if lib else None, defined


def _read_obj(path: Path) -> dict:
    """The pieces of an OBJ file, in the file's units, via tinyobjloader (polygons kept)."""
    text = path.read_text(errors="replace")
    mtl, library, defined = _material_text(path, text)
    reader = tinyobjloader.ObjReader()
    config = tinyobjloader.ObjReaderConfig()
    config.triangulate = False
    if not reader.ParseFromString(text, mtl, config):
        raise ValueError(f"{path}: not a readable OBJ file ({reader.Error().strip()})")
    attrib = reader.GetAttrib()
    v = np.asarray(attrib.vertices, dtype=np.float64).reshape(-1, 3)
    if not len(v):
        raise ValueError(f"{path}: no vertices ('v' lines) found")
    shapes = [s.mesh for s in reader.GetShapes()]
    counts = np.concatenate([np.asarray(m.num_face_vertices, dtype=np.int32) for m in shapes] or [np.zeros(0)])
    corner = {
        key: np.concatenate([np.asarray(getattr(m, f"{key}_indices")(), dtype=np.int64) for m in shapes])
        for key in ("vertex", "texcoord", "normal")
    }
    face_mat = np.concatenate([np.asarray(m.material_ids, dtype=np.int32) for m in shapes])
    materials = reader.GetMaterials()
    out = {"v": v, "counts": counts, "indices": corner["vertex"], "library": library}
    uv = np.asarray(attrib.texcoords, dtype=np.float64).reshape(-1, 2)
    if len(uv) and np.all(corner["texcoord"] >= 0):
        out["uv"], out["uv_indices"] = uv, corner["texcoord"]
    vn = np.asarray(attrib.normals, dtype=np.float64).reshape(-1, 3)
    if len(vn) and np.all(corner["normal"] >= 0):
        out["normals"], out["normal_indices"] = vn, corner["normal"]
    if materials and np.any(face_mat >= 0):
        out["face_materials"], out["material_names"] = face_mat, [m.name for m in materials]
        out["material_colors"] = {m.name: tuple(m.diffuse) for m in materials if m.name in defined}
    return out


def read_surface(path: str | Path, *, units: str = "auto") -> SurfaceMesh:
    """Read a polygon surface: OBJ with its UVs, normals and materials (tinyobjloader), others via meshio.

    Args:
        path: mesh file.
        units: length unit of the file ("m", "cm", "mm") or "auto".
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    if path.suffix.lower() == ".obj":
        parts = _read_obj(path)
    else:
        m = meshio.read(path)
        polys = [c.data for c in m.cells if c.type in ("triangle", "quad") or c.type.startswith("polygon")]
        if not polys:
            raise ValueError(f"{path}: no surface polygons (triangles or quads) found")
        parts = {
            "v": np.asarray(m.points, dtype=np.float64)[:, :3],
            "counts": np.concatenate([np.full(len(p), p.shape[1], np.int32) for p in polys]),
            "indices": np.concatenate([p.ravel() for p in polys]).astype(np.int32),
        }
    if units == "auto":
        units = guess_units(parts["v"])
    if units not in UNITS_M:
        raise ValueError(f"unknown units {units!r}; use one of m, cm, mm or auto")
    return SurfaceMesh(
        parts["v"] * UNITS_M[units],
        parts["counts"],
        parts["indices"],
        uv=parts.get("uv"),
        uv_indices=parts.get("uv_indices"),
        normals=parts.get("normals"),
        normal_indices=parts.get("normal_indices"),
        face_materials=parts.get("face_materials"),
        material_names=parts.get("material_names", []),
        material_library=parts.get("library"),
        material_colors=parts.get("material_colors", {}),
        units=units,
    )


def write_obj(path: str | Path, mesh: SurfaceMesh, *, units: str | None = None) -> Path:
    """Write an OBJ in the source's units (or ``units``): ``mtllib``, ``usemtl`` groups, ``vt``, ``vn``
    and ``f v/vt/vn`` corners as the mesh has them, polygons as given."""
    path = Path(path)
    units = units or mesh.units
    scale = 1.0 / UNITS_M[units]
    lines = [f"# wface waters output, units: {units}"]
    if mesh.material_library:
        lines.append(f"mtllib {mesh.material_library}")
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mesh.vertices_m * scale]
    if mesh.uv is not None:
        lines += [f"vt {u:.9g} {v:.9g}" for u, v in mesh.uv]
    if mesh.normals is not None:
        lines += [f"vn {x:.7g} {y:.7g} {z:.7g}" for x, y, z in mesh.normals]
    ends = np.cumsum(mesh.face_vertex_counts)[:-1]
    corners = [mesh.face_vertex_indices + 1]
    corners.append(mesh.uv_indices + 1 if mesh.uv is not None else None)
    corners.append(mesh.normal_indices + 1 if mesh.normals is not None else None)
    v_idx, t_idx, n_idx = (None if c is None else np.split(c, ends) for c in corners)
    current = None
    for f, face in enumerate(v_idx):
        if mesh.face_materials is not None and mesh.face_materials[f] != current:
            current = mesh.face_materials[f]
            if current >= 0:
                lines.append(f"usemtl {mesh.material_names[current]}")
        if t_idx is None and n_idx is None:
            lines.append("f " + " ".join(map(str, face.tolist())))
            continue
        t = t_idx[f].tolist() if t_idx is not None else [""] * len(face)
        n = n_idx[f].tolist() if n_idx is not None else None
        cells = [
            f"{a}/{b}" + (f"/{n[k]}" if n is not None else "") for k, (a, b) in enumerate(zip(face, t, strict=True))
        ]
        lines.append("f " + " ".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def write_usd(path: str | Path, mesh: SurfaceMesh, *, frames_m: np.ndarray | None = None, fps: float = 24.0) -> Path:
    """Write the mesh (or an animation, ``frames_m`` (F, n, 3) in metres) to USD via ``wface.io.usd``,
    in the source's units with ``metersPerUnit`` to match, UVs, normals and material subsets."""
    points = mesh.vertices_m if frames_m is None else np.asarray(frames_m, dtype=np.float64)
    materials = None
    if mesh.face_materials is not None:
        materials = {name: np.flatnonzero(mesh.face_materials == k) for k, name in enumerate(mesh.material_names)}
        materials = {k: v for k, v in materials.items() if v.size}
    return write_mesh_animation(
        path,
        points_m=points,
        face_vertex_counts=mesh.face_vertex_counts,
        face_vertex_indices=mesh.face_vertex_indices,
        fps=fps,
        name="WatersFace",
        meters_per_unit=UNITS_M[mesh.units],
        uv=mesh.uv,
        uv_indices=mesh.uv_indices,
        normals=None if frames_m is not None else mesh.normals,
        normal_indices=None if frames_m is not None else mesh.normal_indices,
        material_faces=materials,
        material_colors=mesh.material_colors,
    )
