"""``wface waters``: pose a face mesh with Waters vector muscles from a FACS expression or action units."""

from __future__ import annotations

import argparse
import json

from wface.facs import ACTION_UNITS, EXPRESSIONS


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
    p.add_argument("--tets", type=int, default=20000, help="resolution of the built-in face (with --mesh builtin)")
    p.add_argument("--expression", default="neutral", help="expression preset (default: neutral)")
    p.add_argument("--intensity", type=float, default=1.0, help="scale of the preset's action units, 0..1")
    p.add_argument(
        "--au", action="append", metavar="AU=VALUE", help="extra action unit, e.g. --au AU26=0.5 (repeatable)"
    )
    p.add_argument("--layout", help="muscle layout JSON, or a packaged name: ict (default), builtin")
    p.add_argument("--landmarks", help="JSON {AnimFace marker name: vertex index} on --mesh: fit the layout to it")
    p.add_argument("--units", default="auto", choices=("auto", "m", "cm", "mm"), help="length unit of --mesh")
    p.add_argument("--size", type=int, default=600, help="render size in pixels")
    p.add_argument("--no-render", action="store_true", help="skip the PNG renders")
    p.add_argument("--usdc", action="store_true", help="write binary .usdc instead of text .usda")
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from wface.waters.expressions import parse_au_assignments
    from wface.waters.pipeline import pose_mesh

    mesh, rig = args.mesh, None
    if args.mesh == "builtin":
        from wface.builtin import build_face
        from wface.waters.face_model import face_model_rig

        parse_au_assignments(args.au)  # fail on bad names before building the face
        rig, mesh, _ = face_model_rig(build_face(args.tets))
    summary = pose_mesh(
        mesh,
        args.out,
        expression=args.expression,
        action_units=parse_au_assignments(args.au),
        intensity=args.intensity,
        layout=args.layout,
        landmarks=args.landmarks,
        units=args.units,
        render=not args.no_render,
        size=args.size,
        usd_suffix=".usdc" if args.usdc else ".usda",
        rig=rig,
    )
    print(json.dumps({k: summary[k] for k in ("expression", "jaw_open_deg", "max_displacement_mm", "files")}, indent=2))
    return 0
