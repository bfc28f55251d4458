"""The face model (``FaceModel``, its parts and its ``.npz`` format; docs/design.md, "Units and the face
model"): ``wface.model.material`` holds the flesh and muscle laws and ``ModelError``, ``wface.model.face``
the model, its jaw joint and bone meshes, and saving and loading."""

from wface.model.face import BONES, FORMAT_VERSION, BoneMesh, FaceModel, JawJoint, load_model, model_sha256, save_model
from wface.model.material import BULK_POTENTIALS, FIBRE_CURVES, FIBRE_STRESSES, Material, ModelError

__all__ = [
    "BONES",
    "BULK_POTENTIALS",
    "FIBRE_CURVES",
    "FIBRE_STRESSES",
    "FORMAT_VERSION",
    "BoneMesh",
    "FaceModel",
    "JawJoint",
    "Material",
    "ModelError",
    "load_model",
    "model_sha256",
    "save_model",
]
