"""Bring a motion-capture take onto an actuation basis (Choe & Ko 2001, sec. 4.1).

1. Head motion: every frame is mapped rigidly (Umeyama, no scale) so that the stable markers
   (forehead, nose top) match their positions in the take's reference (neutral) frame.
2. Marker layout: the reference frame of one take is aligned to the basis neutral surface by a
   similarity transform iterated with projection onto the skin, started from named landmark
   vertices; each marker keeps its embedding (triangle, barycentric weights, normal offset), and
   its marker shapes d_ij are the barycentric interpolation of the element shapes.
3. Further takes are aligned by a similarity fit of their reference frame to the layout's rest
   marker positions, so all takes share one marker basis (needed by refinement).
Targets are displacements from the take's own reference frame: d^_fj = T(p_fj) - T(p_0j).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from wface.basis.analysis import MarkerBasis
from wface.basis.core import ActuationBasis
from wface.mesh.align import (
    FACE_SCALE_RANGE,
    STABLE_MARKERS,
    MarkerEmbedding,
    Similarity,
    align_to_surface,
    landmark_array,
    remove_head_motion,
    umeyama,
)

__all__ = ["CaptureOnBasis", "MarkerLayout", "stabilise_capture"]


@dataclass
class MarkerLayout:
    """Markers embedded in a basis' neutral surface.

    Attributes:
        marker_names: k names.
        embedding: surface embedding in the basis skin triangles.
        triangles: (t, 3) the skin triangles the embedding indexes.
        rest_m: (k, 3) marker rest positions in the model frame (surface point + normal offset).
        surface_m: (k, 3) embedded surface points on the neutral.
        alignment_rms_m: RMS marker-to-surface distance of the aligned reference frame.
        landmark_residual_m: (k,) distance of each aligned marker to its landmark vertex.
    """

    marker_names: list[str]
    embedding: MarkerEmbedding
    triangles: np.ndarray
    rest_m: np.ndarray
    surface_m: np.ndarray
    alignment_rms_m: float
    landmark_residual_m: np.ndarray

    @classmethod
    def from_frame(
        cls,
        basis: ActuationBasis,
        marker_names: Sequence[str],
        markers_m: np.ndarray,
        *,
        landmarks: Mapping[str, int] | None = None,
        with_scale: bool = True,
    ) -> MarkerLayout:
        """Align one (neutral) frame of markers to the basis skin and embed them.

        Args:
            basis: the actuation basis.
            marker_names: k marker names.
            markers_m: (k, 3) marker positions in the capture frame, metres.
            landmarks: {marker name: basis vertex} for the start transform.
            with_scale: similarity (True) or rigid alignment.
        """
        tris = basis.skin_triangles
        if landmarks:
            unknown = [n for n in landmarks if n not in set(marker_names)]
            if len(unknown) == len(landmarks):
                raise ValueError(
                    f"none of the landmark names ({', '.join(unknown[:8])}) is a marker of the take "
                    f"(e.g. {', '.join(list(marker_names)[:8])})"
                )
            if unknown:
                warnings.warn(
                    f"landmarks that are not markers of the take, not used: {', '.join(unknown)}", stacklevel=2
                )
        lm = landmark_array(marker_names, landmarks) if landmarks else None
        res = align_to_surface(markers_m, basis.neutral_m, tris, landmark_vertices=lm, with_scale=with_scale)
        lo, hi = FACE_SCALE_RANGE
        if with_scale and not lo <= res.transform.scale <= hi:
            raise ValueError(
                f"the take aligns to the basis at scale {res.transform.scale:.3g} (plausible: {lo:g} to {hi:g}): "
                "the alignment failed; give --landmarks {marker name: basis vertex} (at least 3 markers of the take), "
                "and check the take's length units"
            )
        surface = res.embedding.surface_points(basis.neutral_m, tris)
        return cls(list(marker_names), res.embedding, tris, res.aligned_m, surface, res.rms_history_m[-1],
                   res.landmark_residual_m)  # fmt: skip

    def marker_basis(self, basis: ActuationBasis) -> MarkerBasis:
        """Marker shapes d_ij (k, 3, B) by barycentric interpolation of the element shapes."""
        emb = self.embedding
        if np.any(emb.triangle < 0):
            missing = [n for n, t in zip(self.marker_names, emb.triangle, strict=False) if t < 0]
            raise ValueError(f"marker layout has markers without an embedding (missing at rest): {missing}")
        corners = self.triangles[emb.triangle]  # (k, 3)
        shapes = np.einsum("kv,bkvc->kcb", emb.barycentric, basis.shapes_m[:, corners, :])
        return MarkerBasis(shapes, list(self.marker_names), list(basis.names), self.rest_m)


@dataclass
class CaptureOnBasis:
    """A take in the model frame.

    Attributes:
        positions_m: (frames, k, 3) head-stabilised, aligned marker positions.
        displacements_m: (frames, k, 3) displacements from the reference frame (targets d^).
        transform: similarity from the stabilised capture frame to the model frame.
        head_rms_m: (frames,) RMS residual of the stable markers' rigid fit (head-motion removal).
        marker_names: k names (layout order).
        rate_hz: frame rate.
        source: file name.
    """

    positions_m: np.ndarray
    displacements_m: np.ndarray
    transform: Similarity
    head_rms_m: np.ndarray
    marker_names: list[str]
    rate_hz: float
    source: str


def stabilise_capture(
    take,
    layout: MarkerLayout,
    *,
    stable_markers: Sequence[str] = STABLE_MARKERS,
    reference_frame: int = 0,
    with_scale: bool = True,
) -> CaptureOnBasis:
    """Head-stabilise a take and map it to the model frame of a marker layout.

    Args:
        take: a :class:`wface.io.mocap.MocapTake` holding (at least) the layout's markers.
        layout: the marker layout on the basis.
        stable_markers: names of markers rigid with the skull (at least 3 present in the take).
        reference_frame: the neutral frame of this take.
        with_scale: allow a scale in the take-to-layout fit (a different capture session).
    """
    missing = [n for n in layout.marker_names if n not in take.marker_names]
    if missing:
        raise ValueError(f"{take.source or 'take'}: lacks markers of the layout: {missing}")
    sub = take.select(layout.marker_names)
    stable = [i for i, n in enumerate(layout.marker_names) if n in set(stable_markers)]
    if len(stable) < 3:
        raise ValueError(
            f"{take.source or 'take'}: needs >= 3 stable markers for head-motion removal, got {len(stable)}"
        )
    p = sub.positions_m
    steady, tfs = remove_head_motion(p, stable, reference_frame=reference_frame)
    head_rms = np.array(
        [
            np.sqrt(np.nanmean(np.sum((tf.apply(p[f, stable]) - p[reference_frame, stable]) ** 2, axis=1)))
            for f, tf in enumerate(tfs)
        ]
    )
    tf = umeyama(steady[reference_frame], layout.rest_m, with_scale=with_scale)
    aligned = tf.apply(steady)
    disp = aligned - aligned[reference_frame]
    return CaptureOnBasis(aligned, disp, tf, head_rms, list(layout.marker_names), take.rate_hz, take.source)
