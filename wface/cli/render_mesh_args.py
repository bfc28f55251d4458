"""``--render-mesh MESH`` (and ``--render-mesh-units``): the user's own mesh moved with the FEM face
in the USD output of ``track``, ``demo``, ``edit`` and ``resim`` (``wface.faces.render_mesh``).

A command that reads a take (``--take``) carries the take's render mesh on without the option: the
file its ``animation_render_mesh.usdc`` was written from, in the same units. ``--render-mesh none``
leaves it out; a file since moved is said, not silently dropped."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from wface.faces.render_mesh import bind_render_mesh
from wface.io.usd.render_mesh import recorded_render_mesh
from wface.mesh.meshfile import read_surface_mesh

__all__ = ["add_render_mesh_arguments", "render_mesh_from_args"]


def _readable_mesh(path: str) -> str:
    """``--render-mesh``'s type: the file is read once when the options are parsed, so a missing or
    broken mesh stops the command before a face is built or a frame tracked (it is read again to bind)."""
    if path == "none":
        return path
    try:
        read_surface_mesh(path)
    except (OSError, ValueError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return path


def add_render_mesh_arguments(p: argparse.ArgumentParser) -> None:
    """Add ``--render-mesh`` and ``--render-mesh-units`` to a sub-command parser."""
    p.add_argument(
        "--render-mesh",
        metavar="MESH",
        type=_readable_mesh,
        help="a triangle/quad mesh (.obj with UVs and materials, .ply, .stl, ...) bound to the face and written "
        "to USD beside the FEM skin (its own layer, in its own units); best on a face fitted to it "
        "(wface model fit --surface MESH). With --take the take's own render mesh is carried on unless "
        "this names another, or 'none'",
    )
    p.add_argument("--render-mesh-units", default="auto", help="units of --render-mesh: auto, m, cm, mm")


def render_mesh_from_args(args, model):
    """The bound ``RenderMesh`` of the options, or None; says on stderr how it was placed and bound
    (stdout stays clean for ``--json``)."""
    path, units = getattr(args, "render_mesh", None), getattr(args, "render_mesh_units", "auto")
    if path == "none":
        return None
    if not path and getattr(args, "take", None):
        path, units = _take_render_mesh(Path(args.take), units)
    if not path:
        return None
    rm = bind_render_mesh(model, path, units=units)
    b = rm.binding
    print(
        f"render mesh {path}: {rm.mesh.n_points} vertices, {rm.mesh.n_faces} faces, {rm.mesh.meters_per_unit:g} m "
        f"per unit, placed by {rm.placement}; {len(b.inside)} inside the tets, {len(b.outside)} outside "
        f"(median {1e3 * float(np.median(b.distance_m[b.outside]) if len(b.outside) else 0):.1f} mm off the skin)",
        file=sys.stderr,
    )
    return rm


def _take_render_mesh(take: Path, units):
    """(the mesh file and units a take's render mesh was written from, or None), said on stderr."""
    recorded = recorded_render_mesh(take / "animation_render_mesh.usdc")  # beside animation.usdc or .usda
    if recorded is None:
        return None, units
    source, meters_per_unit = recorded
    if not Path(source).is_file():
        print(
            f"warning: the take's render mesh {source} is not found: this output has none (pass --render-mesh "
            "FILE to bind it again, or --render-mesh none to say so)",
            file=sys.stderr,
        )
        return None, units
    print(f"render mesh from the take: {source} (--render-mesh none to leave it out)", file=sys.stderr)
    return source, meters_per_unit
