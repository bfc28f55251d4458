"""Markers as named locators: one Xform per marker with a time-sampled translation and a small sphere.

A DCC shows each marker by its name (Blender: an Empty-like object per marker; Maya: a transform
node; Houdini: a primitive with a path), which a point cloud whose point count changes per frame
cannot give. Layout under ``prim_path`` (an Xform, e.g. ``/Face/Markers/Captured``)::

    <marker><suffix>          Xform, translate op time-sampled (metres); in the frames where the
                              marker is missing (NaN) it is hidden twice over: visibility
                              "invisible" and a scale op of 0 (Blender's importer reads transforms
                              but not animated visibility), and the translation holds the last
                              seen position (the first seen one before it)
      <marker><suffix>        Mesh: a once-subdivided icosahedron (42 points) of radius
                              ``radius_m`` with a constant displayColor, named like its locator
                              (Blender merges an Xform with its one child into a single object
                              named after the child, so the object keeps the name). A mesh, not a
                              UsdGeom.Sphere: Blender 5 imports a Sphere without its material
                              binding, so the markers rendered grey

The original names (which need not be USD identifiers) are in the uniform string array
``wface:markerNames`` of ``prim_path``, in order, and ``wface:markerName`` of each locator.
``suffix`` keeps the two marker sets apart in a DCC whose object names are global (Blender):
captured ``Chin``, tracked ``Chin_tracked``.
"""

from __future__ import annotations

import numpy as np

from wface.io.usd._common import _identifier, _write_mesh

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
    ball, tris = _icosphere(1)
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
        counts = np.full(len(tris), 3)
        _write_mesh(stage, f"{xf.GetPath()}/{ident}", radius_m * ball, counts, tris.ravel(), colors=rgb, normals=ball)
    return group


def _icosphere(subdivisions: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(unit points (n, 3), outward-wound triangles (m, 3)) of an icosahedron split ``subdivisions`` times."""
    t = (1.0 + 5.0**0.5) / 2.0
    pts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t)]
    pts += [(0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    tris = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2)]
    tris += [(10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5)]
    tris += [(2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    points = [np.array(p, dtype=float) / np.linalg.norm(p) for p in pts]
    mid: dict[tuple[int, int], int] = {}  # edge -> its midpoint's index; edges are new each level

    def middle(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in mid:
            m = points[a] + points[b]
            points.append(m / np.linalg.norm(m))
            mid[key] = len(points) - 1
        return mid[key]

    for _ in range(subdivisions):
        split = []
        for a, b, c in tris:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            split += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        tris = split
    return np.array(points), np.array(tris, dtype=np.int64)


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
