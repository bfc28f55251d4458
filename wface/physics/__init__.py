"""The physics face: nonlinear FEM forces, energy, stiffness and quasistatic equilibria.

Main entry point: ``Simulator(model, device="cpu", precision="float64", solver="auto")`` with
``energy``, ``forces``, ``muscle_forces``, ``tangent`` / ``stiffness_matvec`` /
``assemble_stiffness``, ``stiffness_solver`` (many right-hand sides) and ``solve``.
Bone placement lives in ``wface.controls``. Implicit dynamics (inertia, Rayleigh
damping, backward Euler and implicit midpoint): ``DynamicSimulator(sim)`` in
``wface.physics.dynamics``.
"""

from wface.mesh.quality import count_inverted
from wface.physics.dynamics import Damping, DynamicSimulator, DynamicState, lumped_masses
from wface.physics.simulator import Simulator, StiffnessSolver, Tangent

__all__ = [
    "Damping",
    "DynamicSimulator",
    "DynamicState",
    "Simulator",
    "StiffnessSolver",
    "Tangent",
    "count_inverted",
    "lumped_masses",
]
