"""One call from a mesh file and an expression to written outputs (used by ``wface waters`` and the example)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from wface.files import read_landmarks, write_json
from wface.io.usd import write_surface_mesh
from wface.mesh.materials import face_appearance
from wface.mesh.meshfile import SurfaceMesh, read_surface_mesh, write_obj
from wface.waters.expressions import expression_pose
from wface.waters.fit import fit_layout
from wface.waters.layout import MuscleLayout, load_layout
from wface.waters.render import render_mesh
from wface.waters.rig import WatersRig

__all__ = ["ICT_VERTEX_COUNT", "layout_for_mesh", "load_landmark_vertices", "pose_mesh"]

ICT_VERTEX_COUNT = 26719


def load_landmark_vertices(path: str | Path, mesh: SurfaceMesh) -> dict[str, np.ndarray]:
    """Landmark positions from a JSON ``{name: vertex index}`` on ``mesh``."""
    return {name: mesh.vertices_m[i] for name, i in read_landmarks(path, n_vertices=mesh.n_vertices).items()}


def layout_for_mesh(
    mesh: SurfaceMesh, *, layout: str | Path | None = None, landmarks: str | Path | None = None
) -> MuscleLayout:
    """The layout to use on ``mesh``: the given one, fitted to ``landmarks`` when given; default ICT."""
    lay = load_layout(layout if layout is not None else "ict")
    if landmarks is not None:
        target = load_landmark_vertices(landmarks, mesh)
        lay = fit_layout(lay, target, target_vertices_m=mesh.vertices_m, target_triangles=mesh.triangles())
    elif layout is None and mesh.n_vertices != ICT_VERTEX_COUNT:
        raise ValueError(
            f"the mesh has {mesh.n_vertices} vertices, not the ICT-FaceKit head's {ICT_VERTEX_COUNT}: give --layout "
            "(a layout made for this mesh) or --landmarks (JSON {AnimFace marker name: vertex index}) to fit one"
        )
    return lay


def pose_mesh(
    mesh: SurfaceMesh | str | Path,
    out_dir: str | Path,
    *,
    expression: str = "neutral",
    action_units: Mapping[str, float] | None = None,
    intensity: float = 1.0,
    layout: str | Path | MuscleLayout | None = None,
    landmarks: str | Path | None = None,
    units: str = "auto",
    render: bool = True,
    size: int = 600,
    usd_suffix: str = ".usda",
    stem: str | None = None,
    rig: WatersRig | None = None,
) -> dict:
    """Deform a mesh into an expression and write OBJ, USD, PNG and a JSON summary into ``out_dir``.

    Returns:
        The summary (also written to ``out_dir/<stem>.json``).
    """
    expression_pose(expression, intensity=intensity, extra_action_units=action_units)  # bad names fail first
    if not isinstance(mesh, SurfaceMesh):
        mesh = read_surface_mesh(mesh, units=units)
    if rig is None:
        lay = layout if isinstance(layout, MuscleLayout) else layout_for_mesh(mesh, layout=layout, landmarks=landmarks)
        rig = WatersRig(lay, mesh.vertices_m, triangles=mesh.triangles())
    pose = expression_pose(
        expression, intensity=intensity, extra_action_units=action_units, muscle_names=rig.muscle_names
    )
    t0 = time.perf_counter()
    x = rig.deform(pose.contractions, jaw_opening_deg=pose.jaw_opening_deg)
    seconds = time.perf_counter() - t0
    if not np.all(np.isfinite(x)):
        raise FloatingPointError("deformed mesh contains NaN or inf")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = stem or (expression if not action_units else f"{expression}+" + "+".join(sorted(action_units)))
    posed = mesh.with_vertices(x)
    files = {
        "obj": str(write_obj(out / f"{stem}.obj", posed)),
        "usd": str(write_surface_mesh(out / f"{stem}{usd_suffix}", posed, name="WatersFace")),
    }
    disp_mm = np.linalg.norm(x - mesh.vertices_m, axis=1) * 1e3
    cap_mm, capped = rig.layout.max_displacement_m * 1e3, len(rig.vertices_at_cap(pose.contractions))
    if render:
        tri = mesh.triangles()
        box = None  # frame the face: the layout's landmarks, else the muscles' reach
        marks = np.array(list(rig.layout.landmarks_m.values())).reshape(-1, 3)
        region = marks if len(marks) >= 4 else mesh.vertices_m[rig.influenced]
        if len(region):
            lo, hi = region.min(axis=0), region.max(axis=0)
            pad = 0.25 * (hi - lo)
            box = np.ravel(np.column_stack([lo - pad, hi + pad]))
        rgb, opacity = face_appearance(mesh)  # eyes, teeth and overlays by material group
        tri_face = mesh.triangle_faces()
        view = {"size": size, "bounds_m": box, "zoom": 1.3, "visible": opacity[tri_face] > 0}
        files["png"] = str(render_mesh(out / f"{stem}.png", x, tri, title=stem, triangle_rgb=rgb[tri_face], **view))
        files["png_displacement"] = str(
            render_mesh(
                out / f"{stem}_displacement.png",
                x,
                tri,
                displacement_mm=disp_mm,
                title=f"{stem}: displacement",
                colour_label="mm" + (f"\n(capped at {cap_mm:g})" if capped else ""),
                **view,
            )
        )
    summary = {
        "expression": expression,
        "action_units": pose.action_units,
        "contractions": pose.contractions,
        "jaw_opening_deg": pose.jaw_opening_deg,
        "layout": rig.layout.name,
        "muscles": len(rig.muscle_names),
        "vertices": mesh.n_vertices,
        "max_displacement_mm": float(disp_mm.max()),
        "displacement_cap_mm": cap_mm,  # the layout's per-vertex cap on the muscles' displacement
        "vertices_at_cap": capped,
        "deform_seconds": seconds,
        "files": files,
    }
    write_json(out / f"{stem}.json", summary)
    return summary
