"""Four-fold test of basis refinement on real data: ICT-FaceKit shapes, AnimFace performances.

For each AnimFace take held out in turn: align the markers to the ICT neutral (built-in
landmarks + projection), analyse it with the ICT basis, refine the basis on the other three takes
(ridge weight towards the ICT shapes and number of iterations chosen by leave-one-take-out
validation inside the three training takes only; ``--no-select --regularization L`` fixes
the weight instead and iterates until the training error saturates), and
measure the held-out marker RMS error before and after refinement, both with the refined marker
shapes and with the refined whole-mesh basis (after RBF carry-over). Writes OUT/folds.json and
a plot per fold.

Data: ICT-FaceKit (MIT, USC ICT) and AnimFace (CC BY-SA 4.0, Miguel Ramos Carretero, Bournemouth
University, 2019).

    python examples/basis_ict_animface.py --out basis_folds            # full run
    python examples/basis_ict_animface.py --out /tmp/x --frame-step 20 --max-iterations 2 --no-select
    python examples/basis_ict_animface.py --out /tmp/x --no-select --compare-metrics   # surface vs straight carry
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

TAKES = ("JawMoCap.c3d", "CheeksMoCap.c3d", "EyebrowsMoCap.c3d", "NoseMoCap.c3d")


def main(argv: list[str] | None = None) -> dict:
    from wface.basis import (
        MarkerLayout,
        analyze,
        default_face_split,
        interpolate_to_mesh,
        load_basis,
        refine_marker_basis,
        stabilise_capture,
    )
    from wface.basis.landmarks import load_ict_animface_landmarks
    from wface.basis.plots import plot_analysis
    from wface.basis.refine import select_regularization
    from wface.io.mocap import read_c3d

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ap.add_argument("--out", required=True)
    ap.add_argument("--frame-step", type=int, default=1, help="use every N-th frame (tiny runs)")
    ap.add_argument("--max-iterations", type=int, default=30)
    ap.add_argument("--rel-tol", type=float, default=1e-3)
    ap.add_argument("--regularization", type=float, default=0.3, help="used with --no-select")
    ap.add_argument("--no-select", action="store_true", help="skip the inner validation of the ridge weight")
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--split", action="store_true", help="upper/lower face split in analysis and refinement")
    ap.add_argument("--support", type=float, default=None, help="locality: support fraction (e.g. 0.1)")
    ap.add_argument(
        "--metric",
        choices=("surface", "euclidean"),
        default="surface",
        help="RBF carry-over to the mesh: along the surface (default) or straight distances",
    )
    ap.add_argument(
        "--compare-metrics",
        action="store_true",
        help="also score the carry-over with the other metric (test_rms_mm_after_mesh_<metric>)",
    )
    ap.add_argument("--only", help="run only the fold holding out this take (e.g. EyebrowsMoCap.c3d)")
    args = ap.parse_args(argv)
    data, out = Path(args.data), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    basis = load_basis(data / "ict-facekit" / "ict_expressions.npz")
    takes = {n: read_c3d(data / "animface" / n).frames(0, None, args.frame_step) for n in TAKES}
    landmarks = load_ict_animface_landmarks()
    folds = []
    for test in TAKES:
        if args.only and test != args.only:
            continue
        t0 = time.perf_counter()
        train = [n for n in TAKES if n != test]
        first = takes[train[0]]
        layout = MarkerLayout.from_frame(basis, first.marker_names, first.positions_m[0], landmarks=landmarks)
        mb = layout.marker_basis(basis)
        split = default_face_split(mb.marker_names, mb.element_names) if args.split else None
        disp = {n: stabilise_capture(takes[n], layout).displacements_m for n in TAKES}
        if args.no_select:
            lam, n_it, scores = args.regularization, args.max_iterations, {}
        else:
            lam, n_it, scores = select_regularization(
                mb,
                [disp[n] for n in train],
                split=split,
                support_fraction=args.support,
                choose_iterations=True,
                max_iterations=args.max_iterations,
            )
        res = refine_marker_basis(
            mb,
            [disp[n] for n in train],
            regularization=lam,
            split=split,
            support_fraction=args.support,
            max_iterations=n_it,
            rel_tol=args.rel_tol if args.no_select else 0.0,
        )
        before = analyze(mb, disp[test], split=split)
        after = analyze(res.basis, disp[test], split=split)
        change = res.basis.shapes_m - mb.shapes_m
        mesh = interpolate_to_mesh(basis, layout.surface_m, change, metric=args.metric)
        after_mesh = analyze(layout.marker_basis(mesh), disp[test], split=split)
        by_metric = {args.metric: after_mesh.total_rms_m * 1e3}
        if args.compare_metrics:
            other = "euclidean" if args.metric == "surface" else "surface"
            mesh_other = interpolate_to_mesh(basis, layout.surface_m, change, metric=other)
            by_metric[other] = analyze(layout.marker_basis(mesh_other), disp[test], split=split).total_rms_m * 1e3
        fold = {
            "test": test,
            "train": train,
            "frames_test": int(disp[test].shape[0]),
            "frames_train": int(sum(disp[n].shape[0] for n in train)),
            "regularization": lam,
            "iterations_chosen": n_it,
            "regularization_validation_rms_mm": {str(k): v * 1e3 for k, v in scores.items()},
            "train_rms_mm_per_iteration": res.errors_mm,
            "test_rms_mm_before": before.total_rms_m * 1e3,
            "test_rms_mm_after": after.total_rms_m * 1e3,
            "test_rms_mm_after_mesh_rbf": after_mesh.total_rms_m * 1e3,
            "mesh_rbf_metric": args.metric,
            **{f"test_rms_mm_after_mesh_{m}": v for m, v in by_metric.items()},
            "test_displacement_rms_mm": float(np.sqrt(np.nanmean(np.sum(disp[test] ** 2, axis=2))) * 1e3),
            "seconds": time.perf_counter() - t0,
        }
        folds.append(fold)
        mesh_txt = ", ".join(f"{m} {v:.3f}" for m, v in by_metric.items())
        print(f"{test}: lambda {lam:g}, train {res.errors_mm[0]:.3f} -> {min(res.errors_mm):.3f} mm "
              f"({res.iterations} it), test {fold['test_rms_mm_before']:.3f} -> {fold['test_rms_mm_after']:.3f} mm "
              f"(mesh {mesh_txt}), {fold['seconds']:.0f} s", flush=True)  # fmt: skip
        if not args.no_plot:
            stem = Path(test).stem
            plot_analysis(before, out / f"{stem}_before.png", rate_hz=takes[test].rate_hz, title=f"{test}: ICT basis")
            plot_analysis(after, out / f"{stem}_after.png", rate_hz=takes[test].rate_hz,
                          title=f"{test}: basis refined on {', '.join(train)}")  # fmt: skip
    summary = {
        "folds": folds,
        "test_rms_mm_before_mean": float(np.mean([f["test_rms_mm_before"] for f in folds])),
        "test_rms_mm_after_mean": float(np.mean([f["test_rms_mm_after"] for f in folds])),
        "frame_step": args.frame_step,
        "split": bool(args.split),
        "support_fraction": args.support,
    }
    (out / "folds.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


if __name__ == "__main__":
    main()
