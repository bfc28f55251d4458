"""The contact penalty: its stiffness, its profile (plain C1 or C2-ramped) and the contact points of a surface.

E(g) per pair of penetration g = gap - phi (m); see ``wface.physics.contact`` for the model.
"""

from __future__ import annotations

import numpy as np

from wface.model import FaceModel

__all__ = [
    "DEFAULT_STIFFNESS_FACTOR",
    "TRACKING_SMOOTHING_M",
    "contact_points",
    "default_contact_stiffness",
    "median_edge_length",
    "penalty_profile",
]

DEFAULT_STIFFNESS_FACTOR = 100.0
# The C2 ramp width d (m) that `wface track` / `demo` use: a frame's linear prediction sees no contact
# stiffness in lips that only touch, and over a wide ramp the overshoot into the other lip costs
# little force, so Newton starts close. 0.5 mm against 0.05 mm: NoseMoCap 0:60 at 5,280 tets (lips,
# teeth) 877 -> 65 factorisations at the same marker RMS (docs/design.md, "Contact").
TRACKING_SMOOTHING_M = 5e-4


def median_edge_length(model: FaceModel) -> float:
    """Median rest tet edge length h in metres."""
    x, t = model.rest_positions_m, model.tets
    edges = np.concatenate([x[t[:, a]] - x[t[:, b]] for a, b in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))])
    return float(np.median(np.linalg.norm(edges, axis=1)))


def default_contact_stiffness(model: FaceModel, factor: float = DEFAULT_STIFFNESS_FACTOR) -> float:
    """k = factor * 6 (mu10 + mu01) * h in N/m, h = median rest tet edge length (module docstring)."""
    h = median_edge_length(model)
    return float(factor * 6.0 * (model.material.mu10_pa + model.material.mu01_pa) * h)


def contact_points(tri_a: np.ndarray, tri_b: np.ndarray, edge_midpoints: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Contact points of surface a against surface b: its nodes and (``edge_midpoints``) the midpoints of
    its edges, as (S, 2) node ids and (S, 2) weights. Points on a node shared with b (where the two
    surfaces are joined, e.g. the mouth corners) are left out: they never separate."""
    tri_a = np.asarray(tri_a, dtype=np.int64).reshape(-1, 3)
    shared = np.zeros(int(max(tri_a.max(initial=0), np.max(tri_b, initial=0))) + 1, dtype=bool)
    shared[np.asarray(tri_b).ravel()] = True
    nodes = np.unique(tri_a)
    nodes = nodes[~shared[nodes]]
    edges = np.unique(np.sort(np.concatenate([tri_a[:, [0, 1]], tri_a[:, [1, 2]], tri_a[:, [2, 0]]]), axis=1), axis=0)
    edges = edges[~shared[edges].any(axis=1)] if edge_midpoints else np.zeros((0, 2), dtype=np.int64)
    pn = np.concatenate([np.repeat(nodes[:, None], 2, axis=1), edges])
    pw = np.concatenate([np.tile([1.0, 0.0], (len(nodes), 1)), np.full((len(edges), 2), 0.5)])
    return pn, pw


def penalty_profile(g: np.ndarray, k: float, smoothing_m: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Penalty energy per pair E(g), its slope E'(g) (the normal force, N) and curvature E''(g) (N/m)
    for penetrations g (m).

    smoothing_m = 0: E = k/2 max(0, g)^2 (C1; E'' jumps from 0 to k at contact).
    smoothing_m = d > 0: the C2 penalty E = k g^3 / (6 d) for 0 < g < d (the stiffness rises linearly
    from 0 at contact to k at g = d), E = k/2 (g - d/2)^2 + k d^2/24 beyond (force k (g - d/2)): no
    force before contact (surfaces that touch at rest stay at rest), about d/2 more penetration.
    """
    g = np.asarray(g, dtype=np.float64)
    if smoothing_m <= 0.0:
        gp = np.maximum(g, 0.0)
        return 0.5 * k * gp**2, k * gp, np.where(g >= 0.0, k, 0.0)
    d = float(smoothing_m)
    s = np.maximum(g, 0.0)
    ramp = s < d
    e = np.where(ramp, k * s**3 / (6.0 * d), 0.5 * k * (s - 0.5 * d) ** 2 + k * d * d / 24.0)
    fn = np.where(ramp, 0.5 * k * s**2 / d, k * (s - 0.5 * d))
    kn = np.where(ramp, k * s / d, k)
    return e, fn, kn
