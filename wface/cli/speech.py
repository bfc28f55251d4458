"""``wface speech``: play an ArtiSynth speech gesture (excitation curves) on the Badin face.

Writes into --out: lip_opening.csv (time, lip opening area in mm^2, the Mouth_Up - Mouth_Down
distance, the lip gap, activations of the driven muscles), lip_opening.png, aperture_first.png and
aperture_last.png (the aperture measure), animation.usdc (skin, markers, per-muscle activations, the
area as metadata and time samples) and report.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from pathlib import Path

from wface.cli.closing import print_outputs
from wface.cli.contact_args import add_contact_arguments, contact_from_args
from wface.cli.errors import UsageError
from wface.cli.validate import non_negative_float, options_given, positive_float, positive_int
from wface.faces.artisynth import import_artisynth
from wface.files import write_json
from wface.mesh.surface import boundary_faces
from wface.model import BULK_POTENTIALS, load_model
from wface.speech.aperture import ApertureView
from wface.speech.artisynth_demo import lip_opening_demo_model, ooml_exciter_tets, without_idle_fibres
from wface.speech.dynamic import GestureDynamics
from wface.speech.gestures import LOWER_OOM_CHOICES, map_gesture_to_model, read_gesture, with_lower_oom
from wface.speech.output import write_aperture_pictures, write_gesture_usd, write_lip_opening, write_states
from wface.speech.playback import compare_with_reference, lip_area_points, simulate_gesture, summarize
from wface.takes.provenance import command_provenance
from wface.takes.store import claim_take_dir

_EPILOG = """\
The gesture folders (speech/closure, speech/fricative, speech/approximant of the ArtiSynth face
data) hold one excitation curve per muscle and 0probes.art, which names the muscle each curve
drives and whether ArtiSynth plays it (active). Each frame is a quasistatic equilibrium
warm-started from the previous one (default), or with --dynamic the curves drive the implicit
dynamic FEM (inertia; ArtiSynth's backward Euler, 5 ms steps, Rayleigh damping alpha = 19 1/s,
beta = 0.055 s, gravity). The lip opening area is the mouth aperture in mm^2 seen in ArtiSynth's
orthographic camera against its green plane at Badin x = 0.1 m (--area-view frontal: straight from
the front); the Mouth_Up - Mouth_Down distance is reported too. --setup artisynth sets the face up
as ArtiSynth's BadinFaceDemoLipOpening (its ten OOP rings, muscle stress 1e5 Pa, inner surface fixed,
its flesh law and deviatoric fibre stress; --idle-muscles off: the muscles the gesture never drives carry
no fibres, as there; --muscle-curves artisynth: BlemkerMuscle's curves on OOP and GenericMuscle's, with no
force-length curve and no passive stress, on the others, as there; --muscle-elements artisynth: every other
muscle on the demo's own whole hexes; --lower-oom exciter: the exciter OOMl on exactly its 232 target
hexes, the lower lip's part of OOM; --ring-directions delaunay: the OOP rings' fibre directions blended as
ArtiSynth blends them; --bulk-potential quadratic: the flesh's bulk energy kappa/2 (J - 1)^2, ArtiSynth's,
where wface's is kappa/2 (ln J)^2); --setup artisynth-exact: each of these but --idle-muscles at the
demo's choice, and --exact-damping with --dynamic, an option given still winning. Writes report.json,
lip_opening.csv and .png, the aperture pictures of the first and last frames, states.npz (every frame's
node positions, markers and activations: np.load) and animation.usdc.

examples:
  wface speech --model ../shared/data/artisynth-face --gesture closure --out closure_out
  wface speech --model badin.npz --gesture fricative --fps 25 --out fricative_out
  wface speech --model badin.npz --gesture approximant --max-frames 5 --out quick
  wface speech --model badin.npz --gesture closure --contact lips --max-frames 6 --out closure_contact
  wface speech --model badin.npz --gesture approximant --setup artisynth --dynamic --contact lips --out dyn
  wface speech --model badin.npz --gesture approximant --setup artisynth --contact lips,skull \\
      --contact-inside-at-rest push --out skull   # ArtiSynth's lip-skull contact (jaw and maxilla)
  wface speech --model badin.npz --gesture approximant --setup artisynth --idle-muscles off --dynamic \\
      --exact-damping --contact lips,skull --contact-inside-at-rest push --out as_demo   # nearest ArtiSynth's demo
  wface speech --model badin.npz --gesture closure --setup artisynth --muscle-curves artisynth --dynamic \\
      --exact-damping --contact lips,skull --contact-inside-at-rest push --out closure_as   # its muscle laws
  wface speech --model badin.npz --gesture fricative --setup artisynth --muscle-curves artisynth \\
      --muscle-elements artisynth --lower-oom exciter --dynamic --exact-damping --contact lips,skull \\
      --contact-inside-at-rest push --out fricative_as   # ArtiSynth's muscles, elements and exciter
  wface speech --model badin.npz --gesture fricative --setup artisynth --muscle-curves artisynth \\
      --muscle-elements artisynth --lower-oom exciter --bulk-potential quadratic --dynamic --exact-damping \\
      --contact lips,skull --contact-inside-at-rest push --out fricative_quad   # and its bulk potential
  wface speech --model badin.npz --gesture approximant --setup artisynth-exact --dynamic \\
      --contact lips,skull --contact-inside-at-rest hold --out as_exact   # every one of the demo's choices
"""


# the options that act with --dynamic only
_DYNAMIC_ONLY = ("scheme", "max_step_ms", "damping_alpha", "damping_beta", "exact_damping", "no_gravity")
# the options that set up ArtiSynth's demo, with --setup artisynth only (the order they are checked in)
_SETUP_ONLY = ("idle_muscles", "muscle_curves", "muscle_elements", "bulk_potential", "ring_directions")
_SETUPS = ("import", "artisynth", "artisynth-exact")
# The options --setup artisynth-exact changes, each with its default and the demo's own choice. They parse to
# None when not given, so that an option given with its default value still wins over the preset. Not
# --idle-muscles: with the demo's curves the idle muscles but OOP carry no passive stress anyway, and OOP, idle
# in the closure and the fricative, keeps BlemkerMuscle's passive curve in the demo.
_PRESET = {
    "muscle_curves": ("wface", "artisynth"),
    "muscle_elements": ("import", "artisynth"),
    "ring_directions": ("nearest", "delaunay"),
    "bulk_potential": ("log", "quadratic"),
    "lower_oom": ("whole", "exciter"),
    "exact_damping": (False, True),  # with --dynamic
}


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
        help="folder holding the gesture folders, the only one looked in when given "
        "(default: MODEL_DATA/speech, or ../shared/data/artisynth-face/speech)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--overwrite", action="store_true", help="replace the results of another run that OUT holds")
    p.add_argument(
        "--fps", type=positive_float, default=100.0, help="frame rate (default 100, the original's output rate)"
    )
    p.add_argument(
        "--max-frames", type=positive_int, help="subsample to at most this many frames (first and last kept)"
    )
    p.add_argument(
        "--tol", type=positive_float, default=1e-4, help="relative force residual of each solve (default 1e-4)"
    )
    p.add_argument("--all-probes", action="store_true", help="also play probes marked active=false")
    p.add_argument(
        "--lower-oom",
        choices=list(LOWER_OOM_CHOICES),
        help="what the OOMl exciter drives: the whole OOM (default, approximation; exciter with --setup "
        "artisynth-exact), its lower lip's part (the OOM "
        "fibre entries nearer the lower lip's surface become muscles OOMl_l and OOMl_r), exactly the exciter's "
        "own targets (ArtiSynth's OOMl.art: 232 of OOM's hexes; with --setup artisynth) or nothing",
    )
    add_contact_arguments(
        p, smoothing_mm=0.1, freeze_below=None, obstacles=False, where="every frame's solve", lip_surface="smooth"
    )
    _add_setup_arguments(p)
    p.add_argument("--dynamic", action="store_true", help="play through the implicit dynamic FEM (inertia)")
    p.add_argument(
        "--scheme", choices=["be", "midpoint"], default="be", help="dynamic scheme (default be, ArtiSynth's)"
    )
    p.add_argument(
        "--max-step-ms", type=positive_float, default=5.0, help="longest dynamic time step in ms (default 5)"
    )
    p.add_argument(
        "--damping-alpha", type=non_negative_float, default=19.0, help="mass damping alpha in 1/s (default 19)"
    )
    p.add_argument(
        "--damping-beta", type=non_negative_float, default=0.055, help="stiffness damping beta in s (default 0.055)"
    )
    p.add_argument(
        "--exact-damping",
        action=argparse.BooleanOptionalAction,
        help="stiffness damping with the exact tangent, as ArtiSynth's (default: the projected one; the exact "
        "one with --setup artisynth-exact)",
    )
    p.add_argument("--no-gravity", action="store_true", help="dynamic playback without gravity")
    p.add_argument(
        "--area-view",
        choices=["artisynth", "frontal"],
        default="artisynth",
        help="lip opening area camera: ArtiSynth's (20 deg upward, default) or straight from the front",
    )
    p.add_argument(
        "--area-resolution-mm",
        type=positive_float,
        default=0.05,
        help="scanline spacing of the area measure in mm (default 0.05)",
    )
    p.add_argument(
        "--max-iterations", type=positive_int, default=40, help="Newton iteration cap per frame (default 40)"
    )
    p.add_argument("--no-usd", action="store_true", help="skip animation.usdc")
    p.add_argument(
        "--no-rig",
        action="store_true",
        help="animation.usdc without the UsdSkel rig (the rig costs one solve per muscle, ~20 s each on Badin)",
    )
    p.set_defaults(func=run_speech, dynamic_option_defaults={k: p.get_default(k) for k in _DYNAMIC_ONLY})


def _add_setup_arguments(p: argparse.ArgumentParser) -> None:
    """--setup and the options that set up ArtiSynth's demo with it (usage errors without it)."""
    p.add_argument(
        "--setup",
        choices=list(_SETUPS),
        default="import",
        help="the face as imported (default) or as ArtiSynth's BadinFaceDemoLipOpening sets it up (artisynth); "
        "artisynth-exact: the same with every option below at the demo's own choice (--muscle-curves artisynth "
        "--muscle-elements artisynth --ring-directions delaunay --bulk-potential quadratic --lower-oom exciter, "
        "and --exact-damping with --dynamic); an option given still wins",
    )
    p.add_argument(
        "--data",
        help="the artisynth-face data folder for --setup artisynth, the only one looked in when given "
        "(default: --model's folder or ../shared/data/artisynth-face)",
    )
    p.add_argument(
        "--idle-muscles",
        choices=["passive", "off"],
        default="passive",
        help="with --setup artisynth, the muscles the gesture never drives: wface's passive fibres (default) or "
        "none, as ArtiSynth's demo (its GenericMuscle's passive stress is 0.05 Pa)",
    )
    p.add_argument(
        "--muscle-curves",
        choices=["wface", "artisynth"],
        help="with --setup artisynth, the muscles' force-length and passive curves: wface's on every muscle "
        "(default) or the demo's own, BlemkerMuscle's on OOP and GenericMuscle's (no force-length, no passive "
        "stress) on the others",
    )
    p.add_argument(
        "--muscle-elements",
        choices=["import", "artisynth"],
        help="with --setup artisynth, every muscle but OOP as the import embeds it (default) or as the demo "
        "has it: the whole hexes whose centres lie within 6 mm of its fibres",
    )
    p.add_argument(
        "--ring-directions",
        choices=["nearest", "delaunay"],
        help="with --setup artisynth, the OOP rings' fibre directions: the fibre ring's nearest segment (default) or "
        "ArtiSynth's own blend of the segments around each ring hex (its DelaunayInterpolator)",
    )
    p.add_argument(
        "--bulk-potential",
        choices=list(BULK_POTENTIALS),
        help="with --setup artisynth, the flesh's bulk energy: wface's kappa/2 (ln J)^2 (default) or the demo's "
        "own kappa/2 (J - 1)^2 (ArtiSynth's QUADRATIC); the two part as the volume changes",
    )
    p.set_defaults(setup_option_defaults={k: p.get_default(k) for k in _SETUP_ONLY})


def _load_model(path: Path):
    if path.is_dir():
        return import_artisynth(path, progress=True)

    return load_model(path)


def _gesture_dir(args) -> Path:
    g = Path(args.gesture)
    if (g / "0probes.art").exists():
        return g
    if args.speech_dir:  # the folder given, and no other (it fell through to the shared data before)
        given = Path(args.speech_dir)
        if (given / args.gesture / "0probes.art").exists():
            return given / args.gesture
        there = sorted(d.name for d in given.glob("*") if (d / "0probes.art").exists()) if given.is_dir() else []
        raise FileNotFoundError(
            f"--speech-dir {given}: no {args.gesture}/0probes.art there "
            f"({'its gestures: ' + ', '.join(there) if there else 'it holds no gesture folder'})"
        )
    candidates = []
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


def _data_dir(args) -> Path:
    if args.data:  # the folder given, and no other
        if not (Path(args.data) / "badinface_oop_csa_midsagittal.elem").exists():
            raise FileNotFoundError(
                f"--data {args.data}: not the artisynth-face data folder (no badinface_oop_csa_midsagittal.elem)"
            )
        return Path(args.data)
    candidates = []
    if Path(args.model).is_dir():
        candidates.append(Path(args.model))
    candidates += [
        Path(__file__).resolve().parents[3] / "shared" / "data" / "artisynth-face",
        Path.cwd().parent / "shared" / "data" / "artisynth-face",
    ]
    for c in candidates:
        if (c / "badinface_oop_csa_midsagittal.elem").exists():
            return c
    raise FileNotFoundError(
        f"--setup artisynth: no artisynth-face data folder among {[str(c) for c in candidates]} (use --data)"
    )


def _check_model(args, model, gesture, mapping) -> None:
    """Refuse a model the gesture cannot be played on, naming what it lacks."""
    if not any(mapping.muscles.values()):
        wanted = ", ".join(sorted({p.target for p in gesture.probes})) or "none"
        raise ValueError(
            f"{args.model}: the model has none of the muscles the gesture drives ({wanted}); it has "
            f"{', '.join(model.muscle_names[:8])}...: play speech on the Badin face (wface model import artisynth)"
        )
    for probe in mapping.unmapped:  # played by ArtiSynth, not here: say so, not only in report.json
        why = next((n for n in mapping.notes if probe in n or "OOMl" in n), "the model lacks its muscle")
        warnings.warn(f"probe {probe} is not played: {why}", stacklevel=2)
    lacking = [n for n in ("Mouth_Up", "Mouth_Down") if n not in model.marker_names]
    if lacking:
        raise ValueError(
            f"{args.model}: the lip opening is measured between markers the model lacks: {', '.join(lacking)}"
        )


def _dynamics(args) -> GestureDynamics | None:
    """The dynamic playback's settings (``--dynamic``), or None for quasistatic."""
    if not args.dynamic:
        return None
    return GestureDynamics(
        scheme=args.scheme,
        max_step_s=args.max_step_ms * 1e-3,
        alpha_per_s=args.damping_alpha,
        beta_s=args.damping_beta,
        exact_damping=args.exact_damping,
        gravity_m_s2=None if args.no_gravity else (0.0, -9.8, 0.0),
    )


def _write_pictures_and_usd(args, out: Path, model, result, view, gesture) -> list[str]:
    """The aperture pictures of the first and last frames and animation.usdc; returns their names."""
    occluders, lips = boundary_faces(model.tets), lip_area_points(model)
    frames = {"first": 0, "last": len(result.times_s) - 1}
    xs = [result.node_positions_m[f] for f in frames.values()]
    files = [f"aperture_{tag}.png" for tag in frames]
    write_aperture_pictures(  # one window for both: they are there to be compared
        [out / name for name in files],
        xs,
        occluders,
        view,
        resolution_m=args.area_resolution_mm * 1e-3,
        near_points_m=[None if lips is None else x[lips] for x in xs],
        titles=[f"{result.gesture} t = {result.times_s[f]:.3f} s ({result.mode})" for f in frames.values()],
    )
    if not args.no_usd:
        F = len(result.times_s)
        fps_out = (
            args.fps
            if args.max_frames is None
            else max(1.0, (F - 1) / max(result.times_s[-1] - result.times_s[0], 1e-9))
        )
        write_gesture_usd(
            out / "animation.usdc",
            result,
            model,
            fps=fps_out,
            source=str(gesture.directory),
            progress=True,
            rig=not args.no_rig and "active",
        )
        files.append("animation.usdc")
    return files


def _check_options(args) -> None:
    """Options that would do nothing are usage errors (they were dropped silently). Then the preset's options
    not given take their default or, with --setup artisynth-exact, the demo's choice (``_PRESET``), and
    artisynth-exact is --setup artisynth from there on (``args.setup_preset`` keeps the name)."""
    given = options_given(args, args.dynamic_option_defaults)
    if given and not args.dynamic:
        raise UsageError(f"{', '.join(given)} set(s) the dynamic playback: add --dynamic, or leave it out")
    for option in options_given(args, args.setup_option_defaults):
        if args.setup == "import":
            raise UsageError(f"{option} sets up ArtiSynth's demo: add --setup artisynth, or leave it out")
    exact = args.setup == "artisynth-exact"
    for key, (default, demo) in _PRESET.items():
        if getattr(args, key) is None:
            setattr(args, key, demo if exact and (key != "exact_damping" or args.dynamic) else default)
    args.setup_preset, args.setup = args.setup, "artisynth" if exact else args.setup
    if args.lower_oom == "exciter" and args.setup != "artisynth":
        raise UsageError(
            "--lower-oom exciter takes the targets of ArtiSynth's demo on its hexes: add --setup artisynth, or use "
            "--lower-oom lower"
        )
    if args.data and args.setup != "artisynth":
        raise UsageError(
            "--data is the artisynth-face folder of --setup artisynth: add --setup artisynth, or leave it out"
        )


def run_speech(args: argparse.Namespace) -> int:
    started = time.time()
    _check_options(args)

    out = Path(args.out)
    t_start = time.perf_counter()
    model = _load_model(Path(args.model))
    if args.setup == "artisynth":
        curves = "artisynth" if args.muscle_curves == "artisynth" else "law"
        model = lip_opening_demo_model(
            model,
            _data_dir(args),
            muscle_curves=curves,
            muscle_elements=args.muscle_elements,
            bulk_potential=args.bulk_potential,
            ring_directions=args.ring_directions,
        )
    gesture = read_gesture(_gesture_dir(args), include_inactive=args.all_probes)
    if args.lower_oom in ("lower", "exciter"):
        targets = ooml_exciter_tets(model, _data_dir(args)) if args.lower_oom == "exciter" else None
        model = with_lower_oom(model, targets)
    mapping = map_gesture_to_model(gesture, model, lower_oom=args.lower_oom)
    _check_model(args, model, gesture, mapping)
    if args.idle_muscles == "off":
        model = without_idle_fibres(model, mapping.driven_muscles(gesture, model))
    contact = contact_from_args(args, model)  # a refused contact leaves --out as it was
    claim_take_dir(out, command_provenance("speech", model, args), overwrite=args.overwrite)
    t_load = time.perf_counter() - t_start
    dynamics = _dynamics(args)
    view = ApertureView.for_model(model, frontal=args.area_view == "frontal")
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
        dynamics=dynamics,
        view=view,
        area_resolution_m=args.area_resolution_mm * 1e-3,
    )
    csv, png = write_lip_opening(out, result, model, reference=gesture.reference_lip_area)
    files = [csv.name, png.name, write_states(out / "states.npz", result, model).name]
    files += _write_pictures_and_usd(args, out, model, result, view, gesture)
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
            "played_probes": sorted(p for p in gesture.curves if p not in mapping.unmapped),
            "unmapped_probes": mapping.unmapped,
            "interpolation": {k: c.order for k, c in gesture.curves.items()},
            "tol": args.tol,
            "setup": args.setup_preset,
            # the setup's options as played (those --setup artisynth-exact sets, and --idle-muscles)
            "setup_options": {k: getattr(args, k) for k in ("idle_muscles", *_PRESET)},
            "idle_muscles_without_fibres": model.metadata.get("idle_muscles_without_fibres", []),
            "material": dataclasses.asdict(model.material),  # the flesh law and fibre stress played
            "lip_surface": args.lip_surface if contact is not None else None,
            "reference_comparison": compare_with_reference(result, gesture.reference_lip_area),
            "contact_stiffness_n_per_m": None if contact is None else contact.stiffness_n_per_m,
            "contact_smoothing_m": None if contact is None else contact.smoothing_m,
            # flesh inside a bone or teeth mesh at rest: {mesh: nodes} left out (ignore) or held at their rest
            # depth (hold); both {} when pushed out
            "contact_inside_at_rest": None if contact is None else contact.inside_at_rest,
            "contact_ignored_at_rest": None if contact is None else contact.ignored_at_rest,
            "contact_held_at_rest": None if contact is None else contact.held_at_rest,
            "setup_seconds": t_load,
            "wall_seconds": time.perf_counter() - t_start,
            "lip_opening_definition": "distance between the Mouth_Up and Mouth_Down skin markers (mm)",
            "lip_opening_area_definition": "mouth aperture seen in an orthographic view against a window behind "
            "the face, mm^2 in the image plane (wface.speech.aperture); occluders: the face's boundary "
            "triangles; only apertures near the lip surfaces",
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
    write_json(out / "report.json", report)
    lo, ar = report["lip_opening_mm"], report["lip_opening_area_summary_mm2"]
    print(
        f"{result.gesture} ({result.mode}): lip opening area {ar['first']:.2f} -> {ar['last']:.2f} mm^2 "
        f"(min {ar['min']:.2f}, max {ar['max']:.2f}); Mouth_Up - Mouth_Down {lo['first']:.2f} -> {lo['last']:.2f} mm; "
        f"{report['frames']} frames, {report['seconds_total']:.1f} s of solves"
    )
    ref = report["reference_comparison"]
    if ref is not None:
        o, w = ref["original"], ref["wface"]
        print(
            f"original (recorded): settled {o['settled_mm2']:.1f} -> final {o['final_mm2']:.1f} mm^2; wface: "
            f"{w['settled_mm2']:.1f} -> {w['final_mm2']:.1f} mm^2; RMS difference {ref['rms_mm2']:.1f} mm^2"
        )
    if report.get("lip_gap_mm_min") is not None:
        print(
            f"lip gap min {report['lip_gap_mm_min']:+.3f} mm, max penetration "
            f"{report['max_penetration_mm_max']:.3f} mm (contact: {args.contact or 'none'})"
        )
    print_outputs(out, since=started)
    return 0
