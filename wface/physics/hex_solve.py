"""Equilibria and implicit time steps of a trilinear-hex mesh, with contact and inertia.

The hex nodes x (n, 3) carry the flesh through the quadrature tets y = T x of
``wface.physics.hexes`` (energy E(T x), forces T^T f_y, stiffness T^T K_y T). Contact acts on the
nodes z = B x of a tet model whose positions are a fixed linear map of the hex nodes (``embedding``
B, (n_z, n) sparse; e.g. the tet split of the same hexes, whose face and cell centres follow the
trilinear field, so its boundary triangles lie on the hexes' bilinear faces): energy E_c(B x),
forces B^T f_c, Gauss-Newton Hessian B^T H_c B (``wface.physics.contact``, lips and bones alike).

A backward Euler step of length h from (x_n, v_n) minimises, over the free nodes (the held ones at
their targets), the incremental potential of ``wface.physics.dynamics`` (scheme "be", ArtiSynth's
ConstrainedBackwardEuler):

    Phi(y) = 1/(2 h^2) |y - x_n - h v_n|_M^2 + E(y, a) + E_c(B y) + 1/(2 h) d^T C d - y^T M g,

with d = y - x_n, Rayleigh damping C = alpha M + beta K_n (the projected stiffness at x_n) and the
lumped mass M: the row sums of the consistent mass, m_a = rho sum_g w_g det J_g N_a(xi_g) (the
Gauss points' masses shared by their shape functions; each of a box's nodes gets an eighth of its
cell), or ArtiSynth's equal shares of each element's mass (``hex_masses``). Then x_{n+1} = y and
v_{n+1} = (y - x_n) / h. The equilibrium (``HexBody.solve``) is the same minimisation without the
inertia, damping and gravity terms.

Newton with the projected tangent (each Gauss point's, Teran et al. 2005) plus the contact's
Gauss-Newton Hessian and the step's constant (1/h^2 + alpha/h) M + (beta/h) K_n, all positive
(semi-)definite, with an Armijo backtracking line search on the potential; converged when the
gradient over the free nodes is at most tol times the scale (the free forces at rest for an
equilibrium, as ``wface.physics.newton``; the gradient at the predictor for a step, as
``wface.physics.dynamics``), floored at 1e-3 (mu10 + mu01) V^(2/3).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

from wface.physics.hexes import HexQuadrature
from wface.physics.newton import decrease_from_slopes
from wface.solvers.linear import DirectFactor

__all__ = ["MASS_LUMPINGS", "HexBody", "HexSolve", "hex_masses"]


MASS_LUMPINGS = ("rows", "equal")


def hex_masses(quad: HexQuadrature, density_kg_m3: float, lumping: str = "rows") -> np.ndarray:
    """(n_nodes,) lumped masses, kg.

    Args:
        lumping: "rows": the row sums of the consistent mass, m_a = rho sum_g w_g det J_g N_a(xi_g);
            "equal": each element's mass shared equally by its distinct nodes (ArtiSynth's
            ``HexElement``/``WedgeElement`` node mass weights, 1/8 and 1/6).
    """
    if lumping not in MASS_LUMPINGS:
        raise ValueError(f"lumping must be one of {MASS_LUMPINGS}, got {lumping!r}")
    if lumping == "equal":
        mass = density_kg_m3 * np.bincount(quad.hex_of_point, weights=quad.gauss_volume_m3, minlength=len(quad.hexes))
        srt = np.sort(quad.hexes, axis=1)
        first = np.ones(srt.shape, bool)
        first[:, 1:] = srt[:, 1:] != srt[:, :-1]  # each distinct node of a hex once
        share = np.where(first, (mass / first.sum(axis=1))[:, None], 0.0)
        return np.bincount(srt.reshape(-1), weights=share.reshape(-1), minlength=quad.n_nodes)
    share = density_kg_m3 * quad.gauss_volume_m3[:, None] * quad.shape_values  # (G, 8)
    nodes = quad.hexes[quad.hex_of_point]  # (G, 8)
    return np.bincount(nodes.reshape(-1), weights=share.reshape(-1), minlength=quad.n_nodes)


@dataclass
class HexSolve:
    """A converged (or capped) minimisation over the hex nodes: an equilibrium or one time step."""

    x_m: np.ndarray  # (n_nodes, 3)
    iterations: int
    residual_rel: float
    converged: bool
    energy_j: float  # flesh + contact energy at x_m
    contact_energy_j: float = 0.0
    max_penetration_m: float = 0.0


class HexBody:
    """A hex mesh's flesh (through ``sim``, a ``Simulator`` of ``quadrature_model(model, quad)``), its
    free nodes, and optionally contact on an embedded tet model and inertia (module docstring).

    Args:
        sim: the simulator of the quadrature tets.
        quad: the ``HexQuadrature``.
        free: (k,) free hex nodes; the others stay where each solve's start puts them.
        contact: a ``wface.physics.contact.Contact`` of the tet model that ``embedding`` places.
        embedding: (n_z, n_nodes) sparse B, the contact model's node positions z = B x; default: the
            identity (the contact model's nodes are the hex nodes).
        density_kg_m3: mass density for the time steps; default: the material's.
        mass_lumping: ``hex_masses``'s "rows" (default) or "equal" (ArtiSynth's).
        dilatation: a ``wface.physics.hex_dilatation.MeanDilatation`` of ``quad``: the bulk term with one
            volume ratio per hex (ArtiSynth's ``ELEMENT``), for a ``sim`` whose material has kappa = 0
            (checked: the bulk term would otherwise count twice); default: the kernels' per-point term.
    """

    def __init__(
        self,
        sim,
        quad: HexQuadrature,
        free,
        *,
        contact=None,
        embedding=None,
        density_kg_m3=None,
        mass_lumping="rows",
        dilatation=None,
    ):
        self.sim, self.quad = sim, quad
        if dilatation is not None:
            if dilatation.quad is not quad:
                raise ValueError("dilatation must be built on the same HexQuadrature as the body")
            if sim.model.material.kappa_pa != 0:
                raise ValueError(
                    f"with a mean dilatation the simulator's material must have kappa_pa = 0 "
                    f"(got {sim.model.material.kappa_pa}): its per-point bulk term would count twice"
                )
        self.dilatation = dilatation
        self.free = np.asarray(free, dtype=np.int64).reshape(-1)
        if self.free.size and (self.free.min() < 0 or self.free.max() >= quad.n_nodes):
            raise ValueError(f"free hex nodes must lie in [0, {quad.n_nodes})")
        self.dofs = (3 * self.free[:, None] + np.arange(3)).reshape(-1)
        self._T_free = quad.dof_map(self.dofs)  # K_UU = T_U^T K_y T_U
        self._T_all = None  # the damping stiffness needs the held columns too (moving bones)
        self.contact = contact
        if contact is not None:
            B = sp.identity(quad.n_nodes, format="csr") if embedding is None else sp.csr_matrix(embedding)
            n_z = contact.model.n_nodes
            if B.shape != (n_z, quad.n_nodes):
                raise ValueError(
                    f"embedding has shape {B.shape}; the contact model has {n_z} nodes and the hexes {quad.n_nodes}"
                )
            self.embedding = B
            self._B_free = sp.kron(B, sp.identity(3), format="csr")[:, self.dofs].tocsr()
            self._all_dofs = SimpleNamespace(node_to_dof=np.arange(n_z), shape=(3 * n_z, 3 * n_z))
        mat = sim.model.material
        rho = mat.density_kg_m3 if density_kg_m3 is None else float(density_kg_m3)
        if not (np.isfinite(rho) and rho > 0):
            raise ValueError(f"density must be finite and > 0 kg/m^3, got {rho}")
        self.masses_kg = hex_masses(quad, rho, mass_lumping)
        self._m_free3 = np.repeat(self.masses_kg[self.free], 3)
        self._floor = 1e-3 * (mat.mu10_pa + mat.mu01_pa) * quad.volume_m3 ** (2.0 / 3.0)

    # ------------------------------------------------------------------ pieces
    def embed(self, x_m: np.ndarray) -> np.ndarray:
        """(n_z, 3) contact-model node positions of hex-node positions ``x_m``."""
        return np.asarray(self.embedding @ x_m)

    def energy_forces(self, x_m: np.ndarray, activations):
        """(flesh + contact energy J, (n, 3) forces N, the contact pairs or None) at ``x_m``."""
        e, fy = self.sim.energy_and_forces(self.quad.virtual_positions(x_m), activations)
        f = self.quad.node_forces(fy)
        if self.dilatation is not None:
            e_vol, f_vol = self.dilatation.energy_and_forces(x_m)
            e, f = e + e_vol, f + f_vol
        pairs = None
        if self.contact is not None:
            pairs = self.contact.evaluate(self.embed(x_m))
            e, f = e + pairs.energy, f + np.asarray(self.embedding.T @ pairs.forces())
        return e, f, pairs

    def stiffness(self, x_m: np.ndarray, activations, pairs=None, *, project: bool = True) -> sp.csr_matrix:
        """(3k, 3k) flesh tangent (projected per Gauss point, or exact) plus the contact's Gauss-Newton
        Hessian over the free dofs."""
        Ky = self.sim.tangent(self.quad.virtual_positions(x_m), activations, project=project).assemble()
        K = self.quad.node_stiffness(Ky, self._T_free)
        if self.dilatation is not None:
            K = K + self.dilatation.hessian(x_m, project=project)[self.dofs][:, self.dofs]
        if pairs is not None:
            K = K + self._B_free.T @ pairs.assemble(self._all_dofs) @ self._B_free
        return K.tocsr()

    def _set_pose(self, x_m: np.ndarray) -> None:
        if self.contact is not None:
            self.contact.set_pose(self.embed(x_m)[self.contact.model.attached_nodes])

    # ------------------------------------------------------------------ the minimisation
    def _minimise(self, x0, activations, *, tol, max_iterations, scale, extra=None) -> HexSolve:
        """Newton on the free nodes from ``x0``; ``extra`` = (x -> (phi, gradient over free dofs (3k,)),
        their constant (3k, 3k) Hessian) adds the step's terms."""
        x = np.array(x0, dtype=np.float64)
        self._set_pose(x)

        def potential(xx):
            e, f, pairs = self.energy_forces(xx, activations)
            g = -f[self.free].reshape(-1)
            phi = e
            if extra is not None:
                p_extra, g_extra = extra[0](xx)
                phi, g = phi + p_extra, g + g_extra
            return phi, g, e, pairs

        phi, g, e, pairs = potential(x)
        if scale is None:
            scale = max(float(np.linalg.norm(g)), self._floor)
        factor, res = None, float("inf")
        for it in range(max_iterations + 1):
            res = float(np.linalg.norm(g)) / scale
            if res <= tol or it == max_iterations:
                break
            H = self.stiffness(x, activations, pairs)
            if extra is not None:
                H = H + extra[1]
            factor = DirectFactor(H.tocsr(), reuse=factor)
            dx = np.zeros_like(x)
            dx[self.free] = factor.solve(-g).reshape(-1, 3)
            step, slope = 1.0, float(g @ dx[self.free].reshape(-1))
            if not slope < 0:
                break
            while True:
                trial = potential(x + step * dx)
                if trial[0] <= phi + 1e-4 * step * slope or step < 1e-6:
                    break
                if step == 1.0:  # the potential's rounding may hide the decrease; the slopes at both ends show it
                    end_slope = float(trial[1] @ dx[self.free].reshape(-1))
                    if decrease_from_slopes(slope, end_slope, abs(phi)) <= 1e-4 * slope:
                        break
                step *= 0.5
            x = x + step * dx
            phi, g, e, pairs = trial
        if factor is not None:
            factor.free()
        out = HexSolve(x, it, res, res <= tol, e)
        if pairs is not None:
            out.contact_energy_j = float(pairs.energy)
            out.max_penetration_m = float(pairs.stats()["max_penetration_m"])
        return out

    def solve(self, activations, x0_m, *, tol: float = 1e-6, max_iterations: int = 60, force_scale=None) -> HexSolve:
        """The equilibrium under ``activations`` from ``x0_m`` (held nodes stay there); the scale defaults
        to the free forces at rest under ``activations``, floored (module docstring)."""
        if force_scale is None:
            _, f, _ = self.energy_forces(self.quad.rest_m, activations)
            force_scale = max(float(np.linalg.norm(f[self.free])), self._floor)
        return self._minimise(x0_m, activations, tol=tol, max_iterations=max_iterations, scale=force_scale)

    def step(
        self,
        x_m: np.ndarray,
        v_m_s: np.ndarray,
        dt_s: float,
        activations,
        *,
        held_m: np.ndarray | None = None,
        alpha_per_s: float = 0.0,
        beta_s: float = 0.0,
        gravity_m_s2=None,
        activations_start=None,
        tol: float = 1e-6,
        max_iterations: int = 25,
        exact_damping: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, HexSolve]:
        """One backward Euler step from (``x_m``, ``v_m_s``) of length ``dt_s`` under ``activations``
        (module docstring). ``held_m`` (n, 3): where the held nodes go at the step's end (default:
        they stay); ``activations_start``: at x_n, for the damping stiffness (default: ``activations``);
        ``exact_damping``: damp with the exact stiffness at x_n, as ArtiSynth does, not the projected one
        (where it is indefinite, a large ``beta_s`` makes the step's Hessian so, and the solve refuses it).

        Returns:
            (x_{n+1}, v_{n+1}, ``HexSolve`` of the step).
        """
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be finite and > 0, got {dt_s}")
        h = float(dt_s)
        x_n = np.asarray(x_m, dtype=np.float64)
        v_n = np.asarray(v_m_s, dtype=np.float64)
        y0 = x_n + h * v_n
        held = np.ones(self.quad.n_nodes, bool)
        held[self.free] = False
        y0[held] = x_n[held] if held_m is None else np.asarray(held_m, dtype=np.float64)[held]
        m3 = self._m_free3
        g_force = None if gravity_m_s2 is None else (m3.reshape(-1, 3) * np.asarray(gravity_m_s2)[None]).reshape(-1)
        kn_free = kn_rows = None
        if beta_s > 0:
            a_n = activations if activations_start is None else activations_start
            Ky = self.sim.tangent(self.quad.virtual_positions(x_n), a_n, project=not exact_damping).assemble()
            if self._T_all is None:
                self._T_all = self.quad.dof_map()
            kn_rows = (self._T_free.T @ Ky @ self._T_all).tocsr()  # (3k, 3n): free rows, all columns
            if self.dilatation is not None:
                kn_rows = (kn_rows + self.dilatation.hessian(x_n, project=not exact_damping)[self.dofs]).tocsr()
            kn_free = kn_rows[:, self.dofs].tocsr()
        yhat = (x_n + h * v_n)[self.free].reshape(-1)
        hess = sp.diags((1.0 / h**2 + alpha_per_s / h) * m3)
        if kn_free is not None:
            hess = hess + (beta_s / h) * kn_free
        hess = hess.tocsr()

        def step_terms(y):
            yu = y[self.free].reshape(-1)
            r = yu - yhat
            du = yu - x_n[self.free].reshape(-1)
            phi = 0.5 / h**2 * float(np.sum(m3 * r * r)) + 0.5 * alpha_per_s / h * float(np.sum(m3 * du * du))
            grad = m3 * r / h**2 + alpha_per_s / h * m3 * du
            if kn_rows is not None:
                kd = kn_rows @ (y - x_n).reshape(-1)  # K_UU d_U + K_UC d_C
                # 1/2 d^T K_n d = 1/2 d_U K_UU d_U + d_U K_UC d_C + (terms without y's free part)
                phi += beta_s / h * float(du @ kd - 0.5 * du @ (kn_free @ du))
                grad = grad + beta_s / h * kd
            if g_force is not None:
                phi -= float(g_force @ yu)
                grad = grad - g_force
            return phi, grad

        r = self._minimise(
            y0, activations, tol=tol, max_iterations=max_iterations, scale=None, extra=(step_terms, hess)
        )
        return r.x_m, (r.x_m - x_n) / h, r
