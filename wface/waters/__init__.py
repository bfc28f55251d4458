"""Waters (1987) vector muscles: linear and sphincter muscles on a surface mesh, FACS expressions.

Modules: ``muscles`` (the formulas), ``layout`` (JSON layouts), ``rig`` (a layout compiled on a
mesh), ``fit`` (carry a layout to another face by landmarks), ``calibrate`` (fit muscle parameters to
reference shapes), ``expressions`` (FACS action units and presets), ``face_model`` (the built-in /
any FaceModel's skin), ``warp_backend`` (direct evaluation with a Warp kernel), ``render``
(off-screen pictures), ``pipeline`` (mesh file -> posed OBJ/USD/PNG); meshes are read and written by
``wface.mesh.meshfile``. An
ellipsoid head for data-free use is ``wface.testing.synthetic_head``.

Quick start::

    from wface.waters import WatersRig, expression_pose, load_layout
    from wface.mesh.meshfile import read_surface_mesh

    mesh = read_surface_mesh("generic_neutral_mesh.obj", units="cm")      # ICT-FaceKit head
    rig = WatersRig(load_layout("ict"), mesh.vertices_m, triangles=mesh.triangles())
    pose = expression_pose("happy", muscle_names=rig.muscle_names)
    x = rig.deform(pose.contractions, jaw_opening_deg=pose.jaw_opening_deg)  # (n, 3) metres
"""

from wface.waters.expressions import Pose, expression_pose, interpolate_poses, pose_from_action_units
from wface.waters.fit import fit_layout
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
    "fit_layout",
    "interpolate_poses",
    "load_layout",
    "pose_from_action_units",
    "save_layout",
]
