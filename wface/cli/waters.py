"""``wface waters``: pose a face mesh with Waters vector muscles from a FACS expression or action units."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from wface.cli.closing import print_outputs
from wface.cli.validate import UsageError, face_tets, positive_int, probability
from wface.faces.builtin import build_face
from wface.facs import ACTION_UNITS, EXPRESSIONS
from wface.files import write_json
from wface.io.usd import write_surface_mesh
from wface.mesh.meshfile import read_surface_mesh
from wface.waters.expressions import expression_pose, interpolate_poses, parse_au_assignments
from wface.waters.face_model import face_model_rig
from wface.waters.pipeline import layout_for_mesh, pose_mesh
from wface.waters.rig import WatersRig

_HEAD_SIZE_M = (0.05, 1.0)  # a face or head mesh's largest extent, metres


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "waters",
        help="deform a face mesh with Waters (1987) vector muscles: FACS expressions and action units",
        description="Deform a surface mesh with Waters vector muscles. Writes DIR/<name>.obj, .usda, .png "
        "(shaded), _displacement.png and .json (contractions, jaw angle, displacement). Expressions: "
        + ", ".join(EXPRESSIONS)
        + ". Action units: "
        + ", ".join(ACTION_UNITS)
        + " (append L or R for one side, e.g. AU12L=1).",
    )
    p.add_argument(
        "--mesh",
        required=True,
        help="surface mesh (OBJ, or any format meshio reads), or 'builtin' for the built-in face's skin "
        "(the ICT layout fitted to its markers, jaw weights from its bones)",
    )
    p.add_argument(
        "--tets",
        type=face_tets,
        default=None,
        help="resolution of the built-in face (with --mesh builtin; default 20000)",
    )
    p.add_argument("--expression", default="neutral", help="expression preset (default: neutral)")
    p.add_argument("--intensity", type=probability, default=1.0, help="scale of the preset's action units, 0..1")
    p.add_argument(
        "--au",
        action="append",
        metavar="AU=VALUE",
        help="set an action unit's intensity in place of the preset's, e.g. --au AU26=0.5, one side with L / R "
        "(--au AU12R=0 keeps a smile on the left only; repeatable)",
    )
    p.add_argument("--layout", help="muscle layout JSON, or a packaged name: ict (default), builtin")
    p.add_argument("--landmarks", help="JSON {AnimFace marker name: vertex index} on --mesh: fit the layout to it")
    p.add_argument("--units", default="auto", choices=("auto", "m", "cm", "mm"), help="length unit of --mesh")
    p.add_argument("--size", type=positive_int, default=600, help="render size in pixels")
    p.add_argument("--no-render", action="store_true", help="skip the PNG renders")
    p.add_argument("--usdc", action="store_true", help="write binary .usdc instead of text .usda")
    p.add_argument("--blend-to", metavar="EXPRESSION", help="also write an animation from --expression to this preset")
    p.add_argument(
        "--frames", type=positive_int, default=None, help="frames of the --blend-to animation (24 fps; default 24)"
    )
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=_run)


def _refuse_ignored_options(args: argparse.Namespace) -> None:
    """Options that would do nothing here are errors, not silently dropped."""
    builtin = args.mesh == "builtin"
    ignored = [
        ("--landmarks", builtin and args.landmarks, "the built-in face has its own layout"),
        ("--units", builtin and args.units != "auto", "the built-in face is in metres"),
        ("--tets", not builtin and args.tets is not None, "it sizes the built-in face (--mesh builtin)"),
        ("--frames", not args.blend_to and args.frames is not None, "it counts the --blend-to animation's frames"),
    ]
    for flag, hit, why in ignored:
        if hit:
            raise UsageError(f"{flag} does nothing here: {why}")


def _run(args: argparse.Namespace) -> int:

    # bad names fail before any work
    extra = parse_au_assignments(args.au)
    expression_pose(args.expression, intensity=args.intensity, extra_action_units=extra)
    _refuse_ignored_options(args)
    args.frames = 24 if args.frames is None else args.frames
    args.tets = 20000 if args.tets is None else args.tets
    if args.blend_to:
        expression_pose(args.blend_to)
        if args.frames < 2:
            raise ValueError(f"--frames must be >= 2, got {args.frames}")
    if args.mesh == "builtin":
        rig, mesh, _ = face_model_rig(build_face(args.tets))
    else:
        mesh = read_surface_mesh(args.mesh, units=args.units)
        size_m = float(np.ptp(mesh.vertices_m, axis=0).max())
        if not _HEAD_SIZE_M[0] <= size_m <= _HEAD_SIZE_M[1]:  # the layouts' muscles are in metres
            raise ValueError(
                f"{args.mesh} is {size_m:.3g} m across read at {mesh.meters_per_unit:g} m per unit, where a head is "
                f"{_HEAD_SIZE_M[0]:g} to {_HEAD_SIZE_M[1]:g} m: check --units"
            )
        lay = layout_for_mesh(mesh, layout=args.layout, landmarks=args.landmarks)
        rig = WatersRig(lay, mesh.vertices_m, triangles=mesh.triangles())
    summary = pose_mesh(
        mesh,
        args.out,
        expression=args.expression,
        action_units=extra,
        intensity=args.intensity,
        render=not args.no_render,
        size=args.size,
        usd_suffix=".usdc" if args.usdc else ".usda",
        rig=rig,
    )
    obj = Path(summary["files"]["obj"])
    if args.blend_to:
        summary["files"]["animation"] = str(_blend(args, summary, rig, mesh))
        write_json(obj.with_suffix(".json"), summary)  # the summary names the blend too
    print(
        f"{obj.stem}: jaw open {summary['jaw_opening_deg']:.1f} deg, largest skin displacement "
        f"{summary['max_displacement_mm']:.2f} mm{_cap_note(summary)}"
    )
    written = {Path(p) for p in summary["files"].values()} | {obj.with_suffix(".json")}  # pose_mesh's summary
    print_outputs(args.out, sorted(written, key=lambda p: p.name))
    return 0


def _cap_note(summary: dict) -> str:
    """What the largest displacement owes to the layout's cap, when muscles reached it ("" otherwise)."""
    n, cap = summary["vertices_at_cap"], summary["displacement_cap_mm"]
    if not n:
        return ""
    at = (
        "the layout's cap"
        if abs(summary["max_displacement_mm"] - cap) < 1e-6
        else f"the layout caps muscles at {cap:g} mm"
    )
    return f" ({at}; {n} vertices at it)"


def _blend(args: argparse.Namespace, summary: dict, rig, mesh):
    """Write OUT/<expression>_to_<blend_to>.usda (.usdc with --usdc): a linear blend in action-unit space."""

    start = summary["action_units"]
    frames = []
    for k in range(args.frames):
        pose = interpolate_poses(start, args.blend_to, k / (args.frames - 1), muscle_names=rig.muscle_names)
        frames.append(rig.deform(pose.contractions, jaw_opening_deg=pose.jaw_opening_deg))
    path = Path(args.out) / f"{args.expression}_to_{args.blend_to}{'.usdc' if args.usdc else '.usda'}"
    return write_surface_mesh(path, mesh, frames_m=np.stack(frames), fps=24.0, name="WatersFace")
