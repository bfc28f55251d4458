"""``wface bench --suite track``: seconds per tracked frame and its breakdown (quasistatic solves,
Jacobians, the small Gauss-Newton system) on a synthetic performance of the built-in face."""

from __future__ import annotations

import time

import numpy as np

from wface.bench import suite_result
from wface.faces.builtin import build_face
from wface.tracking.rig import FaceRig
from wface.tracking.sequence import embed_model_markers, track_sequence
from wface.tracking.synthetic import synthesize_performance
from wface.warp_runtime import resolve_device

DEFAULT_TETS = (20_000, 100_000)


def _one(n_tets: int, device: str, frames: int) -> dict:

    model = build_face(n_tets)
    kwargs = {"device": "cpu" if device == "auto" else device, "tol": 1e-6}
    rig = FaceRig(model, **kwargs)
    markers = embed_model_markers(model)
    perf = synthesize_performance(rig, markers, frames=frames, seed=0, noise_mm=0.5)
    t = time.perf_counter()
    recs = track_sequence(model, perf.markers_m, marker_names=model.marker_names, markers=markers, rig_kwargs=kwargs)
    wall = time.perf_counter() - t
    later = recs[1:] or recs  # the first frame starts cold (more Gauss-Newton steps)
    med = lambda key: float(np.median([r.stats[key] for r in later]))  # noqa: E731
    return {
        "tets": model.n_tets,
        "frames": frames,
        "seconds_per_frame": med("seconds"),
        "seconds_first_frame": recs[0].stats["seconds"],
        "breakdown_seconds_per_frame": {
            "quasistatic_solves": med("quasistatic_s"),
            "jacobians": med("jacobian_s"),
            "gauss_newton_system": med("gauss_newton_system_s"),
        },
        "quasistatic_solves_per_frame": med("quasistatic_solves"),
        "gauss_newton_steps_per_frame": med("gauss_newton_steps"),
        "wall_seconds": wall,
    }


def run(args) -> dict:
    sizes = args.tets or list(DEFAULT_TETS)
    device = resolve_device("cpu" if args.device == "auto" else args.device)
    return suite_result("track", device, [_one(int(n), device, 4) for n in sizes])
