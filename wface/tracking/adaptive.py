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

import numpy as np

from wface.tracking.rig import FaceRig, RigLinearization, RigState

__all__ = [
    "carry_after_step",
    "carry_linearization",
    "is_adaptive",
    "jacobian_is_stale",
    "rebuild_linearization",
    "release_at_end",
    "restore_spare",
    "spare_state",
]


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
    lin = carry_linearization(est, lin, state, stale=stale)
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


def carry_linearization(est, lin: RigLinearization, state: RigState, *, stale: bool) -> RigLinearization:
    """The linearisation at the new equilibrium ``state`` from ``lin`` (at the previous one), which is
    consumed: its Jacobian kept with its factor (``stale`` False), or solved again at ``state`` with
    the factor made during this step when there is one (``fresh``), else with a new factor there
    (``FrameEstimator._linearize`` of ``est``: the held muscles' columns left out)."""
    chord = lin.take_chord()
    if not stale:
        kept = {"age": lin.age + 1, "jacobian_at": lin.jacobian_at, "held": lin.held, "fill": lin.fill}
        return RigLinearization(state, lin.jy, chord, **kept)
    if chord is not None and not getattr(chord, "fresh", False):
        chord.free()  # from an earlier frame: factor at the new equilibrium instead
        chord = None
    if chord is not None:
        chord.fresh = False
    return est._linearize(state, keep_factor=True, stiffness=chord)


# ---------------------------------------------------------------------- resumed takes
# A resumed take continues bit for bit when the frame files hold what is handed from frame to frame:
# where the kept factor was made (``factor_controls``/``factor_y_m``), where the kept Jacobian was solved
# and with which factor (``jacobian_*``), and in the second pass the factor handed between its frames
# (``spare_*``). PARDISO in its reproducible mode refactors them bit for bit (docs/design.md).


def rebuild_linearization(rig: FaceRig, state: RigState, chord, kept: dict | None) -> RigLinearization:
    """The linearisation a resumed take hands to its next frame: the Jacobian solved again where and with
    the factor it was solved with (``kept``: a frame's stored state), the factor ``chord`` kept with it;
    without ``kept``, the Jacobian at ``state`` with ``chord`` (the per-frame scheme's)."""
    if kept is None:
        return rig.linearize(state, stiffness=chord)
    factor = rig.stiffness_at(kept["jacobian_factor_controls"], kept["jacobian_factor_y_m"], warn=False)
    y = np.asarray(kept["jacobian_y_m"])
    jy = rig.linearize(RigState(state.controls, y, y), keep_factor=False, stiffness=factor).jy
    return RigLinearization(
        state, jy, chord, age=int(kept["jacobian_age"]), jacobian_at=(y, (factor.at[0], factor.at[1]))
    )


def spare_state(est) -> dict:
    """What a second-pass frame file stores of the factor handed to the next frame (``est._spare``)."""
    at = getattr(est._spare, "at", None)
    return {} if at is None else {"spare_controls": at[0], "spare_y_m": at[1]}


def restore_spare(est, state: dict | None) -> None:
    """Rebuild the handed-on second-pass factor from a frame file's ``spare_state`` (nothing when absent)."""
    est.free()
    if state and "spare_y_m" in state and is_adaptive(est):
        est.keep_spare(est.rig.stiffness_at(state["spare_controls"], state["spare_y_m"], warn=False))
