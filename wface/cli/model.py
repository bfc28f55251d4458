"""``wface model build | info | import``: make, inspect and import face models."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from wface.cli.validate import (
    face_tets,
    finite_float,
    non_negative_int,
    npz_file,
    refuse_existing,
    tet_mesh_file,
)
from wface.faces.artisynth import import_artisynth
from wface.faces.builtin import build_face
from wface.faces.fit import fit_template, ict_feature_landmarks, select_target_faces
from wface.faces.summary import model_summary
from wface.files import read_landmarks
from wface.io.mocap import read_mocap
from wface.mesh.meshfile import read_surface_mesh
from wface.mesh.tetio import model_cell_data, write_tet_mesh
from wface.model import load_model, save_model

_BUILD_EPILOG = """\
The built-in face is a deterministic procedural head: soft tissue between a lofted skull and the
skin, a mouth that opens, teeth, 35 named muscles with fibre fields, 47 skin markers (AnimFace
names) and a jaw joint. Resolution goes from ~1K to 2M tets; the same --tets gives the same file.

examples:
  wface model build --tets 20000 --out face20k.npz
  wface model build --tets 400000 --out face400k.npz --vtu face400k.vtu
  wface model build --tets 20000 --free-to-mm 34 --out face_midface.npz   # the midface's deep side free
"""


_FIT_EPILOG = """\
Morphs a template face onto a subject: the skin onto the target (landmarks, then non-rigid
closest-point registration with a thin-plate smoothness term), the interior by an elastic
relaxation that keeps every tet positive, each bone by its best similarity; muscles,
attachments, markers and the jaw joint are carried along. Prints (and stores in the model's
metadata) the surface distance, landmark residuals, mesh quality before/after and inverted tets.

--landmarks is a JSON map {marker name: target vertex id, or [x, y, z] in the mesh's units}; with
the ICT-FaceKit head (generic_neutral_mesh.obj, 26,719 vertices) wface uses 18 facial features of
it by default. Names are the template's marker names (AnimFace names on the built-in face).

examples:
  wface model fit --template builtin --tets 20000 --surface ../shared/data/ict-facekit/generic_neutral_mesh.obj \\
      --out actor.npz
  wface model fit --template builtin --markers take.c3d --neutral-frame 0 --out actor.npz
  wface model fit --template badin.npz --surface scan.ply --landmarks scan_landmarks.json --out actor.npz
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
    b.add_argument("--tets", type=face_tets, default=20000, help="target number of tetrahedra (default 20000)")
    b.add_argument("--out", required=True, type=npz_file, help="output model file (.npz)")
    b.add_argument("--overwrite", action="store_true", help="replace an existing --out (and --vtu) file")
    b.add_argument(
        "--free-to-mm",
        type=_free_to_mm,
        default=18.0,
        help="how far above the mouth line the bone side of lips and cheeks is free of the maxilla, 5-40 mm "
        "(default 18: the oral vestibule; 34 frees the midface's deep surface too, measured on real capture "
        "in README, 'Your actor, your head')",
    )
    b.add_argument(
        "--vtu", type=tet_mesh_file, help="also export the tet mesh (with muscle and bone data) to this .vtu/.msh file"
    )
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
    imp.add_argument("--out", required=True, type=npz_file, help="output model file (.npz)")
    imp.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    imp.set_defaults(func=_import)

    f = msub.add_parser(
        "fit",
        help="fit a template face to a head mesh and/or a neutral marker frame",
        description="Fit a template face to an actor's head mesh or neutral marker frame.",
        epilog=_FIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    f.add_argument("--template", default="builtin", help="'builtin' or a face model .npz (default builtin)")
    f.add_argument("--tets", type=face_tets, default=20000, help="size of the built-in template (default 20000)")
    f.add_argument("--surface", help="target head mesh: .obj, .ply, .stl, .off, ...")
    f.add_argument("--units", default="auto", help="units of --surface: auto, m, cm, mm (default auto)")
    f.add_argument("--surface-groups", help="material groups of --surface that are skin (default: not eyes/teeth)")
    f.add_argument("--landmarks", help="JSON {marker name: target vertex id} for --surface")
    f.add_argument("--markers", help="motion capture (.c3d, .trc, .csv) whose neutral frame is the actor's face")
    f.add_argument(
        "--neutral-frame",
        type=non_negative_int,
        default=None,
        help="frame of --markers showing the neutral face (default 0)",
    )
    f.add_argument("--out", required=True, type=npz_file, help="output model file (.npz)")
    f.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    f.add_argument("--json", action="store_true", help="print the fit report as JSON")
    f.set_defaults(func=_fit)
    p.set_defaults(func=lambda a: p.print_help() or 2)


def _free_to_mm(text: str) -> float:
    """``--free-to-mm``'s type: 5-40 mm (checked before the face is built)."""
    value = finite_float(text)
    if not 5.0 <= value <= 40.0:
        raise argparse.ArgumentTypeError(f"must be within [5, 40] mm above the mouth line, got {text}")
    return value


def _refuse_existing(args: argparse.Namespace) -> None:
    """An existing --out (or build's --vtu) is not replaced unasked (an imported 3 MB Badin model was silently
    rebuilt as a 640 KB built-in face), and that is said before any work."""
    refuse_existing(("--out", args.out), ("--vtu", getattr(args, "vtu", None)), overwrite=args.overwrite)


def _build(args: argparse.Namespace) -> int:
    _refuse_existing(args)

    t0 = time.perf_counter()
    model = build_face(args.tets, progress=not args.quiet, free_to_mm=args.free_to_mm)
    path = save_model(model, args.out)
    q = model.metadata["quality"]
    print(
        f"wrote {path}: {model.n_tets} tets, {model.n_nodes} nodes, {_channels(model)}, "
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
    free = "" if s["free_to_mm"] is None else f"; bone side free to {s['free_to_mm']:g} mm above the mouth line"
    print(f"  attached nodes: cranium {s['attached_nodes']['cranium']}, jaw {s['attached_nodes']['jaw']}{free}")
    print(f"  {len(s['muscles'])} muscles: {', '.join(s['muscles'])}")
    for name, p in s["pressure_actuators"].items():
        print(
            f"  pressure actuator {name}: up to {p['max_pa'] / 1e3:g} kPa on {p['wall_triangles']} wall triangles, "
            "control -1 (suction) .. 1"
        )
    print(f"  {len(s['markers'])} markers: {', '.join(s['markers'])}")
    print(f"  bones: {', '.join(s['bones'])}; action units: {', '.join(s['action_units'])}")
    mat = s["material"]
    print(
        f"  flesh mu10 {mat['mu10_pa']:g} Pa, mu01 {mat['mu01_pa']:g} Pa, mu20 {mat['mu20_pa']:g} Pa, "
        f"kappa {mat['kappa_pa']:g} Pa ({mat.get('bulk_potential', 'log')} bulk potential); "
        f"muscle sigma_max {mat['sigma_max_pa']:g} Pa, "
        f"{mat['fibre_stress']} fibre stress" + "".join(f"; {m} {c} curves" for m, c in mat["muscle_curves"].items())
    )
    fit = s.get("fit")
    if fit:
        sd = fit["surface_distance_mm"]
        target = fit["surface"] or f"{fit['markers']} neutral markers"
        dist = f"surface distance {sd['mean']:.2f} mm mean, {sd['max']:.2f} max, " if sd else ""
        lm = fit["landmark_rms_mm"]
        print(f"  fitted to {target}: {dist}landmarks {lm:.2f} mm RMS, {fit['inverted_tets']} inverted tets")
    return 0


def _import(args: argparse.Namespace) -> int:
    _refuse_existing(args)
    if Path(args.directory).is_file():
        raise ValueError(
            f"{args.directory} is a file: give the ArtiSynth face's directory (the one holding badinjaw.obj)"
        )
    if not Path(args.directory).is_dir():
        raise FileNotFoundError(f"source directory not found: {args.directory}")

    model = import_artisynth(args.directory)
    path = save_model(model, args.out)
    print(f"wrote {path}: {model.n_tets} tets, {model.n_nodes} nodes, {_channels(model)}")
    return 0


def _channels(model) -> str:
    """ "35 muscles and 1 pressure actuator", as ``wface model info`` counts them."""
    n_pressure = len(model.pressure_actuators)
    text = f"{model.n_muscles - n_pressure} muscles"
    return text + (f" and {n_pressure} pressure actuator{'s' * (n_pressure > 1)}" if n_pressure else "")


def _fit_landmarks(args, mesh, say) -> dict | None:
    if args.landmarks:
        return read_landmarks(args.landmarks, n_vertices=mesh.n_points, points=True)
    if mesh.n_points == 26719:  # the ICT-FaceKit head topology
        say("landmarks: 18 facial features of the ICT-FaceKit head (eye and mouth corners, lips, brows, nose)")
        return ict_feature_landmarks()
    return None


def _fit(args: argparse.Namespace) -> int:
    _refuse_existing(args)
    say = print if not args.json else (lambda msg: print(msg, file=sys.stderr))  # --json: stdout is the JSON
    if not (args.surface or args.markers):
        raise ValueError("give --surface HEAD.obj|ply|stl, --markers TAKE.c3d, or both")
    if args.neutral_frame is not None and not args.markers:
        raise ValueError("--neutral-frame picks a frame of --markers, which is not given")
    mesh = faces = landmarks = markers = names = None  # the targets first: a bad file fails before a face is built
    if args.surface:
        mesh = read_surface_mesh(args.surface, units=args.units)
        groups = [g.strip() for g in args.surface_groups.split(",")] if args.surface_groups else None
        faces = select_target_faces(mesh, groups)
        used = ", ".join(g for g, ids in mesh.face_groups.items() if set(ids.tolist()) <= set(faces.tolist()))
        say(
            f"target {args.surface}: {mesh.n_points} vertices, {mesh.n_faces} faces ({len(faces)} skin: "
            f"{used or 'all'}), {mesh.meters_per_unit:g} m per unit"
        )
        landmarks = _fit_landmarks(args, mesh, say)
    if args.markers:
        take = read_mocap(args.markers)
        args.neutral_frame = 0 if args.neutral_frame is None else args.neutral_frame
        if not 0 <= args.neutral_frame < take.n_frames:
            raise ValueError(f"--neutral-frame {args.neutral_frame} is outside {args.markers}'s {take.n_frames} frames")
        markers, names = take.positions_m[args.neutral_frame], take.marker_names
    template = build_face(args.tets, progress=True) if args.template == "builtin" else load_model(args.template)
    res = fit_template(
        template,
        surface=mesh,
        surface_faces=faces,
        landmarks=landmarks,
        markers_m=markers,
        marker_names=names,
        progress=say,
    )
    path = save_model(res.model, args.out)
    rep = res.report.as_dict()
    sd = rep["surface_distance_mm"]
    qb, qr, qa = rep["quality_before"], rep["quality_relaxed"], rep["quality_after"]
    if sd:
        say(f"surface distance to the target: mean {sd['mean']:.2f} mm, max {sd['max']:.2f} mm")
    if rep["landmark_rms_mm"] is not None:
        worst = max(rep["landmark_residual_mm"].items(), key=lambda kv: kv[1])
        say(f"landmarks: RMS {rep['landmark_rms_mm']:.2f} mm, worst {worst[0]} {worst[1]:.2f} mm")
    say(
        f"min dihedral {qb['min_dihedral_deg']:.1f} -> {qa['min_dihedral_deg']:.1f} deg (relaxed "
        f"{qr['min_dihedral_deg']:.1f}), min volume ratio {qb['min_volume_ratio']:.3f} -> "
        f"{qa['min_volume_ratio']:.3f} (relaxed {qr['min_volume_ratio']:.3f}), inverted tets {qa['inverted']}, "
        f"scale {rep['scale']:.3f}"
    )
    for bone, b in rep["bones"].items():
        dev = b["attachment_deviation_mm"]
        say(
            f"{bone}: similarity scale {b['scale']:.3f}, attached nodes {dev['mean']:.2f} mm "
            f"(max {dev['max']:.2f}) off it"
        )
    say(f"wrote {path}: {res.model.n_tets} tets, {len(res.model.marker_names)} markers, {rep['seconds']:.1f} s")
    if args.json:
        json.dump(rep, sys.stdout, indent=2)
        print()
    return 0
