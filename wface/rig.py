"""The face as a function of its controls, X(c), and its Jacobian dX/dc (seed 000, sections 5-8).

c = (a, b): M activations then the 24 bone parameters of ``wface.controls``. The equilibrium is
solved in the cranium frame, Y(a, Mm, tm); world positions are X = Mc Y + tc.

Jacobians at an equilibrium Y* (K = -df/dx, the exact tangent at Y*):
- activations (eq. 5):   K_UU dY_U/da_i = f_i(Y*)_U          (f_i: muscle i at full activation)
- jaw parameters (eq. 6): K_UU dY_U/db_j = -K_UC dX_C/db_j
- cranium parameters:     dX/dMc_rc = e_r Y_c,  dX/dtc = I    (analytic)
and dX/da = Mc dY/da, dX/db_jaw = Mc dY/db_jaw. All M + 12 solved columns share one
factorisation of K_UU (multi right-hand side), or one preconditioner when no direct solver exists.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from wface.controls import IDENTITY_BONES, affine_from_params, attached_positions, attached_positions_jacobian
from wface.model import FaceModel

__all__ = ["FaceRig", "RigState"]


@dataclass
class RigState:
    """An equilibrium of the rig for controls c."""

    controls: np.ndarray  # (M + 24,)
    y_m: np.ndarray  # (n, 3) equilibrium in the cranium frame
    x_m: np.ndarray  # (n, 3) world positions
    newton_iterations: int = 0
    residual_rel: float = 0.0
    converged: bool = True
    inverted_elements: int = 0
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)


class FaceRig:
    """Forward model X(c) and Jacobians of a face model.

    Args:
        model: the face.
        device, precision, solver: passed to ``wface.physics.simulator.Simulator``.
        tol: relative residual of the quasistatic solves.
    """

    def __init__(
        self,
        model: FaceModel,
        *,
        device: str = "cpu",
        precision: str = "float64",
        solver: str = "auto",
        tol: float = 1e-6,
        simulator=None,
    ):
        from wface.physics.simulator import Simulator

        self.model = model
        self.sim = simulator or Simulator(model, device=device, precision=precision, solver=solver)
        self.tol = tol
        self.n_muscles = model.n_muscles
        self.n_controls = model.n_muscles + 24
        self._dxc_djaw = attached_positions_jacobian(model).reshape(-1, 12)  # (3a, 12)
        n = model.n_nodes
        free = model.free_nodes
        fixed = model.attached_nodes
        self._free_dofs = (3 * free[:, None] + np.arange(3)).ravel()
        self._fixed_dofs = (3 * fixed[:, None] + np.arange(3)).ravel()
        self._n = n
        self.counters = {"quasistatic_solves": 0, "linear_solves": 0, "newton_iterations": 0, "cg_iterations": 0}

    # ------------------------------------------------------------------ controls
    def rest_controls(self) -> np.ndarray:
        return np.concatenate([np.zeros(self.n_muscles), IDENTITY_BONES])

    def split(self, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(c, dtype=np.float64)
        if c.shape != (self.n_controls,):
            raise ValueError(f"controls have shape {c.shape}, expected ({self.n_controls},)")
        return c[: self.n_muscles], c[self.n_muscles :]

    # ------------------------------------------------------------------ forward model
    def equilibrium(self, c: np.ndarray, y0: np.ndarray | None = None) -> RigState:
        """Solve the quasistatic equilibrium for controls c, warm-started from y0 (cranium frame)."""
        a, b = self.split(c)
        # Activations slightly outside [0, 1] can occur inside a penalty method: the physics
        # sees them clipped (the penalty keeps them near the box).
        a_phys = np.clip(a, 0.0, 1.0)
        t0 = time.perf_counter()
        eq = self.sim.solve(a_phys, attached_positions(self.model, b, frame="cranium"), y0, tol=self.tol)
        self.counters["quasistatic_solves"] += 1
        self.counters["newton_iterations"] += eq.iterations
        self.counters["cg_iterations"] += getattr(eq, "cg_iterations", 0)
        if not eq.converged:
            warnings.warn(
                f"quasistatic solve stopped at residual {eq.residual_rel:.2e} (tol {self.tol:g})", stacklevel=2
            )
        Mc, tc = affine_from_params(b[:12])
        return RigState(
            np.array(c, dtype=np.float64),
            eq.x,
            eq.x @ Mc.T + tc,
            eq.iterations,
            eq.residual_rel,
            eq.converged,
            eq.inverted_elements,
            time.perf_counter() - t0,
        )

    def predict_y(self, state: RigState, dy_dc: np.ndarray, dc: np.ndarray) -> np.ndarray:
        """Linearised equilibrium Y(c + dc) ~ Y + dY/dc dc in the cranium frame (a warm start)."""
        return state.y_m + (dy_dc @ dc).reshape(-1, 3)

    # ------------------------------------------------------------------ Jacobians
    def jacobian_y(self, state: RigState) -> np.ndarray:
        """dY/d(a, b_jaw) in the cranium frame: (3n, M + 12) for all nodes."""
        from wface.solvers.linear import DirectFactor, NotPositiveDefiniteError, direct_backend

        a, _ = self.split(state.controls)
        a = np.clip(a, 0.0, 1.0)
        y = state.y_m
        U, C = self._free_dofs, self._fixed_dofs
        M = self.n_muscles
        K = self.sim.assemble_stiffness(y, a, project=False).tocsr()
        K_uu = K[U][:, U]
        K_uc = K[U][:, C]
        rhs = np.empty((len(U), M + 12))
        if M:
            f = self.sim.muscle_forces(y).reshape(M, -1)  # (M, 3n)
            rhs[:, :M] = f[:, U].T
        rhs[:, M:] = -(K_uc @ self._dxc_djaw)
        sol = self._solve_many(K_uu, K, y, a, rhs, DirectFactor, NotPositiveDefiniteError, direct_backend)
        self.counters["linear_solves"] += rhs.shape[1]
        J = np.zeros((3 * self._n, M + 12))
        J[U] = sol
        J[C, M:] = self._dxc_djaw
        return J

    def _solve_many(self, K_uu, K, y, a, rhs, DirectFactor, NotPD, direct_backend):
        if direct_backend() is not None:
            try:
                return DirectFactor(K_uu).solve(rhs)
            except NotPD:
                warnings.warn(
                    "exact tangent not positive definite at this equilibrium; Jacobians use the projected tangent",
                    stacklevel=3,
                )
                Kp = self.sim.assemble_stiffness(y, a, project=True).tocsr()
                U = self._free_dofs
                return DirectFactor(Kp[U][:, U]).solve(rhs)
        # No direct backend: preconditioned CG per column, one Jacobi preconditioner for all.
        from scipy.sparse.linalg import cg

        d = K_uu.diagonal()
        prec = 1.0 / np.where(np.abs(d) > 0, d, 1.0)
        from scipy.sparse.linalg import LinearOperator

        P = LinearOperator(K_uu.shape, matvec=lambda v: prec * v)
        out = np.empty_like(rhs)
        for j in range(rhs.shape[1]):
            out[:, j], info = cg(K_uu, rhs[:, j], M=P, rtol=1e-10, maxiter=20 * K_uu.shape[0])
        return out

    def jacobian(self, state: RigState, nodes: np.ndarray | None = None) -> np.ndarray:
        """World dX/dc for the given nodes (default all): (len(nodes), 3, M + 24)."""
        nodes = np.arange(self._n) if nodes is None else np.asarray(nodes, dtype=np.int64)
        Jy = self.jacobian_y(state).reshape(self._n, 3, -1)[nodes]  # (k, 3, M + 12)
        return self.world_jacobian(state, Jy, nodes)

    def world_jacobian(self, state: RigState, jy_nodes: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """Assemble world dX/dc (k, 3, M + 24) from cranium-frame dY/d(a, b_jaw) of k nodes."""
        M = self.n_muscles
        _, b = self.split(state.controls)
        Mc, _ = affine_from_params(b[:12])
        y = state.y_m[nodes]
        k = len(nodes)
        J = np.zeros((k, 3, M + 24))
        moved = np.einsum("rs,ksc->krc", Mc, jy_nodes)
        J[:, :, :M] = moved[:, :, :M]
        J[:, :, M + 12 :] = moved[:, :, M:]
        for r in range(3):
            J[:, r, M + 3 * r : M + 3 * r + 3] = y  # dX_r/dMc_rc = Y_c
            J[:, r, M + 9 + r] = 1.0
        return J
