"""Held-out markers: hide some markers from the fit and measure how well the face predicts them.

Fitting ~40 markers with ~60 controls is easy; a marker the tracker never saw shows whether the
face is right between markers. ``select_holdout`` picks the hidden markers (every Nth by height,
or by name), ``hide`` blanks them in the fit's targets (NaN: the tracker drops them), and
``holdout_report`` measures the simulated hidden markers against the capture per frame and per
marker. The hidden markers still take part in the neutral frame's alignment and embedding (their
rest place on the skin is calibration, as a scan would give it); their motion is never seen.

Report keys: ``holdout_markers`` (names), ``holdout_rms_mm`` (per frame), ``holdout_rms_mm_mean``,
``holdout_max_mm``, ``holdout_rms_mm_per_marker`` ({name: mm}), ``holdout_samples`` (the hidden
samples the capture has). ``add_holdout`` puts them in a tracking report and counts the hidden
samples apart from the capture's missing ones (``missing_samples``: what the capture lacks).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["add_holdout", "hide", "holdout_report", "plot_holdout", "select_holdout"]


def select_holdout(spec: str, marker_names, reference_m: np.ndarray) -> np.ndarray:
    """Indices of the markers to hide.

    Args:
        spec: "N" (every Nth marker by height, top to bottom, starting with the Nth) or
            "NAME,NAME,..." (those markers).
        marker_names: the k marker names.
        reference_m: (k, 3) a frame in the model's frame (+y up); missing markers (NaN) sort last.

    Returns:
        Sorted (h,) int indices.
    """
    names = list(marker_names)
    spec = str(spec).strip()
    if spec.isdigit():
        n = int(spec)
        if n < 2:
            raise ValueError(f"--holdout {spec}: hide every Nth marker needs N >= 2")
        y = np.asarray(reference_m, dtype=np.float64)[:, 1]
        order = np.argsort(-np.nan_to_num(y, nan=-np.inf), kind="stable")  # top to bottom
        idx = order[n - 1 :: n]
    else:
        wanted = [s.strip() for s in spec.split(",") if s.strip()]
        unknown = [w for w in wanted if w not in names]
        if unknown:
            raise ValueError(f"--holdout: unknown marker(s) {', '.join(unknown)}; the capture has {', '.join(names)}")
        idx = np.array([names.index(w) for w in wanted])
    if len(idx) == 0 or len(idx) >= len(names) - 2:
        raise ValueError(
            f"--holdout {spec} hides {len(idx)} of {len(names)} markers; keep at least 3 and hide at least 1"
        )
    return np.sort(np.asarray(idx, dtype=np.int64))


def hide(targets_m: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """A copy of (F, k, 3) targets with the hidden markers set to NaN."""
    out = np.array(targets_m, dtype=np.float64, copy=True)
    out[:, np.asarray(indices, dtype=np.int64)] = np.nan
    return out


def holdout_report(records, targets_m: np.ndarray, indices: np.ndarray, marker_names) -> dict:
    """Errors of the hidden markers: simulated (``FrameRecord.markers_m``) against the capture.

    Args:
        records: the tracked frames (``wface.takes.store.FrameRecord``), in the order of ``targets_m``.
        targets_m: (F, k, 3) the full capture in the model's frame (hidden markers present).
        indices: the hidden markers.
        marker_names: the k names.

    Returns:
        The report keys of the module docstring.
    """
    idx = np.asarray(indices, dtype=np.int64)
    sim = np.array([r.markers_m for r in records])[:, idx]
    err = np.linalg.norm(sim - np.asarray(targets_m)[: len(records), idx], axis=2) * 1e3  # (F, h) mm, NaN = missing
    seen = np.isfinite(err)
    per_frame = [float(np.sqrt(np.mean(e[s] ** 2))) if s.any() else None for e, s in zip(err, seen, strict=True)]
    count = seen.sum(axis=0)
    per_marker = np.sqrt((np.where(seen, err, 0.0) ** 2).sum(axis=0) / np.maximum(count, 1))
    names = [marker_names[i] for i in idx]
    return {
        "holdout_markers": names,
        "holdout_rms_mm": per_frame,
        "holdout_rms_mm_mean": float(np.mean([v for v in per_frame if v is not None])) if seen.any() else None,
        "holdout_max_mm": float(np.nanmax(err)) if seen.any() else None,
        "holdout_rms_mm_per_marker": {
            n: (float(v) if c else None) for n, v, c in zip(names, per_marker, count, strict=True)
        },
        "holdout_samples": int(seen.sum()),
    }


def add_holdout(report: dict, records, targets_m: np.ndarray, indices: np.ndarray, marker_names) -> dict:
    """``report`` (``wface.tracking.report.build_report`` of the fit) with the ``holdout_report`` keys;
    the hidden samples the capture has are no longer counted as missing (the fit saw them as NaN).
    Returns the report, updated in place."""
    hold = holdout_report(records, targets_m, indices, marker_names)
    report.update(hold)
    if "missing_samples" in report:
        report["missing_samples"] = int(report["missing_samples"]) - hold["holdout_samples"]
    present = np.isfinite(np.asarray(targets_m)[: len(records)]).all(axis=2)  # (F, k) the capture has the sample
    for i in np.asarray(indices, dtype=np.int64):
        stats = (report.get("marker_stats") or {}).get(str(marker_names[i]))
        if stats is not None:  # hidden, not missing: the fit never saw the samples the capture has
            stats["held_out"] = int(present[:, i].sum())
            stats["missing"] = int(stats["missing"]) - stats["held_out"]
    return report


def plot_holdout(path: str | Path, report: dict, *, fps: float) -> Path:
    """A PNG of the held-out error: RMS per frame beside the fitted markers' RMS, and per marker."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    hold = np.array([np.nan if v is None else v for v in report["holdout_rms_mm"]], dtype=float)
    used = np.asarray(report.get("marker_rms_mm", []), dtype=float)
    t = np.arange(len(hold)) / fps
    per = report["holdout_rms_mm_per_marker"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.6), gridspec_kw={"width_ratios": [2, 1]})
    if used.size == hold.size:
        a.plot(t, used, label=f"fitted markers (mean {np.nanmean(used):.2f} mm)", color="#1f77b4")
    a.plot(t, hold, label=f"held-out markers (mean {np.nanmean(hold):.2f} mm)", color="#d62728")
    a.set_xlabel("time (s)")
    a.set_ylabel("RMS error (mm)")
    a.legend(loc="upper right", fontsize=8)
    a.grid(alpha=0.3)
    names = list(per)
    b.barh(names, [np.nan if per[n] is None else per[n] for n in names], color="#d62728")
    b.set_xlabel("RMS over the take (mm)")
    b.invert_yaxis()
    b.tick_params(axis="y", labelsize=7)
    fig.suptitle("held-out markers (never seen by the fit)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
