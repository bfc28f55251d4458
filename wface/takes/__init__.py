"""Takes: performances of a face, their files, their edits and their two replays.

A ``Take`` (``take``) holds one row of controls per frame: activations, per-muscle force-length
scales, cranium and jaw motion, frame numbers and rate. It is what tracking produces and what the
rest of this package consumes:

- ``store``: the one owner of a take's files (frames/, controls.npz / .csv, report.json, fps);
- ``pose``, ``expressions``, ``edits``: editing in activation space (Sifakis et al. 2005,
  section 9): ``Pose`` values (rigid cranium, jaw on its joint, activations in [0, 1]), named
  expressions and FACS specs, and the edits interpolate, blend, exaggerate, layer and retime;
- ``quasistatic``: the quasistatic replay, one equilibrium per frame (``simulate_poses``);
- ``dynamic``: the dynamic replay through the implicit dynamic FEM (``resimulate``, ``wface resim``);
- ``usd``: the one place that writes a take as USD; ``output``: the files of an edit.

Example::

    from wface.faces.builtin import build_face
    from wface.takes import expression_pose, exaggerate, interpolate, simulate_poses

    model = build_face(3000)
    smile, surprise = expression_pose(model, "smile"), expression_pose(model, "surprise")
    poses = [interpolate(smile, surprise, t, joint=model.jaw_joint) for t in (0, 0.5, 1)]
    poses.append(exaggerate(smile, 1.5, joint=model.jaw_joint))
    result = simulate_poses(model, poses)        # result.x_m: (4, n, 3) metres
"""

from wface.takes.dynamic import ResimResult, resimulate
from wface.takes.edits import SCALE_MODES, blend, exaggerate, interpolate, layer, retime
from wface.takes.expressions import expression_names, expression_pose
from wface.takes.output import write_contact_sheet, write_edit
from wface.takes.pose import Pose, clamp_jaw, pose_from_bones, pose_from_controls, rest_pose, split_drives
from wface.takes.quasistatic import EditResult, quasistatic_frames, simulate_poses
from wface.takes.store import load_take, write_controls
from wface.takes.take import Take
from wface.takes.usd import write_take_usd

__all__ = [
    "SCALE_MODES",
    "EditResult",
    "Pose",
    "ResimResult",
    "Take",
    "blend",
    "clamp_jaw",
    "exaggerate",
    "expression_names",
    "expression_pose",
    "interpolate",
    "layer",
    "load_take",
    "pose_from_bones",
    "pose_from_controls",
    "quasistatic_frames",
    "resimulate",
    "rest_pose",
    "retime",
    "simulate_poses",
    "split_drives",
    "write_contact_sheet",
    "write_controls",
    "write_edit",
    "write_take_usd",
]
