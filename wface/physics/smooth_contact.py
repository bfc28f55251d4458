"""Self-contact against smooth lip surfaces: a C2 contact energy for Newton's quadratic convergence.

``Contact(surface="smooth")`` measures each contact point q of one lip against the other lip's
smooth signed distance phi (``wface.mesh.smooth_distance``: blended planes of its Loop refinement
y = S x) instead of the faceted one. With the C2 penalty ramp (``smoothing_m``) the energy
E_c = sum_p Psi(gap - phi_p) is then C2 in the positions, so Newton with its exact Hessian

    d2E_c = sum_p Psi''(g_p) grad phi_p grad phi_p^T - Psi'(g_p) hess phi_p

converges quadratically near contact, where the faceted distance's gradient jumps across every
edge bisector (``wface.physics.contact``). ``assemble(pattern, exact=False)`` (the projected tangent)
keeps the positive semi-definite Gauss-Newton part; ``exact=True`` adds the curvature term.

The derivatives live in an extended space, the model's nodes followed by the refined vertices of
every smooth surface, and reach the nodes through the constant map P = [I; S] (``_Extension``):
J = J_ext P, H = P^T H_ext P.

Fallback: phi is defined within about one support radius R of the surface (``SmoothSurface``); a
point deeper inside (a Newton trial that overshoots) blends to the faceted signed distance phi_f,
phi = beta phi_s + (1 - beta) phi_f with beta = s(W / W_ref) (s the C2 smoothstep, W the support
weight, W_ref = ``_BLEND_WEIGHT`` x the median W on the rest surface): contact cannot be lost by going deep.
In the blend band the Hessian is Gauss-Newton only.

Rims: the lip surfaces are open. Near the other surface's rim the blended planes extend it
beyond its boundary, so each pair's energy is tapered, E_p = tau(iota_p) Psi(g_p), with iota the
support-weighted share of refined triangles that do not touch the rim (``SmoothHits.interior``: 1
well inside, 0 beyond the rim) and tau = s((iota - 0.25) / 0.5): contact fades out smoothly over
about one support radius at the rim instead of switching off where the closest faceted point
reaches the boundary (the faceted model's rule, which made the residual jump by 10x whenever a
pressed point crossed it). The taper's own second derivatives (tau' Psi hess iota, tau'' Psi) are
left out of the exact Hessian (pairs at the rim only). A deep point (beta < 1) whose faceted
closest point is on the rim is no contact, as in the faceted model.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

from wface.mesh.signed_distance import SignedSurface
from wface.mesh.smooth_distance import SmoothSurface
from wface.physics.penalty import penalty_profile

__all__ = ["CombinedPairs", "SmoothPairs", "SmoothSelfContact"]

_RIM = (0.25, 0.75)  # iota below the first: no contact; above the second: full contact
_BLEND_WEIGHT = 0.05  # W_ref / median W on the rest surface: below W_ref the faceted distance takes over


def _smoothstep(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C2 smoothstep 6 s^5 - 15 s^4 + 10 s^3 of s clipped to [0, 1], and its derivative."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s * s), 30 * s * s * (1 - s) ** 2


class _Extension:
    """The extended index space (nodes, then each surface's refined vertices) and P = [I; S_1; ...]."""

    def __init__(self, n_nodes: int, surfaces: list[SmoothSurface]):
        self.n = n_nodes
        self.offsets, blocks, start = [], [sp.identity(n_nodes, format="csr")], n_nodes
        for s in surfaces:
            self.offsets.append(start)
            cols = s.nodes[s.S.indices]
            blocks.append(sp.csr_matrix((s.S.data, cols, s.S.indptr), shape=(s.S.shape[0], n_nodes)))
            start += s.S.shape[0]
        self.size = start
        self.P = sp.kron(sp.vstack(blocks).tocsr(), sp.identity(3), format="csr")  # (3 N_ext, 3 n)


class SmoothSelfContact:
    """The smooth self-contact of a ``Contact``: one smooth surface per self-contact direction.

    Args:
        model: the face.
        directions: ``Contact.self_contact`` entries (name, point nodes (S, 2), point weights (S, 2),
            triangles of the other surface).
        levels, radius_factor: the ``SmoothSurface`` refinement and support radii.
    """

    def __init__(self, model, directions, *, levels: int = 2, radius_factor: float = 1.5, through_nodes: bool = False):
        x = model.rest_positions_m
        self.directions = directions
        self.surfaces = [
            SmoothSurface(tri, x, levels=levels, radius_factor=radius_factor, through_nodes=through_nodes)
            for *_, tri in directions
        ]
        self.ext = _Extension(model.n_nodes, self.surfaces)
        # W on the rest surface (at its refined vertices): full smooth weight above _BLEND_WEIGHT x its median
        self.weight_ref = []
        for s in self.surfaces:
            W = s.evaluate(s.refined(x), x).weight
            self.weight_ref.append(_BLEND_WEIGHT * float(np.median(W[W > 0])))

    def evaluate(self, contact, x: np.ndarray, first_source: int) -> SmoothPairs:
        """The active smooth pairs of ``contact`` at x (n, 3); sources numbered from ``first_source``."""
        rows = []
        for k, ((_, pn, pw, tri), surf) in enumerate(zip(self.directions, self.surfaces, strict=True)):
            if len(pn):
                part = self._direction(contact, x, k, pn, pw, tri, surf, first_source + k)
                if part is not None:
                    rows.append(part)
        return SmoothPairs(self, contact, rows)

    def _direction(self, contact, x, k, pn, pw, tri, surf, source):
        q = np.einsum("pk,pkd->pd", pw, x[pn])
        reach = contact.gap_m + contact.self_max_depth_m + surf.max_radius_m
        y = surf.refined(x)
        cand = np.flatnonzero(np.all((q >= y.min(0) - reach) & (q <= y.max(0) + reach), axis=1))
        if not cand.size:
            return None
        hs = surf.evaluate(q[cand], x)
        beta, dbeta = _smoothstep(hs.weight / self.weight_ref[k])
        hf = _faceted(x, tri, q[cand], beta < 1.0)  # only where the smooth distance does not hold alone
        tau, dtau = _smoothstep((hs.interior - _RIM[0]) / (_RIM[1] - _RIM[0]))
        phi_s = np.nan_to_num(hs.phi_m)
        phi = beta * phi_s + (1 - beta) * hf.phi_m
        tau = np.where(beta < 1.0, tau * ~hf.on_boundary, tau)
        active = (tau > 0) & (phi > -contact.self_max_depth_m) & (phi <= contact.gap_m)
        if not active.any():
            return None
        sel = np.flatnonzero(active)
        return {
            "sel": sel,
            "n_cand": len(cand),
            "phi": phi[sel],
            "beta": beta,
            "dbeta": dbeta / self.weight_ref[k],
            "tau": tau,
            "dtau": dtau / (_RIM[1] - _RIM[0]),
            "phi_s": phi_s,
            "smooth": hs,
            "faceted": hf,
            "tri": tri,
            "pn": pn[cand],
            "pw": pw[cand],
            "surface": k,
            "source": source,
        }


def _faceted(x, tri, q, need):
    """``SignedSurface.signed`` of the points ``need`` selects; zeros elsewhere (only ever weighted by 0)."""
    k = len(q)
    hit = SimpleNamespace(
        phi_m=np.zeros(k),
        normal=np.zeros((k, 3)),
        triangle=np.zeros(k, np.int64),
        barycentric=np.zeros((k, 3)),
        on_boundary=np.zeros(k, bool),
    )
    if need.any():
        h = SignedSurface(x, tri, orient=False).signed(q[need])
        for key in ("phi_m", "normal", "triangle", "barycentric", "on_boundary"):
            getattr(hit, key)[need] = getattr(h, key)
    return hit


def _coo_rows(rows, cols, vals, shape):
    if not rows:
        return sp.csr_matrix(shape)
    return sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape).tocsr()


def _scatter(out, p_of, pn, pw, corner_ids, g):
    """Append to ``out`` = (rows, cols, vals) the rows p_of of an (P, 3 N_ext) matrix from per-entry
    gradients g (E, 4, 3): slot 0 to the contact point's nodes (weights pw), slots 1-3 to the refined
    corner ids (extended space)."""
    rows, cols, vals = out
    for kk in range(2):
        rows.append(np.repeat(p_of, 3))
        cols.append((3 * pn[:, kk, None] + np.arange(3)).ravel())
        vals.append((pw[:, kk, None] * g[:, 0]).ravel())
    for a in range(3):
        rows.append(np.repeat(p_of, 3))
        cols.append((3 * corner_ids[:, a, None] + np.arange(3)).ravel())
        vals.append(g[:, a + 1].ravel())


class SmoothPairs:
    """The active smooth self-contact pairs at one configuration, with energy, forces and Hessians.

    Attributes (per pair): ``node`` (first node of the contact point), ``distance_m`` (phi),
    ``penetration_m`` (gap - phi), ``blend`` (beta: 1 smooth, 0 faceted), ``taper`` (tau: 1 inside,
    fading to 0 at the other surface's rim), ``source``, and the penalty's ``pair_energy`` (tau Psi),
    ``force_magnitude`` (tau Psi') and ``normal_stiffness`` (tau Psi'').
    """

    def __init__(self, owner: SmoothSelfContact, contact, parts: list[dict]):
        self.ext = owner.ext
        self.n_nodes = contact.model.n_nodes
        self.names = contact.names
        self.stiffness_n_per_m = contact.stiffness_n_per_m
        self.smoothing_m = contact.smoothing_m
        per = {k: [] for k in ("node", "phi", "beta", "tau", "dtau", "weight", "source")}
        mats = {k: ([], [], []) for k in ("J", "A", "B", "I")}  # grad phi, grad phi_s, grad W, grad iota
        self._blocks = []
        base = 0
        for part in parts:
            base = self._add_part(part, base, per, mats)
        cat = lambda k, dt=float: np.concatenate(per[k]).astype(dt) if per[k] else np.zeros(0, dt)  # noqa: E731
        self.node, self.source = cat("node", np.int64), cat("source", np.int64)
        self.distance_m, self.blend, self.taper = cat("phi"), cat("beta"), cat("tau")
        self._dtau, self._weight = cat("dtau"), cat("weight")
        self.penetration_m = contact.gap_m - self.distance_m
        shape = (len(self.node), 3 * self.ext.size)
        self._J, self._A, self._B, self._I = (_coo_rows(*mats[k], shape) for k in ("J", "A", "B", "I"))
        e, fn, kn = penalty_profile(self.penetration_m, self.stiffness_n_per_m, contact.smoothing_m)
        self._psi, self._dpsi = e, fn
        self.pair_energy, self.force_magnitude, self.normal_stiffness = self.taper * e, self.taper * fn, self.taper * kn
        self._cache: dict = {}

    def _add_part(self, part, base, per, mats) -> int:
        """Append one direction's active pairs (rows base, base + 1, ...); returns the next base."""
        sel = part["sel"]
        P = len(sel)
        local = np.full(part["n_cand"], -1)
        local[sel] = base + np.arange(P)
        hs, hf = part["smooth"], part["faceted"]
        b, db = part["beta"], part["dbeta"]
        off = self.ext.offsets[part["surface"]]
        for key, val in (
            ("node", part["pn"][sel, 0]),
            ("phi", part["phi"]),
            ("beta", b[sel]),
            ("tau", part["tau"][sel]),
            ("dtau", part["dtau"][sel]),
            ("weight", hs.weight[sel]),
            ("source", np.full(P, part["source"])),
        ):
            per[key].append(val)
        ent = np.flatnonzero(local[hs.entry_point] >= 0)
        pt = hs.entry_point[ent]
        p_of, pn, pw, corners = local[pt], part["pn"][pt], part["pw"][pt], off + hs.corners[ent]
        gphi, gw = hs.grad_phi[ent], hs.grad_weight[ent]
        mix = (part["phi_s"][pt] - hf.phi_m[pt]) * db[pt]  # d phi / d W of the blend
        _scatter(mats["J"], p_of, pn, pw, corners, b[pt, None, None] * gphi + mix[:, None, None] * gw)
        _scatter(mats["A"], p_of, pn, pw, corners, gphi)
        _scatter(mats["B"], p_of, pn, pw, corners, gw)
        _scatter(mats["I"], p_of, pn, pw, corners, hs.grad_interior[ent])
        # faceted part (1 - beta): the point (+n) against its closest coarse triangle (-w_j n)
        fb, n_f = 1.0 - b[sel], hf.normal[sel]
        prow = base + np.arange(P)
        rows, cols, vals = mats["J"]
        tri = part["tri"][hf.triangle[sel]]
        for ids, wts in ((part["pn"][sel], part["pw"][sel]), (tri, -hf.barycentric[sel])):
            for kk in range(ids.shape[1]):
                rows.append(np.repeat(prow, 3))
                cols.append((3 * ids[:, kk, None] + np.arange(3)).ravel())
                vals.append(((fb * wts[:, kk])[:, None] * n_f).ravel())
        self._blocks.append((p_of, ent, hs, pn, pw, off))
        return base + P

    # ------------------------------------------------------------------ energy and forces
    @property
    def energy(self) -> float:
        """E_c in joules."""
        return float(np.sum(self.pair_energy))

    def forces(self) -> np.ndarray:
        """f = -dE_c/dx = sum_p tau_p Psi'(g_p) grad phi_p - tau'_p Psi(g_p) grad iota_p, (n, 3) newtons."""
        if not len(self.node):
            return np.zeros((self.n_nodes, 3))
        f_ext = self._J.T @ self.force_magnitude - self._I.T @ (self._dtau * self._psi)
        return (self.ext.P.T @ f_ext).reshape(-1, 3)

    # ------------------------------------------------------------------ Hessians
    def hessian(self, exact: bool) -> sp.csr_matrix:
        """(3n, 3n) d2E_c: Gauss-Newton (``exact=False``, positive semi-definite) or exact."""
        key = "exact" if exact else "gn"
        if key in self._cache:
            return self._cache[key]
        P = self.ext.P
        n3 = 3 * self.n_nodes
        if not len(self.node):
            H = sp.csr_matrix((n3, n3))
        else:
            H_ext = self._J.T @ sp.diags(self.normal_stiffness) @ self._J
            if exact:
                # the taper's cross term -tau' Psi' (grad iota grad phi^T + grad phi grad iota^T)
                cross = self._I.T @ sp.diags(-self._dtau * self._dpsi) @ self._J
                H_ext = H_ext + self._curvature_ext() + cross + cross.T
            H = (P.T @ H_ext @ P).tocsr()
        H.sum_duplicates()
        H.sort_indices()
        self._cache[key] = H
        return H

    def _curvature_ext(self) -> sp.csr_matrix:
        """-sum_p tau Psi' beta hess phi_s in the extended space (``wface.mesh.smooth_distance``)."""
        c = self.force_magnitude * self.blend
        W = self._weight
        cw = np.where(W > 0, c / np.where(W > 0, W, 1.0), 0.0)
        D = sp.diags(cw)
        H = self._A.T @ D @ self._B
        H = H + H.T
        rows, cols, vals = [], [], []
        for p_of, ent, hs, pn, pw, off in self._blocks:
            if not len(ent):
                continue
            blk = hs.hessian_blocks(ent) * (-c[p_of])[:, None, None]  # (E, 12, 12)
            # slot 0 spreads to the contact point's two nodes, slots 1-3 are refined vertices
            ids = np.concatenate([pn, off + hs.corners[ent]], axis=1)  # (E, 5)
            wts = np.concatenate([pw, np.ones((len(ent), 3))], axis=1)
            slot = np.array([0, 0, 1, 2, 3])
            for i in range(5):
                for j in range(5):
                    b = blk[:, 3 * slot[i] : 3 * slot[i] + 3, 3 * slot[j] : 3 * slot[j] + 3]
                    b = b * (wts[:, i] * wts[:, j])[:, None, None]
                    r = 3 * ids[:, i, None, None] + np.arange(3)[None, :, None]
                    cc = 3 * ids[:, j, None, None] + np.arange(3)[None, None, :]
                    r, cc = np.broadcast_arrays(r, cc)
                    rows.append(r.ravel())
                    cols.append(cc.ravel())
                    vals.append(b.ravel())
        N3 = 3 * self.ext.size
        if rows:
            H = H + sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(N3, N3))
        return H.tocsr()

    def matvec(self, v: np.ndarray, *, exact: bool = False) -> np.ndarray:
        v = np.asarray(v, dtype=np.float64).reshape(-1)
        return (self.hessian(exact) @ v).reshape(-1, 3)

    def diagonal(self, *, exact: bool = False) -> np.ndarray:
        return self.hessian(exact).diagonal().reshape(-1, 3)

    def assemble(self, pattern, *, exact: bool = False) -> sp.csr_matrix:
        """The Hessian restricted to the unknowns of a ``BlockPattern``, CSR (3k, 3k)."""
        dof = np.repeat(3 * pattern.node_to_dof, 3) + np.tile(np.arange(3), self.n_nodes)
        keep = np.repeat(pattern.node_to_dof >= 0, 3)
        H = self.hessian(exact).tocoo()
        ok = keep[H.row] & keep[H.col]
        out = sp.coo_matrix((H.data[ok], (dof[H.row[ok]], dof[H.col[ok]])), shape=pattern.shape).tocsr()
        out.sort_indices()
        return out

    def stats(self) -> dict:
        """As ``ContactPairs.stats``: pressing pairs, deepest penetration (m), force (N), per source."""
        pressing = self.penetration_m > 1e-12
        per = {}
        for s, name in enumerate(self.names):
            sel = (self.source == s) & pressing
            if not np.any(self.source == s):
                continue
            per[name] = {
                "active_nodes": int(np.unique(self.node[sel]).size),
                "max_penetration_m": max(float(self.penetration_m[sel].max()), 0.0) if sel.any() else 0.0,
                "force_n": float(self.force_magnitude[sel].sum()),
                "blended_pairs": int(np.count_nonzero(sel & (self.blend < 1.0))),
                "rim_pairs": int(np.count_nonzero(sel & (self.taper < 1.0))),
            }
        return {
            "active_nodes": int(np.unique(self.node[pressing]).size),
            "max_penetration_m": max(float(self.penetration_m.max()), 0.0) if len(self.node) else 0.0,
            "force_n": float(self.force_magnitude.sum()),
            "sources": per,
        }


class CombinedPairs:
    """Rigid-obstacle ``ContactPairs`` plus ``SmoothPairs``: the interface the solvers use (energy,
    forces, matvec, diagonal, assemble, stats). Per-pair arrays (``node``, ``source``,
    ``penetration_m``, ``distance_m``, ``force_magnitude``) hold the rigid pairs first; other
    attributes are the rigid pairs' (e.g. ``normal`` for the obstacle Jacobians of ``wface.tracking.rig``)."""

    def __init__(self, rigid, smooth: SmoothPairs):
        self.rigid, self.smooth = rigid, smooth
        self.names = rigid.names
        for key in ("node", "source", "penetration_m", "distance_m", "force_magnitude"):
            setattr(self, key, np.concatenate([getattr(rigid, key), getattr(smooth, key)]))

    def __getattr__(self, name):
        if name in ("rigid", "smooth"):
            raise AttributeError(name)
        return getattr(self.rigid, name)

    @property
    def energy(self) -> float:
        return self.rigid.energy + self.smooth.energy

    def forces(self) -> np.ndarray:
        return self.rigid.forces() + self.smooth.forces()

    def matvec(self, v: np.ndarray, *, exact: bool = False) -> np.ndarray:
        return self.rigid.matvec(v) + self.smooth.matvec(v, exact=exact)

    def diagonal(self, *, exact: bool = False) -> np.ndarray:
        return self.rigid.diagonal() + self.smooth.diagonal(exact=exact)

    def assemble(self, pattern, *, exact: bool = False) -> sp.csr_matrix:
        H = (self.rigid.assemble(pattern) + self.smooth.assemble(pattern, exact=exact)).tocsr()
        H.sort_indices()
        return H

    def force_on_face(self, source: str | None = None) -> np.ndarray:
        return self.rigid.force_on_face(source)

    def stats(self) -> dict:
        a, b = self.rigid.stats(), self.smooth.stats()
        pressing = self.penetration_m > 1e-12
        return {
            "active_nodes": int(np.unique(self.node[pressing]).size),
            "max_penetration_m": max(a["max_penetration_m"], b["max_penetration_m"]),
            "force_n": a["force_n"] + b["force_n"],
            "sources": {**{k: v for k, v in a["sources"].items() if k not in b["sources"]}, **b["sources"]},
        }
