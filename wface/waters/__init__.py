"""Waters (1987) vector muscles: linear and sphincter muscles on a surface mesh, FACS expressions.

Modules: ``muscles`` (the formulas), ``layout`` (JSON layouts), ``rig`` (a layout compiled on a
mesh), ``fit`` (carry a layout to another face by landmarks), ``expressions`` (FACS action units and
presets), ``surface`` (mesh I/O), ``render`` (off-screen pictures).
"""

from wface.waters.expressions import Pose, expression_pose, interpolate_poses, pose_from_action_units
from wface.waters.layout import JawPlane, JawRegion, MuscleLayout, load_layout, save_layout
from wface.waters.muscles import LinearMuscle, SphincterMuscle
from wface.waters.rig import WatersRig

__all__ = [
    "JawPlane",
    "JawRegion",
    "LinearMuscle",
    "MuscleLayout",
    "Pose",
    "SphincterMuscle",
    "WatersRig",
    "expression_pose",
    "interpolate_poses",
    "load_layout",
    "pose_from_action_units",
    "save_layout",
]
