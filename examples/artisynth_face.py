"""Import the ArtiSynth "Badin" FEM face, save it as a wface model and render it off-screen.

    python examples/artisynth_face.py [--data ../shared/data/artisynth-face] [--out artisynth_face.npz]
                                      [--png artisynth_face.png] [--radius-mm 4]

Prints a summary (nodes, tets, quality, muscles and their volumes, attachments, markers) and writes
a picture: translucent skin, bones, and the muscle tets coloured per muscle (left muscles a colour,
right muscles a darker shade). Data: ArtiSynth Models (BSD-style; cite Nazari et al. 2010).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from wface.faces import import_artisynth
from wface.model import load_model, save_model

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "artisynth-face"


def summary(model, seconds: float) -> str:
    q = model.metadata["tet_quality"]
    lines = [
        f"ArtiSynth Badin face: {model.n_nodes} nodes, {model.n_tets} tets "
        f"(from {model.metadata['hexes']} hexes, {model.metadata['degenerate_hexes']} degenerate), "
        f"imported in {seconds:.1f} s",
        f"  quality: min dihedral {q['min_dihedral_deg']:.2f} deg, max {q['max_dihedral_deg']:.1f} deg, "
        f"tets below 5 deg {q['slivers_below_5deg']}, inverted {q['inverted']}, "
        f"mean volume ratio {q['mean_volume_ratio']:.3f}",
        f"  volume {model.rest_volume_m3.sum() * 1e6:.1f} cm^3; surfaces: "
        + ", ".join(f"{k} {len(v)} triangles" for k, v in model.surface_groups.items()),
        f"  attached: {len(model.nodes_of_bone('cranium'))} nodes to the cranium, "
        f"{len(model.nodes_of_bone('jaw'))} to the jaw; bones: {', '.join(model.bone_meshes)}",
        f"  jaw hinge through {np.round(model.jaw_joint.midpoint_m, 3).tolist()} m, axis {model.jaw_joint.u}",
        f"  muscles ({model.n_muscles}, fibre radius {model.metadata['fibre_radius_m'] * 1e3:g} mm), volume cm^3:",
    ]
    vol = model.muscle_volume_m3() * 1e6
    for i in range(0, model.n_muscles, 2):
        pair = model.muscle_names[i : i + 2]
        lines.append("    " + "   ".join(f"{n:8s} {v:5.2f}" for n, v in zip(pair, vol[i : i + 2], strict=True)))
    lines.append(f"  markers: {', '.join(model.marker_names)}")
    lines.append(f"  FACS action units: {', '.join(model.facs)}")
    return "\n".join(lines)


def render(model, png: Path, *, window_size=(1600, 800)) -> Path:
    import pyvista as pv

    pv.OFF_SCREEN = True
    x = model.rest_positions_m
    import matplotlib

    cmap = matplotlib.colormaps["tab20"]
    plotter = pv.Plotter(off_screen=True, shape=(1, 2), window_size=window_size, border=False)

    def tri_mesh(v, t):
        return pv.PolyData(v, np.hstack([np.full((len(t), 1), 3), t]).astype(np.int64))

    # dominant muscle of each muscle tet
    best = {}
    for t, m, f in zip(model.fibre_tet, model.fibre_muscle, model.fibre_fraction, strict=True):
        if f > best.get(t, (0, -1.0))[1]:
            best[t] = (m, f)
    tet_ids = np.array(sorted(best))
    tet_muscle = np.array([best[t][0] for t in tet_ids])
    tet_frac = np.array([best[t][1] for t in tet_ids])
    keep = tet_frac >= 0.3
    cells = np.hstack([np.full((keep.sum(), 1), 4), model.tets[tet_ids[keep]]]).astype(np.int64)
    grid = pv.UnstructuredGrid(cells, np.full(keep.sum(), pv.CellType.TETRA, dtype=np.uint8), x)
    names = model.muscle_names
    rgb = []
    for m in tet_muscle[keep]:
        base = names[m].rsplit("_", 1)[0]
        bases = sorted({n.rsplit("_", 1)[0] for n in names})
        c = np.array(cmap(bases.index(base) % 20)[:3])
        rgb.append(c if names[m].endswith("_l") else 0.6 * c)
    grid.cell_data["rgb"] = (np.array(rgb) * 255).astype(np.uint8)

    for col, (azimuth, title) in enumerate(((0.0, "front"), (60.0, "three-quarter, subject's left"))):
        plotter.subplot(0, col)
        for name, mesh in model.bone_meshes.items():
            colour = "ivory" if "teeth" in name else "wheat"
            plotter.add_mesh(tri_mesh(mesh.vertices_m, mesh.triangles), color=colour, opacity=1.0, smooth_shading=True)
        plotter.add_mesh(grid, scalars="rgb", rgb=True, show_edges=False)
        plotter.add_mesh(tri_mesh(x, model.skin_triangles), color="peachpuff", opacity=0.25, smooth_shading=True)
        if len(model.marker_positions_m):
            plotter.add_points(model.marker_positions_m, color="blue", point_size=12, render_points_as_spheres=True)
        plotter.add_text(title, font_size=10)
        # wface frame: +z forward, +y up: look from the front
        centre = x.mean(axis=0)
        plotter.camera.focal_point = centre
        plotter.camera.position = centre + np.array([0.0, 0.0, 0.45])
        plotter.camera.up = (0.0, 1.0, 0.0)
        plotter.camera.azimuth = azimuth
        plotter.reset_camera()  # keep the view direction, fit everything in
        plotter.camera.zoom(1.15)
    plotter.subplot(0, 0)
    legend = []
    for base in sorted({n.rsplit("_", 1)[0] for n in names}):
        bases = sorted({n.rsplit("_", 1)[0] for n in names})
        legend.append([base, cmap(bases.index(base) % 20)[:3]])
    plotter.add_legend(legend, bcolor="white", size=(0.18, 0.35), loc="lower left")
    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png))
    plotter.close()
    return png


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="ArtiSynth face data folder")
    ap.add_argument("--out", type=Path, default=Path("artisynth_face.npz"), help="model file to write")
    ap.add_argument("--png", type=Path, default=Path("artisynth_face.png"), help="picture to write ('' for none)")
    ap.add_argument("--radius-mm", type=float, default=4.0, help="fibre tube radius")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    model = import_artisynth(args.data, fibre_radius_m=args.radius_mm * 1e-3, progress=False)
    seconds = time.perf_counter() - t0
    save_model(model, args.out)
    load_model(args.out)  # round trip check
    print(summary(model, seconds))
    print(f"saved {args.out}")
    if str(args.png):
        print(f"rendered {render(model, args.png)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
