"""Play the ArtiSynth speech gestures on the imported Badin face and compare their lip openings.

Each gesture (closure, fricative, approximant) drives the face's muscles through its measured-style
excitation curves (both sides of each muscle); every frame is a quasistatic equilibrium
warm-started from the previous one. Writes, per gesture, OUT/<gesture>/lip_opening.{csv,png},
report.json and animation.usdc (``wface speech``), and OUT/lip_opening_all.png with the three curves.

With --track-mocap, also tracks an AnimFace take on the Badin face: the capture markers that the
alignment puts within --select-mm of the Badin skin are used (OUT/track/report.json).

Run:
    python examples/badin_speech.py --out badin_speech_out                 # 25 fps, all three
    python examples/badin_speech.py --gestures closure --max-frames 3 --out quick
    python examples/badin_speech.py --gestures --track-mocap ../shared/data/animface/JawMoCap.c3d \
        --track-frames 0:300:10 --out jaw_on_badin

Data: ../shared/data/artisynth-face (ArtiSynth Models, BSD-style; cite Nazari et al. 2010 and
Stavness et al.).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "artisynth-face"


def run(
    out: Path,
    *,
    gestures=("closure", "fricative", "approximant"),
    fps: float = 25.0,
    max_frames: int | None = None,
    data: Path = DATA,
    model_path: Path | None = None,
) -> dict:
    """Play ``gestures``; returns {gesture: summary} and writes the outputs under ``out``."""
    from wface.physics.simulator import Simulator
    from wface.speech import map_gesture_to_model, read_gesture, simulate_gesture, summarize
    from wface.speech.output import write_gesture_usd, write_lip_opening

    if model_path is not None:
        from wface.model import load_model

        model = load_model(model_path)
    else:
        from wface.faces.artisynth import import_artisynth

        model = import_artisynth(data, progress=False)
    sim = Simulator(model)  # one simulator (kernels, sparsity pattern) for all gestures
    out.mkdir(parents=True, exist_ok=True)
    results, summaries = {}, {}
    for name in gestures:
        g = read_gesture(data / "speech" / name)
        res = simulate_gesture(
            model,
            g,
            fps=fps,
            max_frames=max_frames,
            mapping=map_gesture_to_model(g, model),
            simulator=sim,
            progress=True,
        )
        d = out / name
        d.mkdir(exist_ok=True)
        write_lip_opening(d, res, model)
        write_gesture_usd(d / "animation.usdc", res, model, fps=fps, source=str(data / "speech" / name))
        summaries[name] = summarize(res)
        (d / "report.json").write_text(json.dumps(summaries[name], indent=2))
        results[name] = res
    from wface.viz.plots import _plt

    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for name, res in results.items():
        ax.plot(res.times_s, res.lip_opening_mm, "o-", ms=3, label=name)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("Mouth_Up - Mouth_Down (mm)")
    ax.set_title("Badin face: lip opening during speech gestures (quasistatic)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.savefig(out / "lip_opening_all.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return summaries


def track_take(
    out: Path,
    mocap: Path,
    *,
    frames: str = "0:300:10",
    select_mm: float = 5.0,
    data: Path = DATA,
    model_path: Path | None = None,
) -> dict:
    """Track frames A:B:STEP of a capture on the Badin face with the markers that land on its skin."""
    import time

    import numpy as np

    from wface.io.mocap import read_mocap
    from wface.speech.playback import select_capture_markers
    from wface.takes.store import take_from_records, write_controls, write_report
    from wface.tracking.capture import prepare_capture
    from wface.tracking.identifiability import rig_identifiability_mm
    from wface.tracking.report import build_report
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import track_sequence

    if model_path is not None:
        from wface.model import load_model

        model = load_model(model_path)
    else:
        from wface.faces.artisynth import import_artisynth

        model = import_artisynth(data, progress=False)
    a, b, step = (list(map(int, frames.split(":"))) + [1])[:3]
    take = read_mocap(mocap)
    sel = select_capture_markers(model, take.positions_m[a:b], take.marker_names, max_distance_mm=select_mm)
    cap = prepare_capture(model, take.positions_m[a:b:step][:, sel["indices"]], sel["names"])
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    recs = track_sequence(
        model,
        cap.targets_m,
        marker_names=sel["names"],
        markers=cap.markers,
        rig_kwargs={"tol": 1e-6},
        out_dir=out,
        resume=True,
        progress=True,
        first_frame=a,
    )
    wall = time.perf_counter() - t0
    ident = rig_identifiability_mm(FaceRig(model, tol=1e-6), cap.markers)
    rep = build_report(
        model,
        recs,
        markers_data_m=cap.targets_m,
        marker_names=sel["names"],
        rig_info={"device": "cpu", "wall_seconds": wall, "frames_range": [a, b], "frame_stride": step},
        identifiability_mm=ident,
    )
    rep["marker_selection"] = {
        "max_distance_mm": select_mm,
        "landmarks": sel["landmarks"],
        "kept": sel["names"],
        "scale": sel["scale"],
        "landmark_rms_mm": sel["landmark_rms_mm"],
        "distance_mm": dict(zip(take.marker_names, np.round(sel["distance_mm"], 2).tolist(), strict=True)),
    }
    rep["capture_scale"], rep["capture_rest_fit_mm"] = cap.scale, cap.alignment_rms_mm
    write_report(out, rep)
    write_controls(out, model, take_from_records(model, recs, fps=take.rate_hz / step))
    return rep


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--gestures", nargs="*", default=["closure", "fricative", "approximant"])
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--max-frames", type=int)
    p.add_argument("--data", type=Path, default=DATA, help="the artisynth-face data folder")
    p.add_argument("--model", type=Path, help="a saved Badin model (.npz) instead of importing")
    p.add_argument("--track-mocap", type=Path, help="also track this capture (C3D/TRC/CSV) on the Badin face")
    p.add_argument("--track-frames", default="0:300:10", help="A:B:STEP of the capture to track")
    p.add_argument("--select-mm", type=float, default=5.0, help="largest marker distance from the Badin skin")
    a = p.parse_args(argv)
    if a.track_mocap:
        rep = track_take(
            a.out / "track",
            a.track_mocap,
            frames=a.track_frames,
            select_mm=a.select_mm,
            data=a.data,
            model_path=a.model,
        )
        print(
            f"tracked {rep['frames']} frames on {rep['markers']} markers: "
            f"marker RMS {rep['marker_rms_mm_mean']:.3f} mm "
            f"(max {rep['marker_max_mm']:.2f} mm), {rep['seconds_per_frame_median']:.1f} s/frame"
        )
    if not a.gestures:
        return 0
    summaries = run(a.out, gestures=a.gestures, fps=a.fps, max_frames=a.max_frames, data=a.data, model_path=a.model)
    for name, s in summaries.items():
        lo = s["lip_opening_mm"]
        print(
            f"{name:12s} lip opening {lo['first']:6.2f} -> {lo['last']:6.2f} mm "
            f"(min {lo['min']:.2f}, max {lo['max']:.2f}), "
            f"{s['frames']} frames, {s['seconds_total']:.1f} s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
