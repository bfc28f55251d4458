"""Expression editing in activation space (seed 000, section 9): interpolate, blend, exaggerate,
layer and retime expressions and tracked takes, then re-simulate them through the FEM face.

Edits work on ``Pose`` values (activations, per-muscle force-length scale, rigid cranium, jaw in
intuitive parameters), so every edited frame is a physically attainable face: activations stay in
[0, 1] (exaggeration past full activation scales the force-length curve instead), the cranium stays
rigid and the jaw stays on its joint. Modules: ``pose`` (the values), ``ops`` (the edits),
``sources`` (expressions, tracked takes), ``resim`` (quasistatic re-simulation), ``output``
(USD, controls, report, contact sheet).

Example::

    from wface.builtin import build_face
    from wface.editing import expression_pose, exaggerate, interpolate, simulate_poses

    model = build_face(3000)
    smile, surprise = expression_pose(model, "smile"), expression_pose(model, "surprise")
    poses = [interpolate(smile, surprise, t, joint=model.jaw_joint) for t in (0, 0.5, 1)]
    poses.append(exaggerate(smile, 1.5, joint=model.jaw_joint))
    result = simulate_poses(model, poses)        # result.x_m: (4, n, 3) metres
"""

from wface.editing.ops import SCALE_MODES, blend, exaggerate, interpolate, layer, retime
from wface.editing.output import write_contact_sheet, write_edit
from wface.editing.pose import Pose, Take, clamp_jaw, nearest_rotation, pose_from_controls, rest_pose, split_drive
from wface.editing.resim import EditResult, simulate_poses
from wface.editing.sources import expression_names, expression_pose, load_take, save_controls

__all__ = [
    "SCALE_MODES",
    "EditResult",
    "Pose",
    "Take",
    "blend",
    "clamp_jaw",
    "exaggerate",
    "expression_names",
    "expression_pose",
    "interpolate",
    "layer",
    "load_take",
    "nearest_rotation",
    "pose_from_controls",
    "rest_pose",
    "retime",
    "save_controls",
    "simulate_poses",
    "split_drive",
    "write_contact_sheet",
    "write_edit",
]
