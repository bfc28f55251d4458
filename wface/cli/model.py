"""``wface model build | info | import``: make, inspect and import face models."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from wface.cli.validate import positive_int
from wface.faces.artisynth import import_artisynth
from wface.faces.builtin import build_face
from wface.faces.summary import model_summary
from wface.mesh.tetio import model_cell_data, write_tet_mesh
from wface.model import load_model, save_model

_BUILD_EPILOG = """\
The built-in face is a deterministic procedural head: soft tissue between a lofted skull and the
skin, a mouth that opens, teeth, 35 named muscles with fibre fields, 47 skin markers (AnimFace
names) and a jaw joint. Resolution goes from ~1K to 2M tets; the same --tets gives the same file.

examples:
  wface model build --tets 20000 --out face20k.npz
  wface model build --tets 400000 --out face400k.npz --vtu face400k.vtu
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("model", help="build, inspect or import face models", description="Face models.")
    msub = p.add_subparsers(dest="model_command", metavar="ACTION")

    b = msub.add_parser(
        "build",
        help="build the built-in face at a given resolution",
        description="Build the built-in anatomical face and save it as .npz.",
        epilog=_BUILD_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    b.add_argument("--tets", type=positive_int, default=20000, help="target number of tetrahedra (default 20000)")
    b.add_argument("--out", required=True, help="output model file (.npz)")
    b.add_argument("--vtu", help="also export the tet mesh (with muscle and bone data) to this .vtu/.msh file")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    b.set_defaults(func=_build)

    i = msub.add_parser(
        "info",
        help="summarise a model file",
        description="Print sizes, muscles, markers, attachments and mesh quality of a model.",
    )
    i.add_argument("path", help="model file (.npz)")
    i.add_argument("--json", action="store_true", help="print JSON")
    i.set_defaults(func=_info)

    imp = msub.add_parser(
        "import",
        help="import a face model from another tool (artisynth)",
        description="Import an anatomical face model. Formats: artisynth (the ArtiSynth 'Badin' face directory).",
    )
    imp.add_argument("format", choices=["artisynth"], help="source format")
    imp.add_argument("directory", help="source directory")
    imp.add_argument("--out", required=True, help="output model file (.npz)")
    imp.set_defaults(func=_import)
    p.set_defaults(func=lambda a: p.print_help() or 2)


def _build(args: argparse.Namespace) -> int:

    t0 = time.perf_counter()
    model = build_face(args.tets, progress=not args.quiet)
    path = save_model(model, args.out)
    q = model.metadata["quality"]
    print(
        f"wrote {path}: {model.n_tets} tets, {model.n_nodes} nodes, {model.n_muscles} muscles, "
        f"min dihedral {q['min_dihedral_deg']:.1f} deg, {time.perf_counter() - t0:.1f} s"
    )
    if args.vtu:
        cell, point = model_cell_data(model)
        write_tet_mesh(args.vtu, model.rest_positions_m, model.tets, cell_data=cell, point_data=point)
        print(f"wrote {args.vtu}")
    return 0


def _info(args: argparse.Namespace) -> int:

    model = load_model(args.path)
    s = model_summary(model)
    if args.json:
        json.dump(s, sys.stdout, indent=2)
        print()
        return 0
    lo, hi = s["bbox_m"]
    print(f"{args.path}")
    print(
        f"  nodes {s['nodes']}, tets {s['tets']}, min dihedral {s['min_dihedral_deg']:.2f} deg, "
        f"min volume ratio {s['min_volume_ratio']:.3f}, min volume {s['min_volume_m3']:.3g} m^3"
    )
    print(f"  bbox {[round(v, 4) for v in lo]} .. {[round(v, 4) for v in hi]} m")
    print(f"  attached nodes: cranium {s['attached_nodes']['cranium']}, jaw {s['attached_nodes']['jaw']}")
    print(f"  {len(s['muscles'])} muscles: {', '.join(s['muscles'])}")
    print(f"  {len(s['markers'])} markers: {', '.join(s['markers'])}")
    print(f"  bones: {', '.join(s['bones'])}; action units: {', '.join(s['action_units'])}")
    return 0


def _import(args: argparse.Namespace) -> int:

    if not Path(args.directory).is_dir():
        raise FileNotFoundError(f"source directory not found: {args.directory}")

    model = import_artisynth(args.directory)
    path = save_model(model, args.out)
    print(f"wrote {path}: {model.n_tets} tets, {model.n_nodes} nodes, {model.n_muscles} muscles")
    return 0
