"""report.json of a tracked take: the keys listed in the README ("Tracking outputs"); the files are
written by ``wface.takes.store``."""

from __future__ import annotations

import numpy as np

from wface.controls import jaw_limits, jaw_to_intuitive
from wface.tracking.identifiability import OBSERVABLE_MM

__all__ = ["CAPTURE_UNIT_KEYS", "add_capture_units", "build_report"]


#: report keys in the model's millimetres -> the same measure in the capture's (``add_capture_units``)
CAPTURE_UNIT_KEYS = {
    "marker_rms_mm_mean": "marker_rms_capture_mm_mean",
    "marker_rms_mm_inliers": "marker_rms_capture_mm_inliers",
    "holdout_rms_mm_mean": "holdout_rms_capture_mm_mean",
}


def add_capture_units(report: dict, capture_to_model_scale: float) -> dict:
    """``report`` with its marker errors also in the capture's millimetres (updated in place, returned).

    A capture is brought onto the face by a similarity of scale s (``prepare_capture``), so errors
    measured in the face's frame are s times the actor's: on the built-in face the AnimFace actor
    comes in at s = 0.90, and its errors read 10 % smaller than on a face fitted to the actor (s = 1).
    Adds ``capture_to_model_scale`` and, per key of ``CAPTURE_UNIT_KEYS`` present, the error / s.
    """
    s = float(capture_to_model_scale)
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"capture_to_model_scale must be finite and > 0, got {capture_to_model_scale}")
    report["capture_to_model_scale"] = s
    for key, capture_key in CAPTURE_UNIT_KEYS.items():
        if isinstance(report.get(key), (int, float)):
            report[capture_key] = float(report[key]) / s
    return report


def _per_marker_rms_mm(err_mm: np.ndarray, marker_names) -> dict:
    """{marker: RMS error over the frames it was seen in, mm}; None for a marker never seen."""
    seen = np.isfinite(err_mm)
    sq = np.where(seen, err_mm, 0.0) ** 2
    count = seen.sum(axis=0)
    rms = np.sqrt(sq.sum(axis=0) / np.maximum(count, 1))
    return {n: (float(r) if c else None) for n, r, c in zip(marker_names, rms, count, strict=True)}


def _marker_stats(err_mm: np.ndarray, marker_names, robust_mm: float | None) -> tuple[dict, dict]:
    """({marker: seen, missing, held_out, outliers, rms_mm, inlier_rms_mm, max_mm}, totals) of the (F, k) errors.

    A sample is an outlier when its error exceeds ``robust_mm``, the Tukey cut-off the tracker ends
    with (such a marker pulls on the fit with weight 0); without ``robust_mm`` none is. ``rms_mm`` is
    over every sample seen, outliers included (a marker the face cannot follow shows there);
    ``inlier_rms_mm`` over the inliers alone.
    """
    seen = np.isfinite(err_mm)
    outlier = seen & (err_mm > robust_mm) if robust_mm else np.zeros_like(seen)
    inlier = seen & ~outlier
    stats = {}
    for j, name in enumerate(marker_names):
        e_in = err_mm[inlier[:, j], j]
        e_seen = err_mm[seen[:, j], j]
        stats[str(name)] = {
            "seen": int(seen[:, j].sum()),
            "missing": int((~seen[:, j]).sum()),
            "held_out": 0,  # samples hidden from the fit (``wface.tracking.holdout.add_holdout``)
            "outliers": int(outlier[:, j].sum()),
            "rms_mm": float(np.sqrt(np.mean(e_seen**2))) if e_seen.size else None,
            "inlier_rms_mm": float(np.sqrt(np.mean(e_in**2))) if e_in.size else None,
            "max_mm": float(e_seen.max()) if e_seen.size else None,
        }
    e_in = err_mm[inlier]
    totals = {
        "marker_rms_mm_inliers": float(np.sqrt(np.mean(e_in**2))) if e_in.size else None,
        "marker_samples": int(err_mm.size),
        "missing_samples": int((~seen).sum()),
        "outlier_samples": int(outlier.sum()),
        "outlier_threshold_mm": robust_mm,
    }
    return stats, totals


def _jaw_deg(model, bones: np.ndarray) -> np.ndarray:
    return np.array([jaw_to_intuitive(model.jaw_joint, b[12:])["opening_deg"] for b in bones])


def _on_closed_limit(model, jaw_deg: np.ndarray) -> float:
    """Share of frames whose jaw opening (deg) sits on the joint's closed limit (within 1e-3 deg): a capture
    that closes the jaw further than the model allows past its rest (docs/design.md, "Controls and the jaw joint")."""
    if not len(jaw_deg):
        return 0.0
    return float(np.mean(jaw_deg <= jaw_limits(model.jaw_joint)["opening_deg"][0] + 1e-3))


def build_report(
    model,
    records,
    *,
    markers_data_m,
    marker_names,
    rig_info: dict,
    identifiability_mm: np.ndarray,
    truth=None,
    robust_mm: float | None = 3.0,
) -> dict:
    """The report dict. ``truth`` (a SyntheticPerformance) adds the ground-truth errors; ``robust_mm``
    (the tracker's Tukey cut-off) separates inlier from outlier samples."""
    M = model.n_muscles
    C = np.array([r.controls for r in records])
    A, B = C[:, :M], C[:, M:]
    jaw_deg = _jaw_deg(model, B)
    err = np.array([r.marker_error_m for r in records]) * 1e3  # (F, k) mm, NaN = missing
    seen = np.isfinite(err).any(axis=1)  # a frame without usable markers has no error (it was carried)
    per_frame = np.full(len(err), np.nan)
    per_frame[seen] = np.sqrt(np.nanmean(err[seen] ** 2, axis=1))
    secs = np.array([r.stats["seconds"] for r in records])
    observable = identifiability_mm >= OBSERVABLE_MM
    marker_stats, totals = _marker_stats(err, marker_names, robust_mm)
    rep = {
        "frames": len(records),
        "markers": int(np.asarray(markers_data_m).shape[1]),
        "tets": model.n_tets,
        "nodes": model.n_nodes,
        "muscles": M,
        **rig_info,
        "marker_rms_mm": [float(v) if ok else None for v, ok in zip(per_frame, seen, strict=True)],
        "marker_rms_mm_mean": float(np.mean(per_frame[seen])) if seen.any() else None,
        "marker_max_mm": float(np.nanmax(err)) if seen.any() else None,
        "marker_rms_mm_per_marker": _per_marker_rms_mm(err, marker_names),
        **totals,
        "marker_stats": marker_stats,
        "seconds_per_frame": secs.tolist(),
        "seconds_per_frame_median": float(np.median(secs)),
        "seconds_breakdown_median": {
            k: float(np.median([r.stats.get(k, 0.0) for r in records]))
            for k in ("quasistatic_s", "jacobian_s", "gauss_newton_system_s")
        },
        "gauss_newton_steps": int(sum(r.stats["gauss_newton_steps"] for r in records)),
        "quasistatic_solves": int(sum(r.stats["quasistatic_solves"] for r in records)),
        "linear_solves": int(sum(r.stats["linear_solves"] for r in records)),
        "cg_iterations": int(sum(r.stats.get("cg_iterations", 0) for r in records)),
        "activation_bound_violation_max": float(max(0.0, -A.min(), A.max() - 1.0)),
        "inverted_elements": int(max(r.stats["inverted_elements"] for r in records)),
        "muscle_identifiability": dict(zip(model.muscle_names, identifiability_mm.tolist(), strict=True)),
        "observable_threshold_mm_per_unit_activation": OBSERVABLE_MM,
        "observable_muscles": [n for n, o in zip(model.muscle_names, observable, strict=True) if o],
        "jaw_opening_deg": jaw_deg.tolist(),
        "jaw_on_closed_limit_fraction": _on_closed_limit(model, jaw_deg),
    }
    usage = records[-1].stats.get("usage_prior") if records else None
    if usage:  # what the data chose (wface.tracking.refine): per-muscle usage, correlation length, noise
        sd = dict(zip(model.muscle_names, usage["activation_sd"], strict=True))
        rep["usage_prior"] = {**usage, "activation_sd": sd}
        passes = records[-1].stats.get("usage_prior_passes", [])
        rep["usage_prior_fit_seconds"] = [p.get("seconds") for p in passes]
        rep["usage_pass_activation_change_rms"] = [p.get("activation_change_rms") for p in passes]  # refit test
    if truth is not None:
        dA = A - truth.activations[: len(records)]
        rep["activation_rms_error"] = float(np.sqrt(np.mean(dA[:, observable] ** 2))) if observable.any() else None
        rep["activation_rms_error_all"] = float(np.sqrt(np.mean(dA**2)))
        sim = np.array([r.markers_m for r in records])
        d = np.linalg.norm(sim - truth.clean_markers_m[: len(records)], axis=2)
        rep["truth_marker_rms_mm"] = float(np.sqrt(np.mean(d**2)) * 1e3)
        rep["jaw_angle_error_deg"] = float(np.sqrt(np.mean((jaw_deg - truth.jaw_opening_deg[: len(records)]) ** 2)))
        noise = np.linalg.norm(truth.markers_m - truth.clean_markers_m, axis=2)[: len(records)]
        rep["input_noise_rms_mm"] = float(np.sqrt(np.nanmean(noise[~truth.outlier_mask[: len(records)]] ** 2)) * 1e3)
    return rep
