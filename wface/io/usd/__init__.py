"""USD output for DCC tools (Blender, Houdini, usdview): meshes, takes, bases, validation.

Stages are written with usd-core (``pxr``), imported inside the functions that need it. Every
stage says its units and axes in its metadata: ``metersPerUnit = 1`` (positions are metres, as
everywhere in wface; a Waters mesh keeps its source unit, e.g. 0.01 for centimetres), ``upAxis``
(``"Y"`` by default, matching the model's +y up), ``timeCodesPerSecond`` = the capture rate, and
start/end time codes covering the frames. Frames are written at their own frame numbers (the
capture's, ``frames=``; default 0..F-1), and customLayerData["wface"]["first_frame"] holds the
first.

With ``up_axis="Z"`` the data stay as they are and the root prim gets a rotateX(90) op, so the
model's +y points up in a Z-up world.

The path's suffix picks the format: ``.usdc`` (binary crate, the default for ``.usd`` too) or
``.usda`` (text, diff-able).

Modules: ``mesh`` (``write_mesh_animation``: also UVs, normals and material subsets;
``write_surface_mesh``: a ``wface.mesh.meshfile.SurfaceMesh`` in its own units), ``take``
(``write_take``), ``rig`` (a take's skin as UsdSkel blend shapes plus cranium and jaw joints),
``locators`` (markers as named Xforms), ``skel`` (actuation bases as UsdSkel blend shapes),
``validate`` (UsdValidation, extents, UsdSkel synthesis, stage diffs), ``read`` (``read_take``: a
take back into arrays). Everything public is re-exported
here: ``from wface.io.usd import write_take``.
"""

from wface.io.usd._common import UsdWriteError, affine_to_matrix4d, as_polygons
from wface.io.usd.mesh import write_mesh_animation, write_surface_mesh
from wface.io.usd.read import read_take
from wface.io.usd.rig import SkinRig, rig_points
from wface.io.usd.skel import BlendShapeBasis, write_blendshape_basis
from wface.io.usd.take import write_take
from wface.io.usd.validate import (
    UsdValidationFailed,
    assert_stage_valid,
    blendshape_points,
    check_extents,
    compare_stages,
    validate_stage,
)

__all__ = [
    "BlendShapeBasis",
    "UsdValidationFailed",
    "SkinRig",
    "UsdWriteError",
    "affine_to_matrix4d",
    "as_polygons",
    "assert_stage_valid",
    "blendshape_points",
    "check_extents",
    "compare_stages",
    "read_take",
    "rig_points",
    "validate_stage",
    "write_blendshape_basis",
    "write_mesh_animation",
    "write_surface_mesh",
    "write_take",
]
