"""``wface bench --suite basis``: actuation-basis analysis and refinement timings.

Real data when present (ICT-FaceKit 57 shapes, AnimFace 41 markers, from $WFACE_DATA or
../shared/data next to the repository); otherwise a synthetic basis and performance of the same
size (57 elements, 41 markers, smooth random shapes, sparse random contractions). The JSON says
which in ``data``.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from wface.basis import MarkerBasis, MarkerLayout, analyze, load_basis, stabilise_capture
from wface.basis.landmarks import load_ict_animface_landmarks
from wface.basis.refine import model_marker_shapes
from wface.bench import suite_result
from wface.io.mocap import read_c3d

__all__ = ["run"]


def _data_dir() -> Path:
    env = os.environ.get("WFACE_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2].parent / "shared" / "data"


def _real():

    d = _data_dir()
    ict, jaw, cheeks = (
        d / "ict-facekit/ict_expressions.npz",
        d / "animface/JawMoCap.c3d",
        d / "animface/CheeksMoCap.c3d",
    )
    if not (ict.exists() and jaw.exists() and cheeks.exists()):
        return None
    basis = load_basis(ict)
    take = read_c3d(jaw)
    layout = MarkerLayout.from_frame(
        basis, take.marker_names, take.positions_m[0], landmarks=load_ict_animface_landmarks()
    )
    mb = layout.marker_basis(basis)
    return (
        mb,
        stabilise_capture(take, layout).displacements_m,
        stabilise_capture(read_c3d(cheeks), layout).displacements_m,
    )


def _synthetic(frames=1590, markers=41, elements=57, seed=0):

    rng = np.random.default_rng(seed)
    pos = rng.normal(scale=0.04, size=(markers, 3))
    centres = rng.normal(scale=0.04, size=(elements, 3))
    w = np.exp(-np.sum((pos[:, None] - centres[None]) ** 2, axis=2) / (2 * 0.03**2))  # (k, B)
    dirs = rng.normal(scale=0.01, size=(elements, 3))
    shapes = w[:, None, :] * dirs.T[None]
    mb = MarkerBasis(shapes, [f"k{i}" for i in range(markers)], [f"e{i}" for i in range(elements)], pos)
    t = np.arange(frames)[:, None] / 60.0
    x = np.clip(np.sin(2 * np.pi * rng.uniform(0.05, 0.5, elements) * t + rng.uniform(0, 6, elements)), 0, 1)
    x *= rng.random(elements) < 0.5

    def perf(xx):
        return mb.predict(xx) + rng.normal(scale=5e-4, size=(len(xx), markers, 3))

    return mb, perf(x), perf(x[::-1])


def run(args) -> dict:

    repeat = max(1, int(getattr(args, "repeat", 3) or 3))
    real = _real()
    data = "real: ICT-FaceKit expressions + AnimFace JawMoCap/CheeksMoCap" if real else "synthetic (no ../shared/data)"
    mb, d1, d2 = real if real else _synthetic()

    def timed(fn):
        ts = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            out = fn()
            ts.append(time.perf_counter() - t0)
        return float(np.median(ts)), out

    t_warm, an = timed(lambda: analyze(mb, d1))
    t_cold, an_cold = timed(lambda: analyze(mb, d1, warm_start=False))
    t_exact, _ = timed(lambda: analyze(mb, d1[:300], exact=True))
    t_nobound, _ = timed(lambda: analyze(mb, d1, upper=None))
    train = np.concatenate([d1, d2])[:1500]

    def one_iteration():
        a = analyze(mb, train)
        return model_marker_shapes(a.contractions, train, mb.shapes_m, regularization=1.0)

    t_iter, _ = timed(one_iteration)
    t_model, _ = timed(lambda: model_marker_shapes(an.contractions, d1, mb.shapes_m, regularization=1.0))
    n = d1.shape[0]
    entry = {
        "data": data,
        "elements": mb.n_elements,
        "markers": mb.n_markers,
        "frames": n,
        "repeat": repeat,
        "analysis_ms_per_frame": 1e3 * t_warm / n,
        "analysis_ms_per_frame_cold_start": 1e3 * t_cold / n,
        "analysis_ms_per_frame_exact_lstsq_subproblems": 1e3 * t_exact / 300,
        "analysis_ms_per_frame_unbounded_above": 1e3 * t_nobound / n,
        "active_set_iterations_per_frame": float(an.iterations.mean()),
        "active_set_iterations_per_frame_cold_start": float(an_cold.iterations.mean()),
        "marker_rms_mm": an.total_rms_m * 1e3,
        "refinement_iteration_s_1500_frames": t_iter,
        "refinement_frames": int(len(train)),
        "modelling_step_s": t_model,
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }
    return suite_result("basis", "cpu", [entry])  # numpy / scipy only
