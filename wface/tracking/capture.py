"""Bringing a real capture onto a face model (Choe & Ko 2001, section 4.1.1; docs/design.md, "Tracking").

The first frame is aligned to the skin by a similarity transform iterated with projection onto
the surface; markers whose names the model also has pull toward the model's marker as landmarks.
The same similarity maps every frame, so the actor's rigid head motion stays in the data and is
carried by the cranium controls. Each marker is embedded in its closest skin triangle with its
offset along the normal (an off-surface marker keeps its offset).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wface.mesh.align import align_to_surface
from wface.tracking.estimator import MarkerMap

__all__ = ["PreparedCapture", "prepare_capture"]


@dataclass
class PreparedCapture:
    targets_m: np.ndarray  # (F, k, 3) capture in the model frame
    markers: MarkerMap
    marker_names: list[str]
    scale: float
    alignment_rms_mm: float
    matched_names: list[str]


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
    al = align_to_surface(
        ref,
        model.rest_positions_m,
        model.skin_triangles,
        landmark_points_m=landmarks if matched else None,
        with_scale=True,
        landmark_weight=1.0 if matched else 0.0,
        trim_fraction=0.1,
    )
    targets = al.transform.apply(pos)
    return PreparedCapture(
        targets,
        MarkerMap(model, al.embedding),
        list(marker_names),
        float(al.transform.scale),
        float(al.rms_history_m[-1] * 1e3),
        matched,
    )
