"""Read a take written by ``write_take`` back into numpy arrays (round trips, re-rendering, tools).

Values come back as float64 from USD's float32 storage (relative round-off ~6e-8).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.io.usd.locators import read_locators
from wface.io.usd.validate import _open

__all__ = ["read_take"]


def _frames(attr) -> list[float]:
    samples = attr.GetTimeSamples()
    return samples if samples else [None]


def _get(attr, t):
    return attr.Get() if t is None else attr.Get(t)


def read_take(path: str | Path, *, name: str | None = None) -> dict:
    """Arrays of a take stage (see ``write_take`` for the layout).

    Args:
        path: a ``.usda`` / ``.usdc`` written by ``write_take`` (or a ``Usd.Stage``).
        name: root prim name (default: the stage's default prim).

    Returns:
        dict with ``fps``, ``n_frames``, ``time_codes`` (F,) (the frame numbers written),
        ``skin_node_ids`` (v,), ``skin_triangles`` (t, 3) in
        compact skin numbering, ``skin_points_m`` (F, v, 3), and when present:
        ``activations`` (F, M) with ``muscle_names``, ``vertex_activation`` (F, v),
        ``captured_markers_m`` / ``simulated_markers_m`` (F, k, 3; NaN = missing) with
        ``marker_names``, ``cranium_affines`` / ``jaw_affines`` (F, 3, 4; the jaw's local
        transform, relative to the cranium when ``jaw_frame`` is "cranium"), ``basis_weights``
        (F, B) with ``basis_names``, and ``metadata`` (the layer's customLayerData["wface"]).
    """
    from pxr import Usd, UsdGeom, UsdSkel

    stage = _open(path)
    root = stage.GetPrimAtPath(f"/{name}") if name else stage.GetDefaultPrim()
    if not root:
        raise ValueError(f"{path}: no root prim {name or '(default prim)'}")
    rp = root.GetPath()
    skin_prim = stage.GetPrimAtPath(rp.AppendChild("Skin"))
    if not skin_prim:
        raise ValueError(f"{path}: no {rp}/Skin mesh: not a take written by write_take")
    skin = UsdGeom.Mesh(skin_prim)
    times = list(skin.GetPointsAttr().GetTimeSamples()) or [stage.GetStartTimeCode()]
    n_frames = len(times)
    out: dict = {"fps": stage.GetTimeCodesPerSecond(), "n_frames": n_frames, "time_codes": np.asarray(times)}
    out["metadata"] = dict(stage.GetRootLayer().customLayerData.get("wface", {}))
    pv = UsdGeom.PrimvarsAPI(skin_prim)
    node_id = pv.GetPrimvar("wface:nodeId")
    counts = np.asarray(skin.GetFaceVertexCountsAttr().Get())
    if np.any(counts != 3):
        raise ValueError(f"{path}: the skin is not a triangle mesh")
    out["skin_triangles"] = np.asarray(skin.GetFaceVertexIndicesAttr().Get(), dtype=np.int64).reshape(-1, 3)
    out["skin_points_m"] = np.stack([np.asarray(skin.GetPointsAttr().Get(t), dtype=np.float64) for t in times])
    out["skin_node_ids"] = (
        np.asarray(node_id.Get(), dtype=np.int64) if node_id else np.arange(out["skin_points_m"].shape[1])
    )
    act_pv = pv.GetPrimvar("wface:activation")
    if act_pv:
        out["vertex_activation"] = np.stack([np.asarray(act_pv.Get(t), dtype=np.float64) for t in times])

    muscles = stage.GetPrimAtPath(rp.AppendChild("Muscles"))
    if muscles:
        out["muscle_names"] = list(muscles.GetAttribute("wface:muscleNames").Get())
        attr = muscles.GetAttribute("wface:activations")
        out["activations"] = np.stack([np.asarray(attr.Get(t), dtype=np.float64) for t in times])

    for label, key in (("Captured", "captured_markers_m"), ("Simulated", "simulated_markers_m")):
        prim = stage.GetPrimAtPath(rp.AppendPath(f"Markers/{label}"))
        if prim:
            out[key], out["marker_names"] = read_locators(prim, times)

    for sub, key in (("Cranium", "cranium_affines"), ("Cranium/Jaw", "jaw_affines"), ("Jaw", "jaw_affines")):
        prim = stage.GetPrimAtPath(rp.AppendPath(f"Bones/{sub}"))
        if not prim:
            continue
        if sub.endswith("Jaw"):
            out["jaw_frame"] = "cranium" if sub == "Cranium/Jaw" else "world"
        ops = UsdGeom.Xformable(prim).GetOrderedXformOps()
        if not ops:
            continue
        aff = np.zeros((n_frames, 3, 4))
        for f, t in enumerate(times):
            m = np.asarray(UsdGeom.Xformable(prim).GetLocalTransformation(Usd.TimeCode(t)))
            aff[f, :, :3] = m[:3, :3].T
            aff[f, :, 3] = m[3, :3]
        out[key] = aff

    basis = stage.GetPrimAtPath(rp.AppendChild("Basis"))
    if basis:
        anim = UsdSkel.Animation(stage.GetPrimAtPath(rp.AppendPath("Basis/Skel/Anim")))
        out["basis_names"] = list(anim.GetBlendShapesAttr().Get())
        w = anim.GetBlendShapeWeightsAttr()
        out["basis_weights"] = np.stack([np.asarray(w.Get(t), dtype=np.float64) for t in times])
    return out
