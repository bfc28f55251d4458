"""``wface basis``: analyse motion capture into actuation-basis contractions, refine a basis.

Units: basis files in metres (an ICT-FaceKit ``ict_expressions.npz`` in centimetres is converted
on load); C3D/TRC/CSV takes in their declared units (converted to metres); reports in mm.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from wface.basis.capture import MarkerLayout
from wface.basis.core import load_basis
from wface.basis.physical import basis_from_face
from wface.basis.pipeline import analyze_take, default_landmarks, refine_basis, write_analysis
from wface.cli.take_face import DEFAULT_TETS
from wface.cli.validate import (
    face_tets,
    frame_range,
    non_negative_float,
    npz_file,
    positive_float,
    positive_fraction,
    positive_int,
    refuse_existing,
)
from wface.faces.builtin import build_face
from wface.files import file_sha256, read_landmarks, write_json
from wface.io.mocap import read_mocap
from wface.model import load_model
from wface.takes.provenance import run_provenance
from wface.takes.store import claim_take_dir

__all__ = ["register"]

_EPILOG = """\
examples:
  wface basis analyze --basis ../shared/data/ict-facekit/ict_expressions.npz \\
      --mocap ../shared/data/animface/JawMoCap.c3d --out jaw_analysis
  wface basis refine --basis ict_expressions.npz --train Jaw.c3d Cheeks.c3d Nose.c3d --out refined.npz
  wface basis analyze --basis refined.npz --mocap Eyebrows.c3d --out brows
  wface basis info refined.npz
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "basis",
        help="linear actuation basis (Choe & Ko 2001): analyze a take, refine, info, from-face",
        description="Linear actuation basis: E = E0 + sum_i x_i e_i. Analysis finds bounded contractions x per "
        "frame from marker displacements; refinement improves the element shapes from training takes.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    bsub = p.add_subparsers(dest="basis_command", metavar="ACTION")

    def common(q):
        q.add_argument("--basis", required=True, help="basis .npz (wface format) or an ICT-FaceKit ict_expressions.npz")
        q.add_argument("--landmarks", help="JSON {marker name: basis vertex} for the initial alignment "
                       "(default: built-in AnimFace->ICT landmarks when the basis is the ICT face)")  # fmt: skip
        q.add_argument("--exaggerate", action="store_true", help="allow contractions above 1 (x >= 0 only)")
        q.add_argument("--split", action="store_true", help="solve upper and lower face separately")
        q.add_argument("--frames", type=frame_range, help="frame slice START:STOP[:STEP] of every take (default all)")
        q.add_argument("--no-progress", action="store_true", help="no progress bars")

    raw = argparse.RawDescriptionHelpFormatter
    a = bsub.add_parser("analyze", help="contractions per frame of one take", formatter_class=raw,
                        description="Align a take to the basis neutral, remove head motion, and solve the bounded "
                        "least squares per frame. Writes contractions.npz/.csv, marker_error_mm.csv, report.json, "
                        "analysis.png.")  # fmt: skip
    common(a)
    a.add_argument("--mocap", required=True, help="take: .c3d, .trc or .csv")
    a.add_argument("--out", required=True, help="output directory")
    a.add_argument("--no-plot", action="store_true", help="skip analysis.png")
    a.add_argument("--overwrite", action="store_true", help="replace the results of another run that OUT holds")
    a.add_argument("--json", action="store_true", help="print report.json (without per-frame lists) to stdout")
    a.set_defaults(func=_analyze)

    r = bsub.add_parser("refine", help="refine a basis on training takes", formatter_class=raw,
                        description="Fixed-point refinement (analysis <-> per-marker least squares) until the "
                        "training error saturates, then RBF interpolation to the whole mesh. Writes the refined "
                        "basis (.npz) and PATH.report.json with the error of every iteration.")  # fmt: skip
    common(r)
    r.add_argument("--train", required=True, nargs="+", help="training takes (.c3d/.trc/.csv)")
    r.add_argument("--out", required=True, type=npz_file, help="refined basis .npz")
    r.add_argument("--overwrite", action="store_true", help="replace an existing --out file and its PATH.report.json")
    r.add_argument("--regularization", default="auto", type=_regularization,
                   help="ridge weight towards the initial shapes, or 'auto' (leave-one-take-out; default)")  # fmt: skip
    r.add_argument("--support", type=positive_fraction, default=None,
                   help="locality: an element may only change at markers it moves by at least this fraction "
                   "of its largest marker displacement (e.g. 0.1; default off)")  # fmt: skip
    r.add_argument("--carry-metric", choices=("surface", "euclidean"), default="surface",
                   help="distances of the RBF carry-over to the mesh: along the surface (default; touching "
                   "lips and eyelids stay apart) or straight (the paper's thin-plate spline)")  # fmt: skip
    r.add_argument("--max-iterations", type=positive_int, default=30, help="cap on refinement iterations (default 30)")
    r.add_argument(
        "--rel-tol", type=positive_float, default=1e-3, help="stop when the error falls less than this fraction"
    )
    r.set_defaults(func=_refine)

    i = bsub.add_parser("info", help="summarise a basis file")
    i.add_argument("path", help="basis .npz")
    i.add_argument("--json", action="store_true", help="JSON (what info prints either way; as model info --json)")
    i.set_defaults(func=_info)
    f = bsub.add_parser(
        "from-face",
        help="physically derived basis: each muscle of an FEM face activated alone",
        description="Build an actuation basis from an FEM face: element i is the skin displacement with muscle i "
        "alone at --activation (quasistatic solve). Element names are the muscle names.",
    )
    f.add_argument("--model", help="face model (.npz); default: the built-in face with --tets tets")
    f.add_argument(
        "--tets",
        type=face_tets,
        default=DEFAULT_TETS,
        help=f"size of the built-in face when --model is not given (default {DEFAULT_TETS})",
    )
    f.add_argument("--activation", type=positive_fraction, default=1.0, help="activation of each muscle (default 1)")
    f.add_argument("--out", required=True, type=npz_file, help="basis file to write (.npz)")
    f.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    f.set_defaults(func=_from_face)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _from_face(args) -> int:

    refuse_existing(("--out", args.out), overwrite=args.overwrite)  # before the face is built or loaded
    if args.model:
        model = load_model(args.model)
    else:
        model = build_face(args.tets, progress=True)
    basis = basis_from_face(model, activation=args.activation, progress=True)
    basis.save(args.out)
    print(f"wrote {args.out}: {basis.n_elements} elements on {basis.n_vertices} skin vertices")
    return 0


def _load(args):

    basis = load_basis(args.basis)
    landmarks = None
    if args.landmarks:
        landmarks = read_landmarks(args.landmarks, n_vertices=basis.n_vertices)
    return basis, landmarks


def _regularization(text: str) -> str | float:
    """``--regularization``: "auto" or a ridge weight >= 0."""
    if str(text).strip().lower() == "auto":
        return "auto"
    return non_negative_float(text)


def _read(path: str, frames: tuple | None):

    take = read_mocap(path)
    if frames:
        take = take.frames(*frames)
    return take


def _analyze(args) -> int:

    basis, landmarks = _load(args)
    take = _read(args.mocap, args.frames)
    if landmarks is None:
        landmarks = default_landmarks(basis, take.marker_names)
    # aligned before --out is claimed: a take that does not fit leaves no folder behind
    layout = MarkerLayout.from_frame(basis, take.marker_names, take.positions_m[0], landmarks=landmarks)
    run = run_provenance(
        kind="basis analyze",
        model_sha256=file_sha256(args.basis),
        source={"basis": str(args.basis), "mocap": str(args.mocap), "frames": args.frames},
        options={"landmarks": args.landmarks, "exaggerate": args.exaggerate, "split": args.split},
    )
    claim_take_dir(args.out, run, overwrite=args.overwrite)  # another run's results are not replaced silently
    for stale in ("analysis.png", "contractions.npz", "contractions.csv", "marker_error_mm.csv"):
        (Path(args.out) / stale).unlink(missing_ok=True)  # a rerun with --no-plot leaves no old picture
    t0 = time.perf_counter()
    res = analyze_take(basis, take, layout=layout, upper=None if args.exaggerate else 1.0, split=args.split,
                       progress=not args.no_progress)  # fmt: skip
    seconds = time.perf_counter() - t0
    report = write_analysis(
        args.out, res, plot=not args.no_plot, frames=args.frames,
        extra={"basis": str(args.basis), "seconds": seconds, "seconds_per_frame": seconds / take.n_frames,
               "bounds": "x >= 0" if args.exaggerate else "0 <= x <= 1", "split": bool(args.split)},
    )  # fmt: skip
    if args.json:
        print(json.dumps({k: v for k, v in report.items() if not isinstance(v, list | dict)}, indent=2))
    else:
        print(f"{report['frames']} frames, {report['markers']} markers, {report['elements']} elements: marker RMS "
              f"{report['marker_rms_mm_mean']:.3f} mm (mean over frames), displacement RMS "
              f"{report['displacement_rms_mm']:.3f} mm; wrote {args.out}/")  # fmt: skip
    return 0


def _report_path(out: str | Path) -> Path:
    """PATH.report.json beside the refined basis PATH."""
    return Path(out).with_name(Path(out).name + ".report.json")


def _refine(args) -> int:

    report_path = _report_path(args.out)
    refuse_existing(("--out", args.out), ("--out's report", report_path), overwrite=args.overwrite)  # before reading
    basis, landmarks = _load(args)
    takes = [_read(p, args.frames) for p in args.train]
    reg = args.regularization
    t0 = time.perf_counter()
    refined, res, layout, info = refine_basis(
        basis, takes, landmarks=landmarks, upper=None if args.exaggerate else 1.0, split=args.split,
        regularization=reg, max_iterations=args.max_iterations, rel_tol=args.rel_tol, support_fraction=args.support,
        progress=not args.no_progress, carry_metric=args.carry_metric,
    )  # fmt: skip
    out = Path(args.out)
    refined.save(out)
    report = {
        "train": [str(p) for p in args.train],
        "frames": int(sum(t.n_frames for t in takes)),
        "markers": len(layout.marker_names),
        "elements": refined.n_elements,
        "error_rms_mm_per_iteration": res.errors_mm,
        "iterations": res.iterations,
        "carry_metric": args.carry_metric,
        "seconds": time.perf_counter() - t0,
        **info,
    }
    write_json(report_path, report)
    print(f"training RMS {res.errors_mm[0]:.3f} -> {min(res.errors_mm):.3f} mm in {res.iterations} iterations "
          f"(regularization {info['regularization']}); wrote {out} and {report_path}")  # fmt: skip
    return 0


def _info(args) -> int:

    b = load_basis(args.path)
    mags = [float(abs(s).max()) * 1e3 for s in b.shapes_m]
    print(json.dumps({"source": b.source, "vertices": b.n_vertices, "elements": b.n_elements,
                      "polygons": len(b.face_counts), "names": b.names,
                      "max_displacement_mm": dict(zip(b.names, mags, strict=False))}, indent=2))  # fmt: skip
    return 0
