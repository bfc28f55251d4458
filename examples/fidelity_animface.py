"""Fidelity on real capture: the built-in face against the face fitted to the actor, side by side.

    python examples/fidelity_animface.py --out out/fidelity                       # 4 takes, every 10th of 0:300
    python examples/fidelity_animface.py --out out/fidelity --step 1 --workers 2  # all 300 frames (hours on a CPU)
    python examples/fidelity_animface.py --out /tmp/f --takes Jaw --tets 2000 --frames 6 --step 3   # seconds

For each AnimFace take (``$WFACE_DATA/animface/<Take>MoCap.c3d``, ``WFACE_DATA`` defaulting to
``../shared/data``) and each face:

- ``builtin``: the built-in face (``build_face(--tets)``);
- ``fitted``: the same face fitted to the take's neutral marker frame (file frame 0,
  ``wface.faces.fit.fit_template`` with the markers alone: ``wface model fit --markers``);

the capture is aligned and embedded at the neutral frame (``prepare_capture``), every
``--holdout``-th marker by height is hidden from the fit (``wface.tracking.holdout``), and the
frames ``0:--frames:--step`` are tracked (``track_sequence``, warm-started frame to frame).
Per take and face: the fitted markers' RMS (mean over frames), the held-out markers' RMS (both in
the actor's millimetres: the capture comes onto the built-in face scaled by about 0.90, onto the
fitted one by 1, and the face's millimetres would flatter the smaller face), and the
share of frames in which each muscle sits at a bound (activation >= 0.999, "pinned high"; the lower
bound 0 is a resting muscle and is reported apart). Writes ``fidelity.json`` and
``fidelity.md`` (the README's table) under --out, plus one take directory per run
(``<take>_<face>/``, as ``wface track`` writes it, so its report and frames can be inspected).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from wface.faces.builtin import build_face
from wface.faces.fit import fit_template
from wface.io.mocap import read_mocap
from wface.takes.store import take_from_records, write_controls, write_report
from wface.tracking.capture import prepare_capture
from wface.tracking.cluster import dask_executor
from wface.tracking.holdout import hide, holdout_report, select_holdout
from wface.tracking.report import add_capture_units
from wface.tracking.sequence import track_sequence

TAKES = ("Jaw", "Nose", "Cheeks", "Eyebrows")
_PINNED = 0.999  # an activation this close to 1 sits at its upper bound


def data_dir() -> Path:
    return Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))


def pinned_shares(activations: np.ndarray, names: list[str], signed: tuple[str, ...] = ()) -> tuple[dict, dict]:
    """({muscle: share of frames at the upper bound}, {muscle: share at 0}) for muscles that ever touch it;
    a ``signed`` channel (the intra-oral pressure) counts as pinned at either end, -1 or 1."""
    is_signed = np.isin(names, signed)
    hi = np.where(is_signed, np.abs(activations) >= _PINNED, activations >= _PINNED).mean(axis=0)
    lo = (activations <= 1.0 - _PINNED).mean(axis=0)
    return (
        {n: float(v) for n, v in zip(names, hi, strict=True) if v > 0},
        {n: float(v) for n, v in zip(names, lo, strict=True) if v > 0},
    )


def run_one(face, take, frames, holdout: str, out: Path, workers: int) -> dict:
    """Track ``frames`` of ``take`` on ``face`` with hidden markers; returns the numbers."""
    neutral = take.positions_m[0]
    cap = prepare_capture(face, take.positions_m[frames], take.marker_names, reference_positions_m=neutral)
    hidden = select_holdout(holdout, take.marker_names, cap.targets_m[0])
    executor, chunk, close = dask_executor(workers=workers, n_frames=len(frames))
    t0 = time.perf_counter()
    try:
        records = track_sequence(
            face,
            hide(cap.targets_m, hidden),
            marker_names=take.marker_names,
            markers=cap.markers,
            rig_kwargs={"tol": 1e-6},
            chunk_size=chunk,
            executor=executor,
            out_dir=out,
            resume=True,
            progress=workers <= 1,
        )
    finally:
        close()
    err = np.array([r.marker_error_m for r in records]) * 1e3
    used = np.sqrt(np.nanmean(err**2, axis=1))
    hold = holdout_report(records, cap.targets_m, hidden, take.marker_names)
    acts = np.array([r.controls[: face.n_muscles] for r in records])
    hi, lo = pinned_shares(acts, face.muscle_names, tuple(face.pressure_actuators))
    result = {
        "frames": len(records),
        "tets": face.n_tets,
        "alignment_rms_mm": cap.alignment_rms_mm,
        "marker_rms_mm_mean": float(used.mean()),
        "holdout_rms_mm_mean": hold["holdout_rms_mm_mean"],
        "holdout_markers": hold["holdout_markers"],
        "holdout_rms_mm_per_marker": hold["holdout_rms_mm_per_marker"],
        "pinned_high_share": hi,
        "pinned_high_over_10pct": sorted(n for n, v in hi.items() if v > 0.10),
        "at_zero_share": lo,
        "seconds": time.perf_counter() - t0,
        "seconds_per_frame_median": float(np.median([r.stats["seconds"] for r in records])),
    }
    add_capture_units(result, cap.scale)  # the actor's millimetres beside the face's
    write_controls(out, face, take_from_records(face, records, fps=take.rate_hz / max(1, frames[1] - frames[0])))
    write_report(out, {**result, "marker_rms_mm": used.tolist(), "holdout_rms_mm": hold["holdout_rms_mm"]})
    return result


def table(results: dict) -> str:
    """The README's markdown table."""
    rows = [
        "| take | face | frames | face / actor scale | marker RMS used (mm) | held-out RMS (mm) "
        "| muscles pinned high > 10 % of frames |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for key, r in results.items():
        take, face = key.split("/")
        pinned = ", ".join(r["pinned_high_over_10pct"]) or "none"
        rows.append(
            f"| {take} | {face} | {r['frames']} | {r['capture_to_model_scale']:.3f} | "
            f"{r['marker_rms_capture_mm_mean']:.2f} | {r['holdout_rms_capture_mm_mean']:.2f} | {pinned} |"
        )
    return "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--takes", default=",".join(TAKES), help="comma-separated: Jaw, Nose, Cheeks, Eyebrows")
    p.add_argument("--faces", default="builtin,fitted", help="builtin, fitted or both (default both)")
    p.add_argument("--tets", type=int, default=20000, help="size of the built-in face (default 20000)")
    p.add_argument("--frames", type=int, default=300, help="track file frames START:FRAMES (default 300)")
    p.add_argument("--start", type=int, default=0, help="first file frame tracked (default 0; the neutral stays 0)")
    p.add_argument("--step", type=int, default=10, help="every STEP-th of them (default 10; 1 for all)")
    p.add_argument("--holdout", default="5", help="hidden markers: every Nth by height, or names (default 5)")
    p.add_argument("--workers", type=int, default=1, help="Dask workers per take (default 1)")
    p.add_argument(
        "--no-pressure",
        action="store_true",
        help="faces without the intra-oral pressure actuator (the muscles alone; results keyed '<face>-nopressure')",
    )
    p.add_argument(
        "--free-to-mm",
        type=float,
        default=18.0,
        help="the built-in face's bone side free up to this height above the mouth line (default 18, the "
        "vestibule; results keyed '<face>-free<MM>' otherwise)",
    )
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    template = build_face(args.tets, intraoral_pressure=not args.no_pressure, free_to_mm=args.free_to_mm)
    variant = ("-nopressure" if args.no_pressure else "") + (
        f"-free{args.free_to_mm:g}" if args.free_to_mm != 18.0 else ""
    )
    results_path = out / "fidelity.json"
    results = json.loads(results_path.read_text()) if results_path.exists() else {}
    for name in [t.strip() for t in args.takes.split(",") if t.strip()]:
        path = data_dir() / "animface" / f"{name}MoCap.c3d"
        if not path.exists():
            raise FileNotFoundError(f"{path} not found (set WFACE_DATA to the shared data folder)")
        take = read_mocap(path)
        frames = np.arange(args.start, min(args.frames, take.n_frames), args.step)
        if not len(frames):
            raise ValueError(f"no frames in {args.start}:{args.frames}:{args.step} of {take.n_frames}")
        for face_name in [f.strip() for f in args.faces.split(",") if f.strip()]:
            if face_name == "fitted":
                face = fit_template(template, markers_m=take.positions_m[0], marker_names=take.marker_names).model
            elif face_name == "builtin":
                face = template
            else:
                raise ValueError(f"unknown face {face_name!r} (builtin or fitted)")
            key = f"{name}/{face_name}" + variant
            print(f"{key}: {len(frames)} frames, {face.n_tets} tets")
            run_dir = out / key.replace("/", "_")  # one take directory per take, face and variant
            results[key] = run_one(face, take, frames, args.holdout, run_dir, args.workers)
            print(
                f"{key}: used {results[key]['marker_rms_capture_mm_mean']:.2f} mm, held out "
                f"{results[key]['holdout_rms_capture_mm_mean']:.2f} mm (the actor's mm; face / actor scale "
                f"{results[key]['capture_to_model_scale']:.3f}), pinned {results[key]['pinned_high_over_10pct']}"
            )
            results_path.write_text(json.dumps(results, indent=2) + "\n")
    (out / "fidelity.md").write_text(table(results))
    print(table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
