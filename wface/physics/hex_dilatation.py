"""One volume change per hex: the mean-dilatation bulk term of ArtiSynth's hex elements.

ArtiSynth's soft incompressibility ``ELEMENT`` (``FemModel3d.computePressuresAndRinv``; the default
for its linear elements, which have one pressure value each) takes one pressure per element from
the element's volume ratio J_e = V_e(x) / V0_e, with V_e(x) = sum_g w_g det F_g det J0_g the
element's deformed volume by the same Gauss rule, instead of one at each Gauss point (``FULL``, and
wface's flesh law: kappa/2 (ln J)^2 at every point). The bulk energy of the mesh is

    E_vol(x) = sum_e V0_e U(V_e(x) / V0_e),    U(J) = kappa/2 (J - 1)^2   ("quadratic", ArtiSynth's
                                               default ``BulkPotential``)  or kappa/2 (ln J)^2 ("log"),

so the pressure p_e = U'(J_e) is constant over the hex (the mean-dilatation or B-bar element, Hughes
1980; Simo, Taylor and Pister 1985). Its gradient is U'(J_e) dV_e/dx and its Hessian

    U''(J_e) / V0_e  (dV_e/dx)(dV_e/dx)^T  +  U'(J_e) d2V_e/dx2,

with dV_e/dx_a = sum_g w_g cof(F_g) dN_a/dX (g) and the second derivative of each det F_g
d2 det F / dx_ai dx_bj = eps_ijk (F (u_a x u_b))_k, u = dN/dX at the point. ``hessian`` projects
each hex's 24 x 24 block onto its non-negative eigenvalues (Teran et al. 2005), as wface projects
each Gauss point's tangent. Used with the flesh kernels' own bulk term off (kappa = 0 in the
quadrature model's material) by ``wface.physics.hex_solve.HexBody`` (docs/design.md, "Hexes beside
tets").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from wface.model import BULK_POTENTIALS
from wface.physics.hexes import HexQuadrature

__all__ = ["MeanDilatation"]


def _cofactor(F: np.ndarray) -> np.ndarray:
    """cof(F) = det(F) F^-T of (..., 3, 3), by cross products (defined for singular F)."""
    c = np.empty_like(F)
    c[..., :, 0] = np.cross(F[..., :, 1], F[..., :, 2])
    c[..., :, 1] = np.cross(F[..., :, 2], F[..., :, 0])
    c[..., :, 2] = np.cross(F[..., :, 0], F[..., :, 1])
    return c


class MeanDilatation:
    """The bulk energy of a hex mesh with one volume ratio per hex (module docstring).

    Args:
        quad: the hexes (``wface.physics.hexes.hex_quadrature``).
        bulk_modulus_pa: kappa, Pa (>= 0).
        potential: "quadratic" (ArtiSynth's default) or "log" (wface's flesh law's).
    """

    def __init__(self, quad: HexQuadrature, bulk_modulus_pa: float, potential: str = "quadratic"):
        if potential not in BULK_POTENTIALS:
            raise ValueError(f"potential must be one of {BULK_POTENTIALS}, got {potential!r}")
        kappa = float(bulk_modulus_pa)
        if not (np.isfinite(kappa) and kappa >= 0):
            raise ValueError(f"bulk_modulus_pa must be finite and >= 0, got {bulk_modulus_pa!r}")
        self.quad, self.kappa_pa, self.potential = quad, kappa, potential
        self._dNdX = quad.shape_gradients_per_m.reshape(-1, 8, 8, 3)  # (m, g, 8 nodes, 3)
        self._w = quad.gauss_volume_m3.reshape(-1, 8)  # (m, g) w_g det J0_g
        self.rest_volume_m3 = self._w.sum(axis=1)  # (m,)
        u = self._dNdX  # w_g (u_a x u_b) of each point and node pair, for the Hessian of det F
        self._w_uxv = self._w[:, :, None, None, None] * np.cross(u[:, :, :, None, :], u[:, :, None, :, :])
        dof = 3 * quad.hexes[:, :, None] + np.arange(3)  # (m, 8, 3)
        self._dof = dof.reshape(-1, 24)
        self._rows = np.repeat(self._dof, 24, axis=1).reshape(-1)
        self._cols = np.tile(self._dof, (1, 24)).reshape(-1)

    def _gradients(self, x_m: np.ndarray):
        """(F (m, g, 3, 3), V (m,), dV/dx (m, 8, 3)) at hex-node positions ``x_m``."""
        X = np.asarray(x_m, dtype=np.float64)[self.quad.hexes]  # (m, 8, 3)
        F = np.einsum("mad,mgae->mgde", X, self._dNdX)
        cof = _cofactor(F)
        volume = np.einsum("mg,mg->m", self._w, np.linalg.det(F))
        dV = np.einsum("mg,mgde,mgae->mad", self._w, cof, self._dNdX)  # (cof F) dN/dX summed over points
        return F, volume, dV

    def _u(self, J: np.ndarray):
        """(U, U', U'') of volume ratios ``J`` (inf energy where the log potential meets J <= 0)."""
        k = self.kappa_pa
        if self.potential == "quadratic":
            return 0.5 * k * (J - 1.0) ** 2, k * (J - 1.0), np.full_like(J, k)
        with np.errstate(divide="ignore", invalid="ignore"):
            lnJ = np.where(J > 0, np.log(np.where(J > 0, J, 1.0)), np.nan)
            U = np.where(J > 0, 0.5 * k * lnJ**2, np.inf)
            return U, np.nan_to_num(k * lnJ / J), np.nan_to_num(k * (1.0 - lnJ) / J**2)

    def volume_ratios(self, x_m: np.ndarray) -> np.ndarray:
        """(m,) J_e = V_e(x) / V0_e."""
        return self._gradients(x_m)[1] / self.rest_volume_m3

    def energy_and_forces(self, x_m: np.ndarray) -> tuple[float, np.ndarray]:
        """(E_vol J, (n_nodes, 3) forces -dE_vol/dx N)."""
        _, volume, dV = self._gradients(x_m)
        U, dU, _ = self._u(volume / self.rest_volume_m3)
        f = np.zeros((self.quad.n_nodes, 3))
        np.add.at(f, self.quad.hexes, -dU[:, None, None] * dV)
        return float(np.sum(self.rest_volume_m3 * U)), f

    def hessian(self, x_m: np.ndarray, *, project: bool = True) -> sp.csr_matrix:
        """(3 n, 3 n) Hessian of E_vol, each hex's block projected to PSD (``project``) or exact."""
        F, volume, dV = self._gradients(x_m)
        _, dU, d2U = self._u(volume / self.rest_volume_m3)
        g = dV.reshape(-1, 24)
        H = (d2U / self.rest_volume_m3)[:, None, None] * g[:, :, None] * g[:, None, :]
        c = np.einsum("mgkn,mgabn->mabk", F, self._w_uxv, optimize=True)  # sum_g w_g F_g (u_a x u_b)
        skew = np.zeros(c.shape[:3] + (3, 3))  # eps_ijk c_k
        skew[..., 0, 1], skew[..., 0, 2], skew[..., 1, 2] = c[..., 2], -c[..., 1], c[..., 0]
        skew[..., 1, 0], skew[..., 2, 0], skew[..., 2, 1] = -c[..., 2], c[..., 1], -c[..., 0]
        H += dU[:, None, None] * skew.transpose(0, 1, 3, 2, 4).reshape(-1, 24, 24)
        if project:
            lam, Q = np.linalg.eigh(H)
            H = (Q * np.maximum(lam, 0.0)[:, None, :]) @ Q.transpose(0, 2, 1)
        n3 = 3 * self.quad.n_nodes
        K = sp.csr_matrix((H.reshape(-1), (self._rows, self._cols)), shape=(n3, n3))
        K.sum_duplicates()
        return K
