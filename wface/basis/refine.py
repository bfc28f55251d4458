"""Basis refinement (Choe & Ko 2001, sec. 4.2): fixed point between analysis and modelling.

Analysis:  x_f = argmin_{lo <= x <= hi} sum_j |d^_fj - sum_i x_i d_ij|^2   for every training frame f.
Modelling: d_j = argmin_d sum_f |d^_fj - sum_i x_fi d_ij|^2 + lambda |d_j - d_j^0|^2   for every
           marker j (one least-squares problem per marker, all frames; lambda = 0 is the paper's).
Repeat until the total analysis error stops falling (relative drop below ``rel_tol``); every
iteration's error is kept. The refined marker shapes are carried to the whole mesh by RBF
scattered-data interpolation of the correction d_ij - d_ij^0 over the markers' neutral surface
points, faded out away from the markers: by default the thin-plate spline of the surface itself
(biharmonic interpolation along the mesh, so touching lips do not drag each other), optionally
the straight-distance thin-plate spline of the paper.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.linalg import cho_factor, cho_solve
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from tqdm.auto import tqdm

from wface.basis.analysis import Analysis, FaceSplit, MarkerBasis, analyze
from wface.basis.core import ActuationBasis
from wface.mesh.closest import SurfaceQuery
from wface.mesh.surface_fields import biharmonic_interpolate, surface_distances

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
        validation_errors_m: RMS error on the validation takes for each iterate (same indexing
            as ``errors_m``; empty without validation takes).
    """

    basis: MarkerBasis
    errors_m: list[float]
    analyses: list[Analysis] = field(default_factory=list)
    iterations: int = 0
    validation_errors_m: list[float] = field(default_factory=list)

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
    support: np.ndarray | None = None,
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
        support: (k, B) bool, which marker/element shapes may change (default all); the others
            keep the prior, so an element cannot start moving markers it never moved.

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
        if support is not None:
            for jj, j in enumerate(gm):
                rows = present[:, j]
                cols = np.flatnonzero(support[j, ge])
                if not rows.any() or len(cols) == 0:
                    continue
                delta = _solve_change(xg[rows][:, cols], resid[rows, jj], lam)  # (|cols|, 3)
                out[j, :, ge[cols]] = (prior[jj][:, cols] + delta.T).T
        elif same_rows:
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
    support_fraction: float | None = None,
    validation_m: Sequence[np.ndarray] = (),
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
        support_fraction: if given, element i may only change its shape at markers it moves by
            at least this fraction of its largest marker displacement in the initial basis
            (locality: refinement reshapes an element where it acts, never adds far motion).
        validation_m: held-out takes scored (not fitted) at every iterate.
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
        steps = tqdm(steps, desc="refinement", unit="iter")
    support = None
    if support_fraction is not None:
        mag = np.linalg.norm(basis.shapes_m, axis=1)  # (k, B)
        support = mag >= support_fraction * np.maximum(mag.max(axis=0, keepdims=True), 1e-300)
    it = 0
    val_errors: list[float] = []
    for it in steps:
        if validation_m:
            verr = [analyze(current, v, upper=upper, split=split).error_m for v in validation_m]
            verr = np.concatenate([e.ravel() for e in verr])
            val_errors.append(float(np.sqrt(np.nanmean(verr**2))))
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
        shapes = model_marker_shapes(
            x, all_d, current.shapes_m, split=split, regularization=regularization, support=support
        )
        current = current.with_shapes(shapes)
    return RefinementResult(best[1], errors, best[2], it, val_errors)


def interpolate_to_mesh(
    basis: ActuationBasis,
    marker_points_m: np.ndarray,
    shape_change_m: np.ndarray,
    *,
    vertices: np.ndarray | None = None,
    fade_start_m: float = 0.015,
    fade_end_m: float = 0.04,
    smoothing: float = 0.0,
    metric: str = "surface",
) -> ActuationBasis:
    """Carry marker shape changes to the whole mesh by scattered-data interpolation over the neutral.

    e_i' = e_i + w(v) S_i(v), where S_i interpolates the changes d'_ij - d_ij at the markers' neutral
    surface points and w fades from 1 within ``fade_start_m`` of the nearest marker to 0 at
    ``fade_end_m`` (C1 smoothstep), so the interpolant never drags the back of the head.

    ``metric="surface"`` (default) measures along the mesh: S_i is the surface thin-plate spline
    (discrete biharmonic interpolant, :func:`wface.mesh.surface_fields.biharmonic_interpolate`),
    exact at the markers' embedded points, and w uses graph distances along the surface. Parts
    of the face that touch without being connected (lips across the mouth opening, eyelids) do
    not drag each other. ``metric="euclidean"`` is the straight-distance thin-plate spline with
    an affine part (scipy RBFInterpolator) and a straight-distance fade: a lower-lip marker moves
    the touching upper lip as much as its own lip.

    Args:
        basis: the initial basis.
        marker_points_m: (k, 3) neutral surface points of the markers (NaN rows are ignored).
        shape_change_m: (k, 3, B) refined minus initial marker shapes.
        vertices: vertex ids to move (default the basis skin vertices, else all); with the
            surface metric, the surface is the basis triangles with all corners among them.
        fade_start_m, fade_end_m: fade-out distances from the nearest marker.
        smoothing: 0 interpolates exactly; > 0 smooths (RBFInterpolator smoothing for the
            euclidean metric; for the surface, dimensionless, see
            :func:`wface.mesh.surface_fields.biharmonic_interpolate`; needed for two markers at
            one point).
        metric: "surface" or "euclidean".

    Returns:
        A new :class:`ActuationBasis` with refined shapes.
    """
    if metric not in ("surface", "euclidean"):
        raise ValueError(f"interpolate_to_mesh: metric must be 'surface' or 'euclidean', got {metric!r}")
    pts = np.asarray(marker_points_m, dtype=np.float64)
    ch = np.asarray(shape_change_m, dtype=np.float64)
    k, _, nb = ch.shape
    ok = np.isfinite(pts).all(axis=1)
    if vertices is None:
        vertices = basis.skin_vertices if basis.skin_vertices is not None else np.arange(basis.n_vertices)
    vertices = np.asarray(vertices, dtype=np.int64)
    vals = ch[ok].reshape(ok.sum(), 3 * nb)
    if metric == "euclidean":
        field_ = _euclidean_field(basis.neutral_m[vertices], pts[ok], vals, fade_start_m, fade_end_m, smoothing)
    else:
        field_ = _surface_field(basis, vertices, pts[ok], vals, fade_start_m, fade_end_m, smoothing)
    shapes = basis.shapes_m.copy()
    shapes[:, vertices, :] += field_.reshape(len(vertices), 3, nb).transpose(2, 0, 1)
    return ActuationBasis(basis.neutral_m, shapes, list(basis.names), basis.face_counts, basis.face_indices,
                          basis.skin_vertices, basis.source + " (refined)", basis.landmarks)  # fmt: skip


def _fade(dist: np.ndarray, start: float, end: float) -> np.ndarray:
    t = np.clip((dist - start) / max(end - start, 1e-12), 0.0, 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


def _euclidean_field(where, pts, vals, fade_start_m, fade_end_m, smoothing) -> np.ndarray:

    rbf = RBFInterpolator(pts, vals, kernel="thin_plate_spline", degree=1, smoothing=smoothing)
    w = _fade(cKDTree(pts).query(where)[0], fade_start_m, fade_end_m)
    near = w > 0
    out = np.zeros((len(where), vals.shape[1]))
    out[near] = rbf(where[near]) * w[near, None]
    return out


def _surface_field(basis, vertices, pts, vals, fade_start_m, fade_end_m, smoothing) -> np.ndarray:

    mask = np.zeros(basis.n_vertices, dtype=bool)
    mask[vertices] = True
    tri = basis.triangles
    tri = tri[mask[tri].all(axis=1)]
    if len(tri) == 0:
        raise ValueError("interpolate_to_mesh: no triangle has all corners among the vertices to move; "
                         "use metric='euclidean' for a point set")  # fmt: skip
    hit = SurfaceQuery(basis.neutral_m, tri).closest(pts)
    dist = surface_distances(basis.neutral_m, tri, hit.triangle, hit.barycentric, limit_m=fade_end_m)
    w = _fade(dist, fade_start_m, fade_end_m)  # inf (beyond the limit, other parts) -> 0
    near_v = np.zeros(basis.n_vertices, dtype=bool)
    near_v[w > 0] = True
    near_v[tri[hit.triangle].ravel()] = True  # the markers' own triangles always belong to the domain
    keep = near_v[tri].all(axis=1)
    keep &= _joined_to(tri, keep, hit.triangle, basis.n_vertices)  # no part without a marker: singular
    renumber = np.cumsum(keep) - 1
    field_all = biharmonic_interpolate(basis.neutral_m, tri[keep], renumber[hit.triangle], hit.barycentric, vals,
                                       smoothing=smoothing)  # fmt: skip
    return field_all[vertices] * w[vertices, None]


def _joined_to(tri: np.ndarray, keep: np.ndarray, seeds: np.ndarray, n: int) -> np.ndarray:
    """(t,) which kept triangles share a connected part (through kept triangles) with a seed triangle."""

    t = tri[keep]
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]]])
    _, label = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
    good = np.zeros(n, dtype=bool)
    good[np.unique(label[tri[seeds, 0]])] = True
    return good[label[tri[:, 0]]]


def select_regularization(
    basis: MarkerBasis,
    displacements_m: Sequence[np.ndarray],
    candidates: Sequence[float] = (0.03, 0.3, 3.0),
    *,
    upper: float | None = 1.0,
    split: FaceSplit | None = None,
    max_iterations: int = 8,
    frame_step: int = 3,
    support_fraction: float | None = None,
    choose_iterations: bool = False,
) -> tuple[float, dict[float, float]] | tuple[float, int, dict[float, float]]:
    """Pick the ridge weight (and optionally the iteration count) by leave-one-take-out validation.

    Each candidate refines on all training takes but one (every ``frame_step``-th frame, at most
    ``max_iterations`` steps) and is scored by the analysis error on the left-out take; the
    candidate with the lowest mean validation RMS wins. With ``choose_iterations`` the left-out
    take is scored after every iteration and the (lambda, iterations) pair with the lowest mean
    validation RMS wins (early stopping chosen by validation). Needs at least two takes.

    Returns:
        (lambda, {lambda: best mean validation RMS in metres}), or with ``choose_iterations``
        (lambda, iterations, {lambda: best mean validation RMS in metres}).
    """
    takes = [np.asarray(t)[::frame_step] for t in displacements_m]
    if len(takes) < 2:
        raise ValueError("select_regularization: needs at least two training takes")
    scores, best_it = {}, {}
    for lam in candidates:
        curves = []
        for k in range(len(takes)):
            train = [t for i, t in enumerate(takes) if i != k]
            res = refine_marker_basis(basis, train, upper=upper, split=split, max_iterations=max_iterations,
                                      rel_tol=0.0 if choose_iterations else 1e-3, regularization=lam,
                                      support_fraction=support_fraction,
                                      validation_m=[takes[k]] if choose_iterations else ())  # fmt: skip
            if choose_iterations:
                curves.append(res.validation_errors_m)
            else:
                curves.append([analyze(res.basis, takes[k], upper=upper, split=split).total_rms_m])
        n = min(len(c) for c in curves)
        mean_curve = np.mean([c[:n] for c in curves], axis=0)
        best_it[float(lam)] = int(np.argmin(mean_curve))
        scores[float(lam)] = float(mean_curve.min())
    lam = min(scores, key=scores.get)
    if choose_iterations:
        return lam, best_it[lam], scores
    return lam, scores
