"""Per-frame analysis of marker displacements into element contractions (Choe & Ko 2001, sec. 4.1.2).

For frame f with measured marker displacements d^_j (model frame, metres) and marker shapes d_ij
(displacement of marker j when element i contracts fully):

    minimise  sum_j |d^_j - sum_i x_i d_ij|^2   subject to  0 <= x_i <= 1   (or x_i >= 0)

i.e. the QP with Q = 2 D^T D, c = 2 D^T d^, solved by :func:`wface.solvers.bvls.bounded_lstsq`
warm-started from the previous frame. Missing markers drop their rows. With a face split the
markers and elements form disjoint groups (e.g. upper and lower face) solved independently.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from tqdm.auto import tqdm

from wface.solvers.bvls import bounded_lstsq, bounded_qp

__all__ = ["Analysis", "FaceSplit", "MarkerBasis", "analyze", "default_face_split"]

_UPPER_MARKER_KEYS = ("brow", "eye", "forehead")
_UPPER_ELEMENT_KEYS = ("brow", "eye", "pupil")


@dataclass
class MarkerBasis:
    """The actuation basis seen at the markers.

    Attributes:
        shapes_m: (k, 3, B) displacement of marker j, coordinate c, under element i at x_i = 1.
        marker_names: k marker names.
        element_names: B element names.
        rest_m: (k, 3) marker rest positions in the model frame (optional; for plots, RBF).
    """

    shapes_m: np.ndarray
    marker_names: list[str]
    element_names: list[str]
    rest_m: np.ndarray | None = None

    def __post_init__(self):
        self.shapes_m = np.asarray(self.shapes_m, dtype=np.float64)
        k, c, b = self.shapes_m.shape
        if c != 3 or k != len(self.marker_names) or b != len(self.element_names):
            raise ValueError(
                f"MarkerBasis: shapes {self.shapes_m.shape} do not fit {len(self.marker_names)} markers x 3 x "
                f"{len(self.element_names)} elements"
            )

    @property
    def n_markers(self) -> int:
        return self.shapes_m.shape[0]

    @property
    def n_elements(self) -> int:
        return self.shapes_m.shape[2]

    def predict(self, contractions: np.ndarray) -> np.ndarray:
        """Marker displacements (frames, k, 3) for contractions (frames, B)."""
        return np.einsum("kcb,fb->fkc", self.shapes_m, np.atleast_2d(contractions))

    def with_shapes(self, shapes_m: np.ndarray) -> MarkerBasis:
        return MarkerBasis(shapes_m, list(self.marker_names), list(self.element_names), self.rest_m)


@dataclass
class FaceSplit:
    """Disjoint groups of (marker indices, element indices) solved independently."""

    groups: list[tuple[np.ndarray, np.ndarray]]

    def __post_init__(self):
        self.groups = [(np.asarray(m, dtype=np.int64), np.asarray(e, dtype=np.int64)) for m, e in self.groups]
        for kind, pos in (("marker", 0), ("element", 1)):
            allv = np.concatenate([g[pos] for g in self.groups]) if self.groups else np.array([], dtype=np.int64)
            if len(np.unique(allv)) != len(allv):
                raise ValueError(f"FaceSplit: {kind} groups overlap")

    @classmethod
    def whole(cls, n_markers: int, n_elements: int) -> FaceSplit:
        return cls([(np.arange(n_markers), np.arange(n_elements))])


def default_face_split(marker_names: Sequence[str], element_names: Sequence[str]) -> FaceSplit:
    """Upper face (brows, eyes, forehead markers; brow/eye elements) and lower face (the rest)."""
    up_m = np.array([any(k in n.lower() for k in _UPPER_MARKER_KEYS) for n in marker_names])
    up_e = np.array([any(n.lower().startswith(k) for k in _UPPER_ELEMENT_KEYS) for n in element_names])
    return FaceSplit([(np.flatnonzero(up_m), np.flatnonzero(up_e)), (np.flatnonzero(~up_m), np.flatnonzero(~up_e))])


@dataclass
class Analysis:
    """Result of :func:`analyze`.

    Attributes:
        contractions: (frames, B) contractions x.
        fitted_m: (frames, k, 3) model marker displacements D x.
        error_m: (frames, k) |d^_j - D_j x| per marker (NaN where missing).
        marker_rms_m: (frames,) RMS over present markers.
        iterations: (frames,) active-set iterations per frame (all groups).
        element_names, marker_names: labels.
        unobservable: elements that move no marker (left at 0).
    """

    contractions: np.ndarray
    fitted_m: np.ndarray
    error_m: np.ndarray
    marker_rms_m: np.ndarray
    iterations: np.ndarray
    element_names: list[str]
    marker_names: list[str]
    unobservable: list[str] = field(default_factory=list)

    @property
    def marker_rms_mm(self) -> np.ndarray:
        return self.marker_rms_m * 1e3

    @property
    def total_rms_m(self) -> float:
        """RMS marker error over every present marker of every frame."""
        e = self.error_m[np.isfinite(self.error_m)]
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def analyze(
    basis: MarkerBasis,
    displacements_m: np.ndarray,
    *,
    upper: float | None = 1.0,
    split: FaceSplit | None = None,
    warm_start: bool = True,
    exact: bool = False,
    progress: bool = False,
) -> Analysis:
    """Contractions for every frame.

    Args:
        basis: marker shapes (k, 3, B).
        displacements_m: (frames, k, 3) measured marker displacements from the neutral, in the
            model frame; NaN = missing.
        upper: upper bound of every contraction (1.0), or None for x >= 0 only (exaggeration).
        split: disjoint marker/element groups (default: one group).
        warm_start: start each frame from the previous frame's solution and active set.
        exact: solve each subproblem by least squares on D (robust to nearly dependent shapes)
            instead of Cholesky on the normal matrix D^T D (faster, the default).
        progress: show a tqdm progress bar.

    Returns:
        :class:`Analysis`.
    """
    d = np.asarray(displacements_m, dtype=np.float64)
    if d.ndim == 2:
        d = d[None]
    k, _, nb = basis.shapes_m.shape
    if d.shape[1:] != (k, 3):
        raise ValueError(f"analyze: displacements {d.shape} do not match {k} markers of the basis")
    split = split or FaceSplit.whole(k, nb)
    hi = np.inf if upper is None else float(upper)
    n_frames = d.shape[0]
    x = np.zeros((n_frames, nb))
    iters = np.zeros(n_frames, dtype=np.int64)
    present = np.isfinite(d).all(axis=2)
    frames = range(n_frames)
    if progress:
        frames = tqdm(frames, desc="analysis", unit="frame", leave=False)
    # Elements that (nearly) do not move any marker of their group are unobservable: they stay 0
    # (e.g. ICT's eyeLook*/PupilDilate* shapes move only the eyeballs).
    col = np.linalg.norm(basis.shapes_m, axis=(0, 1))
    observable = col > 1e-6 * max(col.max(initial=0.0), 1e-300)
    split = FaceSplit([(gm, ge[observable[ge]]) for gm, ge in split.groups])
    group_mats = [basis.shapes_m[np.ix_(gm, np.arange(3), ge)].reshape(len(gm) * 3, len(ge)) for gm, ge in split.groups]
    group_gram = [a.T @ a for a in group_mats]

    # Cold starts begin at the clipped ridge solution (Q + mu I)^-1 c, mu = 0.1 mean(diag Q): fewer
    # active-set changes than all-at-zero or the clipped (often wild) unconstrained solution.
    def ridge_inverse(q):
        mu = 0.1 * max(np.trace(q) / max(len(q), 1), 1e-300)
        return np.linalg.inv(q + mu * np.eye(len(q)))

    group_pinv = [ridge_inverse(q) for q in group_gram]
    warm = [None] * len(split.groups)
    for f in frames:
        for g, (gm, ge) in enumerate(split.groups):
            if len(ge) == 0:
                continue
            ok = present[f, gm]
            if not ok.any():
                warm[g] = None
                continue
            a = group_mats[g]
            q = group_gram[g]
            if not ok.all():
                a = a.reshape(len(gm), 3, len(ge))[ok].reshape(-1, len(ge))
                q = a.T @ a
            b = d[f, gm[ok]].ravel()
            start = (None, None) if (warm[g] is None or not warm_start) else warm[g]
            if start[0] is None:
                pinv = group_pinv[g] if ok.all() else ridge_inverse(q)
                start = (np.clip(pinv @ (a.T @ b), 0.0, hi), None)
            if exact:
                res = bounded_lstsq(a, b, 0.0, hi, x0=start[0], state0=start[1])
            else:
                res = bounded_qp(q, a.T @ b, 0.0, hi, x0=start[0], state0=start[1], b_norm2=float(b @ b))
            x[f, ge] = res.x
            iters[f] += res.iterations
            warm[g] = (res.x, res.state)
    fitted = basis.predict(x)
    err = np.linalg.norm(d - fitted, axis=2)
    sq = np.where(np.isfinite(err), err**2, 0.0)
    count = np.isfinite(err).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.where(count > 0, np.sqrt(sq.sum(axis=1) / np.maximum(count, 1)), np.nan)
    unobs = [n for n, o in zip(basis.element_names, observable, strict=False) if not o]
    return Analysis(x, fitted, err, rms, iters, list(basis.element_names), list(basis.marker_names), unobs)
