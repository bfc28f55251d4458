"""Tracking a whole take: frames in order with warm starts, split into chunks for parallel workers.

Frames are independent given a start guess (Sifakis et al. 2005, section 9), so a take splits into chunks
of consecutive frames; each chunk starts cold (rest controls, cranium from a rigid fit of the
stable markers, more Gauss-Newton steps) and warm-starts frame to frame inside: each frame hands
the next its equilibrium with the Jacobian and the factorisation there (``RigLinearization``), so a
warm frame starts with no solve and its solves take chord steps with that factor. Chunks run on any
``concurrent.futures``-style executor (``submit`` returning futures), e.g. a process pool or a
Dask ``Client.get_executor()``. With ``out_dir``, each frame is written to
``out_dir/frames/frame_NNNNNN.npz`` as soon as it is done (atomically, ``wface.takes.store``), and
``resume=True`` skips frames already on disk, so an interrupted run loses nothing.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from wface.controls import params_from_affine
from wface.mesh.align import embed_markers, umeyama
from wface.takes.store import FrameRecord, load_frame_records, write_frame
from wface.tracking.estimator import FrameEstimator, MarkerMap, TrackOptions
from wface.tracking.rig import FaceRig, RigState

__all__ = ["dask_executor", "embed_model_markers", "initial_controls", "track_sequence"]

STABLE_MARKERS = ("ForeHead_L", "ForeHead_M", "ForeHead_R", "NoseTop", "Eyebrow_Center")


def embed_model_markers(model, markers_rest_m: np.ndarray | None = None):
    """Embed markers (default: the model's own) in the skin; returns a ``MarkerMap``."""
    pts = model.marker_positions_m if markers_rest_m is None else markers_rest_m
    return MarkerMap(model, embed_markers(pts, model.rest_positions_m, model.skin_triangles))


def initial_controls(rig, markers: MarkerMap, target_m: np.ndarray, marker_names) -> np.ndarray:
    """Rest controls with the cranium set by a rigid fit of the stable markers (all markers if too few)."""
    c = rig.rest_controls()
    rest = markers.positions(rig.model.rest_positions_m)
    idx = [i for i, n in enumerate(marker_names) if n in STABLE_MARKERS]
    ok = [i for i in idx if np.all(np.isfinite(target_m[i]))]
    if len(ok) < 3:
        ok = list(np.flatnonzero(np.isfinite(target_m).all(axis=1)))
    if len(ok) >= 3:
        sim = umeyama(rest[ok], target_m[ok], with_scale=False)
        c[rig.n_muscles : rig.n_muscles + 12] = params_from_affine(sim.rotation, sim.translation_m)
    return c


def _track_chunk(model, embedding, targets, frames, marker_names, options, rig_kwargs, out_dir, resume, progress):
    """Track consecutive frames (runs in a worker). Returns the list of FrameRecords."""
    rig = FaceRig(model, **{"factor_precision": options.factor_precision, **rig_kwargs})
    markers = MarkerMap(model, embedding)
    est = FrameEstimator(rig, markers, options)
    out = []
    done = load_frame_records(out_dir, frames) if (out_dir is not None and resume) else {}
    c, y, a_prev, c_older, lin, resumed = None, None, None, None, None, None
    for j, f in enumerate(tqdm(frames, desc="tracking", disable=not progress, unit="frame")):
        if f in done:
            rec = done[f]
            c_older, c, y, a_prev = c, rec.controls, rec.y_m, rec.controls[: rig.n_muscles]
            if lin is not None:
                lin.free()
            lin = None
            resumed = RigState(rec.controls, rec.y_m, rec.x_m)  # linearised again if the next frame is new
            out.append(rec)
            continue
        if lin is None and resumed is not None and options.reuse_factor:
            lin = rig.linearize(resumed)  # as the interrupted run had it: a resumed take is the same take
        resumed = None
        first = c is None
        c_last = c
        if first:
            c = initial_controls(rig, markers, targets[j], marker_names)
        elif lin is None and c_older is not None and options.extrapolate:
            c = est.retract(2.0 * c - c_older)  # constant-velocity prediction of the controls
        steps = options.gn_steps_first if first else options.gn_steps
        res = est.estimate(int(f), targets[j], c, y, steps=steps, a_prev=a_prev, start=lin)
        c_older = c_last
        c, y, a_prev, lin = res.controls, res.state.y_m, res.controls[: rig.n_muscles], res.linearization
        stats = {
            "gauss_newton_steps": res.gauss_newton_steps,
            "quasistatic_solves": res.quasistatic_solves,
            "linear_solves": res.linear_solves,
            "newton_iterations": res.state.newton_iterations,
            "residual_rel": res.state.residual_rel,
            "inverted_elements": res.state.inverted_elements,
            "penalty": res.penalty,
            "rho": res.rho,
            "seconds": res.seconds,
            **{k: float(v) for k, v in res.timings.items()},
            **{k: res.counts.get(k, 0) for k in ("cg_iterations", "factorizations", "back_solves", "chord_steps")},
            "frame_newton_iterations": res.counts.get("newton_iterations", 0),
        }
        rec = FrameRecord(int(f), res.controls, res.state.x_m, res.state.y_m, res.markers_m, res.marker_error_m, stats)
        if out_dir is not None:
            write_frame(out_dir, rec)
        out.append(rec)
    if lin is not None:
        lin.free()
    return out


def track_sequence(
    model,
    targets_m: np.ndarray,
    *,
    marker_names,
    markers: MarkerMap | None = None,
    options: TrackOptions | None = None,
    rig_kwargs: dict | None = None,
    chunk_size: int | None = None,
    executor=None,
    out_dir: str | Path | None = None,
    resume: bool = False,
    progress: bool = False,
    first_frame: int = 0,
) -> list[FrameRecord]:
    """Track a take. Returns one ``FrameRecord`` per frame, in order.

    Args:
        model: the face.
        targets_m: (F, k, 3) markers in metres, NaN = missing, in the order of ``markers``.
        marker_names: names of the k markers (for the rigid start of each chunk).
        markers: embedding of the k markers in the skin (default: the model's own markers).
        options: estimation settings.
        rig_kwargs: ``FaceRig`` keyword arguments (device, precision, solver, tol).
        chunk_size: frames per chunk (default: the whole take in one chunk).
        executor: ``concurrent.futures``-style executor for the chunks (default: run in-process).
        out_dir: write each frame under ``out_dir/frames`` as soon as it is done.
        resume: reuse frames already written under ``out_dir``.
        first_frame: number of the first frame (frame files are named by it).
    """
    targets = np.asarray(targets_m, dtype=np.float64)
    if targets.ndim != 3 or targets.shape[2] != 3:
        raise ValueError(f"marker data must have shape (frames, markers, 3), got {targets.shape}")
    markers = markers or embed_model_markers(model)
    if targets.shape[1] != len(markers.embedding.triangle):
        raise ValueError(f"marker data has {targets.shape[1]} markers, the embedding {len(markers.embedding.triangle)}")
    options = options or TrackOptions()
    rig_kwargs = rig_kwargs or {}
    out_dir = Path(out_dir) if out_dir is not None else None
    F = targets.shape[0]
    frames = np.arange(first_frame, first_frame + F)
    size = F if not chunk_size else max(1, int(chunk_size))
    chunks = [(s, min(F, s + size)) for s in range(0, F, size)]
    args = [
        (
            model,
            markers.embedding,
            targets[s:e],
            frames[s:e].tolist(),
            list(marker_names),
            options,
            rig_kwargs,
            out_dir,
            resume,
        )
        for s, e in chunks
    ]
    if executor is None or len(chunks) == 1 and executor is None:
        results = [_track_chunk(*a, progress) for a in args]
    else:
        futures = [executor.submit(_track_chunk, *a, False) for a in args]
        results = [fut.result() for fut in futures]
    return [rec for chunk in results for rec in chunk]


def dask_executor(*, workers: int = 1, scheduler: str | None = None, n_frames: int, chunk_size: int | None = None):
    """(executor, chunk_size, close) for ``track_sequence``: a Dask executor on a running scheduler
    (``scheduler`` address) or on a local cluster of ``workers`` processes, or (None, chunk_size,
    no-op) to run in-process. The default chunk size splits the take evenly over the workers."""
    if not (scheduler or workers > 1):
        return None, chunk_size, lambda: None
    from distributed import Client, LocalCluster

    if scheduler:
        client = Client(scheduler)
        workers = max(1, len(client.scheduler_info()["workers"]))
        closers = [client.close]
    else:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
        closers = [client.close, cluster.close]
    chunk = chunk_size or math.ceil(n_frames / workers)
    return client.get_executor(pure=False), chunk, lambda: [c() for c in closers]
