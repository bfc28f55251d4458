"""The physics face: nonlinear FEM forces, energy, stiffness and quasistatic equilibria.

Main entry point: ``Simulator(model, device="cpu", precision="float64", solver="auto")`` with
``energy``, ``forces``, ``muscle_forces``, ``tangent`` / ``stiffness_matvec`` /
``assemble_stiffness``, ``stiffness_solver`` (many right-hand sides) and ``solve``.
Bone placement helpers are in ``wface.physics.bones``.
"""

from wface.physics.simulator import Simulator, StiffnessSolver, Tangent, count_inverted

__all__ = ["Simulator", "StiffnessSolver", "Tangent", "count_inverted"]
