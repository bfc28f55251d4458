"""A face model in numbers: sizes, muscles, markers, attachments, mesh quality, material."""

from __future__ import annotations

import numpy as np

from wface.mesh.quality import dihedral_angles_deg, volume_ratio_quality
from wface.model import FaceModel

__all__ = ["model_summary"]


def model_summary(model: FaceModel) -> dict:
    """Sizes, muscles (the fibre muscles; pressure actuators apart), markers, attachments, mesh
    quality and material of a face (what ``wface model info --json`` prints)."""
    x = model.rest_positions_m
    return {
        "nodes": model.n_nodes,
        "tets": model.n_tets,
        "muscles": [n for n in model.muscle_names if n not in model.pressure_actuators],
        "pressure_actuators": {
            name: {"max_pa": p, "range": [-1.0, 1.0], "wall_triangles": int(len(model.surface_groups[name]))}
            for name, p in model.pressure_actuators.items()
        },
        "markers": list(model.marker_names),
        "attached_nodes": {
            "cranium": int(len(model.nodes_of_bone("cranium"))),
            "jaw": int(len(model.nodes_of_bone("jaw"))),
        },
        "free_to_mm": model.metadata.get("free_to_mm"),  # a built-in face's free bone side (None: the default)
        "min_dihedral_deg": float(dihedral_angles_deg(x, model.tets).min()),
        "min_volume_ratio": float(volume_ratio_quality(x, model.tets).min()),
        "min_volume_m3": float(model.rest_volume_m3.min()),
        "bbox_m": [x.min(axis=0).tolist(), x.max(axis=0).tolist()],
        "bones": sorted(model.bone_meshes),
        "action_units": sorted(model.facs, key=lambda s: int(s[2:])),
        "material": {
            k: v if isinstance(v, str) else dict(v) if k == "muscle_curves" else float(v)
            for k, v in vars(model.material).items()
        },
        "muscle_volume_cm3": dict(
            zip(model.muscle_names, np.round(model.muscle_volume_m3() * 1e6, 4).tolist(), strict=True)
        ),
        "fit": _fit_summary(model.metadata.get("fit")),
    }


def _fit_summary(fit: dict | None) -> dict | None:
    """What ``wface model fit`` measured (``wface.faces.fit``), or None for a model never fitted."""
    if not fit:
        return None
    keys = ("template", "surface", "markers", "scale", "surface_distance_mm", "landmark_rms_mm", "inverted_tets")
    return {k: fit.get(k) for k in keys}
