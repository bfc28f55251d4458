"""``wface edit``: expression editing in activation space, re-simulated through the FEM face.

Sub-commands blend, exaggerate, layer and retime build a take of poses (``wface.takes``), solve
one quasistatic equilibrium per frame (warm-started) and write into --out: animation.usdc (skin,
bones, activations per frame), controls.npz (reloadable: edits chain with --take OUT), report.json
and a contact sheet picture.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from wface.cli.closing import print_outputs
from wface.cli.errors import UsageError
from wface.cli.render_mesh_args import add_render_mesh_arguments, render_mesh_from_args
from wface.cli.take_face import DEFAULT_TETS, face_for_take
from wface.cli.validate import face_tets, finite_float, non_negative_int, positive_float, positive_int
from wface.takes import (
    Take,
    blend,
    exaggerate,
    expression_pose,
    interpolate,
    layer,
    load_take,
    retime,
    simulate_poses,
    write_edit,
)
from wface.takes.provenance import command_provenance
from wface.takes.store import claim_take_dir, require_take_dir
from wface.warp_runtime import quiet_warp

_EPILOG = """\
Edits happen in activation space, so every frame is a face the muscles can make: activations
stay in [0, 1], the head stays rigid, the jaw stays on its joint. Exaggerating past full
activation scales the muscle's force-length curve (Sifakis et al. 2005, section 9), never the activation.

Expressions (--from, --to, --expression, --add, --neutral, --mix) are presets
(happy/smile, sad, fear, anger, surprise, disgust, neutral), inline action units or muscles
("AU12=1,AU6=0.5", "zygomaticus_major_l=0.8", "jaw_open=10"), or a preset with extras
("happy,AU26=0.5"). Takes (--take) are output directories of `wface track`, `wface demo` or
`wface edit`; use the same --model / --tets they were made with.

examples:
  wface edit blend --from smile --to surprise --frames 24 --out smile_to_surprise
  wface edit blend --mix happy:0.7 --mix surprise:0.3 --out mix
  wface edit exaggerate --expression smile --factor 1.5 --out big_smile
  wface edit exaggerate --expression smile --factor 2 --frames 12 --out ramp   # factor 0 -> 2
  wface edit exaggerate --take demo_out --factor 1.5 --out demo_x15
  wface edit layer --take demo_out --add happy --weight 0.5 --fade 5 --out demo_happier
  wface edit retime --take demo_out --speed 2 --out demo_fast
  wface edit retime --take demo_out --fps-out 60 --out demo_60fps
"""


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--model", help="face model (.npz); default: the built-in face with --tets tets")
    p.add_argument(
        "--tets",
        type=face_tets,
        default=None,
        help=f"size of the built-in face when --model is not given (default {DEFAULT_TETS})",
    )
    p.add_argument("--device", default="cpu", help="Warp device: cpu, cuda:0 or auto")
    p.add_argument("--solver", default="auto", choices=["auto", "direct", "cg"], help="linear solver")
    p.add_argument("--tol", type=positive_float, default=1e-6, help="relative residual of each solve (default 1e-6)")
    p.add_argument("--fps", type=positive_float, help="frame rate (default: the take's, else 30)")
    p.add_argument(
        "--neutral",
        default="neutral",
        help="the neutral expression edits are measured from: an expression, or first (a --take's first frame); "
        "default: the rest face",
    )
    p.add_argument("--usda", action="store_true", help="write animation.usda (text) instead of .usdc")
    p.add_argument("--mesh-only", action="store_true", help="USD with the skin mesh only (write_mesh_animation)")
    p.add_argument("--no-pictures", action="store_true", help="skip the contact sheet")
    p.add_argument("--overwrite", action="store_true", help="replace the results of another take that OUT holds")
    add_render_mesh_arguments(p)


def register(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser(
        "edit",
        help="blend, exaggerate, layer or retime expressions and takes in activation space",
        description=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    esub = e.add_subparsers(dest="edit_command", metavar="EDIT")
    e.set_defaults(func=lambda args: (e.print_help(), 2)[1])

    def add(name: str, help_: str, example: str):
        p = esub.add_parser(
            name,
            help=help_,
            description=f"{help_}\n\nexamples:\n{example}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        _common(p)
        return p

    b = add(
        "blend",
        "transition between two expressions (--from/--to) or a static convex mix (--mix)",
        "  wface edit blend --from smile --to surprise --frames 24 --out DIR\n"
        "  wface edit blend --mix happy:0.5 --mix sad:0.5 --out DIR\n",
    )
    b.add_argument("--from", dest="from_", metavar="EXPR", help="start expression")
    b.add_argument("--to", metavar="EXPR", help="end expression")
    b.add_argument(
        "--frames", type=positive_int, default=24, help="frames of the transition, ends included (default 24)"
    )
    b.add_argument("--ease", action="store_true", help="smoothstep timing instead of linear")
    b.add_argument(
        "--mix", action="append", default=[], metavar="EXPR:WEIGHT", help="one frame mixing expressions (repeatable)"
    )
    b.set_defaults(func=run_blend)

    x = add(
        "exaggerate",
        "scale an expression or a take away from neutral (factor > 1 exaggerates, < 1 tones down)",
        "  wface edit exaggerate --expression smile --factor 1.5 --out DIR\n"
        "  wface edit exaggerate --take TRACK_OUT --factor 1.5 --neutral first --out DIR\n",
    )
    src = x.add_mutually_exclusive_group(required=True)
    src.add_argument("--expression", metavar="EXPR", help="expression to exaggerate")
    src.add_argument("--take", metavar="DIR", help="tracked take (output directory of wface track / demo / edit)")
    x.add_argument("--factor", type=finite_float, required=True, help="1: unchanged, 1.5: 50%% more, 0: neutral")
    x.add_argument(
        "--scale-mode",
        default="muscle",
        choices=["muscle", "global"],
        help="where drives above 1 go: each muscle's own force-length scale (default) or one shared scale",
    )
    x.add_argument(
        "--frames",
        type=positive_int,
        default=1,
        help="with --expression: ramp the factor from 0 over N frames (default 1)",
    )
    x.set_defaults(func=run_exaggerate)

    lay = add(
        "layer",
        "add an expression on top of every frame of a take (clamped to the muscles' and joint's bounds)",
        "  wface edit layer --take TRACK_OUT --add happy --weight 0.5 --out DIR\n"
        "  wface edit layer --take TRACK_OUT --add AU4=1 --weight 0.8 --fade 10 --out DIR\n",
    )
    lay.add_argument("--take", required=True, metavar="DIR", help="tracked take")
    lay.add_argument("--add", required=True, metavar="EXPR", help="expression to add")
    lay.add_argument(
        "--weight", type=finite_float, default=1.0, help="amount of the expression (default 1; < 0 removes)"
    )
    lay.add_argument(
        "--fade", type=non_negative_int, default=0, metavar="FRAMES", help="fade the layer in and out over N frames"
    )
    lay.set_defaults(func=run_layer)

    r = add(
        "retime",
        "resample a take in time (speed and/or frame rate), interpolating poses in activation space",
        "  wface edit retime --take TRACK_OUT --speed 0.5 --out DIR     # slow motion\n"
        "  wface edit retime --take TRACK_OUT --fps-out 60 --out DIR\n",
    )
    r.add_argument("--take", required=True, metavar="DIR", help="tracked take")
    r.add_argument(
        "--speed", type=positive_float, default=1.0, help="playback speed (2: twice as fast, half the frames)"
    )
    r.add_argument("--fps-out", type=positive_float, help="output frame rate (default: the take's)")
    r.set_defaults(func=run_retime)


# ---------------------------------------------------------------------- helpers
def _model(args):

    quiet_warp()
    if getattr(args, "take", None):
        # a wrong --take fails before a face is built; a take's controls.npz stands for its directory
        args.take = str(require_take_dir(args.take))
    if args.model and args.tets is not None:
        raise UsageError("--tets does nothing with --model: it sizes the built-in face")
    return face_for_take(args)


def _refuse_neutral(args) -> None:
    """blend and retime measure nothing from a neutral: a --neutral there would be dropped without a word."""
    if args.neutral != "neutral":
        raise UsageError(f"--neutral does nothing in edit {args.edit_command}: exaggerate and layer measure from it")


def _neutral(args, model, take=None):

    if args.neutral == "first":
        if take is None:
            raise ValueError("--neutral first needs a --take")
        return take.poses[0]
    return expression_pose(model, args.neutral)


def _load(args, model):

    return load_take(args.take, model, fps=args.fps, reference=False)


def _finish(args, model, take, info: dict, labels: list[str] | None = None) -> int:
    started = time.time()

    claim_take_dir(args.out, command_provenance(f"edit {args.edit_command}", model, args), overwrite=args.overwrite)
    render_mesh = render_mesh_from_args(args, model)
    t0 = time.perf_counter()
    result = simulate_poses(model, take, device=args.device, solver=args.solver, tol=args.tol, progress=True)
    wall = time.perf_counter() - t0
    info = {"command": f"edit {args.edit_command}", "device": args.device, "solver": args.solver, **info}
    info["wall_seconds"] = wall
    report = write_edit(
        args.out,
        model,
        result,
        info=info,
        usd_name="animation.usda" if args.usda else "animation.usdc",
        mesh_only=args.mesh_only,
        pictures=not args.no_pictures,
        labels=labels,
        progress=True,
        render_mesh=render_mesh,  # in the stage and, with its own shapes, in the rig (Rig/RenderMesh)
    )
    state = "converged" if report["converged"] else "NOT all converged"
    print(
        f"{report['frames']} frames {state}, max skin displacement {max(report['skin_displacement_max_mm']):.2f} mm, "
        f"activations in [{report['activation_min']:.3g}, {report['activation_max']:.3g}]{_pressures(model, report)}, "
        "force-length scale "
        f"<= {report['force_length_scale_max']:.3g}, {report['seconds_per_frame_median']:.2f} s/frame"
    )
    print_outputs(args.out, since=started)
    return 0 if report["converged"] else 3


def _take(model, poses, fps, source):
    return Take.from_poses(list(poses), fps, list(model.muscle_names), model.jaw_joint, source=source)


def _positive_frames(n: int) -> int:
    if n < 1:
        raise ValueError(f"--frames must be >= 1, got {n}")
    return n


# ---------------------------------------------------------------------- sub-commands
def run_blend(args: argparse.Namespace) -> int:

    _refuse_neutral(args)
    fps = args.fps or 30.0
    if args.mix and (args.from_ or args.to):
        raise UsageError("give either --from/--to or --mix, not both")
    if not args.mix and not (args.from_ and args.to):
        raise UsageError("blend needs --from EXPR --to EXPR, or --mix EXPR:WEIGHT (repeatable)")
    model = _model(args)
    joint = model.jaw_joint
    if args.mix:
        specs, weights = [], []
        for item in args.mix:
            spec, sep, w = item.rpartition(":")
            if not sep or not spec:
                raise ValueError(f"--mix expects EXPR:WEIGHT, got {item!r}")
            try:
                weights.append(float(w))
            except ValueError:
                raise ValueError(f"--mix {item!r}: {w!r} is not a number") from None
            specs.append(spec)
        pose = blend(weights, [expression_pose(model, s) for s in specs], joint=joint)
        take = _take(model, [pose], fps, " + ".join(args.mix))
        return _finish(args, model, take, {"edit": "blend", "mix": dict(zip(specs, weights, strict=True))})
    n = _positive_frames(args.frames)
    a, b = expression_pose(model, args.from_), expression_pose(model, args.to)
    ts = np.linspace(0.0, 1.0, n) if n > 1 else np.array([0.0])
    if args.ease:
        ts = ts * ts * (3.0 - 2.0 * ts)
    poses = [interpolate(a, b, float(t), joint=joint) for t in ts]
    take = _take(model, poses, fps, f"{args.from_} -> {args.to}")
    info = {"edit": "interpolate", "from": args.from_, "to": args.to, "t": ts.tolist()}
    return _finish(args, model, take, info, [f"blend {t:.2f}" for t in ts])  # weights, not times


def run_exaggerate(args: argparse.Namespace) -> int:

    f = float(args.factor)
    if not math.isfinite(f) or f < 0:
        raise ValueError(f"--factor must be a finite number >= 0, got {args.factor}")
    model = _model(args)
    joint = model.jaw_joint
    info = {"edit": "exaggerate", "factor": f, "scale_mode": args.scale_mode, "neutral": args.neutral}
    if args.take:
        take = _load(args, model)
        neutral = _neutral(args, model, take)
        poses = [exaggerate(p, f, neutral, joint=joint, scale_mode=args.scale_mode) for p in take.poses]
        take = take.with_poses(poses, source=f"{take.source} x{f:g}")
        return _finish(args, model, take, info, [f"frame {k} x{f:g}" for k in range(len(poses))])
    pose = expression_pose(model, args.expression)
    neutral = _neutral(args, model)
    n = _positive_frames(args.frames)
    factors = np.linspace(0.0, f, n) if n > 1 else np.array([f])
    poses = [exaggerate(pose, float(k), neutral, joint=joint, scale_mode=args.scale_mode) for k in factors]
    take = _take(model, poses, args.fps or 30.0, f"{args.expression} x{f:g}")
    info = {**info, "expression": args.expression, "factors": factors.tolist()}
    return _finish(args, model, take, info, [f"x {k:.2f}" for k in factors])


def _envelope(n: int, fade: int) -> np.ndarray:
    if fade < 0:
        raise ValueError(f"--fade must be >= 0, got {fade}")
    env = np.ones(n)
    if fade and 2 * fade + 1 > n:  # the ramps in and out would overlap: the layer would never reach its weight
        raise ValueError(f"--fade {fade}: a fade in and out needs at least {2 * fade + 1} frames, the take has {n}")
    if fade:
        ramp = np.minimum(1.0, (np.arange(n) + 1.0) / (fade + 1.0))
        env = np.minimum(ramp, ramp[::-1])
    return env


def run_layer(args: argparse.Namespace) -> int:

    w = float(args.weight)
    if not math.isfinite(w):
        raise ValueError(f"--weight must be a finite number, got {args.weight}")
    model = _model(args)
    take = _load(args, model)
    offset = expression_pose(model, args.add)
    neutral = _neutral(args, model, take)
    env = w * _envelope(len(take), args.fade)
    out = layer(take, offset, env, neutral=neutral, joint=model.jaw_joint)
    info = {"edit": "layer", "add": args.add, "weight": w, "fade_frames": args.fade, "neutral": args.neutral}
    return _finish(args, model, out, info)


def run_retime(args: argparse.Namespace) -> int:
    _refuse_neutral(args)
    model = _model(args)
    take = _load(args, model)
    out = retime(take, speed=args.speed, fps_out=args.fps_out, joint=model.jaw_joint)
    info = {"edit": "retime", "speed": args.speed, "fps_in": take.fps, "frames_in": len(take)}
    return _finish(args, model, out, info)


def _pressures(model, report: dict) -> str:
    """The closing line's note of each pressure actuator's range, e.g. ' (intraoral_pressure in [-0.2, 0.4])'
    (signed: -1 suction to 1 puff; the muscles' range is printed before it)."""
    parts = [f"{n} in [{report[n + '_range'][0]:.3g}, {report[n + '_range'][1]:.3g}]" for n in model.pressure_actuators]
    return f" ({', '.join(parts)})" if parts else ""
