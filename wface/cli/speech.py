"""``wface speech``: play an ArtiSynth speech gesture (excitation curves) on the Badin face.

Writes into --out: lip_opening.csv (time, lip opening in mm, its signed vertical part, activations
of the driven muscles), lip_opening.png, animation.usdc (skin, markers, per-muscle activations) and report.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from wface.cli.closing import print_outputs
from wface.cli.contact_args import add_contact_arguments, contact_from_args
from wface.faces.artisynth import import_artisynth
from wface.model import load_model
from wface.speech.gestures import map_gesture_to_model, read_gesture
from wface.speech.output import write_gesture_usd, write_lip_opening
from wface.speech.playback import simulate_gesture, summarize

_EPILOG = """\
The gesture folders (speech/closure, speech/fricative, speech/approximant of the ArtiSynth face
data) hold one excitation curve per muscle and 0probes.art, which names the muscle each curve
drives and whether ArtiSynth plays it (active). Each frame is a quasistatic equilibrium
warm-started from the previous one; the lip opening is the Mouth_Up - Mouth_Down distance.

examples:
  wface speech --model ../shared/data/artisynth-face --gesture closure --out closure_out
  wface speech --model badin.npz --gesture fricative --fps 25 --out fricative_out
  wface speech --model badin.npz --gesture approximant --max-frames 5 --out quick
  wface speech --model badin.npz --gesture closure --contact lips --max-frames 6 --out closure_contact
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "speech",
        help="play an ArtiSynth speech gesture on the Badin face (lip opening, USD)",
        description=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--model",
        required=True,
        help="the Badin face: a saved model (.npz) or the artisynth-face data folder (imported)",
    )
    p.add_argument(
        "--gesture", required=True, help="closure, fricative, approximant, or a folder with 0probes.art and curve files"
    )
    p.add_argument(
        "--speech-dir",
        help="folder holding the gesture folders (default: MODEL_DATA/speech, or ../shared/data/artisynth-face/speech)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--fps", type=float, default=100.0, help="frame rate (default 100, the original's output rate)")
    p.add_argument("--max-frames", type=int, help="subsample to at most this many frames (first and last kept)")
    p.add_argument("--tol", type=float, default=1e-4, help="relative force residual of each solve (default 1e-4)")
    p.add_argument("--all-probes", action="store_true", help="also play probes marked active=false")
    p.add_argument(
        "--lower-oom",
        choices=["whole", "skip"],
        default="whole",
        help="what the OOMl exciter drives: the whole OOM (default, approximation) or nothing",
    )
    add_contact_arguments(p, smoothing_mm=0.1, freeze_below=1.0, obstacles=False, where="every frame's solve")
    p.add_argument("--max-iterations", type=int, default=40, help="Newton iteration cap per frame (default 40)")
    p.add_argument("--no-usd", action="store_true", help="skip animation.usdc")
    p.set_defaults(func=run_speech)


def _load_model(path: Path):
    if path.is_dir():
        return import_artisynth(path, progress=True)

    return load_model(path)


def _gesture_dir(args) -> Path:
    g = Path(args.gesture)
    if (g / "0probes.art").exists():
        return g
    candidates = []
    if args.speech_dir:
        candidates.append(Path(args.speech_dir))
    model = Path(args.model)
    if model.is_dir():
        candidates.append(model / "speech")
    candidates.append(Path(__file__).resolve().parents[3] / "shared" / "data" / "artisynth-face" / "speech")
    candidates.append(Path.cwd().parent / "shared" / "data" / "artisynth-face" / "speech")
    for c in candidates:
        if (c / args.gesture / "0probes.art").exists():
            return c / args.gesture
    raise FileNotFoundError(
        f"gesture {args.gesture!r}: no 0probes.art under {[str(c) for c in candidates]} (use --speech-dir)"
    )


def run_speech(args: argparse.Namespace) -> int:
    started = time.time()

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    model = _load_model(Path(args.model))
    gesture = read_gesture(_gesture_dir(args), include_inactive=args.all_probes)
    mapping = map_gesture_to_model(gesture, model, lower_oom=args.lower_oom)
    t_load = time.perf_counter() - t_start
    contact = contact_from_args(args, model)
    result = simulate_gesture(
        model,
        gesture,
        fps=args.fps,
        max_frames=args.max_frames,
        mapping=mapping,
        tol=args.tol,
        progress=True,
        contact=contact,
        max_iterations=args.max_iterations,
    )
    csv, png = write_lip_opening(out, result, model)
    files = [csv.name, png.name]
    if not args.no_usd:
        F = len(result.times_s)
        fps_out = (
            args.fps
            if args.max_frames is None
            else max(1.0, (F - 1) / max(result.times_s[-1] - result.times_s[0], 1e-9))
        )
        write_gesture_usd(
            out / "animation.usdc", result, model, fps=fps_out, source=str(gesture.directory), progress=True
        )
        files.append("animation.usdc")
    report = summarize(result)
    report.update(
        {
            "model": str(args.model),
            "nodes": int(model.n_nodes),
            "tets": int(len(model.tets)),
            "gesture_dir": str(gesture.directory),
            "probes": [
                {"name": p.name, "drives": p.target, "active": p.active, "file": p.attached_file}
                for p in gesture.probes
            ],
            "played_probes": sorted(gesture.curves),
            "unmapped_probes": mapping.unmapped,
            "interpolation": {k: c.order for k, c in gesture.curves.items()},
            "tol": args.tol,
            "contact_stiffness_n_per_m": None if contact is None else contact.stiffness_n_per_m,
            "contact_smoothing_m": None if contact is None else contact.smoothing_m,
            "setup_seconds": t_load,
            "wall_seconds": time.perf_counter() - t_start,
            "lip_opening_definition": "distance between the Mouth_Up and Mouth_Down skin markers (mm)",
            "reference_lip_opening_area": None
            if gesture.reference_lip_area is None
            else {
                "what": "the original ArtiSynth (dynamic) simulation's lipOpeningArea output, as recorded",
                "times_s": gesture.reference_lip_area[:, 0].tolist(),
                "area": gesture.reference_lip_area[:, 1].tolist(),
                "first": float(gesture.reference_lip_area[0, 1]),
                "last": float(gesture.reference_lip_area[-1, 1]),
            },
            "files": files,
        }
    )
    (out / "report.json").write_text(json.dumps(report, indent=2))
    lo = report["lip_opening_mm"]
    print(
        f"{result.gesture}: lip opening {lo['first']:.2f} -> {lo['last']:.2f} mm (min {lo['min']:.2f}, "
        f"max {lo['max']:.2f}) over {report['frames']} frames, {report['seconds_total']:.1f} s of solves"
    )
    if report.get("lip_gap_mm_min") is not None:
        print(
            f"lip gap min {report['lip_gap_mm_min']:+.3f} mm, max penetration "
            f"{report['max_penetration_mm_max']:.3f} mm (contact: {args.contact or 'none'})"
        )
    print_outputs(out, since=started)
    return 0
