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

from wface.tracking.rig import FaceRig, RigLinearization, RigState

__all__ = ["carry_linearization", "jacobian_is_stale"]


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
