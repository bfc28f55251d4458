"""``wface waters``: pose a face mesh with Waters vector muscles from a FACS expression or action units."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from wface.cli.closing import print_outputs
from wface.cli.validate import UsageError, face_tets, positive_int, probability
from wface.faces.builtin import build_face
from wface.facs import ACTION_UNITS, EXPRESSIONS
from wface.files import file_sha256, write_json
from wface.io.usd import write_surface_mesh
from wface.mesh.meshfile import read_surface_mesh
from wface.takes.provenance import run_provenance
from wface.takes.store import PROVENANCE, TAKE_FILES, TakeDirectoryError, claim_take_dir, recorded_run
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
        + " (append L or R for one side, e.g. AU12L=1). DIR is claimed (provenance.json): another run's results "
        "there are refused unless --overwrite; an input file is never written over.",
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
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the results of another run that OUT holds (an input file is never written over)",
    )
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


def _stem(args: argparse.Namespace, extra: dict) -> str:
    """The name of this run's files: the expression, with the --au action units it sets."""
    return args.expression if not extra else f"{args.expression}+" + "+".join(sorted(extra))


def _outputs(args: argparse.Namespace, stem: str) -> list[Path]:
    """Every file this run writes into --out."""
    usd = ".usdc" if args.usdc else ".usda"
    names = [f"{stem}.obj", f"{stem}{usd}", f"{stem}.json"]
    names += [] if args.no_render else [f"{stem}.png", f"{stem}_displacement.png"]
    names += [f"{args.expression}_to_{args.blend_to}{usd}"] if args.blend_to else []
    return [Path(args.out) / n for n in names]


def _inputs(args: argparse.Namespace) -> list[tuple[str, Path]]:
    """The input files of the run: (option, path), packaged layout names and the built-in face left out."""
    given = [("--mesh", args.mesh if args.mesh != "builtin" else None), ("--layout", args.layout),
             ("--landmarks", args.landmarks)]  # fmt: skip
    return [(flag, Path(path)) for flag, path in given if path and Path(path).is_file()]


def _refuse_writing_over_inputs(args: argparse.Namespace, outputs: list[Path]) -> None:
    """An input file is never replaced by an output (--mesh wself/happy.obj --out wself became the posed mesh),
    nor removed as an earlier result, even with --overwrite."""
    out = Path(args.out)
    written = [*outputs, *(out / n for n in (*TAKE_FILES, PROVENANCE))]
    for flag, path in _inputs(args):
        hit = next((p for p in written if p.exists() and path.samefile(p)), None)
        if hit is not None:
            raise UsageError(
                f"{flag} {path} is the file {hit.name} this run writes in --out {args.out}: choose another --out "
                "(an input is never written over, even with --overwrite)"
            )


def _claim_out(args: argparse.Namespace, extra: dict, outputs: list[Path]) -> None:
    """Claim --out with this run's provenance before the posing: another run's results there (a take, or
    another waters pose, e.g. at another --intensity) are refused unless --overwrite; the very same pose
    again (other render options included) reruns. Files of an older waters run without provenance count as
    another run's. --overwrite removes an earlier waters run's files, never an input."""
    out = Path(args.out)
    builtin = args.mesh == "builtin"
    digests = {flag[2:]: file_sha256(path) for flag, path in _inputs(args)}
    source = {"file": args.mesh, "expression": args.expression, "intensity": args.intensity, "action_units": extra,
              "layout": args.layout, "landmarks": args.landmarks, "units": args.units, "sha256": digests}  # fmt: skip
    if builtin:
        source["tets"] = args.tets
    if args.blend_to:
        source.update(blend_to=args.blend_to, blend_frames=args.frames)
    options = {"size": args.size, "render": not args.no_render, "usdc": args.usdc, "files": [p.name for p in outputs]}
    run = run_provenance(
        kind="waters",
        model_sha256=f"builtin face, {args.tets} tets" if builtin else digests["mesh"],
        source=source,
        options=options,
    )
    found = recorded_run(out) if out.is_dir() else None
    there = [p for p in outputs if p.exists()]
    if there and found is None and not args.overwrite:
        raise TakeDirectoryError(
            f"{out} holds {there[0].name} of an earlier run without provenance: choose another --out, or pass "
            "--overwrite to replace it"
        )
    claim_take_dir(out, run, overwrite=args.overwrite)
    earlier = ((found or {}).get("options") or {}).get("files", []) if (found or {}).get("kind") == "waters" else []
    inputs = [path for _, path in _inputs(args)]
    for name in set(earlier) - {p.name for p in outputs}:  # stale files of the earlier pose (or its renders)
        stale = out / name
        if stale.is_file() and not any(stale.samefile(p) for p in inputs):
            stale.unlink()


def _mesh_rig(args: argparse.Namespace):
    """--mesh read at --units and the layout fitted to it: (mesh, rig)."""
    mesh = read_surface_mesh(args.mesh, units=args.units)
    size_m = float(np.ptp(mesh.vertices_m, axis=0).max())
    if not _HEAD_SIZE_M[0] <= size_m <= _HEAD_SIZE_M[1]:  # the layouts' muscles are in metres
        raise ValueError(
            f"{args.mesh} is {size_m:.3g} m across read at {mesh.meters_per_unit:g} m per unit, where a head is "
            f"{_HEAD_SIZE_M[0]:g} to {_HEAD_SIZE_M[1]:g} m: check --units"
        )
    lay = layout_for_mesh(mesh, layout=args.layout, landmarks=args.landmarks)
    return mesh, WatersRig(lay, mesh.vertices_m, triangles=mesh.triangles())


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
    stem = _stem(args, extra)
    outputs = _outputs(args, stem)
    _refuse_writing_over_inputs(args, outputs)
    if args.mesh == "builtin":
        _claim_out(args, extra, outputs)  # before the face is built
        rig, mesh, _ = face_model_rig(build_face(args.tets))
    else:
        mesh, rig = _mesh_rig(args)  # read and fitted before --out is claimed: a mesh that fails leaves no claim
        _claim_out(args, extra, outputs)
    summary = pose_mesh(
        mesh,
        args.out,
        expression=args.expression,
        action_units=extra,
        intensity=args.intensity,
        render=not args.no_render,
        size=args.size,
        usd_suffix=".usdc" if args.usdc else ".usda",
        stem=stem,
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
    written = {Path(p) for p in summary["files"].values()} | {obj.with_suffix(".json"), Path(args.out) / PROVENANCE}
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
