"""Write the small USD scenes kept in usd_scenes/ (open them in usdview, Blender, Houdini).

    python examples/make_usd_scenes.py                  # regenerate usd_scenes/*.usda
    python examples/make_usd_scenes.py --check          # exit 1 if usd_scenes/ is out of date
    python examples/make_usd_scenes.py --out /tmp/s --only synthetic_take

Scenes (each a .usda text file under 1 MB, so that diffs stay readable):

- synthetic_take: a tracked take of a small synthetic face (``wface.testing.synthetic_face``): skin with
  an activation heat map, captured (red) and simulated (green) markers, cranium and jaw moving,
  per-muscle activation curves, and an actuation basis as UsdSkel blend shapes.
- synthetic_tracked_take: the same performance tracked from its noisy captured markers with the
  linear actuation basis (Choe & Ko 2001: per-frame bounded least squares, ``wface.basis.analysis``):
  the skin is E0 + sum_i x_i e_i, green markers are the fit, red the capture (needs
  ``wface.basis``).
- synthetic_basis: that basis alone, as blend shapes animated by per-frame weights (what
  Blender's USD importer turns into shape keys).
- builtin_face: the built-in face (``wface.faces.builtin``, coarse) at rest with the smile muscles
  active: skin heat map and markers (bone meshes left out: they would triple the file).
- waters_expression: a Waters vector-muscle expression on the synthetic head, blended in from
  neutral (needs ``wface.waters``; skipped with a note when it is absent).

A test (tests/test_usd_scenes.py) regenerates every scene into a temporary directory and compares
it with the committed file: when it fails, run this script and commit usd_scenes/. A scene whose
inputs are absent here (an optional module) is skipped, not failed.

To add a scene (e.g. a tracked take once ``wface demo`` / tracking is on main): write a function
``name(path) -> path`` that builds small inputs and calls ``wface.io.usd.write_take`` (or another
writer), raise ``SceneUnavailable`` when an optional module is missing, and add it to ``SCENES``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENE_DIR = REPO / "usd_scenes"


class SceneUnavailable(RuntimeError):
    """A scene's inputs (an optional module) are not available here."""


def synthetic_take(path: Path) -> Path:
    from wface.io.usd import write_take
    from wface.testing.synthetic_face import synthetic_face, synthetic_take

    model = synthetic_face(nx=10, ny=10, nz=2)
    take = synthetic_take(model, n_frames=20, fps=24.0)
    return write_take(
        path,
        model=model,
        node_positions_m=take["node_positions_m"],
        fps=take["fps"],
        captured_markers_m=take["captured_markers_m"],
        simulated_markers_m=take["simulated_markers_m"],
        cranium_affines=take["cranium_affines"],
        jaw_affines=take["jaw_affines"],
        activations=take["activations"],
        basis=take["basis"],
        basis_weights=take["basis_weights"],
        metadata={"source": "examples/make_usd_scenes.py synthetic_take"},
    )


def synthetic_tracked_take(path: Path) -> Path:
    try:
        from wface.basis.analysis import MarkerBasis, analyze
    except ImportError as exc:  # the basis tracker lives on main
        raise SceneUnavailable(f"wface.basis is not available ({exc})") from exc
    from wface.io.usd import write_take
    from wface.testing.synthetic_face import rotation_about, synthetic_face, synthetic_take

    model = synthetic_face(nx=10, ny=10, nz=2)
    take = synthetic_take(model, n_frames=20, fps=24.0)
    basis = take["basis"]
    nodes = np.asarray(model.metadata["marker_nodes"])
    marker_basis = MarkerBasis(
        basis.deltas_m[:, nodes].transpose(1, 2, 0), model.marker_names, basis.names, rest_m=basis.neutral_m[nodes]
    )
    # Head motion is known here (the cranium affines): capture -> model frame, R^T (p - t).
    cran = take["cranium_affines"]
    rot, trans = cran[:, :, :3], cran[:, :, 3]
    cap = take["captured_markers_m"]
    local = np.einsum("fji,fkj->fki", rot, cap - trans[:, None])
    fit = analyze(marker_basis, local - basis.neutral_m[nodes])
    x = fit.contractions
    nodes_world = np.einsum("fij,fnj->fni", rot, basis.synthesize(x)) + trans[:, None]
    jj = model.jaw_joint
    mid = np.asarray(jj.midpoint_m)
    jaw = []
    for f in range(len(x)):
        rj = rotation_about(jj.u, np.radians(12.0 * x[f, -1]))  # the basis's jaw element: 12 degrees at x = 1
        jaw.append(np.hstack([rj, (mid - rj @ mid)[:, None]]))  # relative to the cranium
    return write_take(
        path,
        model=model,
        node_positions_m=nodes_world,
        fps=take["fps"],
        captured_markers_m=cap,
        simulated_markers_m=nodes_world[:, nodes],
        cranium_affines=cran,
        jaw_affines=np.asarray(jaw),
        activations=np.clip(x[:, : model.n_muscles], 0.0, 1.0),
        basis=basis,
        basis_weights=x,
        metadata={
            "source": "examples/make_usd_scenes.py synthetic_tracked_take",
            "tracker": "wface.basis.analysis.analyze (bounded least squares per frame)",
            "marker_rms_mm_mean": round(float(np.nanmean(fit.marker_rms_mm)), 4),
        },
    )


def synthetic_basis(path: Path) -> Path:
    from wface.io.usd import write_blendshape_basis
    from wface.testing.synthetic_face import synthetic_face, synthetic_take

    model = synthetic_face(nx=10, ny=10, nz=2)
    take = synthetic_take(model, n_frames=20, fps=24.0)
    skin = np.unique(model.skin_triangles)
    remap = np.full(model.n_nodes, -1)
    remap[skin] = np.arange(skin.size)
    return write_blendshape_basis(
        path,
        basis=take["basis"].restricted(skin),
        face_vertex_counts=None,
        face_vertex_indices=remap[model.skin_triangles],
        weights=take["basis_weights"],
        fps=take["fps"],
    )


def builtin_face(path: Path) -> Path:
    try:
        from wface.faces.builtin import build_face
    except ImportError as exc:  # the built-in face lives on main
        raise SceneUnavailable(f"wface.faces.builtin is not available ({exc})") from exc
    from wface.io.usd import write_take

    model = build_face(target_tets=4000)
    smile = {n: 1.0 for n in model.muscle_names if n.startswith(("zygomaticus_major", "levator_anguli_oris"))}
    act = model.activation_vector(smile)[None]
    markers = model.marker_positions_m[None]
    return write_take(
        path,
        model=model,
        node_positions_m=model.rest_positions_m[None],
        fps=24.0,
        simulated_markers_m=markers if markers.shape[1] else None,
        activations=act,
        bone_meshes={},
        metadata={"source": "examples/make_usd_scenes.py builtin_face", "note": "rest pose, no physics"},
    )


def waters_expression(path: Path) -> Path:
    try:
        from wface.testing.synthetic_head import synthetic_head, synthetic_landmarks
        from wface.waters.expressions import interpolate_poses
        from wface.waters.fit import fit_layout
        from wface.waters.layout import load_layout
        from wface.waters.rig import WatersRig
    except ImportError as exc:  # wface.waters lands from the waters branch
        raise SceneUnavailable(f"wface.waters is not available ({exc})") from exc
    from wface.io.usd import write_mesh_animation

    mesh = synthetic_head(24, 48)
    layout = load_layout("ict")
    layout = fit_layout(
        layout, synthetic_landmarks(layout), target_vertices_m=mesh.vertices_m, target_triangles=mesh.triangles()
    )
    rig = WatersRig(layout, mesh.vertices_m)
    frames = []
    for k in range(8):
        pose = interpolate_poses("neutral", "happy", k / 7, muscle_names=rig.muscle_names)
        frames.append(rig.deform(pose.contractions, jaw_opening_deg=pose.jaw_opening_deg))
    frames = np.stack(frames)
    disp_mm = np.linalg.norm(frames[-1] - frames[0], axis=1) * 1000.0
    t = np.clip(disp_mm / max(float(disp_mm.max()), 1e-9), 0, 1)[:, None]
    colors = (1 - t) * np.array([0.87, 0.74, 0.65]) + t * np.array([1.0, 0.86, 0.10])  # skin -> yellow where it moves
    return write_mesh_animation(
        path,
        points_m=frames,
        face_vertex_counts=mesh.face_vertex_counts,
        face_vertex_indices=mesh.face_vertex_indices,
        fps=24.0,
        name="WatersHead",
        colors=colors,
    )


def fem_tracked_take(path: Path) -> Path:
    """The FEM tracker (Sifakis et al. 2005) on the built-in face: a 3-frame synthetic performance tracked from
    its markers (noise-free, so the result converges to the truth and the scene is reproducible);
    the skin is the tracked equilibrium, captured markers red, tracked green."""
    from wface.faces.builtin import build_face
    from wface.takes.store import take_from_records
    from wface.takes.usd import write_take_usd
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import embed_model_markers, track_sequence
    from wface.tracking.synthetic import synthesize_performance

    model = build_face(target_tets=1500)
    markers = embed_model_markers(model)
    perf = synthesize_performance(FaceRig(model), markers, frames=3, seed=11, head_motion=False)
    recs = track_sequence(model, perf.markers_m, marker_names=model.marker_names, markers=markers)
    rms = float(np.sqrt(np.nanmean(np.array([r.marker_error_m for r in recs]) ** 2)) * 1e3)
    return write_take_usd(
        path,
        model,
        np.array([r.x_m for r in recs]),
        take=take_from_records(model, recs, fps=30.0, source="examples/make_usd_scenes.py fem_tracked_take"),
        captured_markers_m=perf.markers_m,
        simulated_markers_m=np.array([r.markers_m for r in recs]),
        bone_meshes={},
        metadata={"marker_rms_mm": round(rms, 3)},
    )


SCENES: dict[str, Callable[[Path], Path]] = {
    "fem_tracked_take": fem_tracked_take,
    "synthetic_take": synthetic_take,
    "synthetic_tracked_take": synthetic_tracked_take,
    "synthetic_basis": synthetic_basis,
    "builtin_face": builtin_face,
    "waters_expression": waters_expression,
}


def make_scenes(out_dir: Path, names: list[str] | None = None, *, quiet: bool = False) -> dict[str, Path | str]:
    """Write the scenes into ``out_dir``; returns name -> path, or name -> reason when skipped."""
    from wface.io.usd import assert_stage_valid

    out_dir.mkdir(parents=True, exist_ok=True)
    result: dict[str, Path | str] = {}
    for name in names or list(SCENES):
        if name not in SCENES:
            raise SystemExit(f"unknown scene {name!r}; known: {', '.join(SCENES)}")
        try:
            path = SCENES[name](out_dir / f"{name}.usda")
        except SceneUnavailable as exc:
            result[name] = f"skipped: {exc}"
            if not quiet:
                print(f"{name}: skipped ({exc})")
            continue
        assert_stage_valid(path)  # every committed scene passes UsdValidation and the extent check
        size = path.stat().st_size
        if size > 1_000_000:
            raise SystemExit(f"{path} is {size / 1e6:.2f} MB: keep scenes under 1 MB (fewer frames / vertices)")
        result[name] = path
        if not quiet:
            print(f"{name}: {path} ({size / 1024:.0f} KiB)")
    return result


# Scenes of tracked takes are reproducible only to the tracker's stopping tolerance: Gauss-Newton
# stops once a step changes the RMS marker residual by less than TrackOptions.tol_mm (1e-3 mm), so
# another BLAS/PARDISO build (other round-off) may stop one such step earlier or later. That step
# moves single nodes by a few times tol_mm: 1e-5 m allowed on positions (node, marker), 1e-5 m / 0.1 m
# lever arm = 1e-4 on bone transforms, and 1e-5 m / (1 mm per unit activation, the observability
# threshold) = 1e-2 on activations and the activation colours. Measured between main's scene (mkl
# 2025.3, parallel ordering) and this one (mkl 2026.2, reproducible mode): 2.3e-6 m, 4.3e-6, 3.6e-5.
# The same libraries on another x86-64 CPU (AVX-512: other round-off in the Warp kernels and MKL)
# moved the rig's blend-shape weights (activations, so 1e-2 as above) by 4.2e-4, the skin normals
# (unit vectors at nodes moved by a few um on mm-long edges) by 1.7e-4, the rig's fit errors in the
# layer metadata by 3e-4 relative, and which points the jaw corrective lists (its offsets at the
# sparsity threshold): compared as dense offsets.
TRACKED_TOLERANCES = {
    "atol": 1e-5,
    "atol_by_attribute": {
        "wface:activation": 1e-2,
        "displayColor": 1e-2,
        "blendShapeWeights": 1e-2,
        "normals": 1e-3,
        "xformOp:transform": 1e-4,
    },
    "metadata_rtol": 1e-3,
}
SCENE_TOLERANCES: dict[str, dict] = {"fem_tracked_take": TRACKED_TOLERANCES}


def check_scenes(scene_dir: Path = SCENE_DIR, names: list[str] | None = None) -> list[str]:
    """Regenerate into a temporary directory and compare with ``scene_dir``; returns the problems."""
    from wface.io.usd import compare_stages

    problems = []
    with tempfile.TemporaryDirectory() as tmp:
        fresh = make_scenes(Path(tmp), names, quiet=True)
        for name, path in fresh.items():
            committed = scene_dir / f"{name}.usda"
            if isinstance(path, str):  # an optional module is absent here: nothing to compare with
                continue
            if not committed.exists():
                problems.append(f"{name}: {committed} is missing")
                continue
            diffs = compare_stages(committed, path, **SCENE_TOLERANCES.get(name, {}))
            problems += [f"{name}: {d}" for d in diffs]
    return problems


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=SCENE_DIR, help="directory to write (default: usd_scenes/)")
    ap.add_argument("--only", nargs="+", metavar="NAME", help=f"scenes to write (default: all of {', '.join(SCENES)})")
    ap.add_argument("--check", action="store_true", help="compare --out with freshly generated scenes; exit 1 if stale")
    args = ap.parse_args(argv)
    if args.check:
        problems = check_scenes(args.out, args.only)
        for p in problems:
            print(p)
        if problems:
            print("usd_scenes/ is out of date: run `python examples/make_usd_scenes.py` and commit usd_scenes/")
            return 1
        print("usd_scenes/ is current")
        return 0
    make_scenes(args.out, args.only)
    return 0


if __name__ == "__main__":
    sys.exit(main())
