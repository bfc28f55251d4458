"""``wface bench --suite track``: seconds per tracked frame, what a frame costs, and how close it comes to
the least a frame needs, on a synthetic performance of the built-in face (docs/design.md, "Performance").

The performance: 60 frames at 30 Hz (2 s) of ``synthesize_performance`` (seed 0, 0.5 mm marker
noise), of which the window of ``--frames`` frames from frame 24 is simulated and tracked, so the
motion between frames is that of a 30 Hz capture. The first frame starts cold; the statistics
per frame are medians over the later, warm-started frames. ``--prior`` is the tracker's
(``TrackOptions.prior``): "auto" (default, as ``wface track``) tracks a first pass and then
``--prior-passes`` passes under the take-wide usage prior, and a frame's numbers are all its passes'
sums (``pass1_seconds_per_frame`` the first alone, ``pass_seconds_per_frame`` each pass's median in
order); "temporal" is the one pass.

Reported per size: seconds per frame and its breakdown; Gauss-Newton steps, quasistatic solves,
Newton iterations (chord steps among them), numeric factorisations and back-solves per frame;
``limit_seconds`` = one numeric factorisation of K_UU (the exact tangent at the last tracked
equilibrium, the analysis reused, in the tracker's factor precision) + one back-solve of the M + 12
solved control columns together, timed in the same run (median of ``--repeat``), and ``limit_ratio``
= seconds per frame / that (``limit_ratio_float64`` against double-precision factors, for reference;
``limit_ratio_cpu`` the same with process CPU time, which a machine shared with other jobs inflates
less than wall time);
the usage prior's take-wide fits between passes (``usage_fit_seconds``, each fit; their sum over the
frames in the breakdown, and ``limit_ratio_with_usage_fits`` with it added to a frame);
peak RSS (the process's high-water mark, reset before tracking where Linux allows it); and the
accuracy against the known truth (activation RMS error over the observable muscles and over all,
tracked-marker error against the clean markers, jaw angle error).
"""

from __future__ import annotations

import resource
import statistics
import time

import numpy as np

from wface.bench import suite_result
from wface.faces.builtin import build_face
from wface.solvers import DirectFactor
from wface.solvers.cudss import CudssFactor
from wface.tracking.estimator import TrackOptions
from wface.tracking.identifiability import rig_identifiability_mm
from wface.tracking.report import build_report
from wface.tracking.rig import FaceRig, RigState
from wface.tracking.sequence import embed_model_markers, track_sequence
from wface.tracking.synthetic import synthesize_performance
from wface.warp_runtime import resolve_device

__all__ = ["DEFAULT_TETS", "bench_size", "limit_seconds", "peak_rss_mb", "reset_peak_rss", "run"]

DEFAULT_TETS = (20_000, 100_000)
TAKE_FRAMES, WINDOW_START, NOISE_MM = 60, 24, 0.5
_PER_FRAME = (
    "gauss_newton_steps",
    "quasistatic_solves",
    "frame_newton_iterations",
    "chord_steps",
    "factorizations",
    "back_solves",
    "linear_solves",
    "cg_iterations",
)


def reset_peak_rss() -> bool:
    """Reset this process's peak-RSS mark (Linux ``/proc/self/clear_refs``); False where unsupported."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_rss_mb() -> float:
    """This process's peak resident set size in MiB (``VmHWM``, else ``ru_maxrss``)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def limit_seconds(rig: FaceRig, state: RigState, *, repeat: int = 3, precision: str | None = None) -> dict:
    """The least a frame needs at ``state``: one numeric factorisation of K_UU and one back-solve of
    the M + 12 solved columns, each the median of ``repeat`` timings (s), in the tracker's factor
    precision (``precision`` overrides it). Direct engine only."""
    precision = precision or rig.factor_precision
    sim = rig.sim
    a = np.clip(state.controls[: rig.n_muscles], 0.0, 1.0)
    pattern = sim.pattern("free")
    exact = rig.exact_tangents_ok  # the tangent the tracker factors (projected with cuDSS)
    values = sim.tangent(state.y_m, a, project=not exact).assemble_upper(pattern)
    B = np.random.default_rng(0).normal(size=(pattern.shape[0], rig.n_muscles + 12))
    factor_s, solve_s, cpu_s = [], [], []
    on_gpu = str(sim.device).startswith("cuda")
    for _ in range(max(1, repeat)):
        t0, c0 = time.perf_counter(), time.process_time()
        if on_gpu:
            factor = CudssFactor(pattern, values)
        else:
            factor = DirectFactor.of_pattern(pattern, values, precision=precision)
        factor_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        factor.solve(B)
        solve_s.append(time.perf_counter() - t0)
        cpu_s.append(time.process_time() - c0)
        factor.free()
    f, s = statistics.median(factor_s), statistics.median(solve_s)
    out = {"numeric_factor_seconds": f, "back_solve_columns_seconds": s, "columns": B.shape[1], "seconds": f + s}
    out["precision"] = "cudss" if on_gpu else precision
    out["cpu_seconds"] = statistics.median(cpu_s)  # process CPU time of factor + solve, all threads
    return out


def bench_size(n_tets: int, *, device: str = "cpu", frames: int = 6, repeat: int = 3, options=None) -> dict:
    """One mesh size (module docstring). ``options``: ``TrackOptions`` of the tracker (default ones)."""
    model = build_face(n_tets)
    kwargs = {"device": device, "tol": 1e-6}
    options = options or TrackOptions()
    rig = FaceRig(model, factor_precision=options.factor_precision, **kwargs)  # the tracker's factors
    markers = embed_model_markers(model)
    window = (WINDOW_START, WINDOW_START + max(2, int(frames)))
    perf = synthesize_performance(rig, markers, frames=TAKE_FRAMES, seed=0, noise_mm=NOISE_MM, window=window)
    rss_reset = reset_peak_rss()
    t = time.perf_counter()
    recs = track_sequence(
        model, perf.markers_m, marker_names=model.marker_names, markers=markers, options=options, rig_kwargs=kwargs
    )
    wall = time.perf_counter() - t
    peak = peak_rss_mb()
    later = recs[1:] or recs  # the first frame starts cold (more Gauss-Newton steps)
    med = lambda key: float(np.median([r.stats.get(key, 0) for r in later]))  # noqa: E731
    out = {
        "tets": model.n_tets,
        "nodes": model.n_nodes,
        "unknowns": 3 * len(model.free_nodes),
        "frames": len(recs),
        "solver": rig.sim.linear_solver,
        "seconds_per_frame": med("seconds"),
        "seconds_per_frame_each": [r.stats["seconds"] for r in recs],
        "seconds_first_frame": recs[0].stats["seconds"],
        "cpu_seconds_per_frame": med("cpu_s"),
        "breakdown_seconds_per_frame": {
            "quasistatic_solves": med("quasistatic_s"),
            "jacobians": med("jacobian_s"),
            "gauss_newton_system": med("gauss_newton_system_s"),
        },
        **{f"{k}_per_frame": med(k) for k in _PER_FRAME},
        "prior": options.prior,  # "auto": 1 + prior_passes passes (the usage prior's refits), each frame's cost summed
        "prior_passes": options.prior_passes if options.prior == "auto" else 0,  # at most
        "prior_refit_change": options.prior_refit_change,
        "peak_rss_mb": peak,
        "peak_rss_scope": "tracking" if rss_reset else "process",
        "wall_seconds": wall,
    }
    fits = recs[-1].stats.get("usage_prior_passes", [])  # the usage prior's fits between passes (take-wide)
    out["prior_passes_run"] = len(fits)  # usage passes done (prior_refit_change may stop them after one)
    if fits:
        out["activation_change_rms"] = [f.get("activation_change_rms") for f in fits]
        out["usage_fit_seconds"] = [float(f.get("seconds", 0.0)) for f in fits]
        out["breakdown_seconds_per_frame"]["usage_fits"] = sum(out["usage_fit_seconds"]) / len(recs)
    each = [r.stats.get("pass_seconds") for r in later]
    if any(each):
        out["pass1_seconds_per_frame"] = float(np.median([e[0] if e else 0.0 for e in each]))  # the temporal prior's
        if all(each) and len({len(e) for e in each}) == 1:  # each pass alone, first to last
            out["pass_seconds_per_frame"] = [float(v) for v in np.median(np.array(each), axis=0)]
    if rig.sim.linear_solver == "direct":
        last = RigState(recs[-1].controls, recs[-1].y_m, recs[-1].x_m)
        out["limit"] = limit_seconds(rig, last, repeat=repeat)
        out["limit_seconds"] = out["limit"]["seconds"]
        out["limit_ratio"] = out["seconds_per_frame"] / out["limit_seconds"]
        if fits:  # with the take-wide usage fits shared out over the frames
            with_fits = out["seconds_per_frame"] + out["breakdown_seconds_per_frame"]["usage_fits"]
            out["limit_ratio_with_usage_fits"] = with_fits / out["limit_seconds"]
        out["limit_ratio_cpu"] = out["cpu_seconds_per_frame"] / out["limit"]["cpu_seconds"]  # CPU time, less load-bound
        if out["limit"]["precision"] == "float32":  # for reference: the limit with double-precision factors
            out["limit_float64"] = limit_seconds(rig, last, repeat=repeat, precision="float64")
            out["limit_ratio_float64"] = out["seconds_per_frame"] / out["limit_float64"]["seconds"]
    out["accuracy"] = _accuracy(model, rig, markers, recs, perf)
    return out


def _accuracy(model, rig, markers, recs, perf) -> dict:
    """Errors against the synthetic truth (the report's keys)."""
    rep = build_report(
        model,
        recs,
        markers_data_m=perf.markers_m,
        marker_names=model.marker_names,
        rig_info={},
        identifiability_mm=rig_identifiability_mm(rig, markers),
        truth=perf,
    )
    keys = ("activation_rms_error", "activation_rms_error_all", "truth_marker_rms_mm", "jaw_angle_error_deg")
    return {k: rep[k] for k in (*keys, "marker_rms_mm_mean", "input_noise_rms_mm")}


def run(args) -> dict:
    sizes = args.tets or list(DEFAULT_TETS)
    device = resolve_device("cpu" if args.device == "auto" else args.device)
    frames = int(getattr(args, "frames", None) or 6)
    repeat = max(1, int(getattr(args, "repeat", 3) or 3))
    passes = getattr(args, "prior_passes", None) or TrackOptions.prior_passes
    change = getattr(args, "prior_refit_change", None)
    change = TrackOptions.prior_refit_change if change is None else float(change)
    options = TrackOptions(
        prior=getattr(args, "prior", None) or "auto", prior_passes=int(passes), prior_refit_change=change
    )
    results = [bench_size(int(n), device=device, frames=frames, repeat=repeat, options=options) for n in sizes]
    notes = {"take": f"frames {WINDOW_START}.. of a {TAKE_FRAMES}-frame 30 Hz synthetic take, {NOISE_MM} mm noise"}
    return suite_result("track", device, results, notes)
