"""Quasistatic solves with contact, restarted: Newton in rounds, each round trying the exact Hessian anew.

``wface.physics.newton`` tries the exact Hessian below a relative residual of 0.1 and, after a
failed attempt (not positive definite or no descent), again only once the residual has fallen 3x
below the failure. With lip contact the early iterates press the lips deep (large contact forces:
the exact contact Hessian -Psi' hess phi is then strongly indefinite) and fail; the projected steps
that follow converge only linearly where the lips' soft sliding modes are softened by the contact
curvature (Badin lip-pressing pose: along the softest mode the elastic stiffness is 1.0 N/m, the
contact curvature -0.9 N/m, the Gauss-Newton contact term +0.08 N/m), so the residual may never fall
below the retry threshold. Restarting Newton from its iterate every ``restart_every`` iterations
resets that threshold; near the solution the exact Hessian is definite and the restarted round
converges quadratically. Measured on the Badin lip-pressing pose (full OOP and MENT, smooth lips):
one run of 60 iterations ends at 3e-4 (55 projected steps); restarted every 20, 2e-4 after 80;
every 5, 6e-9 after 56, the last four iterations 8e-4, 8e-6, 3e-6, 6e-9.
"""

from __future__ import annotations

from dataclasses import replace

__all__ = ["solve_restarted"]


def solve_restarted(
    sim,
    activations=None,
    attached_positions=None,
    x0=None,
    *,
    tol: float = 1e-6,
    max_iterations: int = 60,
    restart_every: int = 5,
    **kwargs,
):
    """``sim.solve`` in rounds of at most ``restart_every`` Newton iterations, each from the last
    iterate, until ``tol`` or ``max_iterations`` in all (module docstring). Other keyword arguments
    (``contact``, ``stiffness``, ...) go to ``Simulator.solve``.

    Returns:
        The last round's ``Equilibrium`` with iterations, history, step lengths, projected steps,
        exact failures, factorisations and seconds summed over the rounds.
    """
    if int(restart_every) < 1:
        raise ValueError(f"restart_every must be >= 1, got {restart_every}")
    total = None
    x = x0
    while True:
        budget = max_iterations - (0 if total is None else total.iterations)
        eq = sim.solve(activations, attached_positions, x, tol=tol, max_iterations=min(restart_every, budget), **kwargs)
        if total is not None:
            eq = replace(
                eq,
                iterations=total.iterations + eq.iterations,
                history=total.history + eq.history[1:],
                step_lengths=total.step_lengths + eq.step_lengths,
                projected_steps=total.projected_steps + eq.projected_steps,
                exact_failures=total.exact_failures + eq.exact_failures,
                factorizations=total.factorizations + eq.factorizations,
                seconds=total.seconds + eq.seconds,
            )
        total = eq
        if eq.converged or eq.iterations >= max_iterations or eq.iterations == 0:
            return eq
        x = eq.x
