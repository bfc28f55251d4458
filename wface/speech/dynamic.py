"""Dynamic playback of a speech gesture: the excitation curves through the implicit dynamic FEM.

The flesh obeys M x'' + C x' = f(x, a(t)) + M g (``wface.physics.dynamics.DynamicSimulator``):
lumped masses from the material density, Rayleigh damping C = alpha M + beta K, optional gravity.
Between two output frames t_{f-1} and t_f the simulator takes n = ceil((t_f - t_{f-1}) / max_step)
equal steps, and every step reads the activations a(t) from the gesture's excitation curves at its
own time (the curves, not an interpolation between frames: a CubicStep ramp of 0.53 s is sampled
every 5 ms, as ArtiSynth's probes are). Frame 0 is the quasistatic equilibrium at a(t_0) (the rest
shape for the ArtiSynth gestures, which start at zero) with zero velocity; with gravity the face then
settles, as the original does (its lip opening grows from 40 to 53 mm^2 in the first 0.2 s).

Defaults (``GestureDynamics()``) are ArtiSynth's BadinFaceDemo (``wface.speech.artisynth_demo``):
backward Euler (ConstrainedBackwardEuler) with steps of at most 5 ms, alpha = 19 1/s, beta = 0.055 s,
gravity 9.8 m/s^2 along -Y (the model's down). With beta = 0.055 s the flesh is heavily
overdamped (zeta = pi f beta: 1.7 at 10 Hz), so the face lags the excitation by about beta.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from wface.physics.dynamics import Damping, DynamicSimulator
from wface.speech.artisynth_demo import ARTISYNTH_DYNAMICS

__all__ = ["GestureDynamics", "play_dynamic"]


@dataclass(frozen=True)
class GestureDynamics:
    """How a gesture is played dynamically (module docstring).

    Attributes:
        scheme: "be" (backward Euler, ArtiSynth's) or "midpoint".
        max_step_s: longest time step, seconds.
        alpha_per_s, beta_s: Rayleigh damping C = alpha M + beta K.
        exact_damping: K exact, as ArtiSynth's, not projected (``Damping.exact_tangent``).
        gravity_m_s2: (3,) gravity in the model frame, or None.
        tol: relative residual of each step's Newton solve.
        max_iterations: Newton iteration cap per step.
    """

    scheme: str = ARTISYNTH_DYNAMICS.scheme
    max_step_s: float = ARTISYNTH_DYNAMICS.max_step_s
    alpha_per_s: float = ARTISYNTH_DYNAMICS.alpha_per_s
    beta_s: float = ARTISYNTH_DYNAMICS.beta_s
    exact_damping: bool = False
    gravity_m_s2: tuple | None = ARTISYNTH_DYNAMICS.gravity_m_s2
    tol: float = 1e-6
    max_iterations: int = 25

    def __post_init__(self):
        if not (np.isfinite(self.max_step_s) and self.max_step_s > 0):
            raise ValueError(f"max_step_s must be finite and > 0 s, got {self.max_step_s}")
        Damping(self.alpha_per_s, self.beta_s)  # validates

    def to_dict(self, model=None) -> dict:
        out = asdict(self)
        out["gravity_m_s2"] = None if self.gravity_m_s2 is None else list(self.gravity_m_s2)
        if model is not None:
            out["density_kg_m3"] = float(model.material.density_kg_m3)
        return out


def play_dynamic(
    sim,
    gesture,
    mapping,
    times_s: np.ndarray,
    *,
    dynamics: GestureDynamics,
    contact=None,
    tol_start: float = 1e-6,
    progress: bool = False,
) -> dict:
    """Positions at ``times_s`` (ascending) of the dynamic playback (module docstring).

    Args:
        sim: the ``Simulator`` of the face.
        gesture: a ``SpeechGesture``; mapping: its ``GestureMapping`` onto the model.
        times_s: (F,) output frame times, seconds.
        dynamics: the integrator settings.
        contact: optional ``wface.physics.contact.Contact`` in the start solve and every step.
        tol_start: relative residual of the quasistatic start.
        progress: print one line per frame.

    Returns:
        dict of per-frame arrays: ``x_m`` (F, n, 3), ``activations`` (F, M), ``newton_iterations``,
        ``residual_rel`` (largest over the frame's steps), ``converged``, ``inverted_elements``,
        ``seconds``, ``steps``, ``kinetic_energy_j``.
    """
    model = sim.model
    times = np.asarray(times_s, dtype=np.float64)
    F = len(times)
    dyn = DynamicSimulator(
        sim,
        scheme=dynamics.scheme,
        damping=Damping(dynamics.alpha_per_s, dynamics.beta_s, exact_tangent=dynamics.exact_damping),
        gravity_m_s2=dynamics.gravity_m_s2,
        tol=dynamics.tol,
        max_iterations=dynamics.max_iterations,
        contact=contact,
    )
    acts = lambda t: mapping.activations(gesture, model, np.atleast_1d(t))  # noqa: E731
    out = {
        "x_m": np.empty((F, model.n_nodes, 3)),
        "activations": acts(times),
        "newton_iterations": np.zeros(F, int),
        "residual_rel": np.zeros(F),
        "converged": np.zeros(F, bool),
        "inverted_elements": np.zeros(F, int),
        "seconds": np.zeros(F),
        "steps": np.zeros(F, int),
        "kinetic_energy_j": np.zeros(F),
    }
    t0 = time.perf_counter()
    kwargs = {} if contact is None else {"contact": contact}
    eq = sim.solve(activations=out["activations"][0], tol=tol_start, **kwargs)
    state = dyn.initial_state(eq.x, None, out["activations"][0], t_s=float(times[0]))
    out["x_m"][0] = eq.x
    out["newton_iterations"][0], out["residual_rel"][0] = eq.iterations, eq.residual_rel
    out["converged"][0], out["inverted_elements"][0] = eq.converged, eq.inverted_elements
    out["seconds"][0] = time.perf_counter() - t0
    try:
        for f in range(1, F):
            t_start = time.perf_counter()
            span = times[f] - times[f - 1]
            n = max(1, int(np.ceil(span / dynamics.max_step_s - 1e-9)))
            stats = None
            for k in range(1, n + 1):
                t = times[f - 1] + span * k / n
                state, st = dyn.step(state, span / n, acts(t)[0])
                stats = st if stats is None else stats.combine(st)
            out["x_m"][f] = state.x_m
            out["newton_iterations"][f], out["residual_rel"][f] = stats.newton_iterations, stats.residual_rel
            out["converged"][f], out["inverted_elements"][f] = stats.converged, stats.inverted_elements
            out["steps"][f], out["kinetic_energy_j"][f] = n, stats.kinetic_energy_j
            out["seconds"][f] = time.perf_counter() - t_start
            if progress:
                print(
                    f"{gesture.name} dynamic frame {f + 1}/{F} t={times[f]:.3f}s: {n} steps, "
                    f"{stats.newton_iterations} Newton its, residual {stats.residual_rel:.1e}, "
                    f"kinetic {stats.kinetic_energy_j:.2e} J, {out['seconds'][f]:.1f} s",
                    flush=True,
                )
    finally:
        dyn.free()
    return out
