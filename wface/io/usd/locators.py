"""Markers as named locators: one Xform per marker with a time-sampled translation and a small sphere.

A DCC shows each marker by its name (Blender: an Empty-like object per marker; Maya: a transform
node; Houdini: a primitive with a path), which a point cloud whose point count changes per frame
cannot give. Layout under ``prim_path`` (an Xform, e.g. ``/Face/Markers/Captured``)::

    <marker><suffix>          Xform, translate op time-sampled (metres); in the frames where the
                              marker is missing (NaN) it is hidden twice over: visibility
                              "invisible" and a scale op of 0 (Blender's importer reads transforms
                              but not animated visibility), and the translation holds the last
                              seen position (the first seen one before it)
      <marker><suffix>        Sphere of radius ``radius_m`` with a constant displayColor, named
                              like its locator (Blender merges an Xform with its one child into a
                              single object named after the child, so the object keeps the name)

The original names (which need not be USD identifiers) are in the uniform string array
``wface:markerNames`` of ``prim_path``, in order, and ``wface:markerName`` of each locator.
``suffix`` keeps the two marker sets apart in a DCC whose object names are global (Blender):
captured ``Chin``, tracked ``Chin_tracked``.
"""

from __future__ import annotations

import numpy as np

from wface.io.usd._common import _identifier, _vt_vec3f

__all__ = ["read_locators", "write_locators"]


def write_locators(
    stage, prim_path: str, positions_m: np.ndarray, names: list[str], *, times, radius_m: float, rgb, suffix: str = ""
):
    """Author one locator per marker (module docstring).

    Args:
        stage: the open ``Usd.Stage``.
        prim_path: path of the Xform that holds the locators.
        positions_m: (F, k, 3) positions per frame; NaN rows are missing markers.
        names: k marker names.
        times: (F,) time codes.
        radius_m: sphere radius.
        rgb: (3,) linear display colour.
        suffix: appended to every locator's prim name.
    """
    from pxr import Gf, Sdf, UsdGeom, Vt

    group = UsdGeom.Xform.Define(stage, prim_path)
    group.GetPrim().CreateAttribute(
        "wface:markerNames", Sdf.ValueTypeNames.StringArray, custom=True, variability=Sdf.VariabilityUniform
    ).Set(Vt.StringArray([str(n) for n in names]))
    taken: set[str] = set()
    for k, name in enumerate(names):
        p = positions_m[:, k]
        seen = np.all(np.isfinite(p), axis=1)
        ident = _identifier(name, taken) + suffix
        xf = UsdGeom.Xform.Define(stage, f"{prim_path}/{ident}")
        xf.GetPrim().CreateAttribute("wface:markerName", Sdf.ValueTypeNames.String, custom=True).Set(str(name))
        op = xf.AddTranslateOp()
        scale = xf.AddScaleOp() if not seen.all() else None
        vis = xf.CreateVisibilityAttr()
        held = p[np.argmax(seen)] if seen.any() else np.zeros(3)
        was_seen = None
        for t, pf, s in zip(times, p, seen, strict=True):
            if s:
                held = pf
            op.Set(Gf.Vec3d(*map(float, held)), float(t))
            if s != was_seen:  # visibility is held between samples: write it where it changes
                vis.Set(UsdGeom.Tokens.inherited if s else UsdGeom.Tokens.invisible, float(t))
                was_seen = s
            if scale is not None:
                scale.Set(Gf.Vec3f(1.0 if s else 0.0), float(t))
        ball = UsdGeom.Sphere.Define(stage, f"{xf.GetPath()}/{ident}")
        ball.CreateRadiusAttr(float(radius_m))
        ball.CreateExtentAttr(_vt_vec3f(np.array([[-radius_m] * 3, [radius_m] * 3])))
        ball.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(_vt_vec3f(np.asarray(rgb, dtype=float)[None]))
    return group


def read_locators(prim, times) -> tuple[np.ndarray, list[str]]:
    """((F, k, 3) positions with NaN where a locator is invisible, names) of a ``write_locators`` group."""
    from pxr import Usd, UsdGeom

    names = list(prim.GetAttribute("wface:markerNames").Get() or [])
    children = [c for c in prim.GetChildren() if c.IsA(UsdGeom.Xform)]
    by_name = {c.GetAttribute("wface:markerName").Get(): c for c in children}
    out = np.full((len(times), len(names), 3), np.nan)
    for k, name in enumerate(names):
        child = by_name.get(name)
        if child is None:
            continue
        xf = UsdGeom.Xformable(child)
        vis = UsdGeom.Imageable(child).GetVisibilityAttr()
        for f, t in enumerate(times):
            code = Usd.TimeCode(t)
            if vis.Get(code) == UsdGeom.Tokens.invisible:
                continue
            out[f, k] = np.asarray(xf.GetLocalTransformation(code))[3, :3]
    return out, names
