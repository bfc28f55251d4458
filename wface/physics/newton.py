"""Quasistatic Newton-Raphson with an energy line search (Sifakis et al. 2005, section 4; docs/design.md "Newton").

Unknowns: the free nodes U (not attached to a bone). Attached nodes C are Dirichlet nodes placed
at their bone positions. Each step solves K_UU dx = f_U(x) with the projected, definite stiffness
and backtracks on the total energy (Armijo). When the start configuration's attached nodes differ
from their targets, a first "lift" step moves them there and the free nodes by the linearised
response K_UU dx_U = f_U(x) - K_UC dx_C, which carries bone motion smoothly into the flesh.

Stiffness (``stiffness=``): "projected" uses the Teran et al. 2005 projected-definite K every step;
"auto" (default) uses the projected K while the relative residual is above ``exact_below`` (0.1) and
then tries the exact Hessian, which gives quadratic convergence near the solution, falling back to
the projected K for that step when the exact K_UU is not positive definite (the Cholesky
factorisation or CG reports it) or the step is not a descent direction; after such a failure at
relative residual r the exact K is tried again only once the residual is below r / 3 (on the Badin
face's full risorius pose: 4 failed attempts instead of 10, same 35 iterations). Measured on the
built-in face (20K tets, jaw 5-25 deg, up to all 35 muscles at 1): the same Newton iteration counts
as trying the exact K from the start, without its failed factorisations, and 1.5-1.7x fewer
iterations than "projected" alone.

Chord steps (``chord=``): a factor of K_UU at a nearby configuration (the tracker hands on the
factor of its last Jacobian, at the previous equilibrium) replaces the fresh factorisation: the lift
and the Newton steps solve with it, back-solves only (a chord, or modified, Newton method with the
energy line search). The chord is dropped, and ordinary Newton steps follow, as soon as a chord step
is cut by the line search, is not a descent direction, or reduces the residual by less than
``chord_rate`` (0.5): its linear rate has become too slow for the back-solves to pay. With
``refactor=`` (a callable x -> a new chord, e.g. the tracker's factor of the exact tangent at x) such
a step refactors at the iterate instead and the chord steps go on with the new factor (adaptive
refactorisation, docs/design.md "Performance"): with it, a step contracting by more than half still
keeps the factor while at its rate at most ``CHORD_STEPS_AHEAD`` (3) more steps reach ``tol`` (a
refactorisation costs several force evaluations); the result hands the new factor back
(``Equilibrium.new_chord``), so that a caller can keep it for the next solves.

Relative residual (``Equilibrium.residual_rel``):
    ||f_U(x)||_2 / max(||f_U(X_load)||_2, f_floor),
where X_load is the rest shape with the attached nodes at their targets (the out-of-balance force
that the activations and the bone displacement cause on the undeformed face) and
f_floor = 1e-3 (mu10 + mu01) V^(2/3) (the force of a 0.1 % strain over the model's cross-section,
V = rest volume), which only matters when the load vanishes. A caller may pass its own
denominator (``force_scale=``), e.g. the tracker's linearised load (``FaceRig.load_force_scale``),
which saves the force evaluation at X_load.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wface.mesh.quality import count_inverted
from wface.physics.contact_tangent import ContactTangent
from wface.physics.frozen import FrozenContact
from wface.solvers import LinearSolver, NotPositiveDefiniteError

__all__ = ["Equilibrium", "decrease_from_slopes", "newton_quasistatic"]


def decrease_from_slopes(start_slope: float, end_slope: float, size: float) -> float:
    """E(x + dx) - E(x) by the trapezoid rule on dE/dt at both ends of the step (exact on a quadratic),
    where the decrease (~start_slope / 2) is below 1e-9 of ``size``, the energy's magnitude, whose sum
    of per-element terms cannot resolve it (``_NewtonRun._decrease_from_forces``); +inf elsewhere."""
    if not -start_slope <= 1e-9 * size:
        return np.inf
    return 0.5 * (start_slope + end_slope)


CHORD_STEPS_AHEAD = 3  # adaptive refactorisation: refactor when more chord steps than this remain at the rate
MAX_STEPS_ON_FACTOR = 8  # ... or after this many chord steps on one factor


@dataclass
class Equilibrium:
    """Result of a quasistatic solve.

    Attributes:
        x: (n, 3) equilibrium positions, metres.
        converged: residual_rel <= tol was reached.
        iterations: Newton iterations (linear solves with K), the lift step included.
        residual_rel: relative force residual at x (module docstring).
        residual_abs: ||f_U(x)||_2 in newtons.
        force_scale: the denominator of residual_rel, newtons.
        inverted_elements: tets with det F <= 0 at x.
        energy: total elastic energy at x, joules.
        cg_iterations: CG iterations over all Newton steps (0 for the direct solver).
        back_solves: right-hand sides solved with a factor (fresh or the chord's).
        chord_steps: steps (the lift included) solved with the ``chord`` factor.
        projected_steps: Newton steps that used the projected stiffness.
        exact_failures: exact-Hessian attempts rejected (not positive definite / not descent).
        factorizations: sparse factorisations done (direct solver; later steps first try CG
            preconditioned by the previous factor).
        solver: linear engine used ("direct" or "cg").
        history: residual_rel after each iteration (first entry: the start).
        step_lengths: line-search step t of each Newton iteration after the lift (1 = full step).
        seconds: wall-clock time of the solve.
        contact_active_nodes: with ``contact``: nodes in contact at x (0 without contact).
        contact_max_penetration_m: deepest penetration g = gap - phi at x, metres.
        contact_force_n: sum of the contact normal force magnitudes k g at x, newtons.
        contact_energy: penalty energy at x, joules (included in ``energy``).
        contact_stats: the same per contact source (``wface.physics.contact.ContactPairs.stats``).
        contact_refreezes: times the frozen self-contact features were re-detected and frozen anew
            (``Contact(freeze_below=...)``, ``wface.physics.frozen``).
        new_chord: with ``refactor``: the last factor it made (owned by the caller from here), or None.
        refactorizations: factors made by ``refactor`` (not in ``factorizations``: the caller counts them).
    """

    x: np.ndarray
    converged: bool
    iterations: int
    residual_rel: float
    residual_abs: float
    force_scale: float
    inverted_elements: int
    energy: float
    cg_iterations: int = 0
    back_solves: int = 0
    chord_steps: int = 0
    projected_steps: int = 0
    factorizations: int = 0
    exact_failures: int = 0
    solver: str = "direct"
    history: list = field(default_factory=list)
    step_lengths: list = field(default_factory=list)
    seconds: float = 0.0
    contact_active_nodes: int = 0
    contact_max_penetration_m: float = 0.0
    contact_force_n: float = 0.0
    contact_energy: float = 0.0
    contact_stats: dict = field(default_factory=dict)
    contact_refreezes: int = 0
    new_chord: object | None = None
    refactorizations: int = 0


def newton_quasistatic(
    sim,
    activations: np.ndarray,
    attached_positions: np.ndarray | None,
    x0: np.ndarray | None,
    *,
    tol: float = 1e-6,
    max_iterations: int = 40,
    solver: str = "auto",
    max_line_search: int = 30,
    refreeze_every: int = 8,
    stiffness: str = "auto",
    reuse_factor: bool = False,
    exact_below: float = 0.1,
    contact=None,
    chord=None,
    chord_rate: float = 0.5,
    factor_precision: str = "float64",
    refactor=None,
    max_refactors: int = 2,
    force_scale: float | None = None,
    twin=None,
) -> Equilibrium:
    """Newton-Raphson for f_U(x, a) = 0 (see module docstring). ``sim`` is a ``Simulator``.

    ``contact``: an optional ``wface.physics.contact.Contact``. Its penalty energy joins the elastic
    energy (line search), its forces the residual and its Gauss-Newton Hessian the stiffness of every
    step (assembled and matrix-free paths); bone-following obstacles are placed from
    ``attached_positions``. The residual scale stays the elastic one of the load on the rest shape.

    ``chord``: a factor of K_UU at a nearby configuration for chord steps (module docstring): an
    object with ``solve(rhs)`` ((3k,) -> (3k,) over the free nodes) and ``coupling(dx_c)`` (K_UC dx_C
    for attached-node moves dx_C (a, 3), (3k,)), such as ``Simulator.stiffness_solver``'s.
    ``factor_precision``: of the direct solver's factors ("float32": inexact Newton steps, 1.5x
    cheaper factorisations; ``wface.solvers.LinearSolver``).
    ``refactor``: with ``chord``, a callable x (n, 3) -> a new chord factored at x (or None), called at
    most ``max_refactors`` times where the chord contracts poorly (module docstring); the newest one is
    ``Equilibrium.new_chord``, the older ones are freed here. ``force_scale``: the residual's
    denominator in newtons (default: ||f_U(X_load)||, module docstring). ``twin``: a single-precision
    ``Simulator`` of the same model whose energies and forces serve the residuals and the line search
    (about 2x cheaper on the CPU; its forces read a float64 equilibrium's residual as ~1e-5 of the load,
    so it suits tolerances of 1e-4, not 1e-6: docs/design.md, "Performance"); ignored with contact.
    """
    model = sim.model
    linear = LinearSolver(
        solver, sim.device, keep_factor=True, precondition=bool(reuse_factor), factor_precision=factor_precision
    )
    engine = linear.engine
    fixed = model.attached_nodes
    rest = model.rest_positions_m
    targets = rest[fixed] if attached_positions is None else np.asarray(attached_positions, dtype=np.float64)
    if targets.shape != (fixed.size, 3):
        raise ValueError(f"attached_positions has shape {targets.shape}, expected ({fixed.size}, 3)")
    pattern = sim.pattern("free")
    if contact is not None:
        contact.set_pose(targets)
    problem = _Problem(sim, activations, contact, twin=twin if contact is None else None)
    scale = _force_scale(sim, activations, targets, pattern.dof_nodes) if force_scale is None else float(force_scale)
    x = rest.copy() if x0 is None else np.array(x0, dtype=np.float64)
    run = _NewtonRun(problem, linear, pattern, scale, x)
    run.chord, run.chord_rate = chord, float(chord_rate)
    run.refactor, run.refactors_left = (refactor if chord is not None else None), int(max_refactors)
    run.lift(fixed, targets)
    run.evaluate()
    run.history.append(run.residual / scale)
    if stiffness not in ("auto", "projected", "exact"):
        raise ValueError(f"stiffness must be 'auto', 'projected' or 'exact', got {stiffness!r}")
    freeze_below = getattr(contact, "freeze_below", None) if contact is not None else None
    if freeze_below is not None and not contact.self_contact:
        freeze_below = None
    run.tol = float(tol)
    run.iterate(
        tol=tol,
        max_iterations=max_iterations,
        max_line_search=max_line_search,
        refreeze_every=refreeze_every,
        stiffness=stiffness,
        exact_below=exact_below,
        freeze_below=freeze_below,
    )
    if run.frozen_at is not None:  # report the true contact state
        run.unfreeze()
    linear.free()
    return run.result(tol, engine)


def _force_scale(sim, a, targets: np.ndarray, free: np.ndarray) -> float:
    """The denominator of the relative residual (module docstring)."""
    model = sim.model
    x_load = model.rest_positions_m.copy()
    x_load[model.attached_nodes] = targets
    mat = model.material
    floor = 1e-3 * (mat.mu10_pa + mat.mu01_pa) * float(model.rest_volume_m3.sum()) ** (2.0 / 3.0)
    return max(float(np.linalg.norm(sim.forces(x_load, a)[free])), floor)


class _Problem:
    """Energy, forces and stiffness of the elastic face plus the optional contact at activations ``a``."""

    def __init__(self, sim, a, contact, twin=None):
        self.sim, self.a, self.contact = sim, a, contact
        self.esim = twin if twin is not None else sim  # energies and forces (a float32 twin, or sim itself)
        # the contact pairs at the latest energy_forces point; "live": the contact in use (the contact, or
        # its self-contact frozen, wface.physics.frozen)
        self.pairs, self.pairs_x, self.live = None, None, contact

    def energy(self, y):
        """Total energy at y (line search)."""
        if self.contact is None:
            return self.esim.energy(y, self.a)
        return self.sim.energy(y, self.a) + self.live.energy(y)

    def energy_forces(self, y):
        """(E, f, sum |E_element|) at y, the contact terms included."""
        e, fy = self.esim.energy_and_forces(y, self.a)
        e_abs = float(np.abs(self.esim.last_element_energies()).sum())
        if self.contact is None:
            return e, fy, e_abs
        pairs = self.live.evaluate(y)
        self.pairs, self.pairs_x = pairs, y.copy()
        return e + pairs.energy, fy + pairs.forces(), e_abs + pairs.energy

    def tangent(self, y, project=True):
        """The stiffness at y; the contact's reuses the pairs of the last ``energy_forces`` at y."""
        tan = self.sim.tangent(y, self.a, project=project)
        if self.contact is None:
            return tan
        same = self.pairs is not None and np.array_equal(self.pairs_x, y)
        return ContactTangent(tan, self.pairs if same else self.live.evaluate(y))


class _NewtonRun:
    """The iterate and the counters of one ``newton_quasistatic`` call."""

    def __init__(self, problem: _Problem, linear: LinearSolver, pattern, scale: float, x: np.ndarray):
        self.problem, self.linear, self.pattern, self.scale = problem, linear, pattern, scale
        self.free = pattern.dof_nodes
        self.x = x
        self.iterations = 0
        self.history: list[float] = []
        self.steps: list[float] = []
        self.energy = self.f = self.energy_abs = self.residual = None
        self.exact_retry_below = 0.0
        self.exact_failures = 0
        self.projected_steps = 0
        self.frozen_at = None  # iteration at which the current frozen features were taken
        self.refreezes = 0
        self.chord, self.chord_rate, self.chord_steps = None, 0.5, 0
        self.refactor, self.refactors_left, self.new_chord, self.refactorizations = None, 0, None, 0
        self.steps_on_factor = 0
        self.twin_dropped = False  # the float32 twin gave way to float64 (``step``)
        self.anderson = _Anderson(depth=5)
        self.tol = 0.0
        self._accepted = None  # (energy, forces, sum |E|) at the line search's accepted point, when known

    def lift(self, fixed: np.ndarray, targets: np.ndarray) -> None:
        """The lift step (module docstring) when the attached nodes are not at their targets."""
        problem, x, free = self.problem, self.x, self.free
        dxc = targets - x[fixed]
        if fixed.size and np.abs(dxc).max() <= 1e-12 * max(float(np.ptp(targets, axis=0).max()), 1e-30):
            x[fixed] = targets  # already there up to round-off (a linear prediction at the targets)
            dxc = np.zeros_like(dxc)
        if fixed.size and np.any(dxc != 0.0):
            # Lift: move the attached nodes to their targets and the free ones by the linear response.
            f = problem.sim.forces(x, problem.a) if problem.contact is None else problem.energy_forces(x)[1]
            if self.chord is not None:  # K_UC dx_C and K_UU^-1 from the nearby configuration
                rhs = self.pattern.gather(f) - self.chord.coupling(dxc)
                self.history.append(float(np.linalg.norm(rhs)) / self.scale)
                dx = self.chord.solve(rhs)
                self.chord_steps += 1
            else:
                tan = problem.tangent(x)
                v = np.zeros_like(x)
                v[fixed] = dxc
                rhs = self.pattern.gather(f - tan.matvec(v))  # f_U - K_UC dx_C
                self.history.append(float(np.linalg.norm(rhs)) / self.scale)
                dx = self.linear.solve(tan, self.pattern, rhs, rtol=1e-6)
            x[fixed] = targets
            x[free] += dx.reshape(-1, 3)
            self.iterations += 1

    def evaluate(self) -> None:
        """Energy, forces and residual at the iterate (kept from the line search when it has them)."""
        known, self._accepted = self._accepted, None
        self.energy, self.f, self.energy_abs = known if known is not None else self.problem.energy_forces(self.x)
        self.residual = float(np.linalg.norm(self.f[self.free]))

    def freeze(self) -> None:
        """Take the self-contact features at the iterate as fixed (``wface.physics.frozen``)."""
        problem = self.problem
        problem.live = FrozenContact(problem.contact, self.x, margin_m=problem.contact.freeze_margin_m)
        self.energy, self.f, self.energy_abs = problem.energy_forces(self.x)

    def unfreeze(self) -> None:
        """Back to the true (re-detected) contact at the iterate; the last residual becomes its residual."""
        self.problem.live = self.problem.contact
        self.evaluate()
        self.history[-1] = self.residual / self.scale

    def iterate(self, *, tol, max_iterations, max_line_search, refreeze_every, stiffness, exact_below, freeze_below):
        """Newton steps until converged or ``max_iterations``, freezing and re-detecting self-contact."""
        scale = self.scale
        self.exact_retry_below = exact_below  # after a failed exact attempt: retry once the residual fell 3x
        while self.iterations < max_iterations:
            stale = self.frozen_at is not None and getattr(self.problem.live, "last_stale", 0) > 0
            if self.frozen_at is not None and (
                self.residual / scale <= tol or stale or self.iterations - self.frozen_at >= refreeze_every
            ):
                # the frozen problem converged (or is taking long): re-detect the pairs at x
                self.unfreeze()
                if self.residual / scale <= tol:
                    self.frozen_at = None
                    break
                self.freeze()
                self.frozen_at, self.refreezes = self.iterations, self.refreezes + 1
            if self.residual / scale <= tol:
                break
            if freeze_below is not None and self.frozen_at is None and self.residual / scale < freeze_below:
                self.freeze()
                self.frozen_at = self.iterations
            self.step(max_line_search, stiffness)

    def step(self, max_line_search: int, stiffness: str) -> None:
        """One Newton (or chord) step with the line search."""
        free = self.free
        rhs = self.pattern.gather(self.f)
        chord = self.chord is not None
        if chord:
            g = self.chord.solve(rhs)  # the plain chord step
            if not float(rhs @ g) > 0:  # not a descent direction: no more chord steps
                self.chord, chord = None, False
            else:
                dx = self.anderson.step(self.x[free].reshape(-1), g)
                if not float(rhs @ dx) > 0:
                    dx = g
                    self.anderson.reset()
        if not chord:
            dx, tan = self.direction(rhs, stiffness)
        dx = dx.reshape(-1, 3)
        slope = float(rhs @ dx.reshape(-1))  # -dE/dt at t = 0 (> 0 for a descent direction)
        if not slope > 0:  # not a descent direction (should not happen with SPD K): steepest descent
            dx = self.f[free] / max(float(np.abs(tan.diagonal()[free]).max()), 1e-30)
            slope = float(rhs @ dx.reshape(-1))
        before = self.residual
        self.x, t = self.line_search(dx, slope, max_line_search)
        self.steps.append(t)
        self.iterations += 1
        self.evaluate()
        self.history.append(self.residual / self.scale)
        if self.problem.esim is not self.problem.sim and (t < 1.0 or not self.residual < before):
            # the float32 twin's round-off stalls the step (its energy cannot see the decrease, or its
            # forces are at their noise floor): float64 from here, re-read at the iterate
            self.problem.esim = self.problem.sim
            self.twin_dropped = True
            self.evaluate()
            self.history[-1] = self.residual / self.scale
            if chord:
                self.chord_steps += 1
                self.steps_on_factor += 1
            return
        if chord:
            self.chord_steps += 1
            self.steps_on_factor += 1
            if self.refactor is not None:  # adaptive: refactor only when the chord will not get there soon
                if self.chord_too_slow(t, self.residual / max(before, 1e-300)):
                    self.chord = None
                    self.refactor_chord()
            elif t < 1.0 or self.residual > self.chord_rate * before:
                self.chord = None  # the chord's linear rate no longer pays: Newton from here

    def chord_too_slow(self, t: float, rate: float) -> bool:
        """Adaptive refactorisation's test: a cut step, no contraction, more than ``CHORD_STEPS_AHEAD``
        further steps to ``tol`` at this step's rate, or ``MAX_STEPS_ON_FACTOR`` steps on one factor. A
        refactorisation costs about as much as 7 force evaluations at 100K tets (docs/design.md,
        "Performance"), a chord step one."""
        if t < 1.0 or not rate < 1.0 or self.steps_on_factor >= MAX_STEPS_ON_FACTOR:
            return True
        if rate <= self.chord_rate:
            return False
        ahead = np.log(max(self.tol * self.scale, 1e-300) / max(self.residual, 1e-300)) / np.log(rate)
        return ahead > CHORD_STEPS_AHEAD

    def refactor_chord(self) -> None:
        """Adaptive refactorisation: a new chord factored at the iterate (``refactor``), while allowed."""
        if self.refactor is None or self.refactors_left <= 0 or self.residual / self.scale <= self.tol:
            return
        new = self.refactor(self.x)
        if new is None:
            self.refactor = None
            return
        if self.new_chord is not None:
            self.new_chord.free()  # an earlier one of this solve: superseded
        self.chord = self.new_chord = new
        self.steps_on_factor = 0
        self.refactors_left -= 1
        self.refactorizations += 1
        self.anderson.reset()

    def direction(self, rhs: np.ndarray, stiffness: str):
        """The Newton direction and the stiffness it solved with: the exact K when it is tried and
        works (module docstring), else the projected K."""
        residual, scale, x = self.residual, self.scale, self.x
        eta = float(np.clip(0.1 * residual / scale, 1e-12, 1e-2))
        dx = None
        attempted = stiffness == "exact" or (
            stiffness == "auto" and residual / scale < self.exact_retry_below and self.linear.exact_tangents_ok
        )
        if attempted:
            tan = self.problem.tangent(x, project=False)
            try:
                dx = self.linear.solve(tan, self.pattern, rhs, rtol=eta)
                if not float(rhs @ dx) > 0:
                    dx = None
            except NotPositiveDefiniteError:
                if stiffness == "exact":
                    raise
                dx = None
        if attempted and dx is None:
            self.exact_failures += 1
            self.exact_retry_below = min(self.exact_retry_below, residual / scale / 3.0)
        if dx is None:
            tan = self.problem.tangent(x)
            dx = self.linear.solve(tan, self.pattern, rhs, rtol=eta)
            self.projected_steps += 1
        return dx, tan

    def line_search(self, dx: np.ndarray, slope: float, max_line_search: int):
        """Backtracking (Armijo) on the total energy: the new iterate and its step length t."""
        x, free, energy = self.x, self.free, self.energy
        sim = self.problem.esim
        slack = (
            64 * np.finfo(np.float64 if sim.precision == "float64" else np.float32).eps * self.energy_abs
        )  # round-off of the energy sum
        t = 1.0
        trial = x.copy()
        for k in range(max_line_search):
            trial[free] = x[free] + t * dx
            if k == 0:  # the full step is usually taken: its forces come in the same pass
                full = self.problem.energy_forces(trial)
                e_trial = full[0]
            else:
                e_trial = self.problem.energy(trial)
            if np.isfinite(e_trial) and e_trial <= energy - 1e-4 * t * slope + slack:
                self._accepted = full if k == 0 else None
                break
            if k == 0 and np.isfinite(e_trial) and self._decrease_from_forces(full[1], dx, slope) <= -1e-4 * slope:
                self._accepted = full  # the energy cannot see the decrease; its slope along the step can
                break
            t *= 0.5
        return trial, t

    def _decrease_from_forces(self, f_trial: np.ndarray, dx: np.ndarray, slope: float) -> float:
        """E(x + dx) - E(x) from the slopes at both ends (the trapezoid rule, exact on a quadratic),
        where the step is too small for the energy sum to resolve; +inf elsewhere.

        Near the solution a Newton step lowers the energy by ~slope / 2, which falls below the round-off
        of the energy, a sum of per-element terms many times larger (1e-18 J against 4e-5 J on the
        pressurised bar test): the Armijo test on the energy then rejects good steps by chance, and
        Newton stalls at a residual of ~1e-7 (which one depended on the MKL release, through the
        last bits of the steps). The trapezoid reads the decrease from forces, with no cancellation;
        its error is third order in the step, negligible where it is used (slope below 1e-9 of the
        energy's size)."""
        size = max(abs(self.energy), self.energy_abs or 0.0)
        if not slope <= 1e-9 * size:
            return np.inf
        end_slope = float(self.pattern.gather(f_trial) @ dx.reshape(-1))  # -dE/dt at t = 1
        return decrease_from_slopes(-slope, -end_slope, size)

    def result(self, tol: float, engine: str) -> Equilibrium:
        """The ``Equilibrium`` at the iterate."""
        problem, linear, residual, scale, x = self.problem, self.linear, self.residual, self.scale, self.x
        extra = {}
        if problem.contact is not None:
            stats = problem.pairs.stats()
            extra = {
                "contact_refreezes": self.refreezes,
                "contact_active_nodes": stats["active_nodes"],
                "contact_max_penetration_m": stats["max_penetration_m"],
                "contact_force_n": stats["force_n"],
                "contact_energy": problem.pairs.energy,
                "contact_stats": stats["sources"],
            }
        return Equilibrium(
            x=x,
            converged=bool(residual / scale <= tol),
            iterations=self.iterations,
            residual_rel=residual / scale,
            residual_abs=residual,
            force_scale=scale,
            inverted_elements=count_inverted(problem.sim.model, x),
            energy=self.energy,
            cg_iterations=linear.cg_iterations,
            back_solves=linear.back_solves + self.chord_steps,
            chord_steps=self.chord_steps,
            projected_steps=self.projected_steps,
            factorizations=linear.factorizations,
            exact_failures=self.exact_failures,
            solver=engine,
            history=self.history,
            step_lengths=self.steps,
            new_chord=self.new_chord,
            refactorizations=self.refactorizations,
            **extra,
        )


class _Anderson:
    """Anderson acceleration of the chord iteration x <- x + g(x), g = F^-1 f_U(x) (F: the chord's
    factor): the next step is g - (dX + dG) gamma with gamma = argmin |g - dG gamma| over the last
    ``depth`` differences of iterates (dX) and of chord steps (dG). On a linear problem this is GMRES on
    F^-1 K (Walker & Ni 2011), much faster than the chord's linear rate when F is an older stiffness."""

    def __init__(self, depth: int = 5):
        self.depth = int(depth)
        self.reset()

    def reset(self) -> None:
        self.xs: list[np.ndarray] = []
        self.gs: list[np.ndarray] = []

    def step(self, x: np.ndarray, g: np.ndarray) -> np.ndarray:
        """The accelerated step from iterate x (3k,) with chord step g (3k,)."""
        self.xs.append(np.array(x, dtype=np.float64))
        self.gs.append(np.array(g, dtype=np.float64))
        if len(self.xs) > self.depth + 1:
            self.xs.pop(0)
            self.gs.pop(0)
        if len(self.xs) < 2:
            return g
        dX = np.stack([b - a for a, b in zip(self.xs[:-1], self.xs[1:], strict=True)], axis=1)
        dG = np.stack([b - a for a, b in zip(self.gs[:-1], self.gs[1:], strict=True)], axis=1)
        scale = np.linalg.norm(dG, axis=0)
        scale[scale == 0] = 1.0
        gamma = np.linalg.lstsq(dG / scale, g, rcond=1e-10)[0] / scale
        return g - (dX + dG) @ gamma
