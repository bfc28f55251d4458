"""A physically derived actuation basis (Choe & Ko 2001 built from the face of Sifakis et al. 2005).

Element i is the skin displacement of the quasistatic FEM face with muscle i alone at activation
``activation`` (divided by it, so x_i = 1 means that activation); the basis linearises the face
about rest. Its element names are the model's muscle names, which the Waters layouts and the FACS
table share, so contractions analysed on one face retarget to another by name. A pressure actuator
gives two elements, its puff and its suction (``<name>_suction``), since a basis weight is >= 0.
"""

from __future__ import annotations

import numpy as np

from wface.basis.core import ActuationBasis
from wface.takes.shapes import muscle_shapes, shape_names

__all__ = ["basis_from_face"]


def basis_from_face(
    model, *, muscles=None, activation: float = 1.0, simulator=None, progress: bool = False
) -> ActuationBasis:
    """Basis of a ``FaceModel``'s skin with one element per muscle (all muscles by default; a pressure
    actuator's two shapes)."""

    names = shape_names(model) if muscles is None else list(muscles)
    skin_nodes, shapes = muscle_shapes(  # the physics lives in wface.takes.shapes (also the take's USD rig)
        model, muscles=names, activation=activation, simulator=simulator, progress=progress
    )
    rest = model.rest_positions_m
    local = np.full(model.n_nodes, -1, dtype=np.int64)
    local[skin_nodes] = np.arange(len(skin_nodes))
    return ActuationBasis.from_displacements(
        rest[skin_nodes],
        shapes,
        names,
        triangles=local[model.skin_triangles],
        source=f"wface FEM face ({model.n_tets} tets), each muscle alone at activation {activation}",
        landmarks=_marker_landmarks(model, skin_nodes),
    )


def _marker_landmarks(model, skin_nodes: np.ndarray) -> dict[str, int] | None:
    """{marker name: nearest skin vertex} for the model's markers, so that a capture with those names
    aligns to the basis without a landmark file (as the model's own tracking does)."""
    names = list(getattr(model, "marker_names", None) or [])
    if not names:
        return None
    rest = model.rest_positions_m[skin_nodes]
    d = np.linalg.norm(np.asarray(model.marker_positions_m)[:, None, :] - rest[None, :, :], axis=2)
    return dict(zip(names, np.argmin(d, axis=1).tolist(), strict=True))
