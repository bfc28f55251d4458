"""Marker data handed to the tracker, checked before any work: shapes, names, and a scale that says metres."""

from __future__ import annotations

import numpy as np

__all__ = ["checked_marker_data"]

_SPAN_RATIO = 3.0  # the markers' spread may differ from the face's by this factor (actor and face sizes)


def _check_marker_span(targets: np.ndarray, rest_markers_m: np.ndarray) -> None:
    """Refuse marker data whose spread (RMS distance from the centroid, over the markers present in a
    frame and at rest) is far from the face's: data in millimetres or centimetres, not metres, would be
    tracked to nonsense (``wface.tracking.capture.prepare_capture`` aligns and scales a capture)."""
    for frame in targets:
        ok = np.isfinite(frame).all(axis=1)
        if ok.sum() >= 3:
            break
    else:
        return

    def spread(p):
        return float(np.sqrt(((p - p.mean(axis=0)) ** 2).sum(axis=1).mean()))

    data, face = spread(frame[ok]), spread(rest_markers_m[ok])
    if face > 0 and not (1.0 / _SPAN_RATIO <= data / face <= _SPAN_RATIO):
        raise ValueError(
            f"marker data spans {data:.4g} (RMS from its centroid) where the face's markers span {face:.4g} m: "
            "targets_m must be in metres, on the face's scale (wface.tracking.capture.prepare_capture aligns "
            "and scales a capture)"
        )


def checked_marker_data(model, targets_m, marker_names, markers) -> np.ndarray:
    """(F, k, 3) float64 marker data, or ``ValueError`` naming what is wrong with it: its shape, the
    marker count against the embedding ``markers`` (a ``MarkerMap``) and ``marker_names``, no frames,
    a spread far from the face's (``_check_marker_span``)."""
    targets = np.asarray(targets_m, dtype=np.float64)
    if targets.ndim != 3 or targets.shape[2] != 3:
        raise ValueError(f"marker data must have shape (frames, markers, 3), got {targets.shape}")
    if targets.shape[1] != len(markers.embedding.triangle):
        raise ValueError(f"marker data has {targets.shape[1]} markers, the embedding {len(markers.embedding.triangle)}")
    if targets.shape[0] == 0:
        raise ValueError("marker data has no frames")
    if len(marker_names) != targets.shape[1]:
        raise ValueError(f"{len(marker_names)} marker_names for {targets.shape[1]} markers")
    _check_marker_span(targets, markers.positions(model.rest_positions_m))
    return targets
