"""Bringing a real capture onto a face model (Choe & Ko 2001, section 4.1.1; docs/design.md, "Tracking").

Sanity first (``check_capture``): samples no face can produce become missing before anything is
fitted to them, counted per marker: non-finite values; positions far outside the head (more than
``max_deformation_m`` from where a rigid motion of the neutral frame puts the marker: no facial
tissue moves 10 cm against the skull); and one-frame spikes faster than ``max_speed_m_s`` (2 m/s,
about ten times the fastest marker in the AnimFace takes) that come back the next frame.

Then the neutral frame is aligned to the skin by a similarity transform iterated with projection
onto the surface; markers whose names the model also has pull toward the model's marker as
landmarks. An implausible fit is refused with what to check (``CaptureError``): a scale outside
[0.5, 2] (after the reader's unit conversion: a wrong unit gives 10x or 1000x), or, with fewer than
three names matched, a shape fit worse than 10 mm RMS. The same similarity maps every frame, so the
actor's rigid head motion stays in the data and is carried by the cranium controls. Each marker is
embedded in its closest skin triangle with its offset along the normal and in the triangle's tangent
frame, so it sits exactly at its neutral-frame place at rest (``wface.mesh.align``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wface.mesh.align import FACE_SCALE_RANGE, align_to_surface, umeyama
from wface.tracking.markers import MarkerMap

__all__ = ["CaptureCheck", "CaptureError", "PreparedCapture", "check_capture", "prepare_capture"]

MAX_SPEED_M_S = 2.0
MAX_DEFORMATION_M = 0.10
MIN_NAMED_MARKERS = 3
MAX_SHAPE_FIT_MM = 10.0


class CaptureError(ValueError):
    """A capture cannot be put on the model as it is; the message says what to check."""


@dataclass
class CaptureCheck:
    """A capture with its impossible samples made missing, and how many there were per marker."""

    positions_m: np.ndarray  # (F, k, 3) cleaned, NaN = missing
    marker_names: list[str]
    non_finite: np.ndarray  # (k,) samples with inf / NaN in some but not all coordinates
    far: np.ndarray  # (k,) samples far outside the head
    jumps: np.ndarray  # (k,) one-frame spikes faster than max_speed_m_s
    settings: dict = field(default_factory=dict)

    @property
    def removed(self) -> int:
        return int(self.non_finite.sum() + self.far.sum() + self.jumps.sum())

    def per_marker(self) -> dict:
        """{marker: {"non_finite", "far", "jumps"}} for the markers that lost samples."""
        out = {}
        for i, name in enumerate(self.marker_names):
            counts = {"non_finite": int(self.non_finite[i]), "far": int(self.far[i]), "jumps": int(self.jumps[i])}
            if any(counts.values()):
                out[name] = counts
        return out

    def report(self) -> dict:
        """The report.json entry: totals, the per-marker counts and the thresholds used."""
        return {
            "removed_samples": self.removed,
            "non_finite": int(self.non_finite.sum()),
            "far_outside_head": int(self.far.sum()),
            "jumps": int(self.jumps.sum()),
            "per_marker": self.per_marker(),
            **self.settings,
        }

    def summary(self) -> str:
        """One line for a warning ("" when nothing was removed)."""
        if not self.removed:
            return ""
        worst = sorted(self.per_marker().items(), key=lambda kv: -sum(kv[1].values()))[:3]
        names = ", ".join(f"{n} {sum(c.values())}" for n, c in worst)
        return (
            f"capture check: {self.removed} impossible samples made missing ({int(self.non_finite.sum())} non-finite, "
            f"{int(self.far.sum())} far outside the head, {int(self.jumps.sum())} jumps faster than "
            f"{self.settings.get('max_speed_m_s', MAX_SPEED_M_S):g} m/s); most in {names}"
        )


def _rigid_residuals(ref: np.ndarray, cur: np.ndarray) -> np.ndarray:
    """(k,) distance of each marker from a robust rigid motion of ``ref`` onto ``cur`` (NaN where missing)."""
    ok = np.isfinite(ref).all(axis=1) & np.isfinite(cur).all(axis=1)
    res = np.full(len(ref), np.nan)
    if ok.sum() < 3:
        return res
    use = ok.copy()
    for _ in range(4):  # refit without the markers that moved most (lips, jaw, corrupted samples)
        sim = umeyama(ref[use], cur[use], with_scale=False)
        res[ok] = np.linalg.norm(sim.apply(ref[ok]) - cur[ok], axis=1)
        cut = max(3.0 * np.median(res[ok]), 5e-3)
        keep = ok & (res <= cut)
        if keep.sum() < 3 or np.array_equal(keep, use):
            break
        use = keep
    return res


def _spikes(pos: np.ndarray, jump_m: float) -> np.ndarray:
    """(F, k) samples that jump more than ``jump_m`` from both neighbours while the neighbours agree."""
    out = np.zeros(pos.shape[:2], dtype=bool)
    if len(pos) < 3:
        return out
    d_prev = np.linalg.norm(pos[1:-1] - pos[:-2], axis=2)
    d_next = np.linalg.norm(pos[1:-1] - pos[2:], axis=2)
    d_skip = np.linalg.norm(pos[2:] - pos[:-2], axis=2)
    with np.errstate(invalid="ignore"):
        out[1:-1] = (d_prev > jump_m) & (d_next > jump_m) & (d_skip <= jump_m)
    return out


def check_capture(
    positions_m: np.ndarray,
    marker_names: list[str],
    *,
    rate_hz: float,
    reference_positions_m: np.ndarray | None = None,
    max_speed_m_s: float = MAX_SPEED_M_S,
    max_deformation_m: float = MAX_DEFORMATION_M,
) -> CaptureCheck:
    """Make impossible samples missing (see the module docstring) and count them per marker.

    Args:
        positions_m: (F, k, 3) marker positions in metres (the reader's units converted), NaN = missing.
        marker_names: the k names.
        rate_hz: frame rate (for the speed limit).
        reference_positions_m: (k, 3) the neutral frame (default: the first frame); rigid motions
            of it say where a marker can be.
        max_speed_m_s: fastest plausible marker speed; a one-frame spike faster than this is removed.
        max_deformation_m: farthest a marker may be from the rigid motion of its neutral position.

    Returns:
        A ``CaptureCheck`` (the cleaned positions and the counts).
    """
    pos = np.array(positions_m, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[2] != 3 or pos.shape[1] != len(marker_names):
        raise ValueError(
            f"capture has shape {pos.shape} for {len(marker_names)} marker names; expected (frames, markers, 3)"
        )
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"capture frame rate must be positive, got {rate_hz}")
    finite = np.isfinite(pos).all(axis=2)
    partly = ~finite & ~np.isnan(pos).all(axis=2)  # inf, or a NaN in only some coordinates
    pos[~finite] = np.nan
    ref = pos[0] if reference_positions_m is None else np.array(reference_positions_m, dtype=np.float64)
    ref = np.where(np.isfinite(ref).all(axis=1)[:, None], ref, np.nan)
    centre = np.nanmedian(ref, axis=0) if np.isfinite(ref).any() else np.zeros(3)
    radius = np.linalg.norm(ref - centre, axis=1)
    reach = max(3.0 * np.nanmedian(radius), 0.3) if np.isfinite(radius).any() else 0.3
    with np.errstate(invalid="ignore"):
        ref[radius > reach] = np.nan  # a neutral sample that no head reaches is not a reference
    far = np.zeros(pos.shape[:2], dtype=bool)
    for t in range(len(pos)):
        with np.errstate(invalid="ignore", over="ignore"):  # a 1e200 sample's distance is inf: far, not a warning
            if np.isfinite(pos[t]).any():  # nor is one in any frame (the neutral one too), with or without a reference
                far[t] = np.linalg.norm(pos[t] - np.nanmedian(pos[t], axis=0), axis=1) > reach
            # the rigid fit without those (a 1e200 sample overflowed it and took its frame's every marker)
            far[t] |= _rigid_residuals(ref, np.where(far[t][:, None], np.nan, pos[t])) > max_deformation_m
    pos[far] = np.nan
    jumps = _spikes(pos, max_speed_m_s / rate_hz)
    pos[jumps] = np.nan
    settings = {"max_speed_m_s": max_speed_m_s, "max_deformation_m": max_deformation_m}
    return CaptureCheck(pos, list(marker_names), partly.sum(axis=0), far.sum(axis=0), jumps.sum(axis=0), settings)


@dataclass
class PreparedCapture:
    targets_m: np.ndarray  # (F, k, 3) capture in the model frame
    markers: MarkerMap
    marker_names: list[str]
    scale: float
    alignment_rms_mm: float
    matched_names: list[str]


def _check_alignment(model, marker_names, matched: list[str], scale: float, rms_mm: float) -> None:
    """Refuse an implausible alignment with what to check (see the module docstring)."""
    names_hint = ""
    if len(matched) < MIN_NAMED_MARKERS:
        some = ", ".join(model.marker_names[:6]) or "(the model has no named markers)"
        names_hint = (
            f"; only {len(matched)} of the capture's {len(marker_names)} marker names match the model's "
            f"(the model has e.g. {some}): rename the markers or use a model with these names"
        )
    lo, hi = FACE_SCALE_RANGE
    if not lo <= scale <= hi:
        raise CaptureError(
            f"the capture aligns to the model at scale {scale:.3g} (plausible: {lo:g} to {hi:g}): check the file's "
            f"length units (a cm file read as mm is 10x too small) and that its markers are on a face{names_hint}"
        )
    if len(matched) < MIN_NAMED_MARKERS and rms_mm > MAX_SHAPE_FIT_MM:
        raise CaptureError(
            f"the capture's shape fits the model's skin to only {rms_mm:.1f} mm RMS (at most {MAX_SHAPE_FIT_MM:g} mm "
            f"without named markers){names_hint}"
        )


def prepare_capture(
    model,
    positions_m: np.ndarray,
    marker_names: list[str],
    *,
    reference_frame: int = 0,
    reference_positions_m: np.ndarray | None = None,
) -> PreparedCapture:
    """Align a capture (F, k, 3) in metres to ``model`` and embed its markers in the skin.

    Args:
        model: the face.
        positions_m: (F, k, 3) marker positions in metres, NaN = missing.
        marker_names: the k marker names (names the model also has act as landmarks).
        reference_frame: the frame of ``positions_m`` that shows the neutral face; it anchors the
            alignment and the embedding.
        reference_positions_m: (k, 3) neutral marker positions given directly (e.g. a frame outside
            the tracked range); overrides ``reference_frame``.
    """

    pos = np.asarray(positions_m, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[2] != 3 or pos.shape[1] != len(marker_names):
        raise ValueError(
            f"capture has shape {pos.shape} for {len(marker_names)} marker names; expected (frames, markers, 3)"
        )
    if reference_positions_m is not None:
        ref = np.asarray(reference_positions_m, dtype=np.float64)
        if ref.shape != pos.shape[1:]:
            raise ValueError(f"reference_positions_m has shape {ref.shape}, expected {pos.shape[1:]}")
        what = "the reference positions"
    else:
        if not -len(pos) <= reference_frame < len(pos):
            raise ValueError(f"reference_frame {reference_frame} is outside the capture's {len(pos)} frames")
        ref = pos[reference_frame]
        what = f"frame {reference_frame} of the capture"
    if np.isfinite(ref).all(axis=1).sum() < 3:
        raise ValueError(f"{what} has fewer than 3 markers present")
    known = dict(zip(model.marker_names, model.marker_positions_m, strict=True))
    landmarks = np.full((len(marker_names), 3), np.nan)  # the model's own marker, not its nearest node
    matched = []
    for i, name in enumerate(marker_names):
        if name in known:
            landmarks[i] = known[name]
            matched.append(name)
    if not model.skin_triangles.size:
        raise CaptureError("the model has no skin triangles to put the markers on (was it built or imported fully?)")
    al = align_to_surface(
        ref,
        model.rest_positions_m,
        model.skin_triangles,
        landmark_points_m=landmarks if matched else None,
        with_scale=True,
        landmark_weight=1.0 if matched else 0.0,
        trim_fraction=0.1,
    )
    _check_alignment(model, marker_names, matched, float(al.transform.scale), float(al.rms_history_m[-1] * 1e3))
    targets = al.transform.apply(pos)
    return PreparedCapture(
        targets,
        MarkerMap(model, al.embedding),
        list(marker_names),
        float(al.transform.scale),
        float(al.rms_history_m[-1] * 1e3),
        matched,
    )
