"""A Waters rig: a layout compiled on one mesh, deforming it from muscle contractions and a jaw angle.

Every muscle is evaluated on the rest mesh (Waters 1987 displaces the neutral face), so the
muscle displacement is linear in the contractions c:  d(v) = sum_i c_i B_i(v), with
B_i(v) = K_i (A_i R_i)^e_i u_i(v) (see ``wface.waters.muscles``) times a region factor. The rig
stores the B_i as one sparse (3n, M) matrix built once (vectorised, only the vertices within each
muscle's reach), so a frame is a sparse mat-vec plus the per-vertex limit and the jaw.

Combination where muscles overlap (Waters 1987, "confluence of two muscle vectors"): each vertex
gets a limit L_v = min(max_displacement, overlap_factor * max_i |B_i(v)|) from its attractors, and
the summed displacement is scaled back to length L_v where it exceeds it. One muscle alone at
c <= 1 is never clamped (overlap_factor >= 1).

Region factors: a muscle with ``region="upper"`` is multiplied by (1 - w_jaw), ``"lower"`` by
w_jaw (w_jaw from the layout's jaw region), so lip muscles move only their own lip. Without a jaw
region (and no jaw weights given) there is no upper/lower split and regions are ignored.

Jaw (AU26): x' = x + w_jaw (Rot(theta) (x - pivot) + pivot - x), applied after the muscles.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from wface.waters.layout import MuscleLayout
from wface.waters.muscles import (
    LinearMuscle,
    linear_muscle_displacement,
    sphincter_muscle_displacement,
)

__all__ = ["WatersRig", "direct_displacement"]


def _check_rest(rest_positions_m) -> np.ndarray:
    x = np.asarray(rest_positions_m, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] == 0:
        raise ValueError(f"rest positions must have shape (n, 3) with n > 0, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("rest positions contain NaN or inf")
    return x


def _muscle_field(points: np.ndarray, muscle) -> np.ndarray:
    if isinstance(muscle, LinearMuscle):
        return linear_muscle_displacement(points, muscle, 1.0)
    return sphincter_muscle_displacement(points, muscle, 1.0)


class WatersRig:
    """A layout compiled on a mesh.

    Args:
        layout: the muscle layout (metres).
        rest_positions_m: (n, 3) rest vertex positions of the mesh, metres.
        muscle_mask: optional (n,) bool: vertices the muscles may move. Default: the layout's
            ``mesh.muscle_vertices`` when the vertex count matches, else every vertex.
        jaw_weights: optional (n,) weights in [0, 1] of jaw following, overriding the layout's jaw
            planes (e.g. from a volumetric model's bone attachments); the pivot and axis still come
            from the layout.
        triangles: optional (t, 3) triangles of the mesh: the planes' weights then respect its mouth
            (``JawRegion.weights_on_mesh``); without them they follow position alone.
    """

    def __init__(
        self,
        layout: MuscleLayout,
        rest_positions_m: np.ndarray,
        *,
        muscle_mask: np.ndarray | None = None,
        jaw_weights: np.ndarray | None = None,
        triangles: np.ndarray | None = None,
    ):

        self.layout = layout
        self.rest_positions_m = _check_rest(rest_positions_m)
        n = len(self.rest_positions_m)
        if muscle_mask is None:
            muscle_mask = layout.muscle_vertex_mask(n)
            if muscle_mask is None and layout.mesh_vertex_count not in (None, n):
                warnings.warn(
                    f"layout {layout.name!r} was made for a mesh of {layout.mesh_vertex_count} vertices; this one has "
                    f"{n}: its muscle vertex ranges are ignored (fit the layout to this face for best results)",
                    stacklevel=2,
                )
        if muscle_mask is not None:
            muscle_mask = np.asarray(muscle_mask, dtype=bool).reshape(-1)
            if muscle_mask.shape != (n,):
                raise ValueError(f"muscle_mask has shape {muscle_mask.shape}, expected ({n},)")
        self.muscle_mask = muscle_mask
        self.has_jaw = jaw_weights is not None or layout.jaw is not None  # else regions do not apply
        if jaw_weights is not None:
            jaw_weights = np.asarray(jaw_weights, dtype=np.float64).reshape(-1)
            if jaw_weights.shape != (n,) or not np.all(np.isfinite(jaw_weights)):
                raise ValueError(f"jaw_weights must be ({n},) finite values, got shape {jaw_weights.shape}")
            if np.any((jaw_weights < 0) | (jaw_weights > 1)):
                raise ValueError("jaw_weights must lie in [0, 1]")
            self.jaw_weights = jaw_weights
        elif layout.jaw is None:
            self.jaw_weights = np.zeros(n)
        elif triangles is not None:
            self.jaw_weights = layout.jaw.weights_on_mesh(self.rest_positions_m, triangles)
        else:
            self.jaw_weights = layout.jaw.weights(self.rest_positions_m)
        tree = cKDTree(self.rest_positions_m)
        rows, cols, vals = [], [], []
        strongest = np.zeros(n)
        for j, m in enumerate(layout.muscles):
            centre = m.bone_m if isinstance(m, LinearMuscle) else m.centre_m
            idx = np.asarray(tree.query_ball_point(centre, m.reach_m * (1 + 1e-9)), dtype=np.int64)
            if muscle_mask is not None and idx.size:
                idx = idx[muscle_mask[idx]]
            if idx.size == 0:
                continue
            idx.sort()
            b = _muscle_field(self.rest_positions_m[idx], m)
            if m.region == "upper" and self.has_jaw:
                b *= (1.0 - self.jaw_weights[idx])[:, None]
            elif m.region == "lower" and self.has_jaw:
                b *= self.jaw_weights[idx][:, None]
            size = np.linalg.norm(b, axis=1)
            keep = size > 0
            idx, b = idx[keep], b[keep]
            strongest[idx] = np.maximum(strongest[idx], size[keep])
            rows.append((3 * idx[:, None] + np.arange(3)).ravel())
            cols.append(np.full(3 * len(idx), j))
            vals.append(b.ravel())
        cat = (lambda a, dt: np.concatenate(a).astype(dt)) if rows else (lambda a, dt: np.zeros(0, dt))
        self.basis = sparse.csr_matrix(
            (cat(vals, np.float64), (cat(rows, np.int64), cat(cols, np.int64))), shape=(3 * n, len(layout.muscles))
        )
        if layout.muscles and not rows:
            lo, hi = self.rest_positions_m.min(axis=0), self.rest_positions_m.max(axis=0)
            raise ValueError(
                f"no muscle of layout {layout.name!r} reaches a vertex of this mesh (it spans "
                f"{np.round(hi - lo, 4).tolist()} in the units given as metres): check the mesh's units "
                "(rest_positions_m in metres) or fit the layout to the mesh (wface.waters.fit)"
            )
        self._jaw_rows = np.flatnonzero(self.jaw_weights > 0)
        self._jaw_w = self.jaw_weights[self._jaw_rows]
        self.vertex_limit_m = np.minimum(layout.max_displacement_m, layout.overlap_factor * strongest)
        self.influenced = np.flatnonzero(strongest > 0)
        rows3 = (3 * self.influenced[:, None] + np.arange(3)).ravel()
        self._basis_rows = self.basis[rows3].tocsr()  # the influenced rows only: a frame touches nothing else

    # --------------------------------------------------------------------------------- inputs
    @property
    def muscle_names(self) -> list[str]:
        return self.layout.muscle_names

    def contraction_vector(self, contractions: Mapping[str, float] | np.ndarray | None) -> np.ndarray:
        """(M,) contractions from ``{muscle name: value}`` or an array; values in [0, 1]."""
        m = len(self.layout.muscles)
        if contractions is None:
            return np.zeros(m)
        if isinstance(contractions, Mapping):
            c = np.zeros(m)
            index = {name: i for i, name in enumerate(self.muscle_names)}
            for name, value in contractions.items():
                if name not in index:
                    known = ", ".join(self.muscle_names)
                    raise KeyError(f"unknown muscle {name!r} for layout {self.layout.name!r}; it has: {known}")
                c[index[name]] = float(value)
        else:
            c = np.asarray(contractions, dtype=np.float64).reshape(-1)
            if c.shape != (m,):
                raise ValueError(f"contraction vector has shape {c.shape}, expected ({m},)")
        if not np.all(np.isfinite(c)):
            raise ValueError("contractions contain NaN or inf")
        if np.any((c < 0) | (c > 1)):
            bad = [self.muscle_names[i] for i in np.flatnonzero((c < 0) | (c > 1))]
            raise ValueError(f"contractions must lie in [0, 1]; out of range: {', '.join(bad)}")
        return c

    # ------------------------------------------------------------------------------- deformation
    def _influenced_displacement(self, c: np.ndarray, limit: bool) -> np.ndarray:
        """(k, 3) displacement of the k influenced vertices (the only ones a muscle moves)."""
        d = (self._basis_rows @ c).reshape(-1, 3)
        if limit and len(d):
            size = np.sqrt(np.einsum("ij,ij->i", d, d))
            cap = self.vertex_limit_m[self.influenced]
            over = size > cap
            if np.any(over):
                d[over] *= (cap[over] / size[over])[:, None]
        return d

    def vertices_at_cap(self, contractions) -> np.ndarray:
        """Ids of the vertices whose muscle displacement the layout's cap (``max_displacement_m``) cut:
        their displacement is the cap, not what the muscles asked for (the overlap limit, lower near
        a single muscle's edge, is not counted)."""
        c = self.contraction_vector(contractions)
        if not c.any():
            return np.zeros(0, dtype=np.int64)
        d = self._influenced_displacement(c, limit=False)
        size = np.sqrt(np.einsum("ij,ij->i", d, d))
        return self.influenced[size > self.layout.max_displacement_m]

    def muscle_displacement(self, contractions, *, limit: bool = True) -> np.ndarray:
        """(n, 3) combined muscle displacement in metres (limited per vertex unless ``limit=False``)."""
        d = np.zeros_like(self.rest_positions_m)
        d[self.influenced] = self._influenced_displacement(self.contraction_vector(contractions), limit)
        return d

    def _jaw_matrix(self, jaw_opening_deg: float) -> np.ndarray | None:
        angle = float(jaw_opening_deg)
        if not np.isfinite(angle):
            raise ValueError(f"jaw angle must be finite, got {jaw_opening_deg!r}")
        if angle == 0.0:
            return None
        jaw = self.layout.jaw
        if jaw is None:
            raise ValueError(f"layout {self.layout.name!r} has no jaw region: it cannot open the jaw (AU26/AU27)")
        if not (-10.0 <= angle <= jaw.max_open_deg):
            raise ValueError(f"jaw angle {angle} deg is outside [-10, {jaw.max_open_deg}] (the layout's max_open_deg)")
        return jaw.rotation(angle) - np.eye(3)

    def jaw_displacement(self, positions_m: np.ndarray, jaw_opening_deg: float) -> np.ndarray:
        """(n, 3) displacement that opens the jaw by ``jaw_opening_deg`` (weighted rotation about the pivot)."""
        out = np.zeros_like(positions_m)
        m = self._jaw_matrix(jaw_opening_deg)
        if m is not None:
            rows = self._jaw_rows
            out[rows] = self._jaw_w[:, None] * ((positions_m[rows] - self.layout.jaw.pivot_m) @ m.T)
        return out

    def deform(self, contractions=None, *, jaw_opening_deg: float = 0.0, limit: bool = True) -> np.ndarray:
        """Deformed vertex positions (n, 3) in metres: rest + muscles, then the jaw rotation."""
        c = self.contraction_vector(contractions)
        m = self._jaw_matrix(jaw_opening_deg)
        x = self.rest_positions_m.copy()
        if c.any():
            x[self.influenced] += self._influenced_displacement(c, limit)
        if m is not None:
            rows = self._jaw_rows
            x[rows] += self._jaw_w[:, None] * ((x[rows] - self.layout.jaw.pivot_m) @ m.T)
        return x


def direct_displacement(layout: MuscleLayout, points_m: np.ndarray, contractions: Mapping[str, float]) -> np.ndarray:
    """Unlimited muscle displacement summed muscle by muscle straight from the formulas (no rig, no masks,
    no region factors): the reference the compiled rig is checked against. (n, 3) metres."""
    p = _check_rest(points_m)
    d = np.zeros_like(p)
    for name, c in contractions.items():
        m = layout.muscle(name)
        d += (
            linear_muscle_displacement(p, m, c)
            if isinstance(m, LinearMuscle)
            else sphincter_muscle_displacement(p, m, c)
        )
    return d
