"""``wface demo`` and ``wface track``: muscle activations and jaw/head motion from markers.

Both write into --out: report.json (the keys in the README), controls.npz / controls.csv
(per-frame activations, bone parameters, jaw pose), frames/ (one file per tracked frame, so an
interrupted run resumes with --resume), animation.usdc (unless --no-usd), pictures, plots and a
movie (unless --no-pictures / --no-movie) and report.html; the closing lines list every file.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from wface.cli.closing import print_outputs
from wface.cli.contact_args import add_contact_arguments, contact_from_args
from wface.faces.builtin import build_face
from wface.io.mocap import read_mocap
from wface.model import load_model
from wface.tracking.capture import prepare_capture
from wface.tracking.estimator import TrackOptions
from wface.tracking.identifiability import rig_identifiability_mm
from wface.tracking.output import write_tracking_outputs
from wface.tracking.report import build_report
from wface.tracking.rig import FaceRig
from wface.tracking.sequence import dask_executor, embed_model_markers, track_sequence
from wface.tracking.synthetic import synthesize_performance

_DEMO_EPILOG = """\
The main job on the built-in face: build the face, synthesise a performance with known
activations, jaw and head motion (forward quasistatic FEM), corrupt the markers like real capture
(noise, outliers, dropped markers), track it, and compare with the truth.

examples:
  wface demo --out demo_out
  wface demo --out demo_out --tets 20000 --frames 60 --noise-mm 0.5 --outliers 0.02 --dropout 0.05
  wface demo --out demo_out --workers 2            # chunks on a local Dask cluster
"""

_TRACK_EPILOG = """\
Markers whose names the model also has (the built-in face uses the AnimFace names) anchor the
alignment of the first frame; all markers are embedded in the skin. Rigid head motion is carried
by the cranium controls.

examples:
  wface track --mocap take.c3d --out run1                      # on the built-in face (5000 tets)
  wface track --model face.npz --mocap take.c3d --out run1 --frames 0:300
  wface track --mocap take.trc --out run1 --workers 4 --resume
  wface track --mocap nexus_export.csv --out run1 --frames 100:400 --neutral-frame 0   # Vicon / Motive CSV
  wface track --mocap take.c3d --out run1 --no-pictures          # numbers and animation.usdc only
  wface track --mocap take.c3d --out run1 --scheduler tcp://10.0.0.5:8786
"""


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--device", default="cpu", help="Warp device: cpu, cuda:0 or auto")
    p.add_argument("--solver", default="auto", choices=["auto", "direct", "cg"], help="linear solver")
    p.add_argument(
        "--workers", type=int, default=1, help="split the take into chunks on a local Dask cluster of N workers"
    )
    p.add_argument("--scheduler", help="address of a running Dask scheduler (instead of a local cluster)")
    p.add_argument("--chunk-size", type=int, help="frames per chunk (default: frames / workers)")
    p.add_argument("--resume", action="store_true", help="reuse frames already written under OUT/frames")
    p.add_argument(
        "--robust-mm", type=float, default=3.0, help="Tukey cut-off on marker residuals in mm (0: plain least squares)"
    )
    p.add_argument("--temporal-weight", type=float, default=0.0, help="pull of activations toward the previous frame")
    p.add_argument("--no-movie", action="store_true", help="skip the mp4 movie")
    p.add_argument(
        "--no-pictures", action="store_true", help="skip pictures, plots and movie (report.html keeps the numbers)"
    )
    p.add_argument("--no-usd", action="store_true", help="skip animation.usdc")
    add_contact_arguments(
        p, smoothing_mm=0.05, obstacles=False, where="every equilibrium and Jacobian (for demo also the ground truth)"
    )


def _contact(args, model):
    """The ``Contact`` of the contact options (a 0.05 mm C2 ramp by default, for smooth Jacobians)."""
    return contact_from_args(args, model)


def register(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser(
        "demo",
        help="the main job: track a synthetic performance on the built-in face",
        description=_DEMO_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _common(d)
    d.add_argument("--tets", type=int, default=5000, help="size of the built-in face in tets (default 5000)")
    d.add_argument("--frames", type=int, default=30, help="frames in the performance (default 30)")
    d.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    d.add_argument("--noise-mm", type=float, default=0.5, help="RMS marker noise in mm (default 0.5)")
    d.add_argument("--outliers", type=float, default=0.02, help="fraction of outlier marker samples (default 0.02)")
    d.add_argument("--dropout", type=float, default=0.05, help="fraction of missing marker samples (default 0.05)")
    d.add_argument("--seed", type=int, default=0, help="random seed of the performance")
    d.set_defaults(func=run_demo)

    t = sub.add_parser(
        "track",
        help="track a motion-capture take (C3D, TRC, CSV) on a face model",
        description=_TRACK_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _common(t)
    t.add_argument("--model", help="face model (.npz); default: the built-in face with --tets tets")
    t.add_argument("--tets", type=int, default=5000, help="size of the built-in face when --model is not given")
    t.add_argument("--mocap", required=True, help="marker file: .c3d, .trc or .csv")
    t.add_argument("--frames", help="frame range A:B (Python slice of the file's frames)")
    t.add_argument(
        "--neutral-frame",
        type=int,
        help="file frame showing the neutral face, which anchors the alignment and the marker embedding "
        "(default: the first frame of the range; it may lie outside the range)",
    )
    t.set_defaults(func=run_track)


def _options(args) -> TrackOptions:
    return TrackOptions(robust_mm=args.robust_mm or None, temporal_weight=args.temporal_weight)


def _run(args, model, targets, marker_names, markers, fps, truth=None, first_frame=0) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rig_kwargs = {"device": args.device, "solver": args.solver, "tol": 1e-6}
    contact = _contact(args, model)
    if contact is not None:
        rig_kwargs["contact"] = contact
    executor, chunk, close = dask_executor(
        workers=args.workers, scheduler=args.scheduler, n_frames=len(targets), chunk_size=args.chunk_size
    )
    try:
        t0 = time.perf_counter()
        records = track_sequence(
            model,
            targets,
            marker_names=marker_names,
            markers=markers,
            options=_options(args),
            rig_kwargs=rig_kwargs,
            chunk_size=chunk,
            executor=executor,
            out_dir=out,
            resume=args.resume,
            progress=True,
            first_frame=first_frame,
        )
        wall = time.perf_counter() - t0
    finally:
        close()
    rig = FaceRig(model, **rig_kwargs)
    info = {
        "device": rig.sim.device,
        "solver": rig.sim.linear_solver,
        "wall_seconds": wall,
        "workers": args.workers if not args.scheduler else "scheduler",
        "contact": getattr(args, "contact", None) or None,
    }
    report = build_report(
        model,
        records,
        markers_data_m=targets,
        marker_names=marker_names,
        rig_info=info,
        identifiability_mm=rig_identifiability_mm(rig, markers),
        truth=truth,
        robust_mm=args.robust_mm or None,
    )
    written = write_tracking_outputs(
        out,
        model,
        records,
        targets_m=targets,
        fps=fps,
        report=report,
        truth=truth,
        usd=not args.no_usd,
        pictures=not args.no_pictures,
        movie=not args.no_movie,
        title=f"wface {args.command}",
        marker_names=list(marker_names),
        progress=True,
    )
    keys = (
        "truth_marker_rms_mm",
        "marker_rms_mm_inliers",
        "outlier_samples",
        "missing_samples",
        "marker_rms_mm_mean",
        "activation_rms_error",
        "activation_rms_error_all",
        "jaw_angle_error_deg",
        "seconds_per_frame_median",
    )
    print("  ".join(f"{k}={report[k]:.4g}" for k in keys if report.get(k) is not None))
    print_outputs(out, written)
    return 0


def run_demo(args: argparse.Namespace) -> int:
    model = build_face(args.tets, progress=True)
    rig = FaceRig(model, device=args.device, solver=args.solver, tol=1e-6, contact=_contact(args, model))
    markers = embed_model_markers(model)
    perf = synthesize_performance(
        rig,
        markers,
        frames=args.frames,
        rate_hz=args.fps,
        seed=args.seed,
        noise_mm=args.noise_mm,
        outliers=args.outliers,
        dropout=args.dropout,
        progress=True,
    )
    np.savez(
        Path(args.out).mkdir(parents=True, exist_ok=True) or Path(args.out) / "truth.npz",
        activations=perf.activations,
        bones=perf.bones,
        clean_markers_m=perf.clean_markers_m,
        markers_m=perf.markers_m,
        outlier_mask=perf.outlier_mask,
    )
    return _run(args, model, perf.markers_m, model.marker_names, markers, args.fps, truth=perf)


def run_track(args: argparse.Namespace) -> int:
    model = load_model(args.model) if args.model else build_face(args.tets, progress=True)
    take = read_mocap(args.mocap)
    for note in take.meta.get("notices", []):
        print(f"note: {note}")
    neutral = args.neutral_frame
    if neutral is not None and not 0 <= neutral < take.n_frames:
        raise ValueError(f"--neutral-frame {neutral} is outside {args.mocap}'s {take.n_frames} frames")
    reference = take.positions_m[neutral] if neutral is not None else None
    first = 0
    if args.frames:
        try:
            a, b = (int(v) if v else None for v in args.frames.split(":"))
        except ValueError:
            raise ValueError(f"--frames must look like A:B, got {args.frames!r}") from None
        first = a or 0
        take = take.frames(a, b)
    if take.n_frames == 0:
        raise ValueError(f"{args.mocap}: no frames in the range {args.frames}")
    cap = prepare_capture(model, take.positions_m, take.marker_names, reference_positions_m=reference)
    print(
        f"aligned {take.n_markers} markers ({len(cap.matched_names)} by name), scale {cap.scale:.3f}, "
        f"rest fit {cap.alignment_rms_mm:.2f} mm RMS"
    )
    return _run(args, model, cap.targets_m, take.marker_names, cap.markers, take.rate_hz, first_frame=first)
