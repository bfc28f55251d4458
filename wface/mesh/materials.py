"""How a mesh's material groups look when the file says nothing (no ``.mtl``): one owner for pictures and USD.

A head mesh such as the ICT-FaceKit neutral names its groups (``M_Face``, ``M_ScleraLeft``,
``M_IrisLeft``, ``M_Teeth``, ``M_GumsTongue``, ``M_EyeLashes``) and has overlay shells that a real
renderer blends in at low opacity: the eye occlusion (a soft shadow on the eyeball), the lacrimal
fluid and the blend between lid and eye. Drawn opaque in one colour these overlays cover the eyes,
which then read as closed. So each group gets a colour and an opacity from the words in its name;
overlays get opacity 0, a group the words do not place a neutral grey. Colours an ``.mtl`` file
defines win (``SurfaceMesh.material_colors``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["SKIN_RGB", "Appearance", "face_appearance", "material_appearance"]

SKIN_RGB = (0.80, 0.62, 0.52)
_OTHER_RGB = (0.55, 0.55, 0.58)

# (words in the lower-cased group name, colour, opacity): first match wins, overlays first
_RULES: tuple[tuple[tuple[str, ...], tuple[float, float, float], float], ...] = (
    (("occlusion", "lacrimal", "tear", "eyeblend", "cornea", "meniscus"), (0.8, 0.8, 0.8), 0.0),
    (("sclera", "eyewhite", "eye_white"), (0.93, 0.91, 0.88), 1.0),
    (("iris", "pupil"), (0.28, 0.18, 0.11), 1.0),
    (("lash", "brow", "hair"), (0.10, 0.08, 0.07), 1.0),
    (("teeth", "tooth"), (0.94, 0.91, 0.82), 1.0),
    (("gum", "tongue", "mouth", "socket"), (0.72, 0.38, 0.38), 1.0),
    (("face", "head", "skin", "body", "neck", "ear"), SKIN_RGB, 1.0),
)


class Appearance(NamedTuple):
    """Colour (0-1 RGB) and opacity (0 hidden, 1 opaque) of a material group."""

    rgb: tuple[float, float, float]
    opacity: float


def material_appearance(name: str, defined_rgb=None) -> Appearance:
    """Colour and opacity of a material group named ``name`` (module docstring); ``defined_rgb`` (the
    ``.mtl``'s diffuse colour) replaces the colour, not an overlay's opacity."""
    key = name.lower()
    rgb, opacity = _OTHER_RGB, 1.0
    for words, colour, alpha in _RULES:
        if any(w in key for w in words):
            rgb, opacity = colour, alpha
            break
    chosen = rgb if defined_rgb is None else defined_rgb
    return Appearance(tuple(float(c) for c in chosen), float(opacity))


def face_appearance(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(p, 3) colour and (p,) opacity of each polygon of a ``SurfaceMesh``: its group's appearance, skin
    for polygons in no group (or a mesh without groups)."""
    rgb = np.tile(np.asarray(SKIN_RGB), (mesh.n_faces, 1))
    opacity = np.ones(mesh.n_faces)
    for name, faces in mesh.face_groups.items():
        look = material_appearance(name, mesh.material_colors.get(name))
        rgb[faces], opacity[faces] = look.rgb, look.opacity
    return rgb, opacity
