"""The contact options every command shares (``--contact``, ``--obstacle``, ``--contact-stiffness``,
``--contact-smoothing-mm``, ``--contact-inside-at-rest``, ``--freeze-below``, ``--lip-surface``) and the
``Contact`` they describe.

The flags mean the same in every command; each command keeps the smoothing and freezing defaults
its tests measured (and says them in its ``--help``).
"""

from __future__ import annotations

import argparse

from wface.cli.errors import UsageError
from wface.cli.validate import finite_float, non_negative_float, options_given, positive_float
from wface.physics.contact import INSIDE_AT_REST, REGIONS, SURFACES, Contact, parse_obstacle

__all__ = ["add_contact_arguments", "contact_from_args"]


def contact_regions(text: str) -> str:
    """``--contact``'s type: comma-separated ``REGIONS`` (a typo is a usage error before any work)."""
    unknown = [r for r in (p.strip() for p in str(text).split(",")) if r and r not in REGIONS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown contact region(s) {', '.join(unknown)}; known: {', '.join(REGIONS)}")
    return text


def obstacle_spec(text: str) -> str:
    """``--obstacle``'s type: a spec ``parse_obstacle`` reads (a malformed one is a usage error before any work)."""
    try:
        parse_obstacle(text)
    except (ValueError, KeyError) as exc:
        raise argparse.ArgumentTypeError(str(exc).strip("'\"")) from None
    return text


def add_contact_arguments(
    p: argparse.ArgumentParser,
    *,
    smoothing_mm: float = 0.0,
    freeze_below: float | None = None,
    obstacles: bool = True,
    where: str = "every solve",
    lip_surface: str = "faceted",
) -> None:
    """Add the contact options to a sub-command parser.

    Args:
        p: the sub-command's parser.
        smoothing_mm: default width of the C2 penalty ramp in mm (0: the plain penalty).
        freeze_below: default relative residual below which Newton freezes the self-contact
            features (``wface.physics.frozen``); None: never.
        obstacles: also offer ``--obstacle``.
        where: what the contact applies to, for the help text.
        lip_surface: default surface of the lip self-contact (one of ``wface.physics.contact.SURFACES``).
    """
    p.add_argument(
        "--contact",
        default="",
        type=contact_regions,
        metavar="REGIONS",
        help=f"contact in {where}, comma-separated: lips (upper vs lower lip self-contact), teeth (flesh "
        "against the teeth meshes), bones (against the cranium, maxilla and jaw meshes), skull (against the jaw and "
        "maxilla only, as ArtiSynth's lip-skull contact); teeth, bones and skull move with their bone (default: none)",
    )
    if obstacles:
        p.add_argument(
            "--obstacle",
            action="append",
            default=[],
            type=obstacle_spec,
            metavar="SPEC",
            help="rigid obstacle pressed into the face (repeatable), metres: sphere:X,Y,Z,R (ball of radius R "
            "at X,Y,Z) or plane:PX,PY,PZ,NX,NY,NZ (solid half-space through P, outward normal N toward the face)",
        )
    p.add_argument(
        "--contact-stiffness",
        type=positive_float,
        default=None,
        metavar="N_PER_M",
        help="contact penalty stiffness in N/m (default: 100 x flesh Young's modulus x median edge length)",
    )
    p.add_argument(
        "--contact-smoothing-mm",
        type=non_negative_float,
        default=smoothing_mm,
        metavar="MM",
        help=f"width of the C2 penalty ramp in mm (default {smoothing_mm:g}; 0: the plain penalty)",
    )
    p.add_argument(
        "--contact-inside-at-rest",
        choices=list(INSIDE_AT_REST),
        default="ignore",
        help="flesh nodes that lie inside a bone or teeth mesh at rest (the Badin data: up to 8.7 mm in the teeth, "
        "0.58 mm in the maxilla): left out of that mesh's contact (ignore: the default, the rest shape stays an "
        "equilibrium), pushed out like every other node (push: ArtiSynth's collisions beyond their penetration "
        "tolerance) or held in contact at their rest depth (hold: ArtiSynth's within it, e.g. its 1 mm lip-skull "
        "tolerance on wface's tets). docs/design.md, 'Contact'",
    )
    p.add_argument(
        "--freeze-below",
        type=finite_float,
        default=-1.0 if freeze_below is None else freeze_below,
        metavar="R",
        help="relative residual below which Newton freezes the lip contact features "
        f"(default {'never' if freeze_below is None else f'{freeze_below:g}'}; 1: always; negative: never; "
        "see wface.physics.frozen)",
    )
    p.add_argument(
        "--lip-surface",
        choices=list(SURFACES),
        default=lip_surface,
        help=f"surface of the lip contact (default {lip_surface}): smooth (C2 blend of the lips' Loop refinement; "
        "Newton converges quadratically near contact; the lips round up to 0.5 mm inside their nodes on Badin), "
        "smooth_through_nodes (the same, offset at rest to pass through the lip nodes) or faceted (the collision "
        "triangles as they are; --freeze-below works only there). docs/design.md, 'Smooth lip surfaces'",
    )
    p.set_defaults(
        contact_option_defaults={
            "contact_stiffness": None,
            "contact_smoothing_mm": smoothing_mm,
            "contact_inside_at_rest": "ignore",
            "freeze_below": -1.0 if freeze_below is None else freeze_below,
            "lip_surface": lip_surface,
        }
    )


def contact_from_args(args: argparse.Namespace, model):
    """The ``wface.physics.contact.Contact`` the parsed options describe, or None without any.

    Unknown regions and malformed obstacle specs raise ValueError with the offending text."""
    regions = getattr(args, "contact", "") or ""
    specs = getattr(args, "obstacle", []) or []
    if not regions and not specs:
        given = options_given(args, getattr(args, "contact_option_defaults", {}))
        if given:  # they were silently dropped
            names = ", ".join(given)
            raise UsageError(f"{names} set(s) the contact, which is off: add --contact REGIONS or --obstacle")
        return None
    lips = "lips" in [r.strip() for r in regions.split(",")]
    surface = getattr(args, "lip_surface", "faceted") if lips else "faceted"  # the lip contact's only
    if surface != "faceted" and args.freeze_below >= 0:
        raise UsageError(
            f"--freeze-below freezes faceted lip features; the lip surface is {surface}: "
            "use --freeze-below with --lip-surface faceted, or leave it out"
        )
    return Contact.from_spec(
        model,
        regions,
        specs,
        stiffness_n_per_m=args.contact_stiffness,
        smoothing_m=args.contact_smoothing_mm * 1e-3,
        freeze_below=None if args.freeze_below < 0 else args.freeze_below,
        inside_at_rest=getattr(args, "contact_inside_at_rest", "ignore"),
        surface=surface,
    )
