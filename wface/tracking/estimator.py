"""Per-frame estimation of controls from markers: Gauss-Newton with progressive penalties and a
golden-section line search (seed 000, sections 5 and 9; DESIGN.md section 5).

Objective: phi(c) = sum_k w_k |m_k(X(c)) - t_k|^2 over the markers present in the frame, with
m_k the embedded marker (barycentric point of its skin triangle plus its rest offset along the
normal) and w_k robust weights. One Gauss-Newton step:
  1. linearise m(c + dc) ~ m(c) + J dc with J = W dX/dc (``FaceRig.jacobian``);
  2. for rho rising geometrically (x1.05) from rho0 phi up to 1e6 phi, solve the small system
     (2 J^T W J + rho H_p + 2 lam I_a) dc = -(2 J^T W r + rho g_p + 2 lam (a - a_prev)),
     stopping at the first rho whose step keeps the penalties phi_p(c + dc) under ``penalty_tol``.
     The activation bounds are enforced exactly inside this small solve (a bounded least squares,
     since the activation penalty is flat at the bound); rigidity and the jaw joint stay penalties;
  3. golden-section search of phi + rho phi_p along dc (tau in [0, 1]), each evaluation a
     quasistatic solve warm-started from the linearised prediction Y + tau dY/dc dc.
Outliers: weights w_k = min(1, delta / |r_k|) (Huber, iteratively reweighted), delta =
``robust_mm``; None turns it off. Temporal regularisation lam (default 0) is switchable.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from wface.controls import activation_penalty, bone_penalty
from wface.rig import FaceRig, RigState

__all__ = ["TrackOptions", "FrameResult", "FrameEstimator", "MarkerMap"]

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass
class TrackOptions:
    """Settings of the per-frame estimation (defaults follow seed 000)."""

    gn_steps_first: int = 4  # Gauss-Newton steps on the first frame of a chunk
    gn_steps: int = 1  # on later frames (warm-started)
    rho0: float = 1e-3  # first penalty weight, relative to phi
    rho_growth: float = 1.05
    rho_max: float = 1e6  # relative to phi
    penalty_tol: float = 1e-6  # acceptable phi_p after a step: violations of ~1e-3 (activation, rigidity, 1 mm at the joint)
    line_search_evals: int = 5  # quasistatic solves in the golden-section search
    robust_mm: float | None = 3.0  # Huber threshold on marker residuals (mm); None: plain least squares
    temporal_weight: float = 0.0  # lam: pull of activations toward the previous frame (m^2 per unit^2)
    min_improvement: float = 1e-4  # stop GN when phi drops by less than this fraction


@dataclass
class FrameResult:
    """Estimated controls of one frame and how they were found."""

    frame: int
    controls: np.ndarray
    state: RigState
    markers_m: np.ndarray  # (k, 3) model markers at the solution
    marker_error_m: np.ndarray  # (k,) distance to the data (NaN where missing)
    gauss_newton_steps: int
    quasistatic_solves: int
    linear_solves: int
    penalty: float
    rho: float
    seconds: float
    timings: dict = field(default_factory=dict)


class MarkerMap:
    """Markers embedded in the skin: positions m(X) and the node set their Jacobian needs."""

    def __init__(self, model, embedding):
        self.model = model
        self.embedding = embedding
        tri = model.skin_triangles[embedding.triangle]
        self.nodes, inverse = np.unique(tri.ravel(), return_inverse=True)
        self._local = inverse.reshape(-1, 3)  # corner -> index into self.nodes
        self._offset = np.nan_to_num(embedding.normal_offset_m)
        self._bary = embedding.barycentric

    def positions(self, x_m: np.ndarray) -> np.ndarray:
        """(k, 3) marker positions on the deformed skin."""
        return self.embedding.marker_positions(x_m, self.model.skin_triangles)

    def jacobian(self, node_jacobian: np.ndarray) -> np.ndarray:
        """(3k, p) marker Jacobian from (len(nodes), 3, p) node Jacobians (offsets held fixed in direction)."""
        Jn = node_jacobian[self._local]  # (k, 3 corners, 3, p)
        return np.einsum("kj,kjdp->kdp", self._bary, Jn).reshape(-1, node_jacobian.shape[-1])


class FrameEstimator:
    """Gauss-Newton estimation of one frame's controls (see module docstring)."""

    def __init__(self, rig: FaceRig, markers: MarkerMap, options: TrackOptions | None = None):
        self.rig = rig
        self.markers = markers
        self.options = options or TrackOptions()
        self.M = rig.n_muscles

    # ------------------------------------------------------------------ objective pieces
    def _penalty(self, c: np.ndarray):
        a, b = self.rig.split(c)
        pa = activation_penalty(a)
        pb = bone_penalty(self.rig.model.jaw_joint, b)
        g = np.concatenate([pa.gradient, pb.gradient])
        H = np.zeros((len(c), len(c)))
        H[: self.M, : self.M] = pa.hessian
        H[self.M :, self.M :] = pb.hessian
        return pa.value + pb.value, g, H

    def _weights(self, residual: np.ndarray) -> np.ndarray:
        delta = self.options.robust_mm
        if delta is None:
            return np.ones(len(residual))
        e = np.linalg.norm(residual, axis=1) * 1e3
        return np.minimum(1.0, delta / np.maximum(e, 1e-12))

    def _phi(self, m: np.ndarray, target: np.ndarray, present: np.ndarray, w: np.ndarray) -> float:
        r = (m - target)[present]
        return float(np.sum(w[present, None] * r**2))

    # ------------------------------------------------------------------ one frame
    def estimate(
        self,
        frame: int,
        target_m: np.ndarray,
        c0: np.ndarray,
        y0: np.ndarray | None = None,
        *,
        steps: int | None = None,
        a_prev: np.ndarray | None = None,
    ) -> FrameResult:
        """Controls for one frame of marker data.

        Args:
            frame: frame number (for the record).
            target_m: (k, 3) marker positions, NaN rows = missing markers.
            c0: starting controls (the previous frame's, or the rest controls).
            y0: warm start of the equilibrium (cranium frame), e.g. the previous frame's.
            steps: Gauss-Newton steps (default from the options: first / later frame).
            a_prev: activations of the previous frame for the temporal term.
        """
        opt = self.options
        t_start = time.perf_counter()
        rig = self.rig
        counters0 = dict(rig.counters)
        target = np.asarray(target_m, dtype=np.float64)
        present = np.isfinite(target).all(axis=1)
        if present.sum() < 3:
            raise ValueError(f"frame {frame}: only {int(present.sum())} markers present; need at least 3")
        steps = opt.gn_steps if steps is None else steps
        timings = {"quasistatic_s": 0.0, "jacobian_s": 0.0, "gauss_newton_system_s": 0.0}

        t = time.perf_counter()
        state = rig.equilibrium(c0, y0)
        timings["quasistatic_s"] += time.perf_counter() - t
        c = state.controls
        m = self.markers.positions(state.x_m)
        w = self._weights(np.where(present[:, None], m - target, 0.0))
        rho = 0.0
        gn_done = 0
        for _ in range(steps):
            phi = self._phi(m, target, present, w)
            t = time.perf_counter()
            Jy = rig.jacobian_y(state)
            Jn = rig.world_jacobian(state, Jy.reshape(rig.model.n_nodes, 3, -1)[self.markers.nodes], self.markers.nodes)
            J = self.markers.jacobian(Jn)  # (3k, p)
            timings["jacobian_s"] += time.perf_counter() - t

            t = time.perf_counter()
            rows = np.repeat(present, 3)
            wr = np.repeat(w, 3)[rows]
            Jp = J[rows]
            r = (m - target).reshape(-1)[rows]
            A = 2.0 * (Jp.T * wr) @ Jp
            g = 2.0 * (Jp.T * wr) @ r
            if opt.temporal_weight > 0 and a_prev is not None:
                A[: self.M, : self.M] += 2.0 * opt.temporal_weight * np.eye(self.M)
                g[: self.M] += 2.0 * opt.temporal_weight * (c[: self.M] - a_prev)
            pen, gp, Hp = self._penalty(c)
            scale = max(phi, 1e-12)
            # The smallest rho on the grid rho0 phi * growth^k (k = 0..K) whose step satisfies the
            # penalties, found by bisection over k (feasibility grows with rho).
            K = int(np.ceil(np.log(opt.rho_max / opt.rho0) / np.log(opt.rho_growth)))
            steps_at: dict[int, np.ndarray] = {}

            def step_at(k: int) -> np.ndarray:
                if k not in steps_at:
                    r_k = opt.rho0 * scale * opt.rho_growth**k
                    steps_at[k] = self._bounded_step(A + r_k * Hp, g + r_k * gp, c)
                return steps_at[k]

            lo_k, hi_k = 0, K
            if self._penalty(c + step_at(0))[0] <= opt.penalty_tol:
                hi_k = 0
            while hi_k - lo_k > 1:
                mid = (lo_k + hi_k) // 2
                if self._penalty(c + step_at(mid))[0] <= opt.penalty_tol:
                    hi_k = mid
                else:
                    lo_k = mid
            rho = opt.rho0 * scale * opt.rho_growth**hi_k
            dc = step_at(hi_k)
            timings["gauss_newton_system_s"] += time.perf_counter() - t

            # Golden-section search on tau in [0, 1] with warm starts from the linear prediction.
            t = time.perf_counter()
            total0 = phi + rho * pen
            cache: dict[float, tuple] = {}

            def evaluate(tau: float):
                if tau not in cache:
                    ct = c + tau * dc
                    y_guess = state.y_m + tau * (Jy @ self._dc_y(dc)).reshape(-1, 3)
                    st = rig.equilibrium(ct, y_guess)
                    mt = self.markers.positions(st.x_m)
                    cache[tau] = (self._phi(mt, target, present, w) + rho * self._penalty(ct)[0], st, mt)
                return cache[tau][0]

            lo, hi = 0.0, 1.0
            x1, x2 = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
            f1, f2 = evaluate(x1), evaluate(x2)
            for _ in range(max(0, opt.line_search_evals - 3)):
                if f1 <= f2:
                    hi, x2, f2 = x2, x1, f1
                    x1 = hi - _GOLDEN * (hi - lo)
                    f1 = evaluate(x1)
                else:
                    lo, x1, f1 = x1, x2, f2
                    x2 = lo + _GOLDEN * (hi - lo)
                    f2 = evaluate(x2)
            evaluate(1.0)  # the full step: the Gauss-Newton point is often the best
            tau_best = min(cache, key=lambda k: cache[k][0])
            timings["quasistatic_s"] += time.perf_counter() - t
            gn_done += 1
            if cache[tau_best][0] >= total0:
                break  # no descent along dc: keep c
            c = c + tau_best * dc
            _, state, m = cache[tau_best]
            w = self._weights(np.where(present[:, None], m - target, 0.0))
            if total0 - cache[tau_best][0] < opt.min_improvement * total0:
                break

        err = np.linalg.norm(m - target, axis=1)
        err[~present] = np.nan
        used = {k: rig.counters[k] - counters0[k] for k in rig.counters}
        return FrameResult(
            frame,
            c,
            state,
            m,
            err,
            gn_done,
            used["quasistatic_solves"],
            used["linear_solves"],
            self._penalty(c)[0],
            rho,
            time.perf_counter() - t_start,
            timings,
        )

    def _bounded_step(self, H: np.ndarray, g: np.ndarray, c: np.ndarray) -> np.ndarray:
        """argmin 1/2 dc^T H dc + g^T dc subject to the linear constraints of the controls.

        Activation bounds 0 <= a <= 1 and the jaw joint psi1..psi6 are linear in c, and their
        quadratic penalties are flat at a bound (no curvature at a = 0 or at psi4 = 0), so a
        linearised penalty model cannot stop a step from crossing them. The small quadratic model
        is therefore minimised under these linear constraints exactly (SLSQP on M + 24 unknowns);
        rigidity stays a penalty (it is not linear).
        """
        from scipy.optimize import minimize

        from wface.controls import _joint_rows

        M = self.M
        p = len(g)
        a = c[:M]
        A, cc, lo, hi = _joint_rows(self.rig.model.jaw_joint)
        jaw = slice(M + 12, M + 24)
        psi0 = A @ c[jaw] + cc
        Ajaw = np.zeros((len(A), p))
        Ajaw[:, jaw] = A
        eq = lo == hi
        cons = [
            {"type": "eq", "fun": lambda d: Ajaw[eq] @ d + psi0[eq], "jac": lambda d: Ajaw[eq]},
            {"type": "ineq", "fun": lambda d: Ajaw[~eq] @ d + psi0[~eq] - lo[~eq], "jac": lambda d: Ajaw[~eq]},
            {"type": "ineq", "fun": lambda d: hi[~eq] - Ajaw[~eq] @ d - psi0[~eq], "jac": lambda d: -Ajaw[~eq]},
        ]
        bounds = [(-ai, 1.0 - ai) for ai in np.clip(a, 0.0, 1.0)] + [(None, None)] * (p - M)
        Hs = 0.5 * (H + H.T)
        x0 = np.zeros(p)
        res = minimize(
            lambda d: 0.5 * d @ Hs @ d + g @ d,
            x0,
            jac=lambda d: Hs @ d + g,
            bounds=bounds,
            constraints=cons,
            method="SLSQP",
            options={"maxiter": 200, "ftol": 1e-14},
        )
        return res.x

    def _dc_y(self, dc: np.ndarray) -> np.ndarray:
        """The part of dc that Y (cranium frame) depends on: activations and jaw parameters."""
        return np.concatenate([dc[: self.M], dc[self.M + 12 :]])
