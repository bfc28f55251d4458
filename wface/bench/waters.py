"""``wface bench --suite waters``: frames per second of Waters vector-muscle expressions.

Mesh: the ICT-FaceKit neutral head (26,719 vertices, 37 muscles) from ../shared/data (or
$WFACE_DATA); without it, a synthetic ellipsoid head of similar size with the ICT layout fitted to
it by landmarks (the JSON says which). A frame = one pose along a loop through every expression
preset: action units -> contractions, sparse muscle field, per-vertex limit, jaw rotation.
Also timed: every muscle evaluated from the formulas on every vertex (numpy, and the Warp kernel
``wface.kernels.waters``), the path for a mesh whose rest shape changes each frame.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from wface.bench import suite_result
from wface.facs import EXPRESSIONS
from wface.mesh.meshfile import read_surface_mesh
from wface.testing.synthetic_head import synthetic_head, synthetic_landmarks
from wface.waters.expressions import interpolate_poses
from wface.waters.fit import fit_layout
from wface.waters.layout import load_layout
from wface.waters.rig import WatersRig, direct_displacement
from wface.waters.warp_backend import WarpWaters

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:  # pragma: no cover - registry hook
    pass


def _ict_mesh_path() -> Path:
    root = Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
    return root / "ict-facekit" / "generic_neutral_mesh.obj"


def run(args: argparse.Namespace) -> dict:

    repeat = max(1, int(getattr(args, "repeat", 3) or 3))
    layout = load_layout("ict")
    path = _ict_mesh_path()
    if path.is_file():
        mesh = read_surface_mesh(path, units="cm")
        source, note = f"ICT-FaceKit generic_neutral_mesh.obj ({path})", ""
    else:
        mesh = synthetic_head(120, 224)
        layout = fit_layout(
            layout, synthetic_landmarks(layout), target_vertices_m=mesh.vertices_m, target_triangles=mesh.triangles()
        )
        source = "synthetic ellipsoid head"
        note = f"real data absent ({path}): fell back to a synthetic mesh; set WFACE_DATA to time the ICT head"

    t0 = time.perf_counter()
    rig = WatersRig(layout, mesh.vertices_m, triangles=mesh.triangles())
    compile_s = time.perf_counter() - t0

    names = list(EXPRESSIONS)
    steps = 10
    poses = []
    for a, b in zip(names, names[1:] + names[:1], strict=True):
        for k in range(steps):
            pose = interpolate_poses(a, b, k / steps, muscle_names=rig.muscle_names)
            poses.append((rig.contraction_vector(pose.contractions), pose.jaw_opening_deg))

    def loop():
        t = time.perf_counter()
        for c, jaw in poses:
            x = rig.deform(c, jaw_opening_deg=jaw)
        return time.perf_counter() - t, x

    loop()  # warm-up
    times = []
    for _ in range(repeat):
        dt, x = loop()
        times.append(dt)
        if not np.all(np.isfinite(x)):
            raise FloatingPointError("waters bench produced NaN")
    per_frame = float(np.median(times)) / len(poses)

    # Reference: every muscle straight from the formulas on every vertex (no precompiled field).
    pose = interpolate_poses("happy", "surprise", 0.5, muscle_names=rig.muscle_names)
    t = time.perf_counter()
    direct_displacement(layout, mesh.vertices_m, {m: pose.contractions.get(m, 0.0) for m in rig.muscle_names})
    direct_s = time.perf_counter() - t

    warp_s = None
    try:
        ww = WarpWaters(layout, device=getattr(args, "device", None) or "auto")
        c = rig.contraction_vector(pose.contractions)
        ww.muscle_displacement(mesh.vertices_m, c, jaw_weights=rig.jaw_weights)  # compile / load the kernel
        t = time.perf_counter()
        for _ in range(repeat):
            ww.muscle_displacement(mesh.vertices_m, c, jaw_weights=rig.jaw_weights)
        warp_s = (time.perf_counter() - t) / repeat
        warp_device = ww.device
    except ImportError:  # pragma: no cover - warp is a core dependency
        warp_device = None

    out = {
        "mesh": source,
        "vertices": mesh.n_vertices,
        "muscles": len(rig.muscle_names),
        "frames": len(poses),
        "repeat": repeat,
        "compile_seconds": compile_s,
        "seconds_per_frame": per_frame,
        "frames_per_second": 1.0 / per_frame,
        "basis_nonzeros": int(rig.basis.nnz),
        "direct_formula_seconds_per_frame": direct_s,
        "direct_formula_frames_per_second": 1.0 / direct_s,
        "warp_direct_device": warp_device,
        "warp_direct_seconds_per_frame": warp_s,
        "warp_direct_frames_per_second": None if not warp_s else 1.0 / warp_s,
        "backend": "numpy + scipy.sparse (CPU)",
    }
    return suite_result("waters", warp_device or "cpu", [out], {"mesh": note} if note else None)
