"""What a dynamic run carries from step to step and reports: the state, the damping, the nodal
masses, the per-step statistics, and the error of a step that ran away (``wface.physics.dynamics``
integrates; docs/design.md, "Dynamics")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Damping", "DivergedError", "DynamicState", "StepStats", "lumped_masses"]


class DivergedError(FloatingPointError):
    """A time step whose positions left what a face can do: NaN/inf, or a node farther from its rest
    place than the whole rest mesh is across (its bounding box's diagonal). Seen with the midpoint
    rule and stiff penalty contact: contact holds the midpoint y, the end point 2 y - x_n overshoots,
    and the energy grows without bound (docs/design.md, "Dynamics")."""


@dataclass(frozen=True)
class Damping:
    """Rayleigh damping C = alpha M + beta K (K: projected stiffness at the start of each step).

    Defaults: alpha = 0 (no drag: in the world frame alpha M would also brake rigid head motion)
    and beta = 2e-4 s, which damps a mode at f Hz with ratio zeta = pi f beta: 6 % at 100 Hz,
    25 % at 400 Hz (the six lowest modes of the 5K-tet built-in face lie at 100-155 Hz), so
    high-frequency mesh noise dies within a few periods while the visible jiggle of the lips and
    cheeks survives a few oscillations. ``Damping.none()`` switches damping off. ``exact_tangent``
    damps with the exact stiffness instead, as ArtiSynth does (docs/design.md, "Dynamics"): where it
    is indefinite, a large beta can leave a step's Hessian indefinite.
    """

    alpha_per_s: float = 0.0
    beta_s: float = 2.0e-4
    exact_tangent: bool = False

    def __post_init__(self):
        for name in ("alpha_per_s", "beta_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"damping {name} must be finite and >= 0, got {value}")

    @classmethod
    def none(cls) -> Damping:
        return cls(0.0, 0.0)

    def ratio(self, frequency_hz: float) -> float:
        """Damping ratio zeta of a mode at ``frequency_hz``."""
        omega = 2.0 * np.pi * frequency_hz
        return self.alpha_per_s / (2.0 * omega) + self.beta_s * omega / 2.0


def lumped_masses(model) -> np.ndarray:
    """(n,) lumped nodal masses in kg: rho V_e / 4 of every tet e to each of its four nodes."""
    rho = float(model.material.density_kg_m3)
    if not (np.isfinite(rho) and rho > 0):
        raise ValueError(f"material density must be finite and > 0 kg/m^3, got {rho}")
    share = np.repeat(rho * model.rest_volume_m3 / 4.0, 4)
    return np.bincount(model.tets.reshape(-1), weights=share, minlength=model.n_nodes)


@dataclass
class DynamicState:
    """The state at one time.

    Attributes:
        t_s: time in seconds.
        x_m: (n, 3) node positions, metres (attached nodes at their bone positions).
        v_m_s: (n, 3) node velocities, m/s.
        activations: (M,) muscle activations at t_s.
    """

    t_s: float
    x_m: np.ndarray
    v_m_s: np.ndarray
    activations: np.ndarray


@dataclass
class StepStats:
    """What one step (or, summed, several substeps) cost and how it ended.

    Attributes:
        newton_iterations: Newton iterations (one linear solve each).
        residual_rel: relative gradient residual at the end (module docstring); the maximum over
            substeps when stats are combined.
        converged: every step reached ``tol``.
        line_search_min: smallest accepted line-search step length.
        kinetic_energy_j: kinetic energy of the free nodes at the end, joules.
        elastic_energy_j: elastic energy E(x, a) at the end, joules.
        inverted_elements: tets with det F <= 0 at the end.
        cg_iterations: CG iterations (CG engine only).
        projected_steps: Newton iterations that used the projected stiffness.
        exact_failures: exact-Hessian attempts rejected (not positive definite / not descent).
        factorizations: sparse factorisations (direct engine only).
        steps: time steps taken.
        seconds: wall-clock time.
    """

    newton_iterations: int = 0
    residual_rel: float = 0.0
    converged: bool = True
    line_search_min: float = 1.0
    kinetic_energy_j: float = 0.0
    elastic_energy_j: float = 0.0
    inverted_elements: int = 0
    cg_iterations: int = 0
    projected_steps: int = 0
    exact_failures: int = 0
    factorizations: int = 0
    steps: int = 0
    seconds: float = 0.0

    def combine(self, later: StepStats) -> StepStats:
        """Stats of this step followed by ``later`` (sums, worst residual, the later end state)."""
        return StepStats(
            newton_iterations=self.newton_iterations + later.newton_iterations,
            residual_rel=max(self.residual_rel, later.residual_rel),
            converged=self.converged and later.converged,
            line_search_min=min(self.line_search_min, later.line_search_min),
            kinetic_energy_j=later.kinetic_energy_j,
            elastic_energy_j=later.elastic_energy_j,
            inverted_elements=later.inverted_elements,
            cg_iterations=self.cg_iterations + later.cg_iterations,
            projected_steps=self.projected_steps + later.projected_steps,
            exact_failures=self.exact_failures + later.exact_failures,
            factorizations=self.factorizations + later.factorizations,
            steps=self.steps + later.steps,
            seconds=self.seconds + later.seconds,
        )
