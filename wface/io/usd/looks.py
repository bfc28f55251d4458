"""A preview material that shows each prim's ``displayColor`` in a DCC's renderer.

``primvars:displayColor`` alone is a viewport hint: Blender imports it as a colour attribute but
renders the prim with its default grey material (Eevee, Cycles, and Workbench unless set to
"Attribute"), so the activation heat map, the red and green markers and the bone white were lost
in a normal render. One ``UsdPreviewSurface`` whose diffuse colour is read from the prim's own
``displayColor`` (a ``UsdPrimvarReader_float3``; Blender turns it into an Attribute node feeding
Base Color) is bound to every gprim that authors one and has no material of its own.
"""

from __future__ import annotations

__all__ = ["DISPLAY_COLOR_MATERIAL", "bind_display_colors"]

DISPLAY_COLOR_MATERIAL = "Looks/DisplayColor"  # under the stage's root prim


def _material(stage, path: str):
    from pxr import Gf, Sdf, UsdShade

    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
    reader = UsdShade.Shader.Define(stage, f"{path}/DisplayColorReader")
    reader.CreateIdAttr("UsdPrimvarReader_float3")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("displayColor")
    reader.CreateInput("fallback", Sdf.ValueTypeNames.Float3).Set(Gf.Vec3f(0.7, 0.7, 0.7))
    result = reader.CreateOutput("result", Sdf.ValueTypeNames.Float3)
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(result)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def bind_display_colors(stage, root: str) -> int:
    """Bind the display-colour material (module docstring) to every gprim under ``root`` that authors
    ``displayColor`` and binds no material; returns how many were bound."""
    from pxr import Usd, UsdGeom, UsdShade

    material = None
    bound = 0
    for prim in Usd.PrimRange(stage.GetPrimAtPath(root)):
        if not prim.IsA(UsdGeom.Gprim) or not UsdGeom.Gprim(prim).GetDisplayColorAttr().HasAuthoredValue():
            continue
        if prim.HasAPI(UsdShade.MaterialBindingAPI) and UsdShade.MaterialBindingAPI(prim).GetDirectBindingRel():
            continue
        if material is None:
            material = _material(stage, f"{root}/{DISPLAY_COLOR_MATERIAL}")
        UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)
        bound += 1
    return bound
