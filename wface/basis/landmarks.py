"""Named marker <-> model vertex landmarks (the AnimFace markers on the ICT-FaceKit neutral).

``wface/data/ict_animface_landmarks.json`` maps each of the 41 AnimFace marker names to one ICT
vertex. It was derived geometrically by :func:`derive_landmarks` from the first frame of
``JawMoCap.c3d``: a similarity fit to 18 semantic seeds (dlib-68 landmark vertices of the ICT
face: eye corners, brows, nose, lip midpoints and corners), then the similarity fit iterated with
projection onto the ICT face region (polygons of vertices 0-9408; Choe & Ko 2001, sec. 4.1.1),
then each marker takes the nearest vertex of its projection's triangle. The actor's markers sit
around the features, not on them (mouth-corner markers ~73 mm apart against ~51 mm between ICT
mouth corners), so the projection, not the seed, fixes each landmark.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from importlib import resources

import numpy as np

from wface.mesh.align import align_to_surface, landmark_array

__all__ = ["ANIMFACE_DLIB_SEEDS", "derive_landmarks", "load_ict_animface_landmarks"]

#: AnimFace marker -> index into the dlib-68 landmark list of ICT's vertex_indices.json
#: (``idx_to_landmark_verts``); used only as the starting correspondence.
ANIMFACE_DLIB_SEEDS: dict[str, int] = {
    "Leye_Inside": 42, "Leye_Outside": 45, "Reye_Inside": 39, "Reye_Outside": 36,
    "Mouth_Lend": 54, "Mouth_Rend": 48, "NoseHead": 30, "Mouth_Up": 51, "Mouth_Down": 57,
    "Leyebrow_Inside": 22, "Leyebrow_M": 24, "Leyebrow_Outside": 26,
    "Reyebrow_Inside": 21, "Reyebrow_M": 19, "Reyebrow_Outside": 17,
    "NoseHead_L": 35, "NoseHead_R": 31, "NoseTop": 28,
}  # fmt: skip


def load_ict_animface_landmarks() -> dict[str, int]:
    """{AnimFace marker name: ICT-FaceKit vertex index} for the 41 AnimFace markers."""
    text = resources.files("wface").joinpath("data", "ict_animface_landmarks.json").read_text()
    return {str(k): int(v) for k, v in json.loads(text).items()}


def derive_landmarks(
    marker_names: Sequence[str],
    markers_m: np.ndarray,
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    seed_vertices: Mapping[str, int],
) -> tuple[dict[str, int], np.ndarray]:
    """Landmark vertex per marker by seeded similarity alignment and projection.

    Args:
        marker_names: k marker names.
        markers_m: (k, 3) one (neutral) capture frame, metres.
        vertices_m: (n, 3) model vertices, metres.
        triangles: (t, 3) skin triangles to project onto.
        seed_vertices: {marker name: vertex} starting correspondences (at least 3).

    Returns:
        ({name: vertex}, (k,) marker-to-surface distance in metres after alignment).
    """

    lm = landmark_array(marker_names, seed_vertices)
    res = align_to_surface(markers_m, vertices_m, triangles, landmark_vertices=lm)
    tri = np.asarray(triangles)[res.embedding.triangle]
    nearest = tri[np.arange(len(tri)), np.argmax(res.embedding.barycentric, axis=1)]
    return {name: int(v) for name, v in zip(marker_names, nearest, strict=True)}, res.distance_m
