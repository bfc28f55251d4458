"""Off-screen pictures of Waters faces with pyvista (imported inside the functions)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.viz.offscreen import offscreen_pyvista
from wface.waters.muscles import LinearMuscle

__all__ = ["render_grid", "render_layout", "render_mesh"]


def _polydata(vertices_m: np.ndarray, triangles: np.ndarray, scalars: np.ndarray | None):
    import pyvista as pv

    faces = np.hstack([np.full((len(triangles), 1), 3), triangles]).astype(np.int64).ravel()
    mesh = pv.PolyData(np.asarray(vertices_m, dtype=np.float64), faces)
    if scalars is not None:
        mesh.point_data["displacement_mm"] = np.asarray(scalars, dtype=np.float64)
    return mesh


def _on_white(text, *, right: bool = False):
    """A text actor on a white box (readable over the dark head), right-aligned with ``right`` (its
    position then is its lower right corner)."""
    prop = text.GetTextProperty()
    prop.SetBackgroundColor(1.0, 1.0, 1.0)
    prop.SetBackgroundOpacity(0.85)
    if right:
        prop.SetJustificationToRight()
        prop.SetVerticalJustificationToBottom()
    return text


def render_mesh(
    path: str | Path,
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    *,
    displacement_mm: np.ndarray | None = None,
    title: str = "",
    size: int = 600,
    clim_mm: tuple[float, float] | None = None,
    focus_m: np.ndarray | None = None,
    zoom: float = 1.25,
    bounds_m: np.ndarray | None = None,
    triangle_rgb: np.ndarray | None = None,
    visible: np.ndarray | None = None,
    colour_label: str = "mm",
) -> Path:
    """Render a mesh seen from the front (+z toward the camera, +y up) to a PNG.

    Args:
        path: output PNG.
        vertices_m: (n, 3) positions, metres.
        triangles: (t, 3) vertex ids.
        displacement_mm: optional (n,) per-vertex colouring (e.g. |displacement| in mm).
        title: text drawn in the corner.
        size: image width and height in pixels.
        clim_mm: colour range for ``displacement_mm``.
        focus_m: (3,) point the camera looks at (default: the mesh centre).
        zoom: camera zoom factor.
        bounds_m: optional (6,) box (xmin, xmax, ymin, ymax, zmin, zmax) to frame instead of the whole mesh.
        triangle_rgb: optional (t, 3) colour per triangle in [0, 1] (default skin; e.g. from the mesh's
            material groups, ``wface.mesh.materials.face_appearance``).
        visible: optional (t,) bool: triangles to draw (e.g. not an eye occlusion overlay).
        colour_label: the colour bar's title (lines split by newlines), drawn above the bar.
    """

    pv = offscreen_pyvista()
    plotter = pv.Plotter(off_screen=True, window_size=(size, size))
    triangles = np.asarray(triangles)
    keep = np.ones(len(triangles), dtype=bool) if visible is None else np.asarray(visible, dtype=bool)
    mesh = _polydata(vertices_m, triangles[keep], displacement_mm)
    if displacement_mm is not None:
        plotter.add_mesh(
            mesh,
            scalars="displacement_mm",
            cmap="magma",
            clim=clim_mm if clim_mm is not None else (0.0, max(float(np.max(displacement_mm)), 1e-6)),
            smooth_shading=True,
            scalar_bar_args={
                "title": "displacement_mm",
                "n_labels": 3,
                "fmt": "%.1f",
                "color": "black",
                "vertical": True,
                "position_x": 0.89,
                "position_y": 0.25,
                "width": 0.06,
                "height": 0.5,
                "label_font_size": 12,
            },
        )
        plotter.scalar_bars["displacement_mm"].SetTitle("")  # VTK's title sat on the top tick label
        label = plotter.add_text(colour_label, position=(0.97, 0.77), viewport=True, font_size=max(7, size // 75))
        _on_white(label, right=True)
    elif triangle_rgb is not None:
        mesh.cell_data["rgb"] = np.clip(np.asarray(triangle_rgb)[keep] * 255.0, 0, 255).astype(np.uint8)
        plotter.add_mesh(mesh, scalars="rgb", rgb=True, smooth_shading=True, specular=0.2)
    else:
        plotter.add_mesh(mesh, color=(0.87, 0.72, 0.62), smooth_shading=True, specular=0.2)
    if title:
        _on_white(plotter.add_text(title, position="upper_edge", font_size=max(8, size // 50)))  # centred, off the edge
    plotter.view_xy()
    if bounds_m is not None:
        plotter.reset_camera(bounds=[float(b) for b in bounds_m])
    if focus_m is not None:
        f = np.asarray(focus_m, dtype=np.float64)
        pos = np.asarray(plotter.camera.position)
        shift = f - np.asarray(plotter.camera.focal_point)
        plotter.camera.focal_point = tuple(f)
        plotter.camera.position = tuple(pos + shift)
    plotter.camera.zoom(zoom)
    plotter.set_background("white")
    path = Path(path)
    plotter.screenshot(str(path))
    plotter.close()
    return path


def render_grid(path: str | Path, images: list[Path], *, columns: int = 4) -> Path:
    """Tile PNGs into one contact sheet (matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt

    rows = (len(images) + columns - 1) // columns
    fig, axes = plt.subplots(rows, columns, figsize=(3 * columns, 3 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, img in zip(axes.ravel(), images, strict=False):
        ax.imshow(mpimg.imread(img))
        ax.set_title(Path(img).stem, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def render_layout(
    path: str | Path,
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    layout,
    *,
    size: int = 700,
    bounds_m: np.ndarray | None = None,
) -> Path:
    """Draw a layout's muscles over a translucent face: linear muscles as arrows from the bony
    attachment V1 (dot) to the insertion V2, sphincters as their ellipses, landmarks as small points."""

    pv = offscreen_pyvista()
    plotter = pv.Plotter(off_screen=True, window_size=(size, size))
    plotter.add_mesh(
        _polydata(vertices_m, triangles, None), color=(0.87, 0.72, 0.62), opacity=0.55, smooth_shading=True
    )
    scale = float(np.ptp(np.asarray(vertices_m), axis=0).max())
    for m in layout.muscles:
        if isinstance(m, LinearMuscle):
            colour = "royalblue" if m.region == "any" else ("seagreen" if m.region == "upper" else "darkorange")
            plotter.add_mesh(pv.Line(m.bone_m, m.insertion_m), color=colour, line_width=4)
            plotter.add_mesh(pv.Sphere(radius=0.006 * scale, center=m.bone_m), color="black")
            plotter.add_mesh(pv.Sphere(radius=0.004 * scale, center=m.insertion_m), color=colour)
        else:
            t = np.linspace(0, 2 * np.pi, 64)
            ring = (
                m.centre_m
                + np.outer(np.cos(t) * m.semi_axes_m[0], m.horizontal)
                + np.outer(np.sin(t) * m.semi_axes_m[1], m.vertical)
            )
            plotter.add_mesh(pv.Spline(ring, 128), color="crimson", line_width=3)
    if layout.landmarks_m:
        pts = np.stack(list(layout.landmarks_m.values()))
        plotter.add_points(pts, color="yellow", point_size=8, render_points_as_spheres=True)
    plotter.add_text(f"{layout.name}: {len(layout.muscles)} muscles", font_size=max(8, size // 50))
    plotter.view_xy()
    if bounds_m is not None:
        plotter.reset_camera(bounds=[float(b) for b in bounds_m])
        plotter.camera.zoom(1.3)
    plotter.set_background("white")
    path = Path(path)
    plotter.screenshot(str(path))
    plotter.close()
    return path
