"""Per-frame estimation of controls from markers: Gauss-Newton with progressive penalties and a
golden-section line search (Sifakis et al. 2005, sections 5 and 9; docs/design.md, "Tracking").

Objective: phi(c) = sum_k w_k |m_k(X(c)) - t_k|^2 over the markers present in the frame, with
m_k the embedded marker (barycentric point of its skin triangle plus its rest offset along the
normal and in the triangle's tangent frame) and w_k robust weights, plus two optional regularisers,
both off by default: temporal smoothness lam |a - a_prev|^2 and a prior mu |a|^2 toward the rest face.
One Gauss-Newton step:
  1. linearise m(c + dc) ~ m(c) + J dc with J = W dX/dc (``FaceRig.jacobian``);
  2. for rho rising geometrically (x1.05 grid, searched by bisection) from rho0 phi up to 1e6 phi,
     solve the small system (2 J^T W J + rho H_p + 2 lam I_a) dc = -(2 J^T W r + rho g_p + 2 lam (a - a_prev)),
     and take the first rho whose bone step is rigid to first order (|sym(M^T dM)| <= 0.05 |dM|).
     The activation bounds and the jaw-joint equalities are kept exactly inside this small solve
     (bounded least squares in the null space of the equalities): their quadratic penalties are
     flat at the bound, so a linearised penalty model cannot stop a step from crossing it.
     Every trial point is retracted onto valid controls (``retract``: rotations by polar
     decomposition, the jaw onto its joint's 3 degrees of freedom within the limits), so the
     penalties phi_p stay ~0 along the search;
  3. golden-section search of phi + rho phi_p along dc (tau in [0, 1]), each evaluation a
     quasistatic solve warm-started from the linearised prediction Y + tau dY/dc dc. When the full
     step tau = 1 already achieves ``accept_full_step`` (80 %) of the reduction the Gauss-Newton
     model predicts, it is taken without the search (one solve instead of five); set None to
     always search, as the paper does.
Steps stop when the objective falls by less than ``min_improvement`` or the RMS marker residual
changes by less than ``tol_mm``.
Outliers: iteratively reweighted Tukey biweights on the marker residuals (``_weights``), whose
cut-off shrinks to ``robust_mm`` as the fit improves; None turns robust weighting off.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from wface.controls import (
    activation_penalty,
    bone_penalty,
    jaw_from_intuitive,
    jaw_to_intuitive,
    params_from_affine,
)
from wface.tracking.adaptive import carry_after_step, is_adaptive, release_at_end
from wface.tracking.markers import MarkerMap
from wface.tracking.rig import FaceRig, RigLinearization, RigState
from wface.tracking.steps import bounded_step, step_basis, step_violation

__all__ = ["TrackOptions", "FrameResult", "FrameEstimator"]

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
HELD_AT_REST = 1e-4  # a muscle the prior holds at rest is there within this (activation units; a
# usage pass leaves it ~1e-6 from the prior's mean)


@dataclass
class TrackOptions:
    """Settings of the per-frame estimation (defaults follow Sifakis et al. 2005)."""

    gn_steps_first: int = 4  # Gauss-Newton steps on the first frame of a chunk
    gn_steps: int = 3  # at most, on later frames (warm-started; stops early, usually after 1-2)
    rho0: float = 1e-3  # first penalty weight, relative to phi
    rho_growth: float = 1.05
    rho_max: float = 1e6  # relative to phi
    rigid_step_tol: float = 0.05  # accepted first-order non-rigidity of a bone step: |sym(M^T dM)| / |dM|
    line_search_evals: int = 5  # quasistatic solves in the golden-section search
    accept_full_step: float | None = 0.8  # take tau = 1 without the search when it achieves this share of
    # the reduction the Gauss-Newton model predicts (None: always run the golden-section search)
    tol_mm: float = 1e-3  # stop when a step changes the RMS marker residual by less than this (mm)
    robust_mm: float | None = (
        3.0  # Tukey cut-off on marker residuals (mm) once the fit is close; None: plain least squares
    )
    prior: str = "auto"  # data-chosen priors (wface.tracking.prior): "auto" temporal + usage (two passes),
    # "temporal" the temporal prior alone (one pass), "off" none
    prior_passes: int = 3  # with prior="auto": passes under the take-wide usage prior after the first, each
    # re-linearised at the one before and its prior refitted (wface.tracking.refine); at most, see below
    prior_refit_change: float = 0.15  # the usage prior is refitted (the passes after the first usage pass)
    # only when that pass moved the activations by more than this (RMS over tracked frames and muscles,
    # activation units): a take the prior corrects heavily (noise, outliers, dropout: 0.25-0.30) gets all
    # prior_passes, a cleaner one (0.5 mm noise: 0.05-0.07) one usage pass; 0: always prior_passes
    # (docs/design.md, "Priors chosen by the data")
    temporal_weight: float = 0.0  # lam: pull of activations toward the previous frame (m^2 per unit^2)
    activation_prior: float = 0.0  # mu: pull of activations toward zero (m^2 per unit^2), a small prior
    extrapolate: bool = True  # start each frame from a constant-velocity prediction of the controls
    # (only when no linearisation of the previous frame is handed on, see ``reuse_factor``)
    min_improvement: float = 0.05  # stop GN when the objective drops by less than this fraction
    reuse_factor: bool = True  # keep the factor and Jacobian of each new equilibrium (the stopping test on
    # the next step's predicted decrease, no start solve, chord steps); False: the paper's loop
    factor_at: str = "adaptive"  # with reuse_factor, where factorisations are done: "adaptive" keeps the
    # factor and the Jacobian from frame to frame, refactoring where a chord step contracts poorly and
    # solving the Jacobian again where a step falls short of its prediction (wface.tracking.adaptive);
    # "prediction": one factorisation per frame at the linear prediction of the new equilibrium (its solve
    # converges in ~2 chord steps and the Jacobian at the equilibrium reuses the factor); "equilibrium"
    # (exact Jacobians; the solves take chord steps with the previous equilibrium's factor)
    jacobian_refresh: float = 0.95  # "adaptive": keep the Jacobian while a step achieves this share of its
    max_jacobian_age: int = 8  # predicted decrease, <= this many steps (0.8: chunks differ from serial by 0.011)
    solve_tol: float | None = 3e-4  # relative residual of the tracker's solves along a step (None: the
    # rig's tol), against the linearised load (FaceRig.load_force_scale): markers within 10-30 um RMS
    float32_forces: bool = True  # with "adaptive": the solves along a step read energies and forces from a
    # float32 twin of the simulator (2x cheaper; reading error ~1e-5 of the load, under solve_tol)
    factor_precision: str = "float32"  # of the tracker's factorisations (Jacobians, chords): single
    # precision is 1.5x faster and within 8e-6 of double at 100K tets, far below the 1 % of the
    # prediction's factor; "float64" for double
    noise_mm: float | None = None  # the capture's marker noise RMS (mm), if known: the steps stop once
    noise_fraction: float = 0.02  # the predicted RMS marker change falls below this fraction of it

    def __post_init__(self) -> None:
        """Refuse settings the tracker would silently read as another (a ``prior="Auto"`` ran as "off")."""
        for name, allowed in _CHOICES.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"TrackOptions.{name} must be one of {allowed}, got {getattr(self, name)!r}")
        for name, low in _COUNTS.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"TrackOptions.{name} must be an integer >= {low}, got {value!r}")
        for name in _POSITIVE + _NON_NEGATIVE + _OPTIONAL_POSITIVE:
            value = getattr(self, name)
            if value is None and name in _OPTIONAL_POSITIVE:
                continue
            ok = isinstance(value, (int, float, np.floating)) and np.isfinite(value)
            if not ok or value < 0 or (value == 0 and name not in _NON_NEGATIVE):
                need = "a number >= 0" if name in _NON_NEGATIVE else "a positive number"
                raise ValueError(f"TrackOptions.{name} must be {need}{' or None' * (name in _OPTIONAL_POSITIVE)}, "
                                 f"got {value!r}")  # fmt: skip


_CHOICES = {
    "prior": ("auto", "temporal", "off"),
    "factor_at": ("adaptive", "prediction", "equilibrium"),
    "factor_precision": ("float32", "float64"),
}
_COUNTS = {"gn_steps_first": 1, "gn_steps": 1, "line_search_evals": 1, "prior_passes": 0, "max_jacobian_age": 0}
_POSITIVE = ("rho0", "rho_growth", "rho_max", "rigid_step_tol", "tol_mm", "min_improvement", "noise_fraction")
_NON_NEGATIVE = ("prior_refit_change", "temporal_weight", "activation_prior", "jacobian_refresh")
_OPTIONAL_POSITIVE = ("accept_full_step", "robust_mm", "solve_tol", "noise_mm")


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
    counts: dict = field(default_factory=dict)  # the rig's counters used by this frame
    linearization: RigLinearization | None = None  # at ``state``: the next frame's ``start``
    system: dict = field(default_factory=dict)  # the last Gauss-Newton system: data_hessian (p, p) = 2 J^T W J
    # (m^2 per unit^2), weighted_rss_m2 and weighted_count (sum of w_k over the coordinates) at the solution


class FrameEstimator:
    """Gauss-Newton estimation of one frame's controls (see module docstring)."""

    def __init__(self, rig: FaceRig, markers: MarkerMap, options: TrackOptions | None = None):
        self.rig = rig
        self.markers = markers
        self.options = options or TrackOptions()
        self.M = rig.n_muscles
        self._spare = None  # "adaptive": a second pass's factor, handed to its next frame

    def keep_spare(self, chord) -> None:
        """Keep ``chord`` (a factor) for the next frame's second-pass solves, freeing the one kept before."""
        if chord is not None and chord is not self._spare:
            self.free()
            self._spare = chord

    def free(self) -> None:
        """Release the factor kept for the next frame (``keep_spare``)."""
        if self._spare is not None:
            self._spare.free()
            self._spare = None

    # ------------------------------------------------------------------ objective pieces
    def _penalty(self, c: np.ndarray):
        a, b = self.rig.split(c)
        pa = activation_penalty(a, self.rig.model.activation_lower_bounds)
        pb = bone_penalty(self.rig.model.jaw_joint, b)
        g = np.concatenate([pa.gradient, pb.gradient])
        H = np.zeros((len(c), len(c)))
        H[: self.M, : self.M] = pa.hessian
        H[self.M :, self.M :] = pb.hessian
        return pa.value + pb.value, g, H

    def _weights(self, residual: np.ndarray) -> np.ndarray:
        """Tukey biweight w = (1 - (e/c)^2)^2 for e < c, 0 beyond, with
        c = max(robust_mm, 4.685 * 1.4826 * median e): wide while the fit is coarse (a cold start),
        shrinking to ``robust_mm`` so that outliers get no weight once the face fits."""
        delta = self.options.robust_mm
        if delta is None:
            return np.ones(len(residual))
        e = np.linalg.norm(residual, axis=1) * 1e3
        present = e > 0
        med = np.median(e[present]) if present.any() else 0.0
        c = max(delta, 4.685 * 1.4826 * med)
        return np.where(e < c, (1.0 - (e / c) ** 2) ** 2, 0.0)

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
        start: RigLinearization | None = None,
        prior=None,
        equilibrium: RigState | None = None,
        marker_jy: np.ndarray | None = None,
        stale_rows: np.ndarray | None = None,
    ) -> FrameResult:
        """Controls for one frame of marker data.

        Args:
            frame: frame number (for the record). target_m: (k, 3) marker positions, NaN rows missing.
            c0: starting controls (the previous frame's, or the rest controls).
            y0: warm start of the equilibrium (cranium frame), e.g. the previous frame's.
            steps: Gauss-Newton steps (default from the options).
            a_prev: activations of the previous frame for the temporal term.
            start: the rig linearised at the previous frame's equilibrium (its ``FrameResult.linearization``):
                the frame starts there (no solve, no Jacobian; chord steps with its factor; ``c0`` and
                ``y0`` ignored), owned by the estimator from here.
            prior: (a - mean)^T weight (a - mean) added to phi (``wface.tracking.prior.GaussianPrior``).
            equilibrium: the equilibrium at ``c0``, already solved (a first pass's): no start solve.
            marker_jy: with ``equilibrium``, its marker nodes' Jacobian rows (k, 3, M + 12), e.g. a first
                pass's (``FaceRig.linearize_rows``): the steps and the stopping test use them, so a
                frame that converges in one step needs no Jacobian at all.
            stale_rows: older marker-node rows of this frame (k, 3, M + 12), e.g. the first pass's: they
                stand in for the columns of the muscles the prior holds at rest (``_held``).
        """
        opt = self.options
        self._prior, self._stale_rows = prior, stale_rows
        t_start, cpu_start = time.perf_counter(), time.process_time()
        rig = self.rig
        counters0 = dict(rig.counters)
        target = np.asarray(target_m, dtype=np.float64)
        present = np.isfinite(target).all(axis=1)
        if present.sum() < 3:
            raise ValueError(f"frame {frame}: only {int(present.sum())} markers present; need at least 3")
        steps = opt.gn_steps if steps is None else steps
        timings = {"quasistatic_s": 0.0, "jacobian_s": 0.0, "gauss_newton_system_s": 0.0}
        t = time.perf_counter()
        state, lin = self._start(c0, y0, start, equilibrium, marker_jy)
        timings["jacobian_s" if equilibrium is not None else "quasistatic_s"] += time.perf_counter() - t
        c = state.controls
        m = self.markers.positions(state.x_m)
        w = self._weights(np.where(present[:, None], m - target, 0.0))
        rho, gn_done = 0.0, 0
        data_hessian = None  # 2 J^T W J of the last Gauss-Newton system (for the usage prior)
        data_system: dict = {}  # that system's step (its data gradient and where it was formed)
        near = None  # the factorised stiffness at the accepted trial's linear prediction ("prediction")
        while True:
            final_jacobian = opt.reuse_factor and (lin is None or lin.full)  # test the next step's prediction
            if gn_done >= steps and not final_jacobian:
                break  # the paper's loop needs no Jacobian at its last point
            if lin is None or lin.state is not state:
                t = time.perf_counter()
                if lin is not None:
                    lin.free()  # the chord of an older equilibrium: its factor slot is needed now
                lin = self._linearize(state, keep_factor=opt.reuse_factor, stiffness=near)
                near = None
                timings["jacobian_s"] += time.perf_counter() - t
            if gn_done >= steps:
                break
            t = time.perf_counter()
            step = self._gn_step(state, lin, m, target, present, w, a_prev)
            timings["gauss_newton_system_s"] += time.perf_counter() - t
            rho, data_hessian, data_system = step["rho"], step["data_hessian"], step
            if opt.reuse_factor and self._converged(step["total0"], step["predicted"], present, relative=gn_done > 0):
                break  # the next step would change the fit by less than the tolerances: done here
            t = time.perf_counter()
            cache, near = self._line_search(step, state, lin, target, present, w, a_prev)
            tau_best = min(cache, key=lambda k: cache[k][0])
            timings["quasistatic_s"] += time.perf_counter() - t
            gn_done += 1
            total0 = step["total0"]
            if near is not None and (tau_best != 1.0 or near.projected):
                near.free()  # too far from the point taken, or not the exact tangent: not for a Jacobian
                near = None
            if cache[tau_best][0] >= total0:
                break  # no descent along dc: keep c
            _, state, m = cache[tau_best]
            lin = carry_after_step(self, lin, state, total0 - cache[tau_best][0], step["predicted"], timings)
            c = state.controls
            w = self._weights(np.where(present[:, None], m - target, 0.0))
            if not final_jacobian:  # stop without a Jacobian at the new point?
                done, data_system = self._done_without_jacobian(lin, state, m, target, present, w, a_prev, step, cache)
                data_hessian = data_system["data_hessian"]
                if done:
                    break

        release_at_end(self, near, lin)  # the factor at the prediction; a second pass's kept for its next frame
        timings["cpu_s"] = time.process_time() - cpu_start  # process CPU time, all threads (less load-bound)
        err = np.where(present, np.linalg.norm(m - target, axis=1), np.nan)
        used = {k: rig.counters[k] - counters0[k] for k in rig.counters}
        if lin is not None and lin.state is not state:
            lin.free()
            lin = None
        system = self._frame_system(m, target, present, w, data_hessian, data_system)
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
            counts=used,
            linearization=lin,
            system=system,
        )

    def _frame_system(self, m, target, present, w, data_hessian, data_system) -> dict:
        """``FrameResult.system``: the weighted residual and the last Gauss-Newton system's data term."""
        system = {"weighted_rss_m2": self._phi(m, target, present, w), "weighted_count": 3.0 * float(w[present].sum())}
        if data_hessian is not None:  # 2 J^T W J, 2 J^T W r and where: the usage prior's input
            system.update(data_hessian=data_hessian, data_gradient=data_system["data_gradient"])
            system["data_at"] = data_system["at"]
        return system

    def _start(self, c0, y0, start, equilibrium, marker_jy) -> tuple[RigState, object]:
        """(the equilibrium a frame starts from, the linearisation there or None): see ``estimate``."""
        if start is not None:
            return start.state, start
        state = equilibrium if equilibrium is not None else self.rig.equilibrium(c0, y0)
        if equilibrium is None or not self.options.reuse_factor:
            return state, None
        spare, self._spare = (self._spare, None) if is_adaptive(self) else (None, None)
        if marker_jy is None:  # no rows: the Jacobian solved with the previous frame's factor (none: in the loop)
            return state, (None if spare is None else self._linearize(state, keep_factor=True, stiffness=spare))
        lin = self.rig.linearize_rows(state, self.markers.nodes, marker_jy, chord=spare)  # None: cannot serve
        if lin is None and spare is not None:
            spare.free()
        return state, lin

    def _held(self, c: np.ndarray) -> np.ndarray | None:
        """Muscles the frame's prior holds at rest (``GaussianPrior.held``) and that are there at controls
        ``c`` (within ``HELD_AT_REST`` of the prior's mean), when the frame has stale rows to stand in for
        their Jacobian columns (``estimate``); None when there are none (docs/design.md, "Performance")."""
        prior = self._prior
        if prior is None or prior.held is None or self._stale_rows is None:
            return None
        held = prior.held & (np.abs(c[: self.M] - prior.mean) <= HELD_AT_REST)
        return held if held.any() else None

    def _linearize(self, state: RigState, **kwargs) -> RigLinearization:
        """``FaceRig.linearize`` at ``state`` without the columns of the muscles held at rest (``_held``),
        whose marker rows come from the frame's stale rows."""
        held = self._held(state.controls)
        lin = self.rig.linearize(state, held=held, **kwargs)
        if held is not None:
            lin.fill = (self.markers.nodes, self._stale_rows)
        return lin

    def _done_without_jacobian(self, lin, state, m, target, present, w, a_prev, step, cache):
        """(stop here, the last Gauss-Newton system: ``_gn_step``'s dict) after the step ``step`` whose new
        point ``state`` gets no Jacobian: the next step as known Jacobian rows predict it
        (``RowsLinearization``), else the paper's test on the achieved decrease (``cache``: the trials)."""
        if lin is not None and not lin.full:
            ahead = self._gn_step(state, lin, m, target, present, w, a_prev)
            return self._converged(ahead["total0"], ahead["predicted"], present), ahead
        total0 = step["total0"]
        return self._converged(total0, total0 - min(v[0] for v in cache.values()), present), step

    def _gn_step(self, state, lin, m, target, present, w, a_prev) -> dict:
        """The Gauss-Newton step from ``state``: dc, rho, the objective there and the decrease the
        linear model predicts for the full step (module docstring, items 1-2)."""
        opt, rig = self.options, self.rig
        c = state.controls
        phi = self._phi(m, target, present, w)
        Jn = rig.world_jacobian(state, lin.node_rows(self.markers.nodes), self.markers.nodes)
        J = self.markers.jacobian(Jn)  # (3k, p)
        rows = np.repeat(present, 3)
        wr = np.repeat(w, 3)[rows]
        Jp = J[rows]
        r = (m - target).reshape(-1)[rows]
        A = 2.0 * (Jp.T * wr) @ Jp
        g = 2.0 * (Jp.T * wr) @ r
        data_hessian, data_gradient = A.copy(), g.copy()
        prior = self._prior
        if prior is not None:
            A[: self.M, : self.M] += 2.0 * prior.weight
            g[: self.M] += 2.0 * prior.weight @ (c[: self.M] - prior.mean)
        if opt.temporal_weight > 0 and a_prev is not None:
            A[: self.M, : self.M] += 2.0 * opt.temporal_weight * np.eye(self.M)
            g[: self.M] += 2.0 * opt.temporal_weight * (c[: self.M] - a_prev)
        if opt.activation_prior > 0:
            A[: self.M, : self.M] += 2.0 * opt.activation_prior * np.eye(self.M)
            g[: self.M] += 2.0 * opt.activation_prior * c[: self.M]
        pen, gp, Hp = self._penalty(c)
        frozen = lin.held if lin.full else None  # no columns at the other nodes: the prediction cannot move them
        dc, rho = self._penalty_step(A, g, Hp, gp, c, max(phi, 1e-12), frozen=frozen)
        total0 = phi + rho * pen + self._reg(c, a_prev)
        predicted = total0 - (float(np.sum(wr * (r + Jp @ dc) ** 2)) + rho * pen + self._reg(c + dc, a_prev))
        return {
            "dc": dc,
            "rho": rho,
            "total0": total0,
            "predicted": predicted,
            "lin": lin,
            "data_hessian": data_hessian,
            "data_gradient": data_gradient,
            "at": c,
        }

    def _converged(self, total: float, decrease: float, present: np.ndarray, *, relative: bool = True) -> bool:
        """The stopping test on a decrease of the objective (achieved, or predicted for the next step):
        below ``min_improvement`` of it (``relative``; not before a frame's first step, where a slow
        motion under the noise would be a small share of the objective and the face would lag), or an
        RMS marker change below ``tol_mm`` or below ``noise_fraction`` of the capture's noise ``noise_mm``."""
        opt = self.options
        n = max(int(present.sum()), 1)
        rms_change_mm = (np.sqrt(max(total, 0.0) / n) - np.sqrt(max(total - decrease, 0.0) / n)) * 1e3
        tol_mm = max(opt.tol_mm, opt.noise_fraction * (opt.noise_mm or 0.0))
        return (relative and decrease < opt.min_improvement * total) or rms_change_mm < tol_mm

    def _line_search(self, step, state, lin, target, present, w, a_prev) -> tuple[dict[float, tuple], object]:
        """(tau -> (objective, state, markers) of the trials along dc, the stiffness factored at the full
        step's prediction or None): the full step alone when it achieves ``accept_full_step`` of the
        predicted decrease, else the golden-section search (which reuses the full step's solve: 5 solves
        in all). The trials take chord steps with the factor at the full step's linear prediction
        (``factor_at="prediction"``) or with that of ``lin`` (at ``state``)."""
        opt = self.options
        chord, near = (lin.chord if lin is not None else None), None
        full = lin is not None and lin.full  # a RowsLinearization's solves use its own factor at ``state``
        holder = lin if (is_adaptive(self) and chord is not None) else None  # its chord may be replaced
        if opt.reuse_factor and opt.factor_at == "prediction" and self.rig.sim.linear_solver == "direct" and full:
            if chord is not None:
                lin.free()  # its Jacobian stays; its factor is not needed any more
            c, dc = state.controls, step["dc"]
            ct = self.retract(c + dc)
            near = chord = self.rig.stiffness_at(ct, state.y_m + lin.predict(self._dc_y(ct - c)), warn=False)
        trial = functools.partial(
            self._trial,
            c=state.controls,
            dc=step["dc"],
            state=state,
            lin=step["lin"],
            target=target,
            present=present,
            w=w,
            rho=step["rho"],
            a_prev=a_prev,
            chord=chord,
            holder=holder,
        )
        cache: dict[float, tuple] = {}
        if opt.accept_full_step is not None:
            cache[1.0] = full = trial(1.0)
            predicted, total0 = step["predicted"], step["total0"]
            if predicted > 0 and total0 - full[0] >= opt.accept_full_step * predicted:
                return cache, near  # the model predicted well: the Gauss-Newton point is taken
        return self._golden_section(trial, cache), near

    @property
    def _step_basis(self) -> np.ndarray:
        """The step's basis in the null space of the jaw joint's equalities (``wface.tracking.steps``)."""
        if not hasattr(self, "_T"):
            self._T = step_basis(self.rig.model.jaw_joint, self.M)
        return self._T

    def _penalty_step(self, A, g, Hp, gp, c, scale, frozen=None) -> tuple[np.ndarray, float]:
        """(dc, rho): the step for the smallest rho on the grid rho0 phi growth^k (k = 0..K) whose bone
        step is rigid to first order, found by bisection over k (rigidity improves with rho), each a
        bounded least-squares step (``wface.tracking.steps``). ``frozen``: (M,) bool, activations the
        step leaves unchanged (their Jacobian columns unknown)."""
        opt = self.options
        K = int(np.ceil(np.log(opt.rho_max / opt.rho0) / np.log(opt.rho_growth)))
        steps: dict[int, np.ndarray] = {}
        start = None  # the last solve's active set: the next rho's warm start
        lower = self.rig.model.activation_lower_bounds

        def step_at(k: int) -> np.ndarray:
            nonlocal start
            if k not in steps:
                r_k = opt.rho0 * scale * opt.rho_growth**k
                steps[k], start = bounded_step(self._step_basis, A + r_k * Hp, g + r_k * gp, c, lower, start, frozen)
            return steps[k]

        lo_k, hi_k = 0, K
        if step_violation(c, step_at(0), self.M) <= opt.rigid_step_tol:
            hi_k = 0
        while hi_k - lo_k > 1:
            mid = (lo_k + hi_k) // 2
            if step_violation(c, step_at(mid), self.M) <= opt.rigid_step_tol:
                hi_k = mid
            else:
                lo_k = mid
        return step_at(hi_k), opt.rho0 * scale * opt.rho_growth**hi_k

    def _trial(self, tau, *, c, dc, state, lin, target, present, w, rho, a_prev, chord=None, holder=None) -> tuple:
        """(objective, state, markers) at the retracted controls ct = retract(c + tau dc), warm-started
        from the linearised equilibrium Y + dY/dc (ct - c) (chord steps with ``chord``, the factor at
        ``state``; with ``holder``, a linearisation, its current factor, refactored where it contracts
        poorly and the new one kept there: ``wface.tracking.adaptive``)."""
        ct = self.retract(c + tau * dc)
        # the linear prediction at the retracted controls: its attached nodes are then exactly at their
        # targets (X_C is affine in the jaw numbers), so the solve needs no lift step
        y_guess = state.y_m + lin.predict(self._dc_y(ct - c))
        opt = self.options
        if holder is not None:
            st = self.rig.equilibrium(
                ct,
                y_guess,
                chord=holder.chord,
                refactor=True,
                tol=opt.solve_tol,
                load_scale=True,
                twin=opt.float32_forces,
            )
            if st.new_chord is not None:
                st.new_chord.fresh = True  # made in this frame, near its equilibrium
                holder.replace_chord(st.new_chord)
                st.new_chord = None
        else:
            st = self.rig.equilibrium(ct, y_guess, chord=chord)
        mt = self.markers.positions(st.x_m)
        value = self._phi(mt, target, present, w) + rho * self._penalty(ct)[0] + self._reg(ct, a_prev)
        return value, st, mt

    def _golden_section(self, trial, cache: dict | None = None) -> dict[float, tuple]:
        """Golden-section search of ``trial(tau)[0]`` on [0, 1] plus the full step tau = 1;
        returns every evaluated tau -> trial result (``line_search_evals`` evaluations, those already
        in ``cache``, such as a full step tried first, included)."""
        cache = {} if cache is None else cache

        def f(tau: float) -> float:
            if tau not in cache:
                cache[tau] = trial(tau)
            return cache[tau][0]

        lo, hi = 0.0, 1.0
        x1, x2 = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
        f1, f2 = f(x1), f(x2)
        for _ in range(max(0, self.options.line_search_evals - 3)):
            if f1 <= f2:
                hi, x2, f2 = x2, x1, f1
                x1 = hi - _GOLDEN * (hi - lo)
                f1 = f(x1)
            else:
                lo, x1, f1 = x1, x2, f2
                x2 = lo + _GOLDEN * (hi - lo)
                f2 = f(x2)
        f(1.0)  # the full step: the Gauss-Newton point is often the best
        return cache

    def _reg(self, c: np.ndarray, a_prev: np.ndarray | None) -> float:
        """Value of the optional regularisers (temporal smoothness, prior toward rest, Gaussian prior)."""
        a = c[: self.M]
        out = self.options.activation_prior * float(a @ a)
        prior = getattr(self, "_prior", None)
        if prior is not None:
            out += float((a - prior.mean) @ prior.weight @ (a - prior.mean))
        if self.options.temporal_weight > 0 and a_prev is not None:
            out += self.options.temporal_weight * float(np.sum((a - a_prev) ** 2))
        return out

    def retract(self, c: np.ndarray) -> np.ndarray:
        """Project controls onto valid ones: activations into [0, 1] ([-1, 1] for a pressure actuator),
        the cranium onto the nearest rotation (polar decomposition), the jaw onto a rigid pose inside
        the joint limits."""

        M = self.M
        out = np.array(c, dtype=np.float64)
        out[:M] = self.rig.model.clip_activations(out[:M])
        for s0 in (M, M + 12):
            U, _, Vt = np.linalg.svd(out[s0 : s0 + 9].reshape(3, 3))
            R = U @ Vt
            if np.linalg.det(R) < 0:
                R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
            out[s0 : s0 + 12] = params_from_affine(R, out[s0 + 9 : s0 + 12])
        joint = self.rig.model.jaw_joint
        pose = jaw_to_intuitive(joint, out[M + 12 :])
        out[M + 12 :] = jaw_from_intuitive(joint, pose["opening_deg"], pose["protrusion_m"], pose["lateral_deg"])
        return out

    def _dc_y(self, dc: np.ndarray) -> np.ndarray:
        """The part of dc that Y (cranium frame) depends on: activations and jaw parameters."""
        return np.concatenate([dc[: self.M], dc[self.M + 12 :]])
