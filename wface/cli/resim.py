"""``wface resim``: play a tracked (or synthetic) take through the implicit dynamic FEM."""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

from wface.cli.closing import print_outputs
from wface.cli.contact_args import add_contact_arguments, contact_from_args
from wface.cli.render_mesh_args import add_render_mesh_arguments, render_mesh_from_args
from wface.cli.simulate import parse_activations
from wface.cli.take_face import DEFAULT_TETS, face_for_take
from wface.cli.validate import UsageError, face_tets, finite_float, non_negative_int, positive_float, positive_int
from wface.physics import Damping, Simulator
from wface.takes.dynamic import compare_with_quasistatic, quasistatic_reference, resimulate
from wface.takes.provenance import command_provenance
from wface.takes.store import USD, claim_take_dir, load_take, require_take_dir, write_report, write_resim_npz
from wface.takes.synthetic import step_take
from wface.takes.usd import skin_mesh, write_take_usd
from wface.warp_runtime import quiet_warp

_DESCRIPTION = """\
Dynamic re-simulation: the activations and bone motion of a take drive an implicit dynamic FEM
(M x'' + C x' + f_int(x, a(t)) = 0, lumped mass from the material density, Rayleigh damping
C = alpha M + beta K), so the flesh gets inertia, overshoot and secondary motion that frame-by-
frame quasistatic tracking cannot have. Between frames, activations and bone positions are
interpolated linearly; each frame is split into --substeps implicit time steps, each a Newton
minimisation of the incremental potential (see wface.physics.dynamics).

Without --take, a synthetic take on the built-in face: rest until --onset-frame, then the
--activation values (default: a full smile, both zygomatici major) switched on suddenly (within
one time step; --onset linear ramps them over one frame) and the jaw opened by --jaw-open degrees
over one frame, held to the end. The report gives the overshoot of the skin past its
quasistatic target.
"""

# the synthetic take's options and their defaults: the parser's, and what a run with --take refuses
_SYNTHETIC_ONLY = {"activation": [], "jaw_open": 0.0, "head_shake": None, "onset_frame": 1, "onset": "step"}

_EPILOG = """\
schemes:
  midpoint  implicit midpoint rule: second order, no numerical damping (energy of a linear
            system is conserved exactly); the flesh rings at its own frequencies, damped only by
            --damping. The default without contact.
  be        backward Euler: first order and L-stable; damps fast motion numerically (more so
            with fewer substeps). The most robust choice for rough takes, and the default with
            contact: the midpoint rule holds contact at each step's midpoint only, its end point
            overshoots, and a lip press diverges (the sixth example below: with midpoint a lip
            node is 300 mm from rest 54 ms in; with be 0.93 Newton iterations a step and the
            skin within 0.01 mm of the quasistatic frames).
  A step that diverges (a node farther from rest than the face is across, or Newton stopping
  short with elements inverted) stops the run with
  exit code 3 and says where; no frames or report are written.

time step (--substeps): the lowest modes of the built-in face ring at 100-155 Hz (5K tets, at
rest; stiffer when muscles are active), periods of 6-10 ms. The default 16 substeps at 30 fps
(dt = 2.1 ms) follows them; with fewer substeps the midpoint rule stays stable but cannot resolve
the ringing (it shows up as frame-to-frame jitter), and backward Euler damps it away.

contact (--contact lips,teeth,bones, --obstacle): the penalty contact of `wface simulate` in
every time step, on faceted lip surfaces unless --lip-surface says otherwise, with backward Euler
unless --scheme says otherwise (above).

damping (--damping ALPHA,BETA, or none): mode f Hz gets the damping ratio
  zeta = ALPHA / (4 pi f) + pi f BETA.   Default 0,2e-4 (6 % at 100 Hz, no drag on head motion).

outputs in --out:
  report.json     per frame: kinetic_energy_j, newton_iterations, residual_rel,
                  inverted_elements, seconds_per_frame, deviation_mm (largest skin distance
                  from the quasistatic frame); seconds_per_step_median, the settings; synthetic:
                  overshoot_mm (peak excursion past the quasistatic target of the skin node that
                  moves most, over all time steps), overshoot_mm_at_frames (sampled at frames)
  resim.npz       positions_m (T, n, 3), per-frame stats, reference_positions_m (quasistatic)
  animation.usdc  time code f = frame f, timeCodesPerSecond = fps; on a face with skin triangles
                  the stage layout of `wface track` / `wface edit` (/Face/Skin, Bones, Muscles),
                  else the boundary as /Face/Mesh

examples:
  wface resim --out smile_dyn                                   # sudden smile, 5000 tets
  wface resim --out smile_dyn --tets 20000 --scheme be --substeps 2
  wface resim --out open_dyn --activation orbicularis_oris_lower=0.5 --jaw-open 15 --frames 20
  wface resim --out shake --activation none --head-shake 15,3   # head shake, no muscle
  wface resim --take run1 --out run1_dyn                        # a `wface track` output dir
  wface resim --out lips --activation orbicularis_oris_upper=1 --contact lips,teeth
  wface resim --take run1 --model face.npz --out run1_dyn --frames 0:60 --damping 5,1e-4
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "resim",
        help="re-simulate a take with inertia (implicit dynamic FEM) and write USD",
        description=_DESCRIPTION,
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    # "--head-shake -10,3": argparse takes a value starting with '-' for an option unless it looks like a
    # negative number; a number list counts as one here (argparse's own attribute, read where it parses)
    p._negative_number_matcher = re.compile(r"^-\d*\.?\d+([eE][-+]?\d+)?(,[-+]?\d*\.?\d+([eE][-+]?\d+)?)*$")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--take", help="tracking output directory (from `wface track` / `wface demo`); omit for synthetic")
    p.add_argument("--model", help="face model (.npz); default: the built-in face with --tets tets")
    p.add_argument(
        "--tets",
        type=face_tets,
        default=None,
        help=f"size of the built-in face when --model is not given (default: the take's face, else {DEFAULT_TETS})",
    )
    p.add_argument(
        "--scheme",
        default="auto",
        choices=["auto", "midpoint", "be"],
        help="time integrator (see below; default auto: midpoint, be with contact)",
    )
    p.add_argument(
        "--substeps",
        type=positive_int,
        default=16,
        help="implicit time steps per capture frame (default 16; a take of every S-th frame takes S x that between "
        "its stored frames, the same time step)",
    )
    p.add_argument("--damping", default="0,2e-4", metavar="ALPHA,BETA", help="Rayleigh alpha (1/s), beta (s), or none")
    p.add_argument(
        "--frame",
        default="world",
        choices=["world", "cranium"],
        help="simulate in the world (head motion shakes the flesh; default) or in the cranium's frame",
    )
    p.add_argument("--fps", type=positive_float, help="frame rate (take: default from its animation.usdc, else 30)")
    p.add_argument(
        "--frames",
        help="take: range A:B of its stored frames, by position (a take of every 10th capture frame: 0:6 is capture "
        "frames 0-50); synthetic: number of frames (default 30)",
    )
    p.add_argument(
        "--activation",
        action="append",
        default=list(_SYNTHETIC_ONLY["activation"]),
        metavar="NAME=VALUE",
        help="synthetic: activation (repeatable; 'none' for no muscle)",
    )
    p.add_argument(
        "--jaw-open",
        type=finite_float,
        default=_SYNTHETIC_ONLY["jaw_open"],
        metavar="DEG",
        help="synthetic: jaw opening at the onset (negative: closed past rest, within the model's range)",
    )
    p.add_argument(
        "--head-shake",
        metavar="DEG,HZ",
        help="synthetic: shake the head (yaw amplitude in degrees, frequency in Hz) from the onset on",
    )
    p.add_argument(
        "--onset-frame",
        type=non_negative_int,
        default=_SYNTHETIC_ONLY["onset_frame"],
        help="synthetic: first frame with the activations on",
    )
    p.add_argument(
        "--onset",
        default=_SYNTHETIC_ONLY["onset"],
        choices=["step", "linear"],
        help="synthetic: activations switch on within one time step (default) or ramp over one frame",
    )
    add_contact_arguments(p, where="every time step and reference frame")
    add_render_mesh_arguments(p)
    p.add_argument("--no-reference", action="store_true", help="skip the quasistatic reference frames")
    p.add_argument("--no-usd", action="store_true", help="skip animation.usdc")
    p.add_argument(
        "--no-rig", action="store_true", help="animation.usdc without the UsdSkel rig (the point cache alone)"
    )
    p.add_argument("--overwrite", action="store_true", help="replace the results of another take that OUT holds")
    p.add_argument("--tol", type=positive_float, default=1e-6, help="relative Newton tolerance per step (default 1e-6)")
    p.add_argument("--device", default="cpu", help="Warp device: cpu (default), cuda:0 or auto")
    p.add_argument("--solver", default="auto", choices=["auto", "direct", "cg"], help="linear solver")
    p.add_argument("--json", action="store_true", help="print the report summary as JSON")
    p.set_defaults(func=_run)


def parse_damping(text: str):
    """ "ALPHA,BETA" or "none" -> ``Damping``; a malformed value raises ValueError."""

    if text.strip().lower() in ("none", "0", "off"):
        return Damping.none()
    parts = text.split(",")
    if len(parts) != 2:
        raise ValueError(f"--damping expects ALPHA,BETA (e.g. 0,2e-4) or none, got {text!r}")
    try:
        alpha, beta = (float(v) for v in parts)
    except ValueError:
        raise ValueError(f"--damping {text!r}: not two numbers") from None
    return Damping(alpha, beta)


def _frame_range(text: str | None) -> slice | None:
    if not text:
        return None
    try:
        if ":" in text:
            a, b = (int(v) if v else None for v in text.split(":"))
            return slice(a, b)
        return slice(0, int(text))
    except ValueError:
        raise ValueError(f"--frames must look like A:B or N, got {text!r}") from None


def _head_shake(text: str | None):
    if not text:
        return None
    try:
        amplitude, frequency = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--head-shake expects DEG,HZ (e.g. 10,3), got {text!r}") from None
    return amplitude, frequency


def _run(args: argparse.Namespace) -> int:
    quiet_warp()
    start = time.perf_counter()
    started = time.time()
    damping = parse_damping(args.damping)
    if args.substeps < 1:
        raise ValueError(f"--substeps must be >= 1, got {args.substeps}")
    if args.fps is not None and not args.fps > 0:
        raise ValueError(f"--fps must be > 0, got {args.fps}")
    _refuse_options_that_do_nothing(args)
    if args.take:
        args.take = str(require_take_dir(args.take))  # a wrong --take fails before a face is built
        if Path(args.out).resolve() == Path(args.take).resolve():  # --overwrite would delete the input
            raise ValueError(f"--out {args.out} is the take being re-simulated (--take): write it to another directory")
    model = face_for_take(args, progress=True)
    if args.take:
        take = load_take(
            args.take, model, fps=args.fps, frames=_frame_range(args.frames), reference=not args.no_reference
        )
        if take.n_frames < 2:
            raise ValueError(f"{args.take}: need at least 2 frames to re-simulate, got {take.n_frames}")
    else:
        n_frames = int(args.frames) if args.frames else 30
        if [item.lower() for item in args.activation] == ["none"]:
            acts = {}
        else:
            acts = parse_activations(args.activation) or {"zygomaticus_major_l": 1.0, "zygomaticus_major_r": 1.0}
        take = step_take(
            model,
            frames=n_frames,
            fps=args.fps or 30.0,
            activations=acts,
            jaw_opening_deg=args.jaw_open,
            onset_frame=args.onset_frame,
            ramp=args.onset,
            head_shake=_head_shake(args.head_shake),
        )
    out = Path(args.out)
    contact = contact_from_args(args, model)  # a refused contact leaves --out as it was
    claim_take_dir(out, command_provenance("resim", model, args), overwrite=args.overwrite)
    sim = Simulator(model, device=args.device, solver=args.solver)
    skin_nodes, _ = skin_mesh(model)
    extra: dict = {}
    reference = take.reference_positions_m
    if reference is None and not args.no_reference:
        q0 = time.perf_counter()
        reference = quasistatic_reference(
            sim, model, take, frame=args.frame, tol=args.tol, contact=contact, progress=True
        )
        extra["quasistatic_seconds_per_frame"] = (time.perf_counter() - q0) / take.n_frames
    synthetic = take.source == "synthetic"
    step_response = synthetic and not args.head_shake  # overshoot of a held step (meaningless for a shaking head)
    substep_skin = []  # synthetic: skin positions after every time step (peaks fall between frames)
    result = _resimulate(args, model, take, damping, sim, contact, skin_nodes, substep_skin, step_response)
    report = {
        "source": take.source,
        "tets": model.n_tets,
        "nodes": model.n_nodes,
        "muscles": model.n_muscles,
        **result.summary(),
        **extra,
    }
    if contact is not None:
        report["contact_regions"] = list(contact.regions)
        report["obstacles"] = list(args.obstacle)
    if reference is not None:
        report.update(
            compare_with_quasistatic(
                result,
                reference,
                skin_nodes,
                onset_frame=args.onset_frame if step_response else None,
                substep_skin_m=substep_skin,
            )
        )
    report["kinetic_energy_peak_j"] = float(result.kinetic_energy_j.max())
    write_resim_npz(out / "resim.npz", result, reference_positions_m=reference)
    if not args.no_usd:
        write_take_usd(
            out / USD,
            model,
            result.positions_m,
            take=take,
            metadata={"dynamic": True},
            render_mesh=render_mesh_from_args(args, model),
            progress=True,
            rig=False if args.no_rig else "active",
        )
    report["seconds"] = time.perf_counter() - start
    write_report(out, report)
    if args.json:
        print(json.dumps({k: v for k, v in report.items() if not isinstance(v, list)}, indent=2))
        return 0
    line = (
        f"{take.n_frames} frames, {result.steps} steps ({result.scheme}, dt {result.dt_s * 1e3:.2f} ms), "
        f"{report['newton_iterations_per_step_mean']:.2f} Newton iterations/step, "
        f"{report['seconds_per_frame_median']:.2f} s/frame"
    )
    if "deviation_mm_max" in report:
        line += f", skin off the quasistatic frames by at most {report['deviation_mm_max']:.2f} mm (at the frames)"
    if "overshoot_mm" in report:  # between frames too: every time step after the onset
        line += (
            f", overshoot past the held pose {report['overshoot_mm']:.2f} mm of its {report['displacement_mm']:.2f} mm "
            "travel (the node moving most, any time step)"
        )
    print(line)
    if not report["converged"]:
        print("warning: some steps did not reach --tol (see residual_rel in report.json)")
    print_outputs(out, since=started)
    return 0


def _resimulate(args, model, take, damping, sim, contact, skin_nodes, substep_skin, step_response):
    """``resimulate`` with the command's settings (synthetic step responses record every step's skin)."""
    return resimulate(
        model,
        take,
        frame=args.frame,
        scheme=args.scheme,  # auto: backward Euler with contact (wface.physics.dynamics.DynamicSimulator)
        substeps=args.substeps,
        damping=damping,
        sim=sim,
        tol=args.tol,
        progress=True,
        on_step=(lambda state: substep_skin.append(state.x_m[skin_nodes].copy())) if step_response else None,
        contact=contact,
    )


def _refuse_options_that_do_nothing(args) -> None:
    """Usage errors (exit 2) for options this run would ignore: the synthetic take's options with
    --take (they were ignored and still recorded in provenance.json), a range for --frames without it."""
    if args.take:
        given = [k for k, default in _SYNTHETIC_ONLY.items() if getattr(args, k) != default]
        if given:
            names = ", ".join("--" + k.replace("_", "-") for k in given)
            raise UsageError(f"{names} shape(s) the synthetic take and would do nothing with --take")
    elif args.frames is not None and not (args.frames.isdigit() and int(args.frames) >= 2):
        raise UsageError(f"--frames {args.frames}: without --take it is the synthetic take's frame count (>= 2)")
