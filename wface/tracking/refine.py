"""From a tracking pass to the next pass's per-frame priors (docs/design.md, "Priors chosen by the data").

A pass's frames are linearised measurements of the activations: the Gauss-Newton model of frame t's
data term at its estimate, minimised over the bones' rigid motion, says a_t ~ N(z_t, sigma^2 I_t^-1)
with I_t = J^T W J's Schur complement onto the activations and I_t z_t = h_t
(``wface.tracking.prior.activation_measurement``), whatever prior and activation bounds the frame was
estimated under, so refitting the take-wide prior never counts an earlier prior twice.
``usage_priors`` fits the take's usage prior to these measurements (``wface.tracking.usage``: T-SBL,
its correlation length chosen by cross-validation) and returns each frame's cavity prior as a
``GaussianPrior``. Each later pass re-linearises at the previous pass's estimate
(``TrackOptions.prior_passes``).
"""

from __future__ import annotations

import numpy as np

from wface.tracking.prior import GaussianPrior
from wface.tracking.usage import UsageFit, fit_usage, frame_priors

__all__ = ["noise_variance_m2", "pass_measurements", "usage_priors"]


def noise_variance_m2(records, n_muscles: int) -> float:
    """sigma^2 (m^2 per coordinate): the weighted residual pooled over the tracked frames over its degrees
    of freedom (3 sum w_k minus the M + 9 fitted controls per frame)."""
    rss = sum(r.stats["weighted_rss_m2"] for r in records)
    dof = sum(max(r.stats["weighted_count"] - n_muscles - 9.0, 1.0) for r in records)
    return rss / dof


def pass_measurements(records) -> tuple[np.ndarray, np.ndarray]:
    """(z (F, M), I (F, M, M)): each frame's data-only measurement of the activations and its information
    (``wface.tracking.prior.activation_measurement``: I z = h, z taken in the range of I; a record
    without h keeps its estimate y_t)."""
    Z, info = [], []
    for rec in records:
        I = np.asarray(rec.state["information"], dtype=np.float64)
        if "information_vector" in rec.state:
            z = np.linalg.pinv(I, rcond=1e-12, hermitian=True) @ np.asarray(rec.state["information_vector"])
        else:
            z = np.asarray(rec.controls[: len(I)], dtype=np.float64)
        Z.append(z)
        info.append(I)
    return np.array(Z), np.array(info)


def usage_priors(records, *, length_frames: float | None = None, progress=None):
    """(per-record GaussianPrior or None, the UsageFit, a JSON summary) for the next pass.

    ``records``: a pass's FrameRecords; carried frames and frames without information get no prior
    (None) and do not enter the fit. None for everything when fewer than two frames can be fitted.
    ``progress``: ``fit_usage``'s, told each stage of the fit."""
    rows = [j for j, r in enumerate(records) if not r.stats.get("carried") and "information" in r.state]
    if len(rows) < 2:
        return [None] * len(records), None, {"frames_fitted": len(rows)}
    fitted = [records[j] for j in rows]
    M = fitted[0].state["information"].shape[0]
    sigma2 = noise_variance_m2(fitted, M)
    Z, info = pass_measurements(fitted)
    Y = np.array([r.controls[:M] for r in fitted])
    dy = Y - Z
    at_z = np.array([r.stats["weighted_rss_m2"] for r in fitted]) - np.einsum("ti,tij,tj->t", dy, info, dy)
    dof = np.array([max(r.stats["weighted_count"] - 9.0, 1.0) for r in fitted])
    fit = fit_usage(
        Z, info, sigma2, length_frames=length_frames, residual_m2=np.maximum(at_z, 0.0), dof=dof, progress=progress
    )
    sigma2 = fit.noise_var_m2
    means, precisions = frame_priors(Z, info, fit)
    priors: list[GaussianPrior | None] = [None] * len(records)
    held = fit.held if fit.held.any() else None  # the muscles the fit holds at rest, shared by every frame
    for k, j in enumerate(rows):
        w = sigma2 * precisions[k]
        priors[j] = GaussianPrior(means[k], 0.5 * (w + w.T), held=held)
    return priors, fit, summary(fit, len(rows))


def summary(fit: UsageFit, frames: int) -> dict:
    """report.json's description of a usage fit."""
    return {
        "frames_fitted": frames,
        "noise_mm": float(np.sqrt(3.0 * fit.noise_var_m2) * 1e3),
        "activation_sd": np.sqrt(fit.gamma).tolist(),
        "correlation_length_frames": fit.length_frames,
        "cv_log_likelihood": None if fit.cv_score is None else {str(k): v for k, v in fit.cv_score.items()},
    }
