"""Render the built-in face: skin (translucent), bones, and muscles coloured by muscle.

    python examples/builtin_face.py --tets 20000 --out out/builtin_face.png

Runs headless (pyvista off-screen). A test runs it with tiny options.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def render_face(model, path: Path, *, size=(1200, 900), show_muscles=True) -> Path:
    import pyvista as pv

    pv.OFF_SCREEN = True
    x = model.rest_positions_m
    faces = lambda tri: np.hstack([np.full((len(tri), 1), 3), tri]).ravel()  # noqa: E731
    plotter = pv.Plotter(off_screen=True, window_size=size, shape=(1, 2), border=False)
    for col, (azimuth, opacity) in enumerate(((0.0, 1.0), (-55.0, 0.35))):
        plotter.subplot(0, col)
        skin = pv.PolyData(x, faces(model.skin_triangles))
        plotter.add_mesh(skin, color=(0.93, 0.76, 0.66), opacity=opacity, smooth_shading=True, specular=0.2)
        for name, bone in model.bone_meshes.items():
            color = (0.95, 0.95, 0.88) if "teeth" in name else (0.86, 0.83, 0.74)
            plotter.add_mesh(pv.PolyData(bone.vertices_m, faces(bone.triangles)), color=color, smooth_shading=True)
        if show_muscles and opacity < 1.0:
            strong = model.fibre_fraction > 0.5
            cells = model.tets[model.fibre_tet[strong]]
            grid = pv.UnstructuredGrid(
                np.hstack([np.full((len(cells), 1), 4), cells]).ravel(), np.full(len(cells), 10, dtype=np.uint8), x
            )
            grid.cell_data["muscle"] = model.fibre_muscle[strong]
            plotter.add_mesh(grid, scalars="muscle", cmap="tab20", show_scalar_bar=False)
        if model.marker_positions_m.size:
            plotter.add_mesh(
                pv.PolyData(model.marker_positions_m), color="red", point_size=9, render_points_as_spheres=True
            )
        plotter.camera_position = "xy"
        plotter.camera.azimuth = azimuth
        plotter.camera.elevation = 5.0
        plotter.reset_camera()
        plotter.camera.zoom(1.25)
    path.parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(path))
    plotter.close()
    return path


def main(argv=None) -> int:
    from wface.faces.builtin import build_face

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tets", type=int, default=20000, help="mesh size in tetrahedra")
    ap.add_argument("--out", default="out/builtin_face.png", help="PNG to write")
    ap.add_argument("--width", type=int, default=1600, help="image width in pixels")
    args = ap.parse_args(argv)
    model = build_face(args.tets, progress=True)
    q = model.metadata["quality"]
    print(
        f"{model.n_tets} tets, {model.n_nodes} nodes, {model.n_muscles} muscles, "
        f"min dihedral {q['min_dihedral_deg']:.1f} deg"
    )
    path = render_face(model, Path(args.out), size=(args.width, int(args.width * 0.6)))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
