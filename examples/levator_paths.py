"""Do the upper-lip levators make NoseMoCap's sneer if they pull the lip back into the face as well as up?

    python examples/levator_paths.py --out out/levator_paths      # built-in face, 5,000 tets, ~3 minutes

In the sneer the capture's upper lip goes up and back (Mouth_UpL1 7.6 mm up, 5.6 mm back), the built-in
face's up and forward ("NoseMoCap's misfit" in README.md). The built-in levators (levator labii superioris,
its alaeque nasi part, zygomaticus minor) run from 15 % of the soft tissue's depth at their origin through
45-50 % to 70 % at their insertion in the lip (``wface.faces.builtin.anatomy``, depth fraction w: 0 bone,
1 skin), so they pull the lip mostly upward. Two variants move the paths deeper so that the pull has a
backward part: ``deep`` puts the origin on the bone (w = 0.02) and the middle at w = 0.15; ``deep_dermis``
also inserts in the dermis (w = 0.85). For each face ``examples/lip_sneer.py``'s measure: the bounded
least-squares fit of the sneer's peaks at the four upper-lip and nose markers by the muscles, linear at
rest and solved as an equilibrium. Writes ``levator_paths.json``.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from lip_sneer import analyse, data_dir  # examples/lip_sneer.py, beside this script

import wface.faces.builtin.face as builtin_face
from wface.faces.builtin import build_face
from wface.io.mocap import read_mocap

LEVATORS = ("levator_labii_superioris", "levator_labii_superioris_alaeque_nasi", "zygomaticus_minor")
VARIANTS = {  # depth fraction w of the path's three control points (origin, middle, insertion); None: unchanged
    "built-in": (None, None, None),
    "deep": (0.02, 0.15, None),
    "deep_dermis": (0.02, 0.15, 0.85),
}


def levator_face(tets: int, depths: tuple):
    """The built-in face with the levators' control points at the depths ``depths``."""
    saved = builtin_face.MUSCLES
    specs = []
    for spec in saved:
        if spec.name in LEVATORS:
            points = [(t, y, w if d is None else d) for (t, y, w), d in zip(spec.points, depths, strict=True)]
            spec = replace(spec, points=tuple(points))
        specs.append(spec)
    builtin_face.MUSCLES = tuple(specs)
    try:
        return build_face(tets)
    finally:
        builtin_face.MUSCLES = saved


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--tets", type=int, default=5000, help="size of the built-in face (default 5000)")
    p.add_argument("--frames", type=int, default=300, help="frames of NoseMoCap to analyse (default 300)")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    take = read_mocap(data_dir() / "animface" / "NoseMoCap.c3d")
    rows = {}
    print("| levators | linear fit (mm RMS) | solved (mm RMS) | Mouth_UpL1 solved residual (lateral, up, forward) mm |")
    print("| --- | --- | --- | --- |")
    for name, depths in VARIANTS.items():
        fit = analyse(levator_face(args.tets, depths), take, args.frames)["peak_fit"]
        rows[name] = {k: fit[k] for k in ("capture_rms_mm", "linear_rms_mm", "solved_rms_mm", "solved_residual_mm")}
        lip = [round(v, 1) for v in fit["solved_residual_mm"]["Mouth_UpL1"]]
        print(f"| {name} | {fit['linear_rms_mm']:.2f} | {fit['solved_rms_mm']:.2f} | {lip} |", flush=True)
    (out / "levator_paths.json").write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
