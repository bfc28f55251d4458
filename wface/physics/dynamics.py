"""Implicit dynamics of a face model: inertia, Rayleigh damping and prescribed bone motion.

Equations of motion of the free nodes U (attached nodes C follow their bones, Dirichlet):

    M x'' + C x' = f(x, a(t)) + M g,        C = alpha M + beta K_n,

with the lumped mass M (rho V_e / 4 to each node of tet e, ``lumped_masses``), the nodal forces
f = -dE/dx of ``Simulator`` (flesh and muscles, activations a(t) in [0, 1]) and an optional
gravity g (off by default). Rayleigh damping (``Damping``): alpha (1/s) damps all motion in the
simulation frame, beta (s) damps the strain rate through the projected stiffness K_n evaluated at
the start of the step (Teran et al. 2005 projection, so C is positive semi-definite). Mode i gets
the damping ratio zeta_i = alpha / (2 omega_i) + beta omega_i / 2.

Each time step of length h is one minimisation of an incremental potential (Kane et al. 2000;
Martin et al. 2011; Gast et al. 2015) over the free nodes, solved by Newton (exact or projected
stiffness, see below) with a backtracking (Armijo) line search on the potential:

    Phi(y) = kappa/2 ||y - y_hat||_M^2 + E(y, a*) + delta/2 (y - x_n)^T C (y - x_n) - g^T M y,

- backward Euler ("be", first order, L-stable: high frequencies are damped numerically):
  kappa = 1/h^2, delta = 1/h, y_hat = x_n + h v_n, a* = a_{n+1}, y_C = x_C(t_{n+1});
  x_{n+1} = y, v_{n+1} = (y - x_n) / h.
- implicit midpoint ("midpoint", second order, symplectic: no numerical damping, energy of a
  linear system conserved exactly; linear momentum conserved, angular momentum too when undamped):
  kappa = 4/h^2, delta = 2/h, y = x_{n+1/2}, y_hat = x_n + h/2 v_n, a* = (a_n + a_{n+1}) / 2,
  y_C = (x_C(t_n) + x_C(t_{n+1})) / 2;  x_{n+1} = 2 y - x_n, v_{n+1} = 4 (y - x_n) / h - v_n.

Stationarity of Phi is exactly the discrete equation of motion of each scheme (e.g. for the
midpoint rule M (v_{n+1} - v_n) / h = f(y, a*) - C (x_{n+1} - x_n) / h + M g). The Newton
Hessian kappa M + delta C + K(y) is symmetric positive definite with the projected K, so every
step is a descent direction. Each step starts from the predictor y_hat (attached nodes at their
targets), which keeps the total momentum of an unconstrained body exact to round-off: the Newton
corrections sum to zero because the rows of K (exact or projected) sum to zero. PARDISO keeps its symbolic analysis
from step to step (numeric refactorisation only). Tried and dropped: CG preconditioned by the
previous factor instead of refactoring (no faster at 5K or 20K tets: 8 CG iterations cost about
one numeric refactorisation), and adding the previous step's Newton correction to the predictor
(on the built-in face at dt = 2 ms it raised the potential: the correction alternates in sign
with the 100+ Hz modes).

Newton Hessian ("auto", default): the exact Hessian of E plus kappa M + delta C, which converges
quadratically (3-5 iterations per step for a sudden full smile at dt = 2 ms on the 5K-tet face,
against 6-9 with the projected K), falling back to the projected K when the factorisation says
it is indefinite (large dt with strongly active muscles).

Convergence: ||grad_U Phi|| <= tol * max(||grad_U Phi(y_0)||, f_floor), y_0 the predictor,
f_floor = 1e-3 (mu10 + mu01) V^(2/3) as in ``wface.physics.newton`` (``StepStats.residual_rel``).
"""

from __future__ import annotations

import time

import numpy as np

from wface.mesh.quality import count_inverted
from wface.physics.contact_tangent import ContactTangent
from wface.physics.dynamic_state import Damping, DivergedError, DynamicState, StepStats, lumped_masses
from wface.solvers import LinearSolver, NotPositiveDefiniteError

__all__ = [
    "SCHEMES",
    "Damping",
    "DivergedError",
    "DynamicSimulator",
    "DynamicState",
    "StepStats",
    "lumped_masses",
]

SCHEMES = ("be", "midpoint")


def _check_array(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{name} has shape {arr.shape}, expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


class DynamicSimulator:
    """Implicit time integration of a ``Simulator``'s face (see the module docstring).

    Args:
        sim: the quasistatic ``Simulator`` (its energy, forces, projected stiffness and linear
            solver are reused); float64 recommended.
        scheme: "midpoint" (second order, energy preserving), "be" (backward Euler, first order,
            numerically dissipative, the most robust) or "auto" (default): the midpoint rule without
            ``contact``, backward Euler with it (the midpoint rule holds contact at the step's midpoint
            only and gains energy at every penalty impact: docs/design.md, "Dynamics").
        damping: Rayleigh damping (default ``Damping()``).
        gravity_m_s2: optional (3,) gravity acceleration, e.g. (0, -9.81, 0); default none.
        tol: relative gradient tolerance of each step's Newton solve.
        max_iterations: Newton iteration cap per step (a step that reaches it is accepted and
            flagged ``converged=False`` in its stats).
        solver: linear engine override ("auto" | "direct" | "cg"); default: the simulator's.
        max_line_search: backtracking halvings per Newton iteration.
        stiffness: Hessian of the Newton steps: "auto" (default: the exact Hessian of E plus the
            inertia and damping terms, falling back to the projected K for one iteration when that
            matrix is not positive definite or gives no descent; after a step with such a
            fallback, the next step tries the exact Hessian only below a relative residual of
            0.1), "projected" (always the
            projected-definite K of Teran et al. 2005) or "exact".
        contact: optional ``wface.physics.contact.Contact`` (lips, teeth, bones, rigid obstacles):
            its penalty energy joins the potential, its forces the gradient and its Gauss-Newton
            Hessian the Newton matrix, as in the quasistatic solve; bone-following obstacles are
            placed from the attached positions at the point where the forces are evaluated.

    Example::

        dyn = DynamicSimulator(Simulator(model), scheme="midpoint")
        state = dyn.initial_state()                      # rest, zero velocity, no activation
        a = model.activation_vector({"zygomaticus_major_l": 1.0})
        for _ in range(40):
            state, stats = dyn.step(state, 1e-3, a)      # attached nodes stay where they are
    """

    def __init__(
        self,
        sim,
        *,
        scheme: str = "auto",
        damping: Damping | None = None,
        gravity_m_s2=None,
        tol: float = 1e-6,
        max_iterations: int = 25,
        solver: str | None = None,
        max_line_search: int = 30,
        stiffness: str = "auto",
        contact=None,
    ):
        if scheme == "auto":
            scheme = "be" if contact is not None else "midpoint"
        if scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {(*SCHEMES, 'auto')}, got {scheme!r}")
        if not (np.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be finite and > 0, got {tol}")
        if stiffness not in ("auto", "projected", "exact"):
            raise ValueError(f"stiffness must be 'auto', 'projected' or 'exact', got {stiffness!r}")
        self.stiffness = stiffness
        # "auto": try the exact Hessian from the first iteration; after a step in which it was
        # rejected, only once the relative residual is below 0.1 (as the quasistatic Newton does)
        self._exact_below = 1.0
        if int(max_iterations) < 1:
            raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
        self.sim = sim
        self.model = sim.model
        self.scheme = scheme
        self.damping = damping if damping is not None else Damping()
        if not isinstance(self.damping, Damping):
            raise TypeError(f"damping must be a Damping, got {type(self.damping).__name__}")
        self.gravity_m_s2 = None if gravity_m_s2 is None else _check_array("gravity_m_s2", gravity_m_s2, (3,))
        self.contact = contact
        self.tol = float(tol)
        self.max_iterations = int(max_iterations)
        self.max_line_search = int(max_line_search)
        # PARDISO keeps its symbolic analysis from step to step (numeric refactorisation only)
        self._linear = LinearSolver(solver or sim.linear_solver, sim.device, keep_factor=True)
        self.engine = self._linear.engine
        self.masses_kg = lumped_masses(self.model)
        rest = self.model.rest_positions_m
        self._span_m = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0)))  # farther than this: diverged
        self._pattern = sim.pattern("free")
        self._free = self._pattern.dof_nodes
        self._fixed = self.model.attached_nodes.astype(np.int64)
        self._m_free3 = np.repeat(self.masses_kg[self._free], 3)  # mass per free dof
        mat = self.model.material
        volume = float(self.model.rest_volume_m3.sum())
        self._floor = 1e-3 * (mat.mu10_pa + mat.mu01_pa) * volume ** (2.0 / 3.0)
        stress = mat.mu10_pa + mat.mu01_pa + mat.sigma_max_pa * float(np.max(self.model.muscle_strength, initial=1.0))
        self._energy_noise = 64 * np.finfo(np.float64).eps * 3.0 * stress * volume
        self._diag_positions = None
        self._kn_csr = None  # (tangent, CSR) of the damping stiffness K_n of the current step

    # ------------------------------------------------------------------ state
    def initial_state(self, x_m=None, v_m_s=None, activations=None, *, t_s: float = 0.0) -> DynamicState:
        """A start state; defaults: rest positions, zero velocity, zero activations."""
        n = self.model.n_nodes
        x = self.model.rest_positions_m.copy() if x_m is None else _check_array("x_m", x_m, (n, 3)).copy()
        v = np.zeros((n, 3)) if v_m_s is None else _check_array("v_m_s", v_m_s, (n, 3)).copy()
        if not np.isfinite(t_s):
            raise ValueError(f"t_s must be finite, got {t_s}")
        return DynamicState(float(t_s), x, v, self.model.activation_vector(activations))

    def kinetic_energy(self, state: DynamicState) -> float:
        """1/2 sum_i m_i |v_i|^2 over the free nodes, joules."""
        v = state.v_m_s[self._free]
        return 0.5 * float(np.einsum("i,ij,ij->", self.masses_kg[self._free], v, v))

    def momentum(self, state: DynamicState) -> np.ndarray:
        """(3,) total linear momentum of all nodes, kg m/s."""
        return self.masses_kg @ state.v_m_s

    def total_energy(self, state: DynamicState) -> float:
        """Kinetic + elastic (+ gravitational with gravity, + contact penalty with contact) energy, J.

        With contact, the obstacles stay where the latest step placed them."""
        e = self.kinetic_energy(state) + self.sim.energy(state.x_m, state.activations)
        if self.contact is not None:
            e += self.contact.energy(state.x_m)
        if self.gravity_m_s2 is not None:
            e -= float(self.masses_kg[self._free] @ (state.x_m[self._free] @ self.gravity_m_s2))
        return e

    # ------------------------------------------------------------------ stepping
    def step(self, state: DynamicState, dt_s: float, activations=None, attached_positions_m=None):
        """Advance ``state`` by one time step.

        Args:
            state: the state at t_n.
            dt_s: step length h > 0, seconds.
            activations: activations at t_{n+1} ((M,) array or {name: value}); default: keep
                ``state.activations``. The midpoint rule evaluates the forces at their average.
            attached_positions_m: (a, 3) positions of ``model.attached_nodes`` at t_{n+1} (e.g.
                ``wface.controls.attached_positions``); default: where they are at t_n.

        Returns:
            (new ``DynamicState``, ``StepStats``).
        """
        start = time.perf_counter()
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"time step dt_s must be finite and > 0, got {dt_s}")
        h = float(dt_s)
        a_next = state.activations if activations is None else self.model.activation_vector(activations)
        fixed = self._fixed
        xc_next = (
            state.x_m[fixed]
            if attached_positions_m is None
            else _check_array("attached_positions_m", attached_positions_m, (fixed.size, 3))
        )
        x_n, v_n = state.x_m, state.v_m_s
        if self.scheme == "be":
            kappa, delta = 1.0 / h**2, 1.0 / h
            y_hat = x_n + h * v_n
            a_eval, y_c = a_next, xc_next
        else:
            kappa, delta = 4.0 / h**2, 2.0 / h
            y_hat = x_n + 0.5 * h * v_n
            a_eval, y_c = 0.5 * (state.activations + a_next), 0.5 * (x_n[fixed] + xc_next)
        y, stats = self._minimise(x_n, state.activations, y_hat, y_c, a_eval, kappa, delta)
        if not np.all(np.isfinite(y)):
            raise DivergedError(f"the step from t = {state.t_s:.6g} s gave NaN/inf positions (dt_s = {h:g})")
        if self.scheme == "be":
            x_new = y
            v_new = (y - x_n) / h
        else:
            x_new = 2.0 * y - x_n
            x_new[fixed] = xc_next
            v_new = 4.0 * (y - x_n) / h - v_n
            v_new[fixed] = (xc_next - x_n[fixed]) / h
        self._check_bounded(x_new, state.t_s, h, stats)
        new = DynamicState(state.t_s + h, x_new, v_new, np.array(a_next, dtype=np.float64))
        stats.kinetic_energy_j = self.kinetic_energy(new)
        stats.elastic_energy_j = self.sim.energy(x_new, a_next)
        stats.inverted_elements = count_inverted(self.model, x_new)
        if not stats.converged and stats.inverted_elements:
            raise DivergedError(
                f"the {self.scheme} step from t = {state.t_s:.6g} s (dt_s = {h:g}) broke down: Newton stopped at a "
                f"residual of {stats.residual_rel:.2g} with {stats.inverted_elements} element(s) inverted. "
                f"{self._cure()} keeps stiff contact and fast motion stable"
            )
        stats.steps = 1
        stats.seconds = time.perf_counter() - start
        return new, stats

    def advance(
        self,
        state: DynamicState,
        duration_s: float,
        substeps: int,
        activations=None,
        attached_positions_m=None,
        *,
        activation_ramp: str = "linear",
        on_step=None,
    ):
        """``substeps`` equal steps over ``duration_s`` towards the given end values (defaults:
        held). Attached positions are interpolated linearly from ``state`` (or given as a callable
        ``s -> (a, 3)`` positions at the fraction s in (0, 1] of the interval, e.g. to keep
        rotating bones rigid between frames); activations too with
        ``activation_ramp="linear"``, or switched to their end value from the first substep on
        with ``"step"`` (a sudden onset; the midpoint rule sees half of it in that substep).
        ``on_step(state)`` is called after every substep (e.g. to record peaks between frames).

        Returns:
            (state at the end, combined ``StepStats``).
        """
        if int(substeps) < 1 or int(substeps) != substeps:
            raise ValueError(f"substeps must be a positive integer, got {substeps}")
        if not (np.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s must be finite and > 0, got {duration_s}")
        if activation_ramp not in ("linear", "step"):
            raise ValueError(f"activation_ramp must be 'linear' or 'step', got {activation_ramp!r}")
        fixed = self._fixed
        a0 = state.activations
        a1 = a0 if activations is None else self.model.activation_vector(activations)
        if callable(attached_positions_m):
            path = attached_positions_m
        else:
            c0 = state.x_m[fixed].copy()
            c1 = (
                c0
                if attached_positions_m is None
                else _check_array("attached_positions_m", attached_positions_m, (fixed.size, 3))
            )

            def path(s):
                return (1 - s) * c0 + s * c1

        total = None
        for k in range(1, int(substeps) + 1):
            s = k / substeps
            a = a1 if activation_ramp == "step" else (1 - s) * a0 + s * a1
            state, stats = self.step(state, duration_s / substeps, a, path(s))
            total = stats if total is None else total.combine(stats)
            if on_step is not None:
                on_step(state)
        return state, total

    def _check_bounded(self, x_new: np.ndarray, t_s: float, h: float, stats: StepStats) -> None:
        """Raise ``DivergedError`` when a node of ``x_new`` lies farther from its rest place than the
        rest mesh is across (no face motion does that; a diverging integration does within a few steps)."""
        moved = np.linalg.norm(x_new - self.model.rest_positions_m, axis=1)
        span = self._span_m
        if np.all(np.isfinite(moved)) and moved.max() <= span:
            return
        far = int(np.nanargmax(np.where(np.isfinite(moved), moved, np.inf)))
        raise DivergedError(
            f"the {self.scheme} step from t = {t_s:.6g} s (dt_s = {h:g}) diverged: node {far} moved "
            f"{moved[far] * 1e3:.3g} mm from its rest place, farther than the rest mesh is across ({span * 1e3:.0f} "
            f"mm); Newton residual {stats.residual_rel:.2g} after {stats.newton_iterations} iterations. "
            f"{self._cure()} keeps stiff contact and fast motion stable"
        )

    def _cure(self) -> str:
        """What keeps a diverging integration stable, for this scheme."""
        return "a smaller time step" if self.scheme == "be" else "backward Euler (scheme 'be') or a smaller time step"

    # ------------------------------------------------------------------ the Newton solve of one step
    def _minimise(self, x_n, a_n, y_hat, y_c, a, kappa, delta):
        """argmin over free nodes of Phi (module docstring); returns (y (n, 3), StepStats)."""
        sim, free, fixed, pattern = self.sim, self._free, self._fixed, self._pattern
        m3 = self._m_free3
        alpha, beta = self.damping.alpha_per_s, self.damping.beta_s
        g_force = None
        if self.gravity_m_s2 is not None:
            g_force = (self.masses_kg[free, None] * self.gravity_m_s2[None, :]).reshape(-1)  # M g on free dofs
        # K at the start of the step: projected (PSD), or exact as ArtiSynth damps
        k_n = sim.tangent(x_n, a_n, project=not self.damping.exact_tangent) if beta > 0 else None
        contact = self.contact
        last_pairs: dict = {}  # contact pairs at the latest point where the gradient was evaluated
        if contact is not None:
            contact.set_pose(y_c)
        mass_coef = kappa + delta * alpha  # diagonal mass factor of the Hessian

        y = y_hat.copy()
        y[fixed] = y_c
        yhat_u = pattern.gather(y_hat)

        def damping_terms(y_full):
            """(C d restricted to free dofs, d^T C d) for d = y - x_n (all nodes)."""
            d = y_full - x_n
            du = pattern.gather(d)
            cd_u = alpha * m3 * du
            quad = alpha * float(np.einsum("i,ij,ij->", self.masses_kg[free], d[free], d[free]))
            if k_n is not None:
                kd = k_n.matvec(d)
                cd_u = cd_u + beta * pattern.gather(kd)
                quad += beta * float(np.sum(d * kd))
            return cd_u, quad

        def potential_and_gradient(y_full):
            e, f = sim.energy_and_forces(y_full, a)
            e_abs = float(np.abs(sim.last_element_energies()).sum())
            if contact is not None:
                pairs = contact.evaluate(y_full)
                last_pairs["x"], last_pairs["pairs"] = y_full, pairs
                e, f, e_abs = e + pairs.energy, f + pairs.forces(), e_abs + pairs.energy
            yu = pattern.gather(y_full)
            r = yu - yhat_u
            cd_u, quad = damping_terms(y_full)
            phi = 0.5 * kappa * float(np.sum(m3 * r * r)) + e + 0.5 * delta * quad
            grad = kappa * m3 * r - pattern.gather(f) + delta * cd_u
            if g_force is not None:
                phi -= float(g_force @ yu)
                grad = grad - g_force
            return phi, grad, e_abs

        def tangent_at(y_full, project: bool):
            tan = sim.tangent(y_full, a, project=project)
            if contact is None:
                return tan
            same = last_pairs.get("x") is y_full
            return ContactTangent(tan, last_pairs["pairs"] if same else contact.evaluate(y_full))

        phi, grad, e_abs = potential_and_gradient(y)
        residual = float(np.linalg.norm(grad))
        scale = max(residual, self._floor)
        stats = StepStats()
        factorizations0 = self._linear.factorizations
        skip_exact = False  # after a rejected exact Hessian, the next iteration goes straight to the projected K
        while residual > self.tol * scale and stats.newton_iterations < self.max_iterations:
            dx = None
            eta = float(np.clip(0.1 * residual / scale, 1e-12, 1e-2))  # inexact-Newton forcing (CG solves)
            attempted = self.stiffness == "exact" or (
                self.stiffness == "auto" and not skip_exact and residual < self._exact_below * scale
            )
            if attempted:
                try:
                    dx, its = self._solve(tangent_at(y, False), k_n, mass_coef, delta * beta, -grad, rtol=eta)
                    stats.cg_iterations += its
                    if not float(grad @ dx) < 0:
                        dx = None
                except NotPositiveDefiniteError:
                    if self.stiffness == "exact":
                        raise
                    dx = None
            skip_exact = attempted and dx is None
            stats.exact_failures += int(skip_exact)
            if dx is None:
                try:
                    dx, its = self._solve(tangent_at(y, True), k_n, mass_coef, delta * beta, -grad, rtol=eta)
                except NotPositiveDefiniteError:  # pragma: no cover - H is SPD by construction
                    dx, its = -grad / (mass_coef * m3), 0
                stats.cg_iterations += its
                stats.projected_steps += 1
            slope = float(grad @ dx)
            if not slope < 0:  # not a descent direction (round-off at the solution): stop
                break
            dx_full = pattern.scatter(dx)
            # Round-off of the potential: the sums themselves, and the cancellation in the flesh
            # energy density (I1~ - 3 ...), whose absolute error scales with mu V, not with E.
            slack = 64 * np.finfo(np.float64).eps * (e_abs + abs(phi)) + self._energy_noise
            t = 1.0
            accepted = False
            for _ in range(self.max_line_search):
                trial = y + t * dx_full
                phi_t, grad_t, e_abs_t = potential_and_gradient(trial)
                if np.isfinite(phi_t) and phi_t <= phi + 1e-4 * t * slope + slack:
                    # within the round-off band the energy cannot rank the points: ask for a
                    # smaller gradient as well
                    if phi_t <= phi + 1e-4 * t * slope or np.linalg.norm(grad_t) < residual:
                        accepted = True
                        break
                t *= 0.5
            stats.newton_iterations += 1
            if not accepted:
                break  # no decrease possible along dx: round-off floor reached
            stats.line_search_min = min(stats.line_search_min, t)
            y, phi, grad, e_abs = trial, phi_t, grad_t, e_abs_t
            residual = float(np.linalg.norm(grad))
        stats.residual_rel = residual / scale
        stats.converged = bool(residual <= self.tol * scale)
        self._exact_below = 0.1 if stats.exact_failures else 1.0
        stats.factorizations = self._linear.factorizations - factorizations0
        return y, stats

    def _solve(self, tangent, k_n, mass_coef: float, damp_coef: float, rhs: np.ndarray, rtol: float = 1e-10):
        """Solve (mass_coef M + damp_coef K_n + K) dx = rhs over the free dofs; returns (dx, cg its)."""
        before = self._linear.cg_iterations
        operator = _StepOperator(self, tangent, k_n, mass_coef, damp_coef)
        dx = self._linear.solve(operator, self._pattern, rhs, rtol=rtol)
        return dx, self._linear.cg_iterations - before

    def _diagonal_positions(self, H) -> np.ndarray:
        """Positions of the diagonal entries in the CSR data of the (fixed) free-node pattern."""
        if self._diag_positions is None or self._diag_positions[0] != H.nnz:
            rows = np.repeat(np.arange(H.shape[0]), np.diff(H.indptr))
            pos = np.flatnonzero(rows == H.indices)
            if pos.size != H.shape[0]:  # pragma: no cover - every node block is stored densely
                raise RuntimeError("stiffness pattern lacks diagonal entries")
            self._diag_positions = (H.nnz, pos)
        return self._diag_positions[1]

    def free(self) -> None:
        """Release the kept factorisation now."""
        self._linear.free()

    def __repr__(self) -> str:
        return (
            f"DynamicSimulator(scheme={self.scheme!r}, damping={self.damping}, engine={self.engine!r}, "
            f"tets={self.model.n_tets})"
        )


class _StepOperator:
    """The Newton matrix of one time step, H = K + damp_coef K_n + mass_coef M (lumped M), as an
    operator on nodal fields for ``wface.solvers.LinearSolver``."""

    def __init__(self, dyn: DynamicSimulator, tangent, k_n, mass_coef: float, damp_coef: float):
        self.dyn = dyn
        self.tangent = tangent
        self.k_n = k_n if (k_n is not None and damp_coef > 0) else None
        self.mass_coef = float(mass_coef)
        self.damp_coef = float(damp_coef)

    def matvec(self, v: np.ndarray) -> np.ndarray:
        out = self.tangent.matvec(v) + self.mass_coef * self.dyn.masses_kg[:, None] * v
        if self.k_n is not None:
            out = out + self.damp_coef * self.k_n.matvec(v)
        return out

    def diagonal(self) -> np.ndarray:
        diag = self.tangent.diagonal() + self.mass_coef * self.dyn.masses_kg[:, None]
        if self.k_n is not None:
            diag = diag + self.damp_coef * self.k_n.diagonal()
        return diag

    def assemble(self, pattern):
        dyn = self.dyn
        H = self.tangent.assemble(pattern)
        if self.k_n is not None:
            if dyn._kn_csr is None or dyn._kn_csr[0] is not self.k_n:
                dyn._kn_csr = (self.k_n, self.k_n.assemble(pattern))  # constant over the step: assemble once
            Kn = dyn._kn_csr[1]
            if np.array_equal(Kn.indptr, H.indptr) and np.array_equal(Kn.indices, H.indices):
                H.data += self.damp_coef * Kn.data  # same block pattern: add values in place
            else:  # pragma: no cover - defensive
                H = (H + self.damp_coef * Kn).tocsr()
                H.sort_indices()
        H.data[dyn._diagonal_positions(H)] += self.mass_coef * np.repeat(dyn.masses_kg[pattern.dof_nodes], 3)
        return H
