"""Basis refinement (Choe & Ko 2001, sec. 4.3): fixed point between analysis and modelling.

Analysis:  x_f = argmin_{lo <= x <= hi} sum_j |d^_fj - sum_i x_i d_ij|^2   for every training frame f.
Modelling: d_j = argmin_d sum_f |d^_fj - sum_i x_fi d_ij|^2 + lambda |d_j - d_j^0|^2   for every
           marker j (one least-squares problem per marker, all frames; lambda = 0 is the paper's).
Repeat until the total analysis error stops falling (relative drop below ``rel_tol``); every
iteration's error is kept. The refined marker shapes are carried to the whole mesh by RBF
scattered-data interpolation of the correction d_ij - d_ij^0 over the markers' neutral surface
points (thin-plate spline, reproducing affine fields), faded out away from the markers.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from wface.basis.analysis import Analysis, FaceSplit, MarkerBasis, analyze
from wface.basis.core import ActuationBasis

__all__ = [
    "RefinementResult",
    "interpolate_to_mesh",
    "model_marker_shapes",
    "refine_marker_basis",
    "select_regularization",
]


@dataclass
class RefinementResult:
    """Result of :func:`refine_marker_basis`.

    Attributes:
        basis: refined marker basis (the iterate with the lowest training error).
        errors_m: total training RMS marker error after the analysis of each iteration
            (entry 0: the initial basis).
        analyses: final analysis of each training take with the refined basis.
        iterations: modelling steps taken.
    """

    basis: MarkerBasis
    errors_m: list[float]
    analyses: list[Analysis] = field(default_factory=list)
    iterations: int = 0

    @property
    def errors_mm(self) -> list[float]:
        return [e * 1e3 for e in self.errors_m]


def model_marker_shapes(
    contractions: np.ndarray,
    displacements_m: np.ndarray,
    prior_shapes_m: np.ndarray,
    *,
    split: FaceSplit | None = None,
    regularization: float = 0.0,
) -> np.ndarray:
    """Modelling step: least-squares marker shapes given contractions.

    Args:
        contractions: (F, B) contractions of all training frames.
        displacements_m: (F, k, 3) measured displacements (NaN = missing).
        prior_shapes_m: (k, 3, B) current shapes; elements a marker group never uses, and the
            regularisation, refer to it.
        split: disjoint marker/element groups: a marker's shape only has its group's elements.
        regularization: lambda, relative to the mean diagonal of X^T X (0: plain least squares,
            minimum-norm change from the prior where X is rank deficient).

    Returns:
        (k, 3, B) refined shapes.
    """
    x = np.asarray(contractions, dtype=np.float64)
    d = np.asarray(displacements_m, dtype=np.float64)
    k, _, nb = prior_shapes_m.shape
    split = split or FaceSplit.whole(k, nb)
    out = prior_shapes_m.copy()
    present = np.isfinite(d).all(axis=2)
    for gm, ge in split.groups:
        if len(ge) == 0 or len(gm) == 0:
            continue
        xg = x[:, ge]
        gram_scale = float(np.mean(np.einsum("fb,fb->b", xg, xg))) if len(xg) else 0.0
        lam = regularization * max(gram_scale, 1e-300)
        prior = prior_shapes_m[np.ix_(gm, np.arange(3), ge)]  # (kg, 3, bg)
        # Residual of the prior: solve for the change (minimum-norm => untouched unused elements).
        pred = np.einsum("kcb,fb->fkc", prior, xg)
        resid = d[:, gm] - pred  # (F, kg, 3)
        same_rows = present[:, gm].all()
        if same_rows:
            delta = _solve_change(xg, resid.reshape(len(xg), -1), lam)  # (bg, kg*3)
            out[np.ix_(gm, np.arange(3), ge)] = prior + delta.reshape(len(ge), len(gm), 3).transpose(1, 2, 0)
        else:
            for jj, j in enumerate(gm):
                rows = present[:, j]
                if not rows.any():
                    continue
                delta = _solve_change(xg[rows], resid[rows, jj], lam)  # (bg, 3)
                out[j, :, ge] = (prior[jj] + delta.T).T
    return out


def _solve_change(x: np.ndarray, r: np.ndarray, lam: float) -> np.ndarray:
    if lam > 0:
        from scipy.linalg import cho_factor, cho_solve

        # (X^T X + lambda I) delta = X^T r: SPD, well conditioned for lambda > 0.
        gram = x.T @ x + lam * np.eye(x.shape[1])
        return cho_solve(cho_factor(gram), x.T @ r)
    return np.linalg.lstsq(x, r, rcond=1e-10)[0]


def refine_marker_basis(
    basis: MarkerBasis,
    displacements_m: Sequence[np.ndarray],
    *,
    upper: float | None = 1.0,
    split: FaceSplit | None = None,
    max_iterations: int = 30,
    rel_tol: float = 1e-3,
    regularization: float = 0.0,
    progress: bool = False,
) -> RefinementResult:
    """Fixed-point refinement of the marker shapes over training takes.

    Args:
        basis: initial marker basis.
        displacements_m: training takes, each (F_t, k, 3) in the model frame.
        upper: contraction upper bound (None: x >= 0).
        split: face split used both in analysis and modelling.
        max_iterations: cap on modelling steps.
        rel_tol: stop when the error falls by less than this fraction in one iteration.
        regularization: see :func:`model_marker_shapes`.
        progress: tqdm progress bars.

    Returns:
        :class:`RefinementResult` (the best iterate; its error is ``min(errors_m)``).
    """
    takes = [np.asarray(t, dtype=np.float64) for t in displacements_m]
    if not takes:
        raise ValueError("refine_marker_basis: no training takes")
    all_d = np.concatenate(takes, axis=0)
    current = basis
    errors: list[float] = []
    best = (np.inf, basis, [])
    steps = range(max_iterations + 1)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(steps, desc="refinement", unit="iter")
    it = 0
    for it in steps:
        analyses = [analyze(current, t, upper=upper, split=split) for t in takes]
        x = np.concatenate([a.contractions for a in analyses], axis=0)
        err = np.concatenate([a.error_m for a in analyses], axis=0)
        total = float(np.sqrt(np.nanmean(err**2)))
        errors.append(total)
        if total < best[0]:
            best = (total, current, analyses)
        if len(errors) > 1 and (errors[-2] - total) < rel_tol * errors[-2]:
            break
        if it == max_iterations:
            break
        shapes = model_marker_shapes(x, all_d, current.shapes_m, split=split, regularization=regularization)
        current = current.with_shapes(shapes)
    return RefinementResult(best[1], errors, best[2], it)


def interpolate_to_mesh(
    basis: ActuationBasis,
    marker_points_m: np.ndarray,
    shape_change_m: np.ndarray,
    *,
    vertices: np.ndarray | None = None,
    fade_start_m: float = 0.015,
    fade_end_m: float = 0.04,
    smoothing: float = 0.0,
) -> ActuationBasis:
    """Carry marker shape changes to the whole mesh by RBF interpolation over the neutral.

    e_i' = e_i + w(v) RBF_i(v), where RBF_i is the thin-plate-spline interpolant (with an affine
    part) of the changes d'_ij - d_ij at the markers' neutral surface points, and w fades from 1
    within ``fade_start_m`` of the nearest marker to 0 at ``fade_end_m`` (C1 smoothstep), so the
    affine part never drags the back of the head.

    Args:
        basis: the initial basis.
        marker_points_m: (k, 3) neutral surface points of the markers.
        shape_change_m: (k, 3, B) refined minus initial marker shapes.
        vertices: vertex ids to move (default the basis skin vertices, else all).
        fade_start_m, fade_end_m: fade-out distances from the nearest marker.
        smoothing: RBFInterpolator smoothing (0: interpolate exactly).

    Returns:
        A new :class:`ActuationBasis` with refined shapes.
    """
    from scipy.interpolate import RBFInterpolator
    from scipy.spatial import cKDTree

    pts = np.asarray(marker_points_m, dtype=np.float64)
    ch = np.asarray(shape_change_m, dtype=np.float64)
    k, _, nb = ch.shape
    ok = np.isfinite(pts).all(axis=1)
    if vertices is None:
        vertices = basis.skin_vertices if basis.skin_vertices is not None else np.arange(basis.n_vertices)
    vertices = np.asarray(vertices, dtype=np.int64)
    vals = ch[ok].reshape(ok.sum(), 3 * nb)
    rbf = RBFInterpolator(pts[ok], vals, kernel="thin_plate_spline", degree=1, smoothing=smoothing)
    where = basis.neutral_m[vertices]
    dist = cKDTree(pts[ok]).query(where)[0]
    t = np.clip((dist - fade_start_m) / max(fade_end_m - fade_start_m, 1e-12), 0.0, 1.0)
    w = 1.0 - t * t * (3.0 - 2.0 * t)
    near = w > 0
    field_ = np.zeros((len(vertices), 3 * nb))
    field_[near] = rbf(where[near]) * w[near, None]
    shapes = basis.shapes_m.copy()
    shapes[:, vertices, :] += field_.reshape(len(vertices), 3, nb).transpose(2, 0, 1)
    return ActuationBasis(basis.neutral_m, shapes, list(basis.names), basis.face_counts, basis.face_indices,
                          basis.skin_vertices, basis.source + " (refined)")  # fmt: skip


def select_regularization(
    basis: MarkerBasis,
    displacements_m: Sequence[np.ndarray],
    candidates: Sequence[float] = (0.03, 0.3, 3.0),
    *,
    upper: float | None = 1.0,
    split: FaceSplit | None = None,
    max_iterations: int = 8,
    frame_step: int = 3,
) -> tuple[float, dict[float, float]]:
    """Pick the ridge weight by leave-one-take-out validation inside the training takes.

    Each candidate refines on all training takes but one (every ``frame_step``-th frame, at most
    ``max_iterations`` steps) and is scored by the analysis error on the left-out take; the
    candidate with the lowest mean validation RMS wins. Needs at least two takes.

    Returns:
        (chosen lambda, {lambda: mean validation RMS in metres}).
    """
    takes = [np.asarray(t)[::frame_step] for t in displacements_m]
    if len(takes) < 2:
        raise ValueError("select_regularization: needs at least two training takes")
    scores = {}
    for lam in candidates:
        errs = []
        for k in range(len(takes)):
            train = [t for i, t in enumerate(takes) if i != k]
            res = refine_marker_basis(basis, train, upper=upper, split=split, max_iterations=max_iterations,
                                      regularization=lam)  # fmt: skip
            errs.append(analyze(res.basis, takes[k], upper=upper, split=split).total_rms_m)
        scores[float(lam)] = float(np.mean(errs))
    return min(scores, key=scores.get), scores
