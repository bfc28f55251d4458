"""The steps behind ``wface basis analyze`` and ``wface basis refine``, usable from Python.

Units: the basis is in metres (ICT npz centimetres are converted on load), takes in metres
(C3D millimetres converted on read); reports give marker errors in millimetres (``*_mm``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wface.basis.analysis import Analysis, FaceSplit, analyze, default_face_split
from wface.basis.capture import CaptureOnBasis, MarkerLayout, stabilise_capture
from wface.basis.core import ActuationBasis
from wface.basis.landmarks import load_ict_animface_landmarks
from wface.basis.plots import frames_title, plot_analysis
from wface.basis.refine import RefinementResult, interpolate_to_mesh, refine_marker_basis, select_regularization
from wface.files import save_npz, write_csv, write_json

__all__ = ["TakeAnalysis", "analyze_take", "default_landmarks", "refine_basis", "write_analysis"]

_ICT_VERTEX_COUNT = 26719


def default_landmarks(basis: ActuationBasis, marker_names: Sequence[str]) -> dict[str, int] | None:
    """The basis's own landmarks (a basis made from a face model) or, for the ICT face, the built-in
    AnimFace->ICT ones, when at least 3 of them are markers of the take."""
    if basis.landmarks:
        hits = {n: basis.landmarks[n] for n in marker_names if n in basis.landmarks}
        return hits if len(hits) >= 3 else None
    if basis.n_vertices != _ICT_VERTEX_COUNT:
        return None

    lm = load_ict_animface_landmarks()
    hits = {n: lm[n] for n in marker_names if n in lm}
    return hits if len(hits) >= 3 else None


@dataclass
class TakeAnalysis:
    """A take analysed on a basis."""

    layout: MarkerLayout
    capture: CaptureOnBasis
    analysis: Analysis


def _split(use_split: bool, marker_names, element_names) -> FaceSplit | None:
    return default_face_split(marker_names, element_names) if use_split else None


def analyze_take(
    basis: ActuationBasis,
    take,
    *,
    landmarks: Mapping[str, int] | None = None,
    layout: MarkerLayout | None = None,
    upper: float | None = 1.0,
    split: bool = False,
    progress: bool = False,
) -> TakeAnalysis:
    """Align a take to the basis (layout from its first frame unless given) and analyse every frame."""
    if landmarks is None:
        landmarks = default_landmarks(basis, take.marker_names)
    if layout is None:
        layout = MarkerLayout.from_frame(basis, take.marker_names, take.positions_m[0], landmarks=landmarks)
    cap = stabilise_capture(take, layout)
    mb = layout.marker_basis(basis)
    an = analyze(mb, cap.displacements_m, upper=upper, split=_split(split, mb.marker_names, mb.element_names),
                 progress=progress)  # fmt: skip
    return TakeAnalysis(layout, cap, an)


def write_analysis(
    out_dir: str | Path,
    result: TakeAnalysis,
    *,
    extra: dict | None = None,
    plot: bool = True,
    frames: tuple | None = None,
) -> dict:
    """Write contractions (npz + CSV), per-frame marker errors (CSV), report.json and a plot (its title
    names the take's file and ``frames``, the slice (start, stop, step) of its frames analysed).

    Returns:
        The report dictionary (also in ``out_dir/report.json``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    an, cap = result.analysis, result.capture
    times = np.arange(an.contractions.shape[0]) / cap.rate_hz
    save_npz(
        out / "contractions.npz", compressed=True, contractions=an.contractions,
        element_names=np.array(an.element_names), marker_names=np.array(an.marker_names),
        marker_error_mm=an.error_m * 1e3, marker_rms_mm=an.marker_rms_mm, times_s=times, rate_hz=cap.rate_hz,
    )  # fmt: skip
    write_csv(
        out / "contractions.csv",
        ["frame", "time_s", *an.element_names],
        ([f, f"{times[f]:.6f}", *(f"{v:.6g}" for v in row)] for f, row in enumerate(an.contractions)),
    )
    write_csv(
        out / "marker_error_mm.csv",
        ["frame", "time_s", "marker_rms_mm", *an.marker_names],
        (
            [f, f"{times[f]:.6f}", f"{an.marker_rms_mm[f]:.6g}", *(f"{v:.6g}" for v in row)]
            for f, row in enumerate(an.error_m * 1e3)
        ),
    )
    x = an.contractions
    report = {
        "frames": int(x.shape[0]),
        "markers": len(an.marker_names),
        "elements": len(an.element_names),
        "source": cap.source,
        "rate_hz": cap.rate_hz,
        "marker_rms_mm": [float(v) if np.isfinite(v) else None for v in an.marker_rms_mm],
        "marker_rms_mm_mean": float(np.nanmean(an.marker_rms_mm)),
        "marker_rms_mm_total": an.total_rms_m * 1e3,
        "marker_max_mm": float(np.nanmax(an.error_m) * 1e3),
        "displacement_rms_mm": float(np.sqrt(np.nanmean(np.sum(cap.displacements_m**2, axis=2))) * 1e3),
        "alignment_rms_mm": result.layout.alignment_rms_m * 1e3,
        "alignment_scale": float(cap.transform.scale),
        "head_motion_residual_mm_mean": float(np.nanmean(cap.head_rms_m) * 1e3),
        "active_set_iterations_mean": float(an.iterations.mean()),
        "contraction_mean": {n: float(v) for n, v in zip(an.element_names, x.mean(axis=0), strict=False)},
        "contraction_max": {n: float(v) for n, v in zip(an.element_names, x.max(axis=0), strict=False)},
        "unobservable_elements": an.unobservable,
    }
    if extra:
        report.update(extra)
    if plot:
        plot_analysis(an, out / "analysis.png", rate_hz=cap.rate_hz, title=frames_title(Path(cap.source).name, frames))
        report["plot"] = "analysis.png"
    write_json(out / "report.json", report)
    return report


def refine_basis(
    basis: ActuationBasis,
    takes: Sequence,
    *,
    landmarks: Mapping[str, int] | None = None,
    upper: float | None = 1.0,
    split: bool = False,
    regularization: float | str = "auto",
    max_iterations: int = 30,
    rel_tol: float = 1e-3,
    support_fraction: float | None = None,
    progress: bool = False,
    carry_metric: str = "surface",
) -> tuple[ActuationBasis, RefinementResult, MarkerLayout, dict]:
    """Refine a basis on training takes and carry the result to the whole mesh.

    The marker layout comes from the first take's first frame; every take is aligned to it.

    Args:
        regularization: ridge weight towards the initial shapes, or "auto" to pick it by
            leave-one-take-out validation (needs >= 2 takes; else 0.3).
        support_fraction: locality mask of :func:`wface.basis.refine.refine_marker_basis`.
        carry_metric: distances of the carry-over to the mesh, see
            :func:`wface.basis.refine.interpolate_to_mesh` ("surface" or "euclidean").

    Returns:
        (refined basis, refinement result, layout, info dict with the chosen regularisation).
    """
    if not takes:
        raise ValueError("refine_basis: no training takes")
    first = takes[0]
    if landmarks is None:
        landmarks = default_landmarks(basis, first.marker_names)
    layout = MarkerLayout.from_frame(basis, first.marker_names, first.positions_m[0], landmarks=landmarks)
    mb = layout.marker_basis(basis)
    disps = [stabilise_capture(t, layout).displacements_m for t in takes]
    sp = _split(split, mb.marker_names, mb.element_names)
    info: dict = {}
    if regularization == "auto":
        if len(disps) >= 2:
            lam, scores = select_regularization(mb, disps, upper=upper, split=sp, support_fraction=support_fraction)
            info["regularization_scores_mm"] = {str(k): v * 1e3 for k, v in scores.items()}
        else:
            lam = 0.3
    else:
        lam = float(regularization)
    info["regularization"] = lam
    res = refine_marker_basis(mb, disps, upper=upper, split=sp, max_iterations=max_iterations, rel_tol=rel_tol,
                              regularization=lam, support_fraction=support_fraction, progress=progress)  # fmt: skip
    refined = interpolate_to_mesh(basis, layout.surface_m, res.basis.shapes_m - mb.shapes_m, metric=carry_metric)
    return refined, res, layout, info
