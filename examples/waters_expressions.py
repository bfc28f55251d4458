"""Waters (1987) vector muscles on the ICT-FaceKit head: every expression preset, rendered off-screen.

Writes OUT/<preset>.png (shaded), OUT/<preset>_displacement.png, OUT/<preset>.obj/.usda, a contact
sheet OUT/expressions.png, OUT/muscles.png (the layout drawn over the face) and OUT/expressions.usdc:
an animation that blends from preset to preset.

    python examples/waters_expressions.py --out out/waters_expressions
    python examples/waters_expressions.py --presets happy --size 200 --out /tmp/w   # quick

``--face builtin`` poses wface's built-in face instead (the ICT layout fitted to its markers).
Without ../shared/data (or $WFACE_DATA) it falls back to a synthetic ellipsoid head with the ICT
layout fitted to it by landmarks, and says so.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from wface.facs import EXPRESSIONS
from wface.io.usd import write_surface_mesh
from wface.mesh.meshfile import read_surface_mesh
from wface.testing.synthetic_head import synthetic_head, synthetic_landmarks
from wface.waters.expressions import interpolate_poses
from wface.waters.fit import fit_layout
from wface.waters.layout import load_layout
from wface.waters.pipeline import pose_mesh
from wface.waters.render import render_grid, render_layout
from wface.waters.rig import WatersRig

DEFAULT_DATA = Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default=str(DEFAULT_DATA / "ict-facekit" / "generic_neutral_mesh.obj"))
    ap.add_argument("--face", choices=("ict", "builtin"), default="ict", help="ICT head (--mesh) or the built-in face")
    ap.add_argument("--tets", type=int, default=20000, help="resolution of the built-in face")
    ap.add_argument("--presets", nargs="+", default=list(EXPRESSIONS), help="presets to render (default: all)")
    ap.add_argument("--size", type=int, default=600, help="image size in pixels")
    ap.add_argument("--blend-frames", type=int, default=12, help="frames between presets in the USD animation")
    ap.add_argument("--out", default="out/waters_expressions")
    args = ap.parse_args(argv)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    layout = load_layout("ict")
    rig = None
    if args.face == "builtin":
        from wface.faces.builtin import build_face
        from wface.waters.face_model import face_model_rig

        rig, mesh, _ = face_model_rig(build_face(args.tets))
        source = f"wface built-in face (~{args.tets} tets), ICT layout fitted by its markers"
    elif Path(args.mesh).is_file():
        mesh = read_surface_mesh(args.mesh, units="cm")
        source = args.mesh
    else:
        mesh = synthetic_head(90, 180)
        layout = fit_layout(
            layout, synthetic_landmarks(layout), target_vertices_m=mesh.vertices_m, target_triangles=mesh.triangles()
        )
        source = "synthetic ellipsoid head (real data absent: " + args.mesh + ")"
        print("note:", source)
    rig = rig or WatersRig(layout, mesh.vertices_m)

    summaries, pictures = {}, []
    for name in args.presets:
        s = pose_mesh(mesh, out, expression=name, rig=rig, size=args.size)
        summaries[name] = {k: s[k] for k in ("contractions", "jaw_opening_deg", "max_displacement_mm")}
        pictures.append(Path(s["files"]["png"]))
        print(f"{name:>9}: max displacement {s['max_displacement_mm']:.1f} mm, jaw {s['jaw_opening_deg']:.1f} deg")
    render_grid(out / "expressions.png", pictures, columns=min(4, len(pictures)))
    marks = np.stack(list(rig.layout.landmarks_m.values()))
    lo, hi = marks.min(axis=0), marks.max(axis=0)
    box = np.ravel(np.column_stack([lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo)]))
    render_layout(out / "muscles.png", mesh.vertices_m, mesh.triangles(), rig.layout, size=args.size, bounds_m=box)

    frames = []
    cycle = args.presets + args.presets[:1]
    for a, b in zip(cycle[:-1], cycle[1:], strict=True):
        for k in range(max(1, args.blend_frames)):
            pose = interpolate_poses(a, b, k / max(1, args.blend_frames), muscle_names=rig.muscle_names)
            frames.append(rig.deform(pose.contractions, jaw_opening_deg=pose.jaw_opening_deg))
    write_surface_mesh(out / "expressions.usdc", mesh, frames_m=np.stack(frames), fps=24.0, name="WatersFace")
    report = {
        "mesh": source,
        "vertices": mesh.n_vertices,
        "muscles": len(rig.muscle_names),
        "animation_frames": len(frames),
        "presets": summaries,
    }
    (out / "expressions.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main()
