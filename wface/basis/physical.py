"""A physically derived actuation basis (Choe & Ko 2001 built from the face of Sifakis et al. 2005).

Element i is the skin displacement of the quasistatic FEM face with muscle i alone at activation
``activation`` (divided by it, so x_i = 1 means that activation); the basis linearises the face
about rest. Its element names are the model's muscle names, which the Waters layouts and the FACS
table share, so contractions analysed on one face retarget to another by name.
"""

from __future__ import annotations

import numpy as np
from tqdm.auto import tqdm

from wface.basis.core import ActuationBasis
from wface.physics.simulator import Simulator

__all__ = ["basis_from_face"]


def basis_from_face(
    model, *, muscles=None, activation: float = 1.0, simulator=None, progress: bool = False
) -> ActuationBasis:
    """Basis of a ``FaceModel``'s skin with one element per muscle (all muscles by default)."""

    if not (0.0 < activation <= 1.0):
        raise ValueError(f"activation must be in (0, 1], got {activation}")
    names = list(model.muscle_names) if muscles is None else list(muscles)
    for name in names:
        model.muscle_index(name)  # unknown names raise a KeyError that lists the known ones
    sim = simulator or Simulator(model)
    rest = model.rest_positions_m
    skin_nodes = np.unique(model.skin_triangles)
    local = np.full(model.n_nodes, -1, dtype=np.int64)
    local[skin_nodes] = np.arange(len(skin_nodes))
    shapes = np.empty((len(names), len(skin_nodes), 3))
    for i, name in enumerate(tqdm(names, desc="muscle shapes", disable=not progress, unit="muscle")):
        eq = sim.solve({name: activation})
        if eq.inverted_elements:
            raise RuntimeError(f"muscle {name} at activation {activation} inverts {eq.inverted_elements} tets")
        shapes[i] = (eq.x[skin_nodes] - rest[skin_nodes]) / activation
    return ActuationBasis.from_displacements(
        rest[skin_nodes],
        shapes,
        names,
        triangles=local[model.skin_triangles],
        source=f"wface FEM face ({model.n_tets} tets), each muscle alone at activation {activation}",
    )
