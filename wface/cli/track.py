"""``wface demo`` and ``wface track``: muscle activations and jaw/head motion from markers.

Both write into --out: report.json (the keys in the README), controls.npz / controls.csv
(per-frame activations, bone parameters, jaw pose), frames/ (one file per tracked frame, so an
interrupted run resumes with --resume), animation.usdc (unless --no-usd), pictures, plots and a
movie (unless --no-pictures / --no-movie) and report.html; the closing lines list every file.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from wface.cli.closing import print_outputs
from wface.cli.contact_args import add_contact_arguments, contact_from_args
from wface.cli.errors import UsageError
from wface.cli.render_mesh_args import add_render_mesh_arguments, render_mesh_from_args
from wface.cli.take_face import DEFAULT_TETS, face_record
from wface.cli.validate import (
    face_tets,
    frame_range,
    holdout_spec,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    probability,
)
from wface.controls import jaw_limits
from wface.faces.builtin import build_face
from wface.files import file_sha256, save_npz
from wface.io.mocap import read_mocap
from wface.model import load_model
from wface.physics.penalty import TRACKING_SMOOTHING_M
from wface.takes.store import claim_take_dir, recorded_run, resume_plan
from wface.tracking.capture import check_capture, prepare_capture
from wface.tracking.cluster import dask_executor
from wface.tracking.estimator import TrackOptions
from wface.tracking.holdout import add_holdout, hide, select_holdout
from wface.tracking.identifiability import rig_identifiability_mm
from wface.tracking.output import write_tracking_outputs
from wface.tracking.report import CAPTURE_UNIT_KEYS, add_capture_units, build_report
from wface.tracking.rig import FaceRig
from wface.tracking.sequence import embed_model_markers, track_sequence, tracking_provenance
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

Before tracking, samples no face can produce (non-finite, far outside the head, one-frame jumps
faster than 2 m/s) become missing and are counted per marker in report.json; a frame left with too
few markers is carried from the frame before. OUT records what made it (provenance.json): --resume
reuses only frames this same run made (same model, capture file, range and options), and the
very same command again continues that way by itself; a directory holding another take, or this
take's finished frames made with other options, is refused unless --resume or --overwrite (which
deletes them).

examples:
  wface track --mocap take.c3d --out run1                      # on the built-in face (5000 tets)
  wface track --model face.npz --mocap take.c3d --out run1 --frames 0:300
  wface track --mocap take.c3d --out preview --frames 0:3000:10   # every 10th frame, at its true time
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
        "--workers",
        type=positive_int,
        default=1,
        help="split the take into chunks on a local Dask cluster of N workers",
    )
    p.add_argument("--scheduler", help="address of a running Dask scheduler (instead of a local cluster)")
    p.add_argument("--chunk-size", type=positive_int, help="frames per chunk (default: frames / workers)")
    p.add_argument(
        "--resume",
        action="store_true",
        help="reuse the frames under OUT/frames that this same run made (checked by fingerprint)",
    )
    p.add_argument(
        "--overwrite", action="store_true", help="replace the results of another take that OUT already holds"
    )
    p.add_argument(
        "--prior",
        choices=["auto", "temporal", "off"],
        default="auto",
        help="priors on the activations whose strength the take itself sets: auto (default) a temporal prior, "
        "then --prior-passes passes under each muscle's usage over the take; temporal: the first alone (one pass, "
        "faster); off",
    )
    p.add_argument(
        "--prior-passes",
        type=positive_int,
        default=TrackOptions.prior_passes,
        help="with --prior auto: at most this many passes under the take-wide usage prior after the first, each "
        f"re-linearised at the one before with its prior refitted (default {TrackOptions.prior_passes})",
    )
    p.add_argument(
        "--prior-refit-change",
        type=non_negative_float,
        default=TrackOptions.prior_refit_change,
        help="with --prior auto: refit the usage prior (the passes after the first usage pass) only when that pass "
        f"moved the activations by more than this RMS (default {TrackOptions.prior_refit_change:g}: heavy noise, "
        "outliers or dropout; 0: always --prior-passes)",
    )
    p.add_argument(
        "--robust-mm",
        type=non_negative_float,
        default=3.0,
        help="Tukey cut-off on marker residuals in mm (0: plain least squares)",
    )
    p.add_argument(
        "--temporal-weight", type=non_negative_float, default=0.0, help="pull of activations toward the previous frame"
    )
    p.add_argument("--no-movie", action="store_true", help="skip the mp4 movie")
    p.add_argument(
        "--no-pictures", action="store_true", help="skip pictures, plots and movie (report.html keeps the numbers)"
    )
    p.add_argument("--no-usd", action="store_true", help="skip animation.usdc")
    p.add_argument(
        "--no-rig",
        action="store_true",
        help="animation.usdc without the UsdSkel rig: the exact point cache alone (no second skin to hide in a "
        "DCC; the rig costs one solve per muscle the take uses)",
    )
    add_contact_arguments(
        p,
        smoothing_mm=1e3 * TRACKING_SMOOTHING_M,
        obstacles=False,
        where="every equilibrium and Jacobian (for demo also the ground truth)",
    )
    p.add_argument(
        "--holdout",
        type=holdout_spec,
        metavar="N|NAME,...",
        help="hide markers from the fit and report their error (holdout_rms_mm): every Nth marker by height, or names",
    )
    add_render_mesh_arguments(p)


def _contact(args, model):
    """The ``Contact`` of the contact options (by default the C2 ramp ``TRACKING_SMOOTHING_M``)."""
    return contact_from_args(args, model)


def register(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser(
        "demo",
        help="the main job: track a synthetic performance on the built-in face",
        description=_DEMO_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _common(d)
    d.add_argument(
        "--tets",
        type=face_tets,
        default=DEFAULT_TETS,
        help=f"size of the built-in face in tets (default {DEFAULT_TETS})",
    )
    d.add_argument("--frames", type=positive_int, default=30, help="frames in the performance (default 30)")
    d.add_argument("--fps", type=positive_float, default=30.0, help="frame rate (default 30)")
    d.add_argument("--noise-mm", type=non_negative_float, default=0.5, help="RMS marker noise in mm (default 0.5)")
    d.add_argument(
        "--outliers", type=probability, default=0.02, help="fraction of outlier marker samples (default 0.02)"
    )
    d.add_argument(
        "--dropout", type=probability, default=0.05, help="fraction of missing marker samples (default 0.05)"
    )
    d.add_argument("--seed", type=non_negative_int, default=0, help="random seed of the performance")
    d.set_defaults(func=run_demo)

    t = sub.add_parser(
        "track",
        help="track a motion-capture take (C3D, TRC, CSV) on a face model",
        description=_TRACK_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _common(t)
    t.add_argument("--model", help="face model (.npz); default: the built-in face with --tets tets")
    t.add_argument(
        "--tets",
        type=face_tets,
        default=None,
        help=f"size of the built-in face without --model (default {DEFAULT_TETS})",
    )
    t.add_argument("--mocap", required=True, help="marker file: .c3d, .trc or .csv")
    t.add_argument(
        "--frames",
        type=frame_range,
        help="frame range A:B, or A:B:S for every S-th frame (a Python slice of the file's frames; the outputs keep "
        "the capture's frame numbers and rate, so a strided take plays at its true speed)",
    )
    t.add_argument(
        "--neutral-frame",
        type=non_negative_int,
        help="file frame showing the neutral face, which anchors the alignment and the marker embedding "
        "(default: the first frame of the range; it may lie outside the range)",
    )
    t.set_defaults(func=run_track)


def _options(args) -> TrackOptions:
    return TrackOptions(
        robust_mm=args.robust_mm or None,
        temporal_weight=args.temporal_weight,
        prior=args.prior,
        prior_passes=args.prior_passes,
        prior_refit_change=args.prior_refit_change,
    )


def _rig_kwargs(args, model) -> dict:
    rig_kwargs = {"device": args.device, "solver": args.solver, "tol": 1e-6}
    contact = _contact(args, model)
    if contact is not None:
        rig_kwargs["contact"] = contact
    return rig_kwargs


def _hidden(args, marker_names, targets):
    """(hidden marker ids or None, the targets the fit sees: the hidden markers missing)."""
    hidden = select_holdout(args.holdout, marker_names, targets[0]) if getattr(args, "holdout", None) else None
    return hidden, (targets if hidden is None else hide(targets, hidden))


def _claim(
    args, model, markers, marker_names, targets, source: dict, rig_kwargs: dict, frames: range | None = None
) -> dict:
    """Provenance of this run; claims --out (refusing another take's directory) and says what --resume reuses."""
    if args.resume and args.overwrite:
        raise UsageError("--resume and --overwrite contradict each other: --resume continues the take in --out, "
                         "--overwrite deletes it")  # fmt: skip
    source = {**source, "holdout": getattr(args, "holdout", None)}  # hidden markers change the fit
    run = tracking_provenance(
        model, markers, options=_options(args), rig_kwargs=rig_kwargs, kind=args.command, source=source
    )
    if not (args.resume or args.overwrite) and (recorded_run(args.out) or {}).get("fingerprint") == run["fingerprint"]:
        args.resume = True  # the very same run again (the README's command twice, a rerun after Ctrl-C)
        print(f"continuing the same run in {args.out} (--overwrite starts it again)")
    note = claim_take_dir(args.out, run, resume=args.resume, overwrite=args.overwrite)
    if note:
        print(note)
    if args.resume:
        two_pass = args.prior == "auto" and len(targets) >= 2  # as wface.tracking.sequence.track_sequence
        frames = frames if frames is not None else range(len(targets))
        fit_targets = _hidden(args, marker_names, targets)[1]  # as the frame files' fingerprints saw them
        print(resume_plan(args.out, frames, fit_targets, run, two_pass=two_pass).summary())
    return run


def _run(
    args,
    model,
    targets,
    marker_names,
    markers,
    fps,
    rig_kwargs,
    truth=None,
    frames: range | None = None,
    run=None,
    info=None,
    capture_scale=None,
):
    out = Path(args.out)
    hidden, fit_targets = _hidden(args, marker_names, targets)
    render_mesh = render_mesh_from_args(args, model)
    executor, chunk, close = dask_executor(
        workers=args.workers, scheduler=args.scheduler, n_frames=len(targets), chunk_size=args.chunk_size
    )
    if chunk and chunk < len(targets) and args.prior == "temporal":
        print(
            "note: with --prior temporal each chunk pools its noise and change statistics afresh after its "
            "warm-up frames, so activations can differ from a serial run (by ~0.02 RMS measured); "
            "--prior auto (the default) refits them over the whole take and matches it"
        )
    try:
        t0 = time.perf_counter()
        records = track_sequence(
            model,
            fit_targets,
            marker_names=marker_names,
            markers=markers,
            options=_options(args),
            rig_kwargs=rig_kwargs,
            chunk_size=chunk,
            executor=executor,
            out_dir=out,
            resume=args.resume,
            progress=True,
            first_frame=frames.start if frames is not None else 0,
            frame_step=frames.step if frames is not None else 1,
            provenance=run,
        )
        wall = time.perf_counter() - t0
    finally:
        close()
    rig = FaceRig(model, **rig_kwargs)
    carried = [r.frame for r in records if r.stats.get("carried")]
    info = {
        "device": rig.sim.device,
        "solver": rig.sim.linear_solver,
        "tracking_wall_seconds": wall,  # the tracking alone: not the face build, pictures or USD
        "face_model": face_record(args),  # what resim / edit --take rebuild (wface.cli.take_face)
        "workers": args.workers if not args.scheduler else "scheduler",
        "contact": getattr(args, "contact", None) or None,
        "contact_smoothing_mm": args.contact_smoothing_mm if getattr(args, "contact", None) else None,
        **(info or {}),
        "carried_frames": carried,
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
    if hidden is not None:
        add_holdout(report, records, targets, hidden, marker_names)
    if capture_scale is not None:
        add_capture_units(report, capture_scale)
    written = write_tracking_outputs(
        out,
        model,
        records,
        targets_m=targets,
        fps=fps,
        report=report,
        truth=truth,
        usd=not args.no_usd,
        rig=not args.no_rig,
        pictures=not args.no_pictures,
        movie=not args.no_movie,
        title=f"wface {args.command}",
        marker_names=list(marker_names),
        progress=True,
        render_mesh=render_mesh,
    )
    keys = (
        "truth_marker_rms_mm",
        "marker_rms_mm_mean",
        "holdout_rms_mm_mean",
        "marker_rms_mm_inliers",
        "outlier_samples",
        "missing_samples",
        "activation_rms_error",
        "activation_rms_error_all",
        "jaw_angle_error_deg",
        "seconds_per_frame_median",
        "capture_to_model_scale",
        *CAPTURE_UNIT_KEYS.values(),
    )
    if carried:
        warnings.warn(
            f"{len(carried)} frames had too few usable markers and were carried from the frame before "
            f"(first: frame {carried[0]}; listed in report.json under carried_frames)",
            stacklevel=1,
        )
    _warn_jaw_on_closed_limit(model, report, truth)
    _warn_rejected_markers(report)
    print("  ".join(f"{k}={report[k]:.4g}" for k in keys if report.get(k) is not None))
    print_outputs(out, [*written, Path(out) / "provenance.json"])  # claimed before the run: what made the take
    return 0


def _warn_jaw_on_closed_limit(model, report: dict, truth) -> None:
    """Say so when a capture's jaw sat on the model's closed limit in more than 10 % of the frames (the
    actor closes it further past the neutral frame than the model allows; docs/design.md, "Controls and
    the jaw joint")."""
    share = report.get("jaw_on_closed_limit_fraction") or 0.0
    if truth is not None or share <= 0.1:
        return
    lo = jaw_limits(model.jaw_joint)["opening_deg"][0]
    hint = (
        "this model's jaw has no closing range past its rest (max_closing_sine 0: a model saved before wface had "
        "one, or made so on purpose): `wface model build` makes a face whose jaw closes by the freeway space"
        if model.jaw_joint.max_closing_sine == 0
        else "the capture closes the jaw further past its neutral frame than the model allows"
    )
    warnings.warn(
        f"the tracked jaw sat on its closed limit ({lo:.1f} deg) in {100 * share:.0f} % of the frames "
        f"(jaw_on_closed_limit_fraction in report.json): {hint}",
        stacklevel=1,
    )


def _warn_rejected_markers(report: dict) -> None:
    """Name the markers the robust fit set aside in most of the frames that saw them: the headline error
    counts inliers, so a marker the face cannot follow (a jaw that does not open as far) would go unseen."""
    worst = [
        (n, st)
        for n, st in (report.get("marker_stats") or {}).items()
        if st.get("seen") and st.get("outliers", 0) > 0.5 * st["seen"]
    ]
    if worst:
        listed = ", ".join(
            f"{n} ({st['outliers']} of {st['seen']} frames, up to {st['max_mm']:.1f} mm)" for n, st in worst
        )
        warnings.warn(
            f"set aside as outliers in most frames (the fit ignores them there, and marker_rms_mm_inliers leaves "
            f"them out): {listed}; the face does not reach where the capture puts them (marker_stats in report.json)",
            stacklevel=1,
        )


def run_demo(args: argparse.Namespace) -> int:
    if args.dropout >= 0.9:  # the tracker needs markers to see: at 1 every sample is missing
        raise UsageError(f"--dropout {args.dropout:g} leaves too few markers to track: give a fraction below 0.9")
    model = build_face(args.tets, progress=True)
    rig = FaceRig(model, device=args.device, solver=args.solver, tol=1e-6, contact=_contact(args, model))
    markers = embed_model_markers(model)
    source = {
        "synthetic": "wface.tracking.synthetic",
        **{k: getattr(args, k) for k in ("seed", "tets", "frames", "fps", "noise_mm", "outliers", "dropout")},
        "contact": args.contact or None,
    }
    if args.out and Path(args.out).is_file():
        raise NotADirectoryError(f"--out {args.out}: is a file, not a directory")
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
    rig_kwargs = _rig_kwargs(args, model)  # one Contact for the provenance and the tracking
    run = _claim(args, model, markers, model.marker_names, perf.markers_m, source, rig_kwargs)
    save_npz(
        Path(args.out) / "truth.npz",
        activations=perf.activations,
        bones=perf.bones,
        clean_markers_m=perf.clean_markers_m,
        markers_m=perf.markers_m,
        outlier_mask=perf.outlier_mask,
    )
    return _run(args, model, perf.markers_m, model.marker_names, markers, args.fps, rig_kwargs, truth=perf, run=run)


def _markers_with_a_rest_place(names, tracked_m, neutral_m, neutral_frame: int) -> np.ndarray:
    """Indices of the markers that can be tracked: present in the neutral frame (which gives each its rest
    place on the skin) and in at least one tracked frame; the others are left out with a warning."""
    at_rest = np.isfinite(neutral_m).all(axis=1)
    seen = np.isfinite(tracked_m).all(axis=2).any(axis=0)
    for mask, why in (
        (~seen, "no samples in the frames tracked"),
        (
            seen & ~at_rest,
            f"missing in the neutral frame {neutral_frame}, which gives a marker its rest place "
            "(--neutral-frame picks another frame)",
        ),
    ):
        if mask.any():
            gone = ", ".join(names[i] for i in np.flatnonzero(mask))
            warnings.warn(f"left out of the fit, {why}: {gone}", stacklevel=2)
    keep = np.flatnonzero(at_rest & seen)
    if len(keep) < 3:
        raise ValueError(
            f"only {len(keep)} markers are present both in the neutral frame {neutral_frame} and in "
            "the frames tracked: pick another --neutral-frame or --frames"
        )
    return keep


def run_track(args: argparse.Namespace) -> int:
    if args.model and args.tets is not None:
        raise UsageError("--tets does nothing here: it sizes the built-in face, and --model gives the face")
    take = read_mocap(args.mocap)  # a bad file fails before the face is built
    model = load_model(args.model) if args.model else build_face(args.tets or DEFAULT_TETS, progress=True)
    for note in take.meta.get("notices", []):
        print(f"note: {note}")
    neutral = args.neutral_frame
    if neutral is not None and not 0 <= neutral < take.n_frames:
        raise ValueError(f"--neutral-frame {neutral} is outside {args.mocap}'s {take.n_frames} frames")
    full = take
    a, b, step = args.frames or (None, None, 1)
    kept = range(take.n_frames)[slice(a, b, step)]  # the capture's frame indices tracked
    if len(kept) == 0:
        raise ValueError(f"{args.mocap}: no frames in the range {args.frames}")
    if b is not None and b > take.n_frames:  # a slice stops at the end: say so, not only the count
        warnings.warn(
            f"--frames {a}:{b}: {args.mocap} has {take.n_frames} frames; tracking {len(kept)} ({kept.start} to "
            f"{kept[-1]})",
            stacklevel=1,
        )
    first = kept.start
    if args.frames:
        take = take.frames(a, b, step)
    neutral_frame = first if neutral is None else neutral
    ref = full.positions_m[neutral_frame]
    check = check_capture(full.positions_m, full.marker_names, rate_hz=full.rate_hz, reference_positions_m=ref)
    if check.removed:
        warnings.warn(check.summary(), stacklevel=1)
    clean = check.positions_m[first : kept.stop : step]
    keep = _markers_with_a_rest_place(take.marker_names, clean, check.positions_m[neutral_frame], neutral_frame)
    names = [take.marker_names[i] for i in keep]
    clean = clean[:, keep]
    reference = check.positions_m[neutral][keep] if neutral is not None else None
    cap = prepare_capture(model, clean, names, reference_positions_m=reference)
    print(
        f"aligned {len(names)} markers ({len(cap.matched_names)} by name), scale {cap.scale:.3f}, "
        f"rest fit {cap.alignment_rms_mm:.2f} mm RMS"
    )
    source = {
        "file": Path(args.mocap).name,
        "sha256": file_sha256(args.mocap),
        "frames": f"{first}:{kept.stop}" + (f":{step}" if step > 1 else ""),
        "neutral_frame": neutral_frame,
    }
    rig_kwargs = _rig_kwargs(args, model)  # one Contact for the provenance and the tracking
    run = _claim(args, model, cap.markers, names, cap.targets_m, source, rig_kwargs, frames=kept)
    info = {"capture_check": check.report()}
    return _run(
        args,
        model,
        cap.targets_m,
        names,
        cap.markers,
        full.rate_hz,
        rig_kwargs,
        frames=kept,
        run=run,
        info=info,
        capture_scale=cap.scale,
    )
