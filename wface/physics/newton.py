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

Relative residual (``Equilibrium.residual_rel``):
    ||f_U(x)||_2 / max(||f_U(X_load)||_2, f_floor),
where X_load is the rest shape with the attached nodes at their targets (the out-of-balance force
that the activations and the bone displacement cause on the undeformed face) and
f_floor = 1e-3 (mu10 + mu01) V^(2/3) (the force of a 0.1 % strain over the model's cross-section,
V = rest volume), which only matters when the load vanishes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wface.mesh.quality import count_inverted
from wface.physics.contact import ContactTangent
from wface.physics.frozen import FrozenContact
from wface.solvers import LinearSolver, NotPositiveDefiniteError

__all__ = ["Equilibrium", "newton_quasistatic"]


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
) -> Equilibrium:
    """Newton-Raphson for f_U(x, a) = 0 (see module docstring). ``sim`` is a ``Simulator``.

    ``contact``: an optional ``wface.physics.contact.Contact``. Its penalty energy joins the elastic
    energy (line search), its forces the residual and its Gauss-Newton Hessian the stiffness of every
    step (assembled and matrix-free paths); bone-following obstacles are placed from
    ``attached_positions``. The residual scale stays the elastic one of the load on the rest shape.
    """
    model = sim.model
    linear = LinearSolver(solver, sim.device, keep_factor=True, precondition=bool(reuse_factor))
    engine = linear.engine
    fixed = model.attached_nodes
    rest = model.rest_positions_m
    targets = rest[fixed] if attached_positions is None else np.asarray(attached_positions, dtype=np.float64)
    if targets.shape != (fixed.size, 3):
        raise ValueError(f"attached_positions has shape {targets.shape}, expected ({fixed.size}, 3)")
    pattern = sim.pattern("free")
    free = pattern.dof_nodes
    a = activations
    if contact is not None:
        contact.set_pose(targets)
    # the contact pairs at the latest energy_forces point; "live": the contact in use (the contact, or
    # its self-contact frozen, wface.physics.frozen)
    state = {"pairs": None, "x": None, "live": contact}

    def energy_only(y):
        if contact is None:
            return sim.energy(y, a)
        return sim.energy(y, a) + state["live"].energy(y)

    def energy_forces(y):
        """(E, f, sum |E_element|) at y, the contact terms included."""
        e, fy = sim.energy_and_forces(y, a)
        e_abs = float(np.abs(sim.last_element_energies()).sum())
        if contact is None:
            return e, fy, e_abs
        pairs = state["live"].evaluate(y)
        state["pairs"], state["x"] = pairs, y.copy()
        return e + pairs.energy, fy + pairs.forces(), e_abs + pairs.energy

    def tangent_at(y, project=True):
        tan = sim.tangent(y, a, project=project)
        if contact is None:
            return tan
        same = state["pairs"] is not None and np.array_equal(state["x"], y)
        return ContactTangent(tan, state["pairs"] if same else state["live"].evaluate(y))

    x_load = rest.copy()
    x_load[fixed] = targets
    mat = model.material
    floor = 1e-3 * (mat.mu10_pa + mat.mu01_pa) * float(model.rest_volume_m3.sum()) ** (2.0 / 3.0)
    scale = max(float(np.linalg.norm(sim.forces(x_load, a)[free])), floor)

    x = rest.copy() if x0 is None else np.array(x0, dtype=np.float64)
    iterations = 0
    history: list[float] = []
    steps: list[float] = []

    dxc = targets - x[fixed]
    if fixed.size and np.any(dxc != 0.0):
        # Lift: move the attached nodes to their targets and the free ones by the linear response.
        tan = tangent_at(x)
        f = sim.forces(x, a) if contact is None else energy_forces(x)[1]
        v = np.zeros_like(x)
        v[fixed] = dxc
        coupling = tan.matvec(v)  # K_{., C} dx_C
        rhs = pattern.gather(f - coupling)
        history.append(float(np.linalg.norm(rhs)) / scale)
        dx = linear.solve(tan, pattern, rhs, rtol=1e-6)
        x[fixed] = targets
        x[free] += dx.reshape(-1, 3)
        iterations += 1

    energy, f, energy_abs = energy_forces(x)
    residual = float(np.linalg.norm(f[free]))
    history.append(residual / scale)
    if stiffness not in ("auto", "projected", "exact"):
        raise ValueError(f"stiffness must be 'auto', 'projected' or 'exact', got {stiffness!r}")
    exact_retry_below = exact_below  # after a failed exact attempt: retry once the residual fell 3x
    exact_failures = 0
    projected_steps = 0
    freeze_below = getattr(contact, "freeze_below", None) if contact is not None else None
    if freeze_below is not None and not contact.self_contact:
        freeze_below = None
    frozen_at = None  # iteration at which the current frozen features were taken
    refreezes = 0

    def freeze():
        state["live"] = FrozenContact(contact, x, margin_m=contact.freeze_margin_m)
        return energy_forces(x)

    while iterations < max_iterations:
        stale = frozen_at is not None and getattr(state["live"], "last_stale", 0) > 0
        if frozen_at is not None and (residual / scale <= tol or stale or iterations - frozen_at >= refreeze_every):
            # the frozen problem converged (or is taking long): re-detect the pairs at x
            state["live"] = contact
            energy, f, energy_abs = energy_forces(x)
            residual = float(np.linalg.norm(f[free]))
            history[-1] = residual / scale
            if residual / scale <= tol:
                frozen_at = None
                break
            energy, f, energy_abs = freeze()
            frozen_at, refreezes = iterations, refreezes + 1
        if residual / scale <= tol:
            break
        if freeze_below is not None and frozen_at is None and residual / scale < freeze_below:
            energy, f, energy_abs = freeze()
            frozen_at = iterations
        rhs = pattern.gather(f)
        eta = float(np.clip(0.1 * residual / scale, 1e-12, 1e-2))
        dx = None
        attempted = stiffness == "exact" or (stiffness == "auto" and residual / scale < exact_retry_below)
        if attempted:
            tan = tangent_at(x, project=False)
            try:
                dx = linear.solve(tan, pattern, rhs, rtol=eta)
                if not float(rhs @ dx) > 0:
                    dx = None
            except NotPositiveDefiniteError:
                if stiffness == "exact":
                    raise
                dx = None
        if attempted and dx is None:
            exact_failures += 1
            exact_retry_below = min(exact_retry_below, residual / scale / 3.0)
        if dx is None:
            tan = tangent_at(x)
            dx = linear.solve(tan, pattern, rhs, rtol=eta)
            projected_steps += 1
        dx = dx.reshape(-1, 3)
        slope = float(rhs @ dx.reshape(-1))  # -dE/dt at t = 0 (> 0 for a descent direction)
        if not slope > 0:  # not a descent direction (should not happen with SPD K): steepest descent
            dx = f[free] / max(float(np.abs(tan.diagonal()[free]).max()), 1e-30)
            slope = float(rhs @ dx.reshape(-1))
        slack = (
            64 * np.finfo(np.float64 if sim.precision == "float64" else np.float32).eps * energy_abs
        )  # round-off of the energy sum
        t = 1.0
        trial = x.copy()
        for _ in range(max_line_search):
            trial[free] = x[free] + t * dx
            e_trial = energy_only(trial)
            if np.isfinite(e_trial) and e_trial <= energy - 1e-4 * t * slope + slack:
                break
            t *= 0.5
        x = trial
        steps.append(t)
        iterations += 1
        energy, f, energy_abs = energy_forces(x)
        residual = float(np.linalg.norm(f[free]))
        history.append(residual / scale)

    if frozen_at is not None:  # report the true contact state
        state["live"] = contact
        energy, f, energy_abs = energy_forces(x)
        residual = float(np.linalg.norm(f[free]))
        history[-1] = residual / scale
    linear.free()
    extra = {}
    if contact is not None:
        stats = state["pairs"].stats()
        extra = {
            "contact_refreezes": refreezes,
            "contact_active_nodes": stats["active_nodes"],
            "contact_max_penetration_m": stats["max_penetration_m"],
            "contact_force_n": stats["force_n"],
            "contact_energy": state["pairs"].energy,
            "contact_stats": stats["sources"],
        }
    return Equilibrium(
        x=x,
        converged=bool(residual / scale <= tol),
        iterations=iterations,
        residual_rel=residual / scale,
        residual_abs=residual,
        force_scale=scale,
        inverted_elements=count_inverted(model, x),
        energy=energy,
        cg_iterations=linear.cg_iterations,
        projected_steps=projected_steps,
        factorizations=linear.factorizations,
        exact_failures=exact_failures,
        solver=engine,
        history=history,
        step_lengths=steps,
        **extra,
    )
