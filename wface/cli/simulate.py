"""``wface simulate``: one quasistatic equilibrium of a face for given activations and jaw opening."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from wface.cli.closing import print_outputs
from wface.cli.contact_args import add_contact_arguments, contact_from_args
from wface.cli.validate import finite_float, positive_float, positive_int
from wface.controls import attached_positions_from_affines, jaw_opening_affine
from wface.files import save_npz, write_json
from wface.model import load_model
from wface.physics import Simulator
from wface.physics.contact import MeshObstacle, bone_affines_from_attached
from wface.physics.contact_solve import solve_restarted
from wface.takes.provenance import command_provenance
from wface.takes.store import claim_take_dir
from wface.viz.contact import plot_lip_section
from wface.warp_runtime import quiet_warp

_EPILOG = """\
Writes DIR/equilibrium.npz (positions_m (n, 3), rest_positions_m, activations, muscle_names) and
DIR/summary.json (newton_iterations, residual_rel, converged, max_displacement_mm,
inverted_elements, seconds, ...). The residual is ||f_free|| relative to the out-of-balance force
of the load on the rest shape (see wface.physics.newton).

With --contact / --obstacle the solve adds penalty contact (wface.physics.contact): the summary then
also holds contact_active_nodes, contact_max_penetration_mm, contact_force_n and per-source numbers.
Lip contact is measured against smooth lip surfaces by default and Newton restarts every 5
iterations (wface.physics.contact_solve): on the Badin face's lip press (OOP and MENT at 1) that
converges to 1e-6 in 78 iterations, where the faceted surfaces stall at a residual of 1e-2.

examples:
  wface simulate --model face.npz --activation zygomaticus_major_l=0.8 --out smile
  wface simulate --model face.npz --jaw-open 12 --activation orbicularis_oris_lower=0.3 --out open --json
  wface simulate --model face.npz --activation orbicularis_oris_upper=1 --activation mentalis_l=1 \\
      --activation mentalis_r=1 --contact lips,teeth --out pressed
  wface simulate --model face.npz --obstacle sphere:0.043,-0.044,0.097,0.015 --contact teeth --out poke  # cheek, 3 mm
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="solve one quasistatic equilibrium for muscle activations and a jaw opening",
        description="Quasistatic FEM equilibrium of a face model (Newton-Raphson with line search).",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--model", required=True, help="face model file (.npz, from `wface model build`)")
    p.add_argument(
        "--activation",
        action="append",
        default=[],
        type=activation_item,
        metavar="NAME=VALUE",
        help="muscle activation in [0, 1], or a pressure actuator in [-1, 1] (intraoral_pressure=0.6 puffs "
        "the cheeks, -0.6 sucks them in; repeatable)",
    )
    p.add_argument(
        "--jaw-open",
        type=finite_float,
        default=0.0,
        metavar="DEG",
        help="jaw opening angle in degrees (negative: closed past rest, within the model's closing range)",
    )
    add_contact_arguments(p, lip_surface="smooth")
    p.add_argument(
        "--picture",
        action="store_true",
        help="also write DIR/lips_section.png: the lips and teeth cut by the mid-sagittal plane, at rest and at "
        "the equilibrium (needs matplotlib and upper_lip / lower_lip surface groups)",
    )
    p.add_argument("--device", default="cpu", help="Warp device: cpu (default), cuda:0 or auto")
    p.add_argument("--solver", default="auto", choices=["auto", "cg", "direct"], help="linear solver")
    p.add_argument("--tol", type=positive_float, default=1e-6, help="relative residual tolerance (default 1e-6)")
    p.add_argument(
        "--max-iterations",
        type=positive_int,
        default=None,
        help="Newton iteration cap (default 40; 100 with lip contact)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--overwrite", action="store_true", help="replace the results of another run that OUT holds")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=_run)


def activation_item(text: str) -> str:
    """``--activation``'s type: NAME=VALUE with a number (the names are checked against the model later)."""
    try:
        parse_activations([text])
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def parse_activations(items: list[str]) -> dict[str, float]:
    """["name=0.5", ...] -> {"name": 0.5}; a malformed item raises ValueError."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            hint = " ('none' stands alone: no other --activation with it)" if item.strip().lower() == "none" else ""
            raise ValueError(f"--activation expects NAME=VALUE, got {item!r}{hint}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"--activation {item!r}: {value!r} is not a number") from None
        if name.strip() in out:  # the last would win without a word
            raise ValueError(f"--activation {name.strip()} is given twice ({out[name.strip()]:g} and {number:g})")
        out[name.strip()] = number
    return out


def _lip_picture(model, x, targets, path: Path) -> Path:
    """Mid-sagittal section of lips and teeth, rest vs equilibrium (teeth placed by the bone targets)."""

    affines = bone_affines_from_attached(model, targets)
    teeth = {}
    for name, mesh in model.bone_meshes.items():
        if "teeth" in name.lower():
            surf = MeshObstacle(mesh.vertices_m, mesh.triangles, bone=mesh.bone).surface(affines)
            teeth[name] = (surf.vertices_m, surf.triangles)
    rest_teeth = {n: (m.vertices_m, m.triangles) for n, m in model.bone_meshes.items() if "teeth" in n.lower()}
    panels = {"rest": model.rest_positions_m, "equilibrium": x}
    return plot_lip_section(model, panels, path, teeth={"rest": rest_teeth, "equilibrium": teeth})


def _run(args: argparse.Namespace) -> int:

    quiet_warp()
    start = time.perf_counter()
    model = load_model(args.model)
    activations = model.activation_vector(parse_activations(args.activation))  # clear KeyError / ValueError
    contact = contact_from_args(args, model)  # clear ValueError for unknown regions / bad specs
    claim_take_dir(args.out, command_provenance("simulate", model, args), overwrite=args.overwrite)
    sim = Simulator(model, device=args.device, solver=args.solver)
    targets = attached_positions_from_affines(model, jaw=jaw_opening_affine(model, args.jaw_open))
    lips = contact is not None and bool(contact.self_contact)
    cap = args.max_iterations or (100 if lips else 40)
    if lips:  # Newton in rounds (wface.physics.contact_solve)
        eq = solve_restarted(sim, activations, targets, tol=args.tol, max_iterations=cap, contact=contact)
    else:
        eq = sim.solve(activations, targets, tol=args.tol, max_iterations=cap, contact=contact)
    out = Path(args.out)
    save_npz(
        out / "equilibrium.npz",
        positions_m=eq.x,
        rest_positions_m=model.rest_positions_m,
        activations=activations,
        muscle_names=np.array(model.muscle_names),
        jaw_opening_deg=np.float64(args.jaw_open),
    )
    disp = np.linalg.norm(eq.x - model.rest_positions_m, axis=1)
    summary = {
        "model": str(args.model),
        "nodes": model.n_nodes,
        "tets": model.n_tets,
        "device": sim.device,
        "solver": eq.solver,
        "activations": {model.muscle_names[i]: float(a) for i, a in enumerate(activations) if a != 0.0},
        "jaw_opening_deg": args.jaw_open,
        "converged": eq.converged,
        "newton_iterations": eq.iterations,
        "projected_steps": eq.projected_steps,
        "residual_rel": eq.residual_rel,
        "residual_abs_n": eq.residual_abs,
        "max_displacement_mm": float(disp.max() * 1e3),
        "inverted_elements": eq.inverted_elements,
        "energy_j": eq.energy,
        "cg_iterations": eq.cg_iterations,
        "factorizations": eq.factorizations,
        "solve_seconds": eq.seconds,
        "seconds": time.perf_counter() - start,
    }
    if args.picture:
        summary["picture"] = str(_lip_picture(model, eq.x, targets, out / "lips_section.png"))
    if contact is not None:
        summary.update(
            contact_regions=list(contact.regions),
            lip_surface=contact.surface if contact.self_contact else None,
            obstacles=list(args.obstacle),
            contact_stiffness_n_per_m=contact.stiffness_n_per_m,
            contact_active_nodes=eq.contact_active_nodes,
            contact_max_penetration_mm=eq.contact_max_penetration_m * 1e3,
            contact_force_n=eq.contact_force_n,
            contact_sources=eq.contact_stats,
        )
    write_json(out / "summary.json", summary)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        state = "converged" if eq.converged else "NOT converged"
        print(
            f"{state} in {eq.iterations} Newton iterations, residual {eq.residual_rel:.2e}, "
            f"max displacement {summary['max_displacement_mm']:.2f} mm, {eq.inverted_elements} inverted, "
            f"{summary['seconds']:.1f} s"
        )
        if contact is not None:
            print(
                f"contact: {eq.contact_active_nodes} nodes, max penetration "
                f"{summary['contact_max_penetration_mm']:.3f} mm, force {eq.contact_force_n:.2f} N"
            )
        written = [out / "equilibrium.npz", out / "summary.json", out / "provenance.json"]
        print_outputs(out, written + ([Path(summary["picture"])] if args.picture else []))  # a claimed --out
    return 0 if eq.converged else 3
