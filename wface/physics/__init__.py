"""The physics face: nonlinear FEM forces, energy, stiffness and quasistatic equilibria.

Main entry point: ``Simulator(model, device="cpu", precision="float64", solver="auto")`` with
``energy``, ``forces``, ``muscle_forces``, ``tangent`` / ``stiffness_matvec`` /
``assemble_stiffness`` and ``solve``. Bone placement helpers are in ``wface.physics.bones``.
"""

from wface.physics.simulator import Simulator, Tangent, count_inverted

__all__ = ["Simulator", "Tangent", "count_inverted"]
