"""One polygon mesh, static or animated, as a USD stage."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.files import save_layer
from wface.io.usd._common import _as_points, _check_path, _new_stage, _write_mesh, as_polygons

__all__ = ["write_mesh_animation"]


def write_mesh_animation(
    path: str | Path,
    *,
    points_m: np.ndarray,
    face_vertex_counts: np.ndarray | None,
    face_vertex_indices: np.ndarray,
    fps: float = 60.0,
    name: str = "Face",
    up_axis: str = "Y",
    colors: np.ndarray | None = None,
) -> Path:
    """Write one polygon mesh, static or animated, to a new USD stage.

    The stage's default prim is ``/<name>`` (an Xform) with the mesh at ``/<name>/Mesh``.
    Topology is written once; points and extent are time-sampled when ``points_m`` is 3-D
    (frame ``f`` at time code ``f``).

    Args:
        path: output file; ``.usda`` writes text, ``.usdc`` / ``.usd`` binary crate.
        points_m: (n, 3) static or (F, n, 3) per-frame vertex positions in metres.
        face_vertex_counts: (p,) vertices per face, or None when ``face_vertex_indices`` holds
            triangles (t, 3).
        face_vertex_indices: flat USD face vertex indices, or (t, 3) triangles.
        fps: frames per second (the stage's timeCodesPerSecond).
        name: name of the root prim (a valid USD identifier).
        up_axis: "Y" (default, wface's convention) or "Z": the root prim then gets a rotateX(90)
            op so that the model's +y points along world +z (points are written unchanged).
        colors: optional displayColor: (3,) constant, (n, 3) per vertex or (F, n, 3) per vertex
            and frame; linear RGB in [0, 1].

    Returns:
        The path written.

    Raises:
        UsdWriteError: wrong shapes, NaN/inf, out-of-range indices or a bad suffix.
    """
    path = _check_path(path)
    p = _as_points(points_m)
    counts, indices = as_polygons(face_vertex_counts, face_vertex_indices, p.shape[-2])
    n_frames = p.shape[0] if p.ndim == 3 else 1
    stage = _new_stage(path, fps=fps, n_frames=n_frames, up_axis=up_axis, root=name)
    _write_mesh(stage, f"/{name}/Mesh", p, counts, indices, colors=colors)
    save_layer(stage.GetRootLayer(), path)  # atomic: a temporary file renamed into place
    return path
