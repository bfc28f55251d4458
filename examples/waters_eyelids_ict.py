"""Calibrate the Waters upper-lid muscle of AU43 (eyes closed) against the ICT-FaceKit eyeBlink shape.

AU43 drove the palpebral ring at half strength, which moves the ICT head's lids 1.1 mm at most where
its artist's eyeBlink_L lowers the upper lid 7.3 mm (mean over the vertices moving more than half the
most) and 9.6 mm at most: a sphincter pulls a ring towards its centre and cannot sweep one lid over
the eye. The upper lid's own palpebral part does, and in Waters' model that is a linear muscle
(``orbicularis_oculi_palpebral_superior_{l,r}``) whose bony end lies below the eye and whose
insertion is the upper lid: the lid moves towards the bone, the lower lid, near the bone, hardly
(Waters' radial fall-off is zero at the attachment). It is placed from the layout's eye landmarks
(Leye_Up, Leye_Down), then calibrated (``wface.waters.calibrate.calibrate_muscle``: bone and
insertion within 15 / 8 mm, zone, fall-off and spring constant; bounded Powell, mirrored) in passes.
Prints the agreement with eyeBlink_L before and after (relative error, and the mean motion along
the artist's direction over the strongly moving vertices against its own magnitude, mm) and writes
OUT/report.json.

    python examples/waters_eyelids_ict.py --out /tmp/lids                       # ~5 min on 2 cores
    python examples/waters_eyelids_ict.py --out /tmp/lids \\
        --write-layout wface/data/waters_ict.json   # then restore the layout's "notes" and run
    # python -c "from wface.waters.face_model import *; from wface.waters.layout import save_layout; \\
    #     save_layout(builtin_face_layout(), 'wface/data/waters_builtin.json')"

Data: ICT-FaceKit (MIT, USC ICT).
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

DEFAULT_DATA = Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
FACE_ROWS = 9409  # ICT face region: vertices 0-9408
MUSCLE = "orbicularis_oculi_palpebral_superior_l"


def placed(layout):
    """The layout with the upper-lid muscles placed from the eye landmarks (replacing any there)."""
    from wface.waters.calibrate import mirror_name
    from wface.waters.muscles import LinearMuscle

    up, down = layout.landmarks_m["Leye_Up"], layout.landmarks_m["Leye_Down"]
    bone = down + 0.5 * (down - up) - np.array([0.0, 0.0, 0.01])  # below the lower lid, under the skin
    left = LinearMuscle(name=MUSCLE, bone_m=bone, insertion_m=up, zone_deg=40.0, spring_constant_m=0.008)
    right = replace(left, name=mirror_name(MUSCLE), bone_m=bone * [-1, 1, 1], insertion_m=up * [-1, 1, 1])
    kept = [m for m in layout.muscles if m.name not in (left.name, right.name)]
    return replace(layout, muscles=[*kept, left, right])


def main(argv: list[str] | None = None) -> dict:
    from wface.basis import ActuationBasis
    from wface.mesh.meshfile import read_surface_mesh
    from wface.waters.calibrate import calibrate_muscle, reference_agreement
    from wface.waters.layout import load_layout, save_layout
    from wface.waters.rig import WatersRig

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--layout", default="ict", help="start layout (file or packaged name; default the packaged ICT)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--max-evaluations", type=int, default=600, help="Powell evaluations per pass")
    ap.add_argument("--passes", type=int, default=2, help="Powell restarts within the same bounds")
    ap.add_argument("--write-layout", help="also write the calibrated layout here (cm, like the packaged one)")
    args = ap.parse_args(argv)
    data, out = Path(args.data), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mesh = read_surface_mesh(data / "ict-facekit" / "generic_neutral_mesh.obj", units="cm")
    rest = mesh.vertices_m
    blink = ActuationBasis.from_ict_npz(data / "ict-facekit" / "ict_expressions.npz", names=["eyeBlink_L"]).shapes_m[0]
    reference = np.zeros_like(rest)
    reference[:FACE_ROWS] = blink[:FACE_ROWS]
    rows = np.arange(FACE_ROWS)

    def agreement(layout):
        rig = WatersRig(layout, rest, triangles=mesh.triangles())
        return vars(reference_agreement(rig, reference, {"AU43L": 1.0}, rows=rows))

    start = load_layout(args.layout)
    before = agreement(start)
    layout = origin = placed(start)
    placed_agreement = agreement(layout)
    fits = []
    for k in range(args.passes):
        res = calibrate_muscle(layout, rest, reference, muscle=MUSCLE, action_units={"AU43L": 1.0}, vertices=rows,
                               max_evaluations=args.max_evaluations, bone_range_m=0.015, insertion_range_m=0.008,
                               bounds_from=origin)  # fmt: skip
        layout = res.layout
        fits.append({"pass": k, "error_before": res.error_before, "error_after": res.error_after})
        print(f"pass {k}: {MUSCLE} vs eyeBlink_L: relative error {res.error_before:.3f} -> {res.error_after:.3f}",
              flush=True)  # fmt: skip
    after = agreement(layout)
    for label, a in (("AU43 before", before), ("placed", placed_agreement), ("calibrated", after)):
        print(f"{label}: relative error {a['relative_error']:.3f}, cosine {a['cosine']:.3f}, along the artist's "
              f"direction {a['along_mm']:.2f} of {a['reference_mm']:.2f} mm")  # fmt: skip
    report = {"before": before, "placed": placed_agreement, "after": after, "fits": fits}
    (out / "report.json").write_text(json.dumps(report, indent=1, default=float))
    if args.write_layout:
        save_layout(layout, args.write_layout, units="cm")
    return report


if __name__ == "__main__":
    main()
