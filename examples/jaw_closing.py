"""Does the actor's jaw close past the neutral frame? A capture against the jaw joint's closing range.

    python examples/jaw_closing.py --out out/jaw_closing                      # CheeksMoCap, 0:300, 5,000 tets
    python examples/jaw_closing.py --out out/jaw_closing --take Nose --tets 20000

A capture's neutral frame is aligned to the face's rest pose, so the rest is the actor's postural
rest, teeth apart; from there a jaw closes by the freeway space (docs/design.md, "Controls and the
jaw joint"). This tracks the take (``$WFACE_DATA/animface/<Take>MoCap.c3d``, every 5th marker by
height hidden) twice on the built-in face: with its joint as built (closing 2.3 degrees past rest
allowed, 4 mm at the incisors) and with the rest as the closed limit (``max_closing_sine`` = 0, the
joint before), the take's first frame as the neutral one. Against them, the capture's own
nose-to-chin distance (NoseTop - Chin, a distance, so head motion does not enter) from the neutral
frame. Writes ``jaw_closing.png`` (the distance, the
tracked jaw opening of both runs with the limits, the per-frame marker RMS used and held out) and
``jaw_closing.json`` (the numbers), and the two runs' outputs under ``closed_at_rest/`` and
``closing/``.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from wface.cli import main as wface_main
from wface.controls import jaw_limits
from wface.faces import build_face
from wface.io.mocap import read_mocap
from wface.model import save_model

RUNS = ("closed_at_rest", "closing")


def data_dir() -> Path:
    return Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))


def track_both(out: Path, take: Path, tets: int, frames: str) -> tuple[dict, float]:
    """Track ``take`` with the built-in face's joint and with rest as the closed limit: ({run: report},
    the built-in face's closing limit in degrees)."""
    face = build_face(tets)
    models = {"closing": face, "closed_at_rest": replace(face, jaw_joint=replace(face.jaw_joint, max_closing_sine=0.0))}
    reports = {}
    for run in RUNS:
        path = save_model(models[run], out / f"{run}.npz")
        args = ["track", "--model", str(path), "--mocap", str(take), "--frames", frames, "--neutral-frame", "0"]
        args += ["--holdout", "5"]
        if wface_main([*args, "--no-pictures", "--no-usd", "--overwrite", "--out", str(out / run)]) != 0:
            raise SystemExit(f"wface track failed for {run}")
        reports[run] = json.loads((out / run / "report.json").read_text())
    return reports, -jaw_limits(face.jaw_joint)["opening_deg"][0]


def nose_to_chin_mm(take_path: Path, frames: str) -> tuple[np.ndarray, float]:
    """(NoseTop - Chin distance change from the take's neutral first frame, mm, per frame of ``frames``;
    the rate in Hz)."""
    take = read_mocap(take_path)
    lo, hi = (int(v) for v in frames.split(":"))
    names = take.marker_names
    p = take.positions_m
    d = np.linalg.norm(p[:, names.index("NoseTop")] - p[:, names.index("Chin")], axis=1) * 1e3
    return d[lo:hi] - d[0], float(take.rate_hz)


def plot(path: Path, res: dict) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(len(res["nose_to_chin_mm"])) / res["rate_hz"]
    fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax0.plot(t, res["nose_to_chin_mm"], "k", lw=1.2)
    ax0.set_ylabel("NoseTop - Chin,\nfrom neutral (mm)")
    ax0.set_title(f"{res['take']}: the capture's nose-to-chin distance and the tracked jaw", fontsize=10)
    style = {"closed_at_rest": ("C3", "rest as the closed limit"), "closing": ("C0", "closing past rest allowed")}
    for run in RUNS:
        color, label = style[run]
        ax1.plot(t, res[run]["jaw_opening_deg"], color=color, lw=1.2, label=label)
        rms = res[run]
        ax2.plot(t, rms["marker_rms_mm"], color=color, lw=1.0, label=f"{label}: used {rms['used_mean_mm']:.2f} mm")
        ax2.plot(
            t, rms["holdout_rms_mm"], color=color, lw=1.0, ls="--", label=f"held out {rms['holdout_mean_mm']:.2f} mm"
        )
    ax1.axhline(0.0, color="C3", ls=":", lw=0.8)
    ax1.axhline(-res["closing_limit_deg"], color="C0", ls=":", lw=0.8)
    ax1.set_ylabel("tracked jaw\nopening (deg)")
    ax1.legend(fontsize=8)
    ax2.set_ylabel("marker RMS (mm)")
    ax2.set_xlabel("time (s)")
    ax2.legend(fontsize=7, ncol=2)
    for ax in (ax0, ax1, ax2):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--take", default="Cheeks", help="AnimFace take: Jaw, Nose, Cheeks (default) or Eyebrows")
    p.add_argument("--tets", type=int, default=5000, help="size of the built-in face (default 5000)")
    p.add_argument("--frames", default="0:300", help="frame range START:END (default 0:300)")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    take = data_dir() / "animface" / f"{args.take}MoCap.c3d"
    if not take.is_file():
        raise SystemExit(f"{take} not found (set WFACE_DATA to the folder holding animface/)")
    reports, closing_limit_deg = track_both(out, take, args.tets, args.frames)
    distance, rate = nose_to_chin_mm(take, args.frames)
    res = {"take": f"{args.take}MoCap", "frames": args.frames, "tets": reports["closing"]["tets"], "rate_hz": rate}
    res["closing_limit_deg"] = closing_limit_deg
    res["nose_to_chin_mm"] = distance.tolist()
    limits = {"closed_at_rest": 0.0, "closing": -res["closing_limit_deg"]}
    for run in RUNS:
        rep = reports[run]
        jaw = np.asarray(rep["jaw_opening_deg"])
        res[run] = {
            "used_mean_mm": rep["marker_rms_mm_mean"],
            "holdout_mean_mm": rep["holdout_rms_mm_mean"],
            "closed_limit_deg": limits[run],
            "frames_on_the_closed_limit": float(np.mean(jaw <= limits[run] + 1e-3)),
            "jaw_opening_min_deg": float(jaw.min()),
            "jaw_opening_deg": jaw.tolist(),
            "marker_rms_mm": rep["marker_rms_mm"],
            "holdout_rms_mm": rep["holdout_rms_mm"],
        }
    (out / "jaw_closing.json").write_text(json.dumps(res, indent=1))
    plot(out / "jaw_closing.png", res)
    for run in RUNS:
        r = res[run]
        print(
            f"{run}: marker RMS {r['used_mean_mm']:.3f} mm used, {r['holdout_mean_mm']:.3f} mm held out; jaw opening "
            f"min {r['jaw_opening_min_deg']:.2f} deg, "
            f"{100 * r['frames_on_the_closed_limit']:.0f} % of frames on its limit"
        )
    print(f"capture: NoseTop - Chin from neutral, min {distance.min():.1f} mm; wrote {out / 'jaw_closing.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
