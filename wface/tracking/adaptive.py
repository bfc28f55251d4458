"""Adaptive factor and Jacobian reuse across a take (docs/design.md, "Performance").

A warm frame's equilibrium moves little from the previous frame's, so neither its stiffness factor
nor its Jacobian needs to be new every frame:

- Kept factor (adaptive refactorisation): the factor handed on from frame to frame serves the chord
  steps of every solve (``FaceRig.equilibrium(..., chord=, refactor=True)``); a solve refactors at its
  iterate only when a chord step contracts the residual by less than half
  (``wface.physics.newton``), and that new factor replaces the kept one.
- Kept Jacobian: after a Gauss-Newton step the Jacobian dY/dc of the previous equilibrium stays in
  use at the new one while the step achieved ``refresh`` of the decrease the linear model predicted
  and it is at most ``max_age`` frames old; else it is solved again at the new equilibrium with a
  factor taken there (the kept one when the solve made it this frame, at an iterate of the step).

The Jacobian only steers the Gauss-Newton steps and warm-starts the solves; the objective and the
stopping test use the exact equilibria, so a kept Jacobian changes the path, not what is fitted,
beyond the stopping test (measured in tests/test_adaptive_reuse.py and the track bench).
"""

from __future__ import annotations

import time

from wface.tracking.rig import FaceRig, RigLinearization, RigState

__all__ = ["carry_after_step", "carry_linearization", "is_adaptive", "jacobian_is_stale", "release_at_end"]


def is_adaptive(est) -> bool:
    """Does the ``FrameEstimator`` ``est`` keep factors and Jacobians across frames (its options, a direct solver)?"""
    opt = est.options
    return opt.reuse_factor and opt.factor_at == "adaptive" and est.rig.sim.linear_solver == "direct"


def carry_after_step(est, lin, state: RigState, achieved: float, predicted: float, timings: dict):
    """After a Gauss-Newton step of ``est`` to ``state`` that achieved ``achieved`` of the ``predicted``
    decrease: its linearisation there (``carry_linearization``; ``lin`` itself unless adaptive and full)."""
    if not (is_adaptive(est) and lin is not None and lin.full):
        return lin
    opt = est.options
    stale = jacobian_is_stale(achieved, predicted, lin.age, refresh=opt.jacobian_refresh, max_age=opt.max_jacobian_age)
    t = time.perf_counter()
    lin = carry_linearization(est.rig, lin, state, stale=stale)
    timings["jacobian_s"] += time.perf_counter() - t
    return lin


def release_at_end(est, near, lin) -> None:
    """At the end of a frame: free ``near`` (a factor at a prediction, or None); adaptive, the factor of a
    second pass's ``RowsLinearization`` is kept for the estimator's next frame (``est.keep_spare``)."""
    if near is not None:
        near.free()
    if is_adaptive(est) and lin is not None and not lin.full:
        est.keep_spare(lin.take_chord())


def jacobian_is_stale(achieved: float, predicted: float, age: int, *, refresh: float, max_age: int) -> bool:
    """Solve the Jacobian again? When the step achieved less than ``refresh`` of the decrease its
    linear model predicted, or the Jacobian has been kept ``max_age`` frames."""
    return age >= max_age or not (predicted > 0 and achieved >= refresh * predicted)


def carry_linearization(rig: FaceRig, lin: RigLinearization, state: RigState, *, stale: bool) -> RigLinearization:
    """The linearisation at the new equilibrium ``state`` from ``lin`` (at the previous one), which is
    consumed: its Jacobian kept with its factor (``stale`` False), or solved again at ``state`` with
    the factor made during this step when there is one (``fresh``), else with a new factor there."""
    chord = lin.take_chord()
    if not stale:
        return RigLinearization(state, lin.jy, chord, age=lin.age + 1)
    if chord is not None and not getattr(chord, "fresh", False):
        chord.free()  # from an earlier frame: factor at the new equilibrium instead
        chord = None
    if chord is not None:
        chord.fresh = False
    return rig.linearize(state, keep_factor=True, stiffness=chord)
