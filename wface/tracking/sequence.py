"""Tracking a whole take: frames in order with warm starts, split into chunks for parallel workers.

Each frame starts from the previous one (a constant-velocity prediction of the controls) and, with
``TrackOptions.prior = "auto"`` (the default), is estimated under the data-chosen temporal prior of
``wface.tracking.prior``. A take splits into chunks of consecutive frames for any
``concurrent.futures``-style executor (``submit`` returning futures), e.g. a process pool or a Dask
``Client.get_executor()``. A chunk starts ``warmup_frames`` before its first frame: those frames are
tracked from a cold start (rest controls, cranium from a rigid fit of the stable markers, more
Gauss-Newton steps) and discarded, so that by its first frame the chunk carries the state a serial
run would (docs/design.md, "Tracking"): the worker count does not change the result beyond the
trackers' tolerance.

Inside a chunk each frame hands the next its equilibrium with the Jacobian and the factorisation
there (``RigLinearization``), so a warm frame starts with no solve and its solves take chord steps
with that factor (docs/design.md, "Tracking": factor reuse).

A frame with fewer than ``min_markers`` usable markers is *carried*: its controls and positions are
held from the frame before (the rest pose at the start of a take), its record says so
(``stats["carried"]``) and the take goes on.

With ``out_dir``, each frame is written to ``out_dir/frames/frame_NNNNNN.npz`` as soon as it is done
(atomically, ``wface.takes.store``) with its provenance (``tracking_provenance``); ``resume=True``
reuses the frames on disk whose fingerprints match (``wface.takes.store.verified_frames``), and
the tracker's carried state is stored in each frame, so an interrupted run resumes bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from wface.controls import params_from_affine
from wface.mesh.align import embed_markers, umeyama
from wface.model import model_sha256
from wface.takes.provenance import array_sha256, frame_fingerprint, run_provenance
from wface.takes.store import (
    FRAMES_DIR,
    REFINE_DIR_PREFIX,
    SURVEY_DIR,
    FrameRecord,
    link_frame,
    verified_frames,
    write_frame,
)
from wface.takes.take import frame_step
from wface.tracking.adaptive import is_adaptive, rebuild_linearization, restore_spare, spare_state
from wface.tracking.estimator import FrameEstimator, TrackOptions
from wface.tracking.inputs import checked_marker_data
from wface.tracking.markers import MarkerMap
from wface.tracking.prior import TemporalPrior, activation_measurement
from wface.tracking.refine import usage_priors
from wface.tracking.rig import FaceRig, RigState

__all__ = [
    "DEFAULT_WARMUP_FRAMES",
    "embed_model_markers",
    "initial_controls",
    "min_usable_markers",
    "track_sequence",
    "tracking_provenance",
]

STABLE_MARKERS = ("ForeHead_L", "ForeHead_M", "ForeHead_R", "NoseTop", "Eyebrow_Center")
DEFAULT_WARMUP_FRAMES = 6  # frames a chunk tracks before its first one (see the module docstring)


def embed_model_markers(model, markers_rest_m: np.ndarray | None = None):
    """Embed markers (default: the model's own) in the skin; returns a ``MarkerMap``.

    ``markers_rest_m``: (k, 3) rest positions in metres, every one finite (a capture's missing
    markers are missing in its frames, not here)."""
    pts = model.marker_positions_m if markers_rest_m is None else np.asarray(markers_rest_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"markers_rest_m has shape {pts.shape}, expected (k, 3)")
    bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
    if bad.size:
        raise ValueError(f"markers_rest_m has NaN or inf at {bad.size} marker(s), first {bad[:5].tolist()}")
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


def min_usable_markers(n_markers: int) -> int:
    """Fewest markers a frame needs to be tracked rather than carried: a fifth of the capture's
    markers, and never fewer than 4 (three fix the head; the jaw and the muscles need more)."""
    return max(4, math.ceil(0.2 * n_markers))


def _describe(value):
    """A JSON-able description of an option value (a ``Contact`` by its settings)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (list, tuple)):
        return [_describe(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _describe(v) for k, v in value.items()}
    if dataclasses.is_dataclass(value):
        return {f.name: _describe(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return array_sha256(value)[:16]
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    attrs = getattr(value, "__dict__", None)
    if attrs is None:
        return repr(value)
    simple = {
        k: v for k, v in attrs.items() if not k.startswith("_") and isinstance(v, (bool, int, float, str, tuple, list))
    }
    return {"type": type(value).__name__, **{k: _describe(v) for k, v in sorted(simple.items())}}


def tracking_provenance(
    model,
    markers: MarkerMap,
    *,
    options: TrackOptions | None = None,
    rig_kwargs: dict | None = None,
    kind: str = "track",
    source: dict | None = None,
) -> dict:
    """The provenance of a tracking run (``wface.takes.provenance.run_provenance``): the model's content
    hash, ``source`` (e.g. the capture file's name, SHA-256 and frame range, or a synthetic take's seed),
    the tracking options, the rig's settings and the marker embedding."""
    e = markers.embedding
    opts = {
        "track": _describe(options or TrackOptions()),
        "rig": _describe(rig_kwargs or {}),
        "embedding_sha256": array_sha256(*_embedding_arrays(e))[:16],
    }
    return run_provenance(kind=kind, model_sha256=model_sha256(model), source=source or {}, options=opts)


def _embedding_arrays(e) -> tuple:
    """The arrays that place the markers (the tangent part only where the embedding carries one)."""
    base = (e.triangle, e.barycentric, e.normal_offset_m)
    return base if e.tangent_offset_m is None else (*base, e.tangent_offset_m)


class _Tracker:
    """The state carried from frame to frame, and one frame's estimation."""

    def __init__(self, model, embedding, marker_names, options, rig_kwargs, min_markers: int, run: dict | None):
        self.rig = FaceRig(model, **{"factor_precision": options.factor_precision, **rig_kwargs})
        self.markers = MarkerMap(model, embedding)
        self.est = FrameEstimator(self.rig, self.markers, options)
        self.options, self.names, self.min_markers, self.run = options, marker_names, min_markers, run
        self.M = self.rig.n_muscles
        self.c = self.y = self.c_older = self.x = None
        self.lin = None  # RigLinearization at the last frame's equilibrium (handed to the next frame)
        self.resumed: RigState | None = None  # the state of a frame reused from disk, linearised on demand
        self.resumed_factor: tuple | None = None  # where its handed-on factor was taken (FrameRecord.state)
        self.prior = TemporalPrior(self.M) if options.prior in ("auto", "temporal") else None

    def resume_from(self, rec: FrameRecord) -> None:
        """Continue from a record on disk (its stored state makes the continuation bit-identical)."""
        older = rec.state.get("controls_before")
        self.c_older = None if older is None or not len(older) else np.array(older)
        self.c, self.y, self.x = rec.controls, rec.y_m, rec.x_m
        if self.prior is not None:
            self.prior = TemporalPrior.from_arrays(self.M, rec.state)
        self.free()
        self.resumed = RigState(rec.controls, rec.y_m, rec.x_m)  # linearised again if the next frame is new
        self.resumed_factor = (
            (rec.state["factor_controls"], rec.state["factor_y_m"]) if "factor_y_m" in rec.state else None
        )
        self.resumed_jacobian = rec.state if "jacobian_y_m" in rec.state else None  # a kept one (adaptive)

    def free(self) -> None:
        """Release the factorisation held for the next frame."""
        if self.lin is not None:
            self.lin.free()
        self.lin = None

    def _state(self) -> dict:
        out = {"controls_before": np.zeros(0) if self.c_older is None else self.c_older}
        if self.prior is not None:
            out.update(self.prior.to_arrays())
        at = None if self.lin is None else self.lin.factored_at
        if at is not None:  # where the handed-on factor was taken: a resumed take rebuilds it exactly
            out["factor_controls"], out["factor_y_m"] = at
        kept = None if self.lin is None else getattr(self.lin, "jacobian_at", None)
        if kept is not None and is_adaptive(self.est):  # where its (kept) Jacobian was solved, and with what
            out["jacobian_y_m"], (out["jacobian_factor_controls"], out["jacobian_factor_y_m"]) = kept
            out["jacobian_age"] = np.array(self.lin.age)
        return out

    def step(self, frame: int, target: np.ndarray) -> FrameRecord:
        present = int(np.isfinite(target).all(axis=1).sum())
        if present < self.min_markers:
            return self._carry(frame, target, present)
        if self.lin is None and self.resumed is not None and self.options.reuse_factor:
            near = None if self.resumed_factor is None else self.rig.stiffness_at(*self.resumed_factor, warn=False)
            self.lin = rebuild_linearization(self.rig, self.resumed, near, getattr(self, "resumed_jacobian", None))
        self.resumed = self.resumed_factor = self.resumed_jacobian = None
        first = self.c is None
        c_last = self.c
        if first:
            c = initial_controls(self.rig, self.markers, target, self.names)
        elif self.lin is None and self.c_older is not None and self.options.extrapolate:
            c = self.est.retract(2.0 * self.c - self.c_older)  # constant-velocity prediction of the controls
        else:
            c = self.c
        opt = self.options
        res = self.est.estimate(
            int(frame),
            target,
            c,
            self.y,
            steps=opt.gn_steps_first if first else opt.gn_steps,
            a_prev=None if self.c is None else self.c[: self.M],
            prior=None if self.prior is None else self.prior.prior(),
            start=self.lin,
        )
        self.lin = res.linearization
        if self.prior is not None:
            self.prior.update(self.rig.model.jaw_joint, res)
        self.c_older, self.c, self.y, self.x = c_last, res.controls, res.state.y_m, res.state.x_m
        state = self._state()
        measured = activation_measurement(self.rig.model.jaw_joint, res.system, self.M) if opt.prior == "auto" else None
        if measured is not None:  # what the markers alone say about the activations: the usage fit's input
            state["information"], state["information_vector"] = measured
        if opt.prior == "auto" and self.lin is not None and self.lin.state is res.state:
            state["marker_jy"] = self.lin.node_rows(self.markers.nodes)  # the second pass's first step
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
            "markers_present": present,
            "carried": False,
            "weighted_rss_m2": float(res.system.get("weighted_rss_m2", 0.0)),
            "weighted_count": float(res.system.get("weighted_count", 0.0)),
            **{k: float(v) for k, v in res.timings.items()},
            **{k: res.counts.get(k, 0) for k in ("cg_iterations", "factorizations", "back_solves", "chord_steps")},
            "frame_newton_iterations": res.counts.get("newton_iterations", 0),
        }
        if self.prior is not None and self.prior.noise_var_m2 is not None:
            stats["noise_mm_estimate"] = float(np.sqrt(3.0 * self.prior.noise_var_m2) * 1e3)
        st, err = res.state, res.marker_error_m
        return FrameRecord(int(frame), res.controls, st.x_m, st.y_m, res.markers_m, err, stats, state)

    def _carry(self, frame: int, target: np.ndarray, present: int) -> FrameRecord:
        """A frame with too few markers: hold the previous frame (the rest pose at the start)."""
        if self.c is None:
            state = self.rig.equilibrium(initial_controls(self.rig, self.markers, target, self.names))
            self.c, self.y, self.x = state.controls, state.y_m, state.x_m
        elif self.x is None:
            self.x = self.rig.equilibrium(self.c, self.y).x_m
        if self.prior is not None:
            self.prior.predict_only()
        self.c_older = self.c  # held: zero velocity into the next frame
        m = self.markers.positions(self.x)
        err = np.linalg.norm(m - target, axis=1)  # NaN where missing
        stats = {
            "gauss_newton_steps": 0,
            "quasistatic_solves": 0,
            "linear_solves": 0,
            "newton_iterations": 0,
            "residual_rel": 0.0,
            "inverted_elements": 0,
            "penalty": 0.0,
            "rho": 0.0,
            "seconds": 0.0,
            "markers_present": present,
            "carried": True,
        }
        return FrameRecord(int(frame), self.c.copy(), self.x, self.y, m, err, stats, self._state())


def _track_chunk(
    model,
    embedding,
    targets,
    frames,
    marker_names,
    options,
    rig_kwargs,
    out_dir,
    run,
    reuse,
    min_markers,
    folder,
    progress,
):
    """Track consecutive frames (runs in a worker): ``targets`` holds ``len(targets) - len(frames)``
    warm-up frames (tracked, not kept) and then the chunk's frames. Returns the chunk's FrameRecords."""
    tracker = _Tracker(model, embedding, marker_names, options, rig_kwargs, min_markers, run)
    n_warm = len(targets) - len(frames)
    done = {}
    if out_dir is not None and reuse:
        done = verified_frames(out_dir, frames, targets[n_warm:], run, folder=folder)[0]
    if n_warm and int(frames[0]) not in done:
        step = frame_step(frames)
        for j in range(n_warm):
            tracker.step(int(frames[0]) - (n_warm - j) * step, targets[j])
    out = []
    desc = "tracking" if folder == FRAMES_DIR else f"tracking (pass 1 of up to {1 + max(1, int(options.prior_passes))})"
    for j, f in enumerate(tqdm(frames, desc=desc, disable=not progress, unit="frame")):
        if f in done:
            tracker.resume_from(done[f])
            out.append(done[f])
            continue
        rec = tracker.step(int(f), targets[n_warm + j])
        if out_dir is not None:
            fingerprint = frame_fingerprint(run, f, targets[n_warm + j])
            rec.provenance = {"run": run, "frame": int(f), "fingerprint": fingerprint}
            write_frame(out_dir, rec, folder=folder)
        out.append(rec)
    tracker.free()
    return out


def _refine_chunk(
    model, embedding, targets, survey, options, rig_kwargs, out_dir, run, reuse, priors, extra, folder, desc, progress
):
    """A refinement pass over consecutive frames (runs in a worker): each frame estimated again from the
    previous pass's solution (``survey``: its FrameRecords) under its own prior from the take-wide usage
    fit (``priors``, one ``GaussianPrior`` or None per frame; ``wface.tracking.refine``). A pass before
    the last (``folder`` not ``frames``) keeps each frame's activation information for the next fit."""
    frames = [r.frame for r in survey]
    done = {}
    if out_dir is not None and reuse:
        done = verified_frames(out_dir, frames, targets, run, extra=extra, folder=folder)[0]
    rig = FaceRig(model, **{"factor_precision": options.factor_precision, **rig_kwargs})
    est = FrameEstimator(rig, MarkerMap(model, embedding), options)
    keep_information = folder != FRAMES_DIR
    out, pending = [], None
    for j, first in enumerate(tqdm(survey, desc=desc, disable=not progress, unit="frame")):
        f = first.frame
        if f in done:
            out.append(done[f])
            pending = done[f].state  # what it handed to the next frame (restored before that one)
            continue
        if pending is not None:
            restore_spare(est, pending)
            pending = None
        stats = dict(first.stats, pass_seconds=list(first.stats.get("pass_seconds", [first.stats["seconds"]])))
        state = {}
        if first.stats.get("carried"):
            rec = FrameRecord(f, first.controls, first.x_m, first.y_m, first.markers_m, first.marker_error_m, stats)
        else:
            start = RigState(  # the first pass's equilibrium, solved there
                first.controls,
                first.y_m,
                first.x_m,
                residual_rel=float(first.stats["residual_rel"]),
                inverted_elements=int(first.stats["inverted_elements"]),
            )
            res = est.estimate(
                f,
                targets[j],
                first.controls,
                first.y_m,
                steps=options.gn_steps,
                prior=priors[j],
                equilibrium=start,
                marker_jy=first.state.get("marker_jy"),
                stale_rows=first.state.get("marker_jy_old"),
            )
            lin = res.linearization
            if keep_information:
                measured = activation_measurement(model.jaw_joint, res.system, est.M)
                if measured is not None:  # what the markers alone say about the activations: the next fit's input
                    state["information"], state["information_vector"] = measured
                if lin is not None and getattr(lin, "full", False) and lin.state is res.state:
                    state["marker_jy"] = lin.node_rows(est.markers.nodes)  # the next pass's first step
                else:  # the rows this pass had, for the held muscles' columns of the next pass's Jacobian
                    old = first.state.get("marker_jy", first.state.get("marker_jy_old"))
                    if old is not None:
                        state["marker_jy_old"] = old
            if lin is not None:  # each pass starts each frame from the previous pass's solution
                if is_adaptive(est):
                    est.keep_spare(lin.take_chord())  # its factor serves the next frame
                lin.free()
            for k in ("cg_iterations", "factorizations", "back_solves", "chord_steps"):
                stats[k] = first.stats.get(k, 0) + res.counts.get(k, 0)
            for k in ("gauss_newton_steps", "quasistatic_solves", "linear_solves", "seconds"):
                stats[k] = first.stats[k] + getattr(res, k)
            stats["pass_seconds"].append(float(res.seconds))  # each pass's own, first to last
            stats.update(
                {k: first.stats.get(k, 0.0) + float(v) for k, v in res.timings.items()},
                newton_iterations=res.state.newton_iterations,
                residual_rel=res.state.residual_rel,
                inverted_elements=res.state.inverted_elements,
                penalty=res.penalty,
                rho=res.rho,
                weighted_rss_m2=float(res.system.get("weighted_rss_m2", 0.0)),
                weighted_count=float(res.system.get("weighted_count", 0.0)),
            )
            st = res.state
            rec = FrameRecord(f, res.controls, st.x_m, st.y_m, res.markers_m, res.marker_error_m, stats, state)
        rec.state = {**(rec.state or {}), **spare_state(est)}  # + the factor handed to the next frame (adaptive)
        if out_dir is not None:
            fingerprint = frame_fingerprint(run, f, targets[j], extra=extra)
            rec.provenance = {"run": run, "frame": int(f), "fingerprint": fingerprint, "extra": extra, "pass": desc}
            write_frame(out_dir, rec, folder=folder)
        out.append(rec)
    est.free()  # the factor kept for a next frame (TrackOptions.factor_at="adaptive")
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
    frame_step: int = 1,
    provenance: dict | None = None,
    warmup_frames: int = DEFAULT_WARMUP_FRAMES,
    min_markers: int | None = None,
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
        resume: reuse the frames already written under ``out_dir`` whose fingerprints match.
        first_frame: number of the first frame (frame files are named by it).
        frame_step: the capture frames between two of ``targets_m`` (``wface track --frames A:B:S``): frame
            k is numbered ``first_frame + k * frame_step``.
        provenance: the run's provenance (``tracking_provenance``; default: one made here, with the
            marker data's hash as its source).
        warmup_frames: frames each chunk after the first tracks before its own and discards.
        min_markers: fewest usable markers a frame needs to be tracked (default ``min_usable_markers``);
            frames with fewer are carried.
    """
    markers = markers or embed_model_markers(model)
    targets = checked_marker_data(model, targets_m, marker_names, markers)
    options = options or TrackOptions()
    rig_kwargs = rig_kwargs or {}
    out_dir = Path(out_dir) if out_dir is not None else None
    run = provenance
    if out_dir is not None and run is None:
        src = {"targets_sha256": array_sha256(targets)[:16], "first_frame": int(first_frame)}
        if int(frame_step) != 1:
            src["frame_step"] = int(frame_step)
        run = tracking_provenance(model, markers, options=options, rig_kwargs=rig_kwargs, source=src)
    min_markers = min_usable_markers(targets.shape[1]) if min_markers is None else int(min_markers)
    usable = np.isfinite(targets).all(axis=2).sum(axis=1)
    if not (usable >= min_markers).any():
        raise ValueError(
            f"marker data: no frame has the {min_markers} usable markers a frame needs (at most {int(usable.max())} "
            f"of {targets.shape[1]} markers present): check the capture's marker names and units"
        )
    F = targets.shape[0]
    if int(frame_step) < 1:
        raise ValueError(f"frame_step must be >= 1, got {frame_step}")
    frames = first_frame + int(frame_step) * np.arange(F)
    size = F if not chunk_size else max(1, int(chunk_size))
    chunks = [(s, min(F, s + size)) for s in range(0, F, size)]
    two_pass = options.prior == "auto" and F >= 2
    folder = SURVEY_DIR if two_pass else FRAMES_DIR
    args = [
        (
            model,
            markers.embedding,
            targets[max(0, s - warmup_frames) : e],
            frames[s:e].tolist(),
            list(marker_names),
            options,
            rig_kwargs,
            out_dir,
            run,
            bool(resume),
            min_markers,
            folder,
        )
        for s, e in chunks
    ]
    records = _run_chunks(_track_chunk, args, executor, progress)
    if not two_pass:
        return records
    ctx = (model, markers, targets, options, rig_kwargs, out_dir, run, resume, chunks, executor, progress)
    return _usage_passes(records, *ctx)


def _usage_passes(
    records, model, markers, targets, options, rig_kwargs, out_dir, run, resume, chunks, executor, progress
):
    """The passes under the take-wide usage prior after the first pass's ``records`` (module docstring):
    up to ``options.prior_passes``, the refits only when the first moved the activations by more than
    ``options.prior_refit_change``. Returns the last pass's records, each with the fits' summaries."""
    summaries = []
    passes = max(1, int(options.prior_passes))
    length = None  # the usage prior's correlation length: chosen by cross-validation on the first fit, kept
    for k in range(passes):  # each pass under priors fitted to the one before (wface.tracking.refine)
        t = time.perf_counter()
        if progress:
            print(f"fitting the usage prior to pass {k + 1} ({len(records)} frames)", file=sys.stderr, flush=True)
        say = (lambda line: print(f"  {line}", file=sys.stderr, flush=True)) if progress else None
        priors, fit, summary = usage_priors(records, length_frames=length, progress=say)
        summary["seconds"] = time.perf_counter() - t
        if progress and fit is not None:
            print(
                f"usage prior: correlation length {fit.length_frames:g} frames, marker noise "
                f"{summary['noise_mm']:.2f} mm ({summary['seconds']:.1f} s)",
                file=sys.stderr,
                flush=True,
            )
        length = None if fit is None else fit.length_frames
        if k and summaries[0].get("cv_log_likelihood") is not None:  # the length was chosen on the first fit
            summary.update(cv_log_likelihood=summaries[0]["cv_log_likelihood"], length_chosen_in_pass=2)
        summaries.append(summary)
        extra = _priors_digest(priors)
        last = k == passes - 1
        where = FRAMES_DIR if last else f"{REFINE_DIR_PREFIX}{k + 2}"
        desc = f"tracking (pass {k + 2} of up to {passes + 1})"
        args = [
            (model, markers.embedding, targets[s:e], records[s:e], options, rig_kwargs, out_dir, run, bool(resume))
            + (priors[s:e], extra, where, desc)
            for s, e in chunks
        ]
        before, records = records, _run_chunks(_refine_chunk, args, executor, progress)
        summary["activation_change_rms"] = activation_change_rms(before, records, model.n_muscles)
        if k == 0 and not last and summary["activation_change_rms"] <= options.prior_refit_change:
            if progress:
                print(
                    f"pass 2 moved the activations by {summary['activation_change_rms']:.3f} RMS "
                    f"(<= {options.prior_refit_change:g}): the usage prior is not refitted",
                    file=sys.stderr,
                    flush=True,
                )
            if out_dir is not None:  # the take's result: this pass's frames (kept where already written),
                frames = [r.frame for r in records]  # linked to the pass's files, not a second copy on disk
                kept = verified_frames(out_dir, frames, targets, run, extra=extra, folder=FRAMES_DIR)[0]
                for rec in records:
                    if rec.frame not in kept:
                        link_frame(out_dir, rec, source=where)
            break
    for rec in records:
        rec.stats["usage_prior"] = summaries[-1]
        rec.stats["usage_prior_passes"] = summaries
    return records


def activation_change_rms(before: list[FrameRecord], after: list[FrameRecord], n_muscles: int) -> float:
    """RMS change of the muscle activations from one pass to the next over the frames tracked in both
    (carried frames left out; 0.0 when there are none)."""
    d = [a.controls[:n_muscles] - b.controls[:n_muscles] for b, a in zip(before, after, strict=True)]
    d = [row for row, a in zip(d, after, strict=True) if not a.stats.get("carried")]
    return float(np.sqrt(np.mean(np.square(d)))) if d else 0.0


def _priors_digest(priors) -> str:
    """A digest of a pass's per-frame priors (the fingerprint's ``extra`` of the frames made under them)."""
    arrays = [a for p in priors if p is not None for a in (p.mean, p.weight)]
    return array_sha256(*arrays)[:16] if arrays else "none"


def _run_chunks(fn, args, executor, progress) -> list[FrameRecord]:
    """``fn(*a, progress)`` for every chunk's arguments, in-process or on the executor; the records in order."""
    if executor is None:
        results = [fn(*a, progress) for a in args]
    else:
        futures = [executor.submit(fn, *a, False) for a in args]
        results = [fut.result() for fut in futures]
    return [rec for chunk in results for rec in chunk]
