"""From a motion-capture take to animation a TD can open: track, edit, re-simulate, export.

    python examples/performance_pipeline.py --out out/pipeline                 # JawMoCap.c3d if present
    python examples/performance_pipeline.py --out out/pipeline --synthetic     # a take with known truth
    python examples/performance_pipeline.py --tets 2000 --frames 4 --no-contact --out /tmp/p   # seconds

Four stages on the built-in face (``wface.faces.builtin.build_face``), each one a public API call a
pipeline would make:

1. **Track** (``wface.tracking``). The capture is ``JawMoCap.c3d`` of the AnimFace set when it is
   found (``--mocap``, default ``$WFACE_DATA/animface/JawMoCap.c3d``, ``WFACE_DATA`` defaulting
   to ``../shared/data``), else a synthetic take
   whose activations are known (``wface.tracking.synthetic.synthesize_performance``, corrupted
   with 0.3 mm of noise). ``prepare_capture`` aligns the capture to the skin and embeds its
   markers using the *neutral frame* (``--neutral-frame``, default file frame 0, which may lie
   outside the tracked range): the neutral frame anchors the embedding, so every later frame is
   expression, not calibration. ``track_sequence`` then finds activations, cranium and jaw motion
   per frame, warm-started frame to frame. The tracked take is written the way ``wface track``
   writes it (``tracked/controls.npz``, ``tracked/frames/``), so ``wface edit`` and
   ``wface resim --take`` can read it too.
2. **Edit** in activation space (``wface.takes``): ``exaggerate`` x1.5 (``--exaggerate``) about
   the rest pose (drives past full activation become force-length scales, never activations
   above 1), then ``layer`` a smile (``expression_pose(model, "smile")``) with a sin^2 envelope
   over the middle half of the take (``--smile``, its peak weight). ``simulate_poses`` solves the
   quasistatic equilibrium of every edited frame.
3. **Re-simulate** the edited take dynamically (``wface.takes.dynamic.resimulate``, implicit midpoint,
   ``--substeps`` per frame): inertia, overshoot, secondary motion from the head motion. The
   edited take is the same ``wface.takes.Take`` type, so its exaggeration (per-muscle
   force-length scales) goes to the dynamic solver as it is. Lip contact (``wface.physics.contact``, lips
   against lips) is tried unless ``--no-contact``; when a contact step fails to converge the
   dynamic pass is redone without contact and the output says so (``contact`` in summary.json).
4. **Export**: one directory per stage, as the commands write them (``tracked/``: controls.npz,
   frames/; ``edited/``: controls.npz with the force-length scales, report.json; ``dynamic/``:
   resim.npz with the quasistatic reference), each with one USD stage ``animation.usdc`` holding a
   time sample per frame (tracked: skin, captured and simulated markers, bones, activations;
   edited: skin, bones, activations; dynamic: the skin), checked with
   ``wface.io.usd.assert_stage_valid``. So ``wface edit exaggerate --take OUT/tracked`` or
   ``wface resim --take OUT/edited`` pick up where the script stops. Next to them:
   ``mouth_corner.png`` (the displacement from rest of the left mouth-corner marker, as embedded at
   the neutral frame, in the cranium frame: the capture and the three stages side by side;
   numbers in ``mouth_corner.csv``) and ``summary.json``: marker RMS of
   the tracking (mm), activation ranges, overshoot and deviation of the dynamic pass from the
   quasistatic edited frames (mm), whether contact was used, seconds per stage.

What to expect from the default run (5,000 tets, JawMoCap file frames 326-372 at 30 fps, 2 CPU
cores, about 65 s: track 10 s, edit 5.5 s, dynamic 46 s with lip contact): 2.6 mm marker RMS
(the procedural face is not the actor: the neutral frame fits the skin to 5.8 mm RMS), the
corner marker moves 16.2 mm tracked and 23.6 mm edited; the tracker drives corrugator_r and
depressor_labii_inferioris_r to full activation, so x1.5 scales their force-length curves by 1.5.
The dynamic pass stays within 0.01 mm of the quasistatic edited frames (no overshoot): a jaw
opening over 0.4 s is slow against the face's 100-155 Hz modes; faster takes lag and overshoot
(the 3-frame synthetic take of the test: 0.9-3 mm). The lips never touch in this window (0.00 mm
overlap without contact), so contact converges but has nothing to do here.

Everything runs headless on the CPU; a test runs it with tiny options (``tests/test_pipeline_example.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

DATA_DIR = Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
DEFAULT_MOCAP = DATA_DIR / "animface" / "JawMoCap.c3d"
MOUTH_CORNER = "Mouth_Lend"  # the AnimFace name of the left mouth corner (the built-in face has it)


def _parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tets", type=int, default=5000, help="size of the built-in face in tetrahedra (default 5000)")
    ap.add_argument("--frames", type=int, default=24, help="frames to track (default 24)")
    ap.add_argument("--out", default="out/performance_pipeline", help="output directory")
    ap.add_argument("--no-contact", action="store_true", help="dynamic pass without lip contact")
    ap.add_argument("--mocap", default=str(DEFAULT_MOCAP), help="C3D/TRC/CSV take (default: AnimFace JawMoCap.c3d)")
    ap.add_argument("--synthetic", action="store_true", help="use a synthetic take even when the capture exists")
    ap.add_argument(
        "--start", type=int, default=326, help="capture: first file frame tracked (default 326: the jaw opens at 332)"
    )
    ap.add_argument("--stride", type=int, default=2, help="capture: keep every N-th frame (default 2: 60 -> 30 fps)")
    ap.add_argument("--neutral-frame", type=int, default=0, help="capture: file frame with the neutral face")
    ap.add_argument("--exaggerate", type=float, default=1.5, help="exaggeration factor (default 1.5)")
    ap.add_argument("--smile", type=float, default=0.6, help="peak weight of the layered smile (default 0.6)")
    ap.add_argument("--substeps", type=int, default=16, help="implicit time steps per frame (default 16)")
    ap.add_argument("--seed", type=int, default=0, help="synthetic take: random seed")
    args = ap.parse_args(argv)
    if args.frames < 2:
        ap.error("--frames must be >= 2 (a dynamic pass needs two frames)")
    return args


# ---------------------------------------------------------------------- stage 1: tracking
def _capture(args, model):
    """(targets (F, k, 3), marker names, MarkerMap, fps, info) in the model's frame."""
    from wface.tracking.capture import prepare_capture

    mocap = Path(args.mocap)
    if not args.synthetic and mocap.exists():
        from wface.io.mocap import read_mocap

        take = read_mocap(mocap)
        neutral = take.positions_m[args.neutral_frame]  # anchors alignment and embedding
        clip = take.frames(args.start, args.start + args.frames * args.stride, args.stride)
        cap = prepare_capture(model, clip.positions_m, clip.marker_names, reference_positions_m=neutral)
        info = {
            "source": str(mocap),
            "file_frames": [args.start, args.start + (clip.n_frames - 1) * args.stride],
            "stride": args.stride,
            "neutral_frame": args.neutral_frame,
            "alignment_rms_mm": cap.alignment_rms_mm,
            "matched_markers": len(cap.matched_names),
        }
        return cap.targets_m, clip.marker_names, cap.markers, clip.rate_hz, info, None
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import embed_model_markers
    from wface.tracking.synthetic import synthesize_performance

    rig = FaceRig(model, tol=1e-6)
    truth = synthesize_performance(
        rig, embed_model_markers(model), frames=args.frames, rate_hz=30.0, seed=args.seed, noise_mm=0.3
    )
    # the rest face is this actor's neutral frame: it anchors the embedding exactly as for a capture
    cap = prepare_capture(model, truth.markers_m, truth.marker_names, reference_positions_m=model.marker_positions_m)
    info = {"source": "synthetic", "seed": args.seed, "noise_mm": 0.3, "alignment_rms_mm": cap.alignment_rms_mm}
    return cap.targets_m, truth.marker_names, cap.markers, 30.0, info, truth


def track(args, model, out: Path):
    from wface.takes.store import take_from_records, write_controls, write_report
    from wface.tracking.sequence import track_sequence

    targets, names, markers, fps, info, truth = _capture(args, model)
    records = track_sequence(
        model,
        targets,
        marker_names=names,
        markers=markers,
        rig_kwargs={"tol": 1e-6},
        out_dir=out / "tracked",
        progress=True,
    )
    write_controls(out / "tracked", model, take_from_records(model, records, fps=fps))
    err_mm = np.array([r.marker_error_m for r in records]) * 1e3
    info["marker_rms_mm"] = float(np.sqrt(np.nanmean(err_mm**2)))
    info["marker_rms_mm_per_frame"] = np.sqrt(np.nanmean(err_mm**2, axis=1)).tolist()
    if truth is not None:
        M = model.n_muscles
        dA = np.array([r.controls[:M] for r in records]) - truth.activations
        info["activation_rms_error"] = float(np.sqrt(np.mean(dA**2)))
    # the keys `wface edit` / `wface resim` check when they read the directory back
    meta = {"frames": len(records), "tets": model.n_tets, "nodes": model.n_nodes, "fps": fps, **info}
    write_report(out / "tracked", meta)
    return records, targets, names, markers, fps, info


# ---------------------------------------------------------------------- stage 2: editing
def edit(args, model, records, fps):
    from wface.physics import Simulator
    from wface.takes import exaggerate, expression_pose, layer, simulate_poses
    from wface.takes.store import take_from_records

    joint = model.jaw_joint
    tracked = take_from_records(model, records, fps=fps)
    big = tracked.with_poses([exaggerate(p, args.exaggerate, joint=joint) for p in tracked.poses])
    F = len(big)
    s = np.clip((np.arange(F) - F / 4) / max(F / 2, 1), 0.0, 1.0)  # the middle half of the take
    envelope = args.smile * np.sin(np.pi * s) ** 2 * ((s > 0) & (s < 1))
    edited = layer(big, expression_pose(model, "smile"), envelope, joint=joint)
    edited = edited.with_poses(edited.poses, source=f"tracked x{args.exaggerate:g} + smile")
    sim = Simulator(model)
    # the exaggeration alone too, to see what each edit does to the mouth corner
    return (
        simulate_poses(model, edited, simulator=sim, progress=True),
        simulate_poses(model, big, simulator=sim),
        envelope,
    )


# ---------------------------------------------------------------------- stage 3: dynamics
def dynamics(args, model, edit_result):
    """(ResimResult, the re-simulated take, quasistatic reference (F, n, 3), contact note)."""
    from wface.physics import Simulator
    from wface.physics.contact import Contact
    from wface.takes.dynamic import quasistatic_reference, resimulate

    take = edit_result.take
    sim = Simulator(model)
    lips = Contact.from_spec(model, "lips")  # also measures how far the lips overlap without contact
    note = {"requested": not args.no_contact, "lip_overlap_mm_without_contact": _lip_overlap_mm(lips, edit_result.y_m)}
    if not args.no_contact:
        contact = lips
        try:
            result = resimulate(model, take, substeps=args.substeps, sim=sim, contact=contact, progress=True)
        except (FloatingPointError, np.linalg.LinAlgError, RuntimeError) as exc:
            result, note["error"] = None, f"{type(exc).__name__}: {exc}"
        if result is not None and result.converged.all():
            note["used"] = True
            note["lip_overlap_mm_dynamic"] = _lip_overlap_mm(lips, result.positions_m)
            note["inverted_elements_max"] = int(result.inverted_elements.max())
            reference = quasistatic_reference(sim, model, take, frame="cranium", contact=contact)
            return result, take, reference, note
        if result is not None:
            bad = np.flatnonzero(~result.converged).tolist()
            note["error"] = f"Newton did not converge in frames {bad} (residual {result.residual_rel.max():.2e})"
        note["used"] = False
        print(f"lip contact in dynamics did not converge on this face ({note['error']}); redoing without contact")
    result = resimulate(model, take, substeps=args.substeps, sim=sim, progress=True)
    return result, take, edit_result.x_m, note


def _lip_overlap_mm(lips, positions_m) -> float:
    """Deepest lip-through-lip penetration over the frames, mm (0: the lips never overlap)."""
    return max(lips.penetration(x)["max_penetration_m"] for x in positions_m) * 1e3


# ---------------------------------------------------------------------- stage 4: output
def _cranium_frame(positions_m, cranium_affines):
    """(F, n, 3) world positions -> the cranium's frame (expression without head motion)."""
    out = np.empty_like(positions_m)
    for k, A in enumerate(cranium_affines):
        out[k] = (positions_m[k] - A[:, 3]) @ np.linalg.inv(A[:, :3]).T
    return out


def _corner_mm(markers, i: int, positions_m, cranium_affines):
    """(F,) displacement from rest of marker ``i`` of ``markers`` (the capture's corner marker as
    embedded at the neutral frame) in the cranium frame, mm."""
    local = _cranium_frame(np.asarray(positions_m), cranium_affines)
    rest = markers.positions(markers.model.rest_positions_m)[i]
    return np.array([np.linalg.norm(markers.positions(x)[i] - rest) for x in local]) * 1e3


def _plot(path: Path, fps: float, curves: dict, captured_mm, exaggerated_mm, factor: float) -> str | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot (mouth_corner.csv has the numbers)")
        return None
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4), sharey=True)
    t = np.arange(len(next(iter(curves.values())))) / fps
    for ax, (name, y) in zip(axes, curves.items(), strict=True):
        if name == "tracked":
            ax.plot(t, captured_mm, "o", color="C3", ms=3, label="captured marker")
        else:
            ax.plot(t, curves["tracked"], color="0.6", lw=1, label="tracked")
        if name == "edited":
            ax.plot(t, exaggerated_mm, color="C1", ls="--", lw=1, label=f"x{factor:g} only")
        ax.plot(t, y, color="C0", lw=2, label=name)
        ax.set_title(name)
        ax.set_xlabel("time (s)")
        ax.legend(loc="upper left", fontsize=8)
    axes[0].set_ylabel(f"{MOUTH_CORNER} from rest (mm)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def main(argv=None) -> int:
    from wface.controls import bone_affines
    from wface.faces.builtin import build_face
    from wface.io.usd import assert_stage_valid
    from wface.takes import write_edit
    from wface.takes.dynamic import deviation_mm
    from wface.takes.store import take_from_records, write_resim_npz
    from wface.takes.usd import skin_mesh, write_take_usd

    args = _parse(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seconds = {}

    t0 = time.perf_counter()
    model = build_face(args.tets, progress=True)
    seconds["build"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    records, targets, names, markers, fps, track_info = track(args, model, out)
    seconds["track"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    edit_result, exaggerated, envelope = edit(args, model, records, fps)
    seconds["edit"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    dyn, dyn_take, reference, contact_note = dynamics(args, model, edit_result)
    seconds["dynamic"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    M = model.n_muscles
    C = np.array([r.controls for r in records])
    tracked_x = np.array([r.x_m for r in records])
    cranium, jaw = (np.stack(a) for a in zip(*(bone_affines(c[M:]) for c in C), strict=True))
    # one directory per stage, laid out as `wface track` / `wface edit` / `wface resim` write them,
    # so each can be fed to the next command (`wface edit ... --take OUT/tracked`, `wface resim --take OUT/edited`)
    stages = {
        "tracked": write_take_usd(
            out / "tracked" / "animation.usdc",
            model,
            tracked_x,
            take=take_from_records(model, records, fps=fps),
            captured_markers_m=targets,
            simulated_markers_m=np.array([r.markers_m for r in records]),
            marker_names=list(names),
        ),
        "edited": out / "edited" / "animation.usdc",
        "dynamic": write_take_usd(
            out / "dynamic" / "animation.usdc", model, dyn.positions_m, take=dyn_take, metadata={"dynamic": True}
        ),
    }
    edit_report = write_edit(out / "edited", model, edit_result, info={"edit": "exaggerate + layer smile"})
    write_resim_npz(out / "dynamic" / "resim.npz", dyn, reference_positions_m=reference)
    for path in stages.values():
        assert_stage_valid(path)

    edited_cranium = np.stack([bone_affines(p.bones(model.jaw_joint))[0] for p in edit_result.take.poses])
    # the corner as the capture sees it: its marker embedded at the neutral frame
    i = list(names).index(MOUTH_CORNER)
    curves = {
        "tracked": _corner_mm(markers, i, tracked_x, cranium),
        "edited": _corner_mm(markers, i, edit_result.x_m, edited_cranium),
        "dynamic": _corner_mm(markers, i, dyn.positions_m, edited_cranium),
    }
    exaggerated_mm = _corner_mm(markers, i, exaggerated.x_m, edited_cranium)
    rest_corner = markers.positions(model.rest_positions_m)[i]
    captured_local = [np.linalg.solve(A[:, :3], p - A[:, 3]) for A, p in zip(cranium, targets[:, i], strict=True)]
    captured_mm = np.linalg.norm(np.array(captured_local) - rest_corner, axis=1) * 1e3  # NaN where missing
    table = np.column_stack([np.arange(len(records)) / fps, captured_mm, *curves.values(), exaggerated_mm, envelope])
    np.savetxt(
        out / "mouth_corner.csv",
        table,
        delimiter=",",
        header="t_s,captured_mm,tracked_mm,edited_mm,dynamic_mm,exaggerated_only_mm,smile_weight",
    )
    plot = _plot(out / "mouth_corner.png", fps, curves, captured_mm, exaggerated_mm, args.exaggerate)
    skin, _ = skin_mesh(model)
    dev = deviation_mm(dyn.positions_m, reference, skin)
    over = curves["dynamic"] - curves["edited"]
    seconds["export"] = time.perf_counter() - t0

    take = edit_result.take
    summary = {
        "tets": model.n_tets,
        "nodes": model.n_nodes,
        "frames": len(records),
        "fps": fps,
        "tracking": track_info,
        "activation_range": {
            "tracked": [float(C[:, :M].min()), float(C[:, :M].max())],
            # muscles the tracker drove to full activation: often a misfit it cannot explain otherwise
            "tracked_saturated_muscles": [
                n for n, a in zip(model.muscle_names, C[:, :M].max(axis=0), strict=True) if a >= 0.999
            ],
            "edited": [float(take.activations.min()), float(take.activations.max())],
            "edited_drive_max": float(take.drives.max()),
            "scaled_muscles": edit_report["scaled_muscles"],
        },
        "mouth_corner_peak_mm": {
            **{k: float(v.max()) for k, v in curves.items()},
            "exaggerated_only": float(exaggerated_mm.max()),
        },
        "dynamic": {
            "scheme": dyn.scheme,
            "substeps": dyn.substeps,
            "converged": bool(dyn.converged.all()),
            "inverted_elements_max": int(dyn.inverted_elements.max()),
            "deviation_from_quasistatic_mm": dev.tolist(),
            "deviation_from_quasistatic_mm_max": float(dev.max()),
            "mouth_corner_overshoot_mm": float(over.max()),
            "mouth_corner_overshoot_mm_per_frame": over.tolist(),
            "contact": contact_note,
        },
        "usd": {k: str(Path(v).relative_to(out)) for k, v in stages.items()},
        "plot": plot,
        "seconds": seconds,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(
        f"tracked {len(records)} frames at {track_info['marker_rms_mm']:.2f} mm marker RMS; "
        f"mouth corner peak {summary['mouth_corner_peak_mm']['tracked']:.2f} -> "
        f"{summary['mouth_corner_peak_mm']['edited']:.2f} mm edited, dynamic overshoot {over.max():+.2f} mm, "
        f"max deviation from quasistatic {dev.max():.2f} mm; "
        f"lip contact: {'on' if contact_note.get('used') else 'off'} (lips overlap "
        f"{contact_note['lip_overlap_mm_without_contact']:.2f} mm without it)"
    )
    print("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in seconds.items()))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
