"""Checks of written stages: USD's validators, extents, UsdSkel blend-shape synthesis, content diffs."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = [
    "UsdValidationFailed",
    "assert_stage_valid",
    "blendshape_points",
    "check_extents",
    "compare_stages",
    "validate_stage",
]


class UsdValidationFailed(AssertionError):
    """A stage failed a UsdValidation validator, the extent check, or the blend-shape check."""


def _open(stage_or_path):
    from pxr import Usd

    if isinstance(stage_or_path, (str, Path)):
        p = Path(stage_or_path)
        if not p.exists():
            raise FileNotFoundError(f"USD file not found: {p}")
        stage = Usd.Stage.Open(str(p))
        if stage is None:
            raise UsdValidationFailed(f"{p}: USD could not open it")
        return stage
    return stage_or_path


def validate_stage(stage_or_path, *, keywords: list[str] | None = None) -> list[str]:
    """Run USD's registered validators (``UsdValidation``) on a stage.

    Args:
        stage_or_path: a ``Usd.Stage`` or a file path.
        keywords: only validators with one of these keywords (e.g. ``["UsdGeomValidators"]``);
            default: every registered validator (usd-core >= 24.11).

    Returns:
        One line per error or warning: ``"<validator>: <message>"``; empty when the stage passes.
    """
    from pxr import UsdValidation

    stage = _open(stage_or_path)
    registry = UsdValidation.ValidationRegistry()
    if keywords is None:
        validators = registry.GetOrLoadAllValidators()
    else:
        names = [m.name for m in registry.GetValidatorMetadataForKeywords(keywords)]
        validators = registry.GetOrLoadValidatorsByName(names)
    if not validators:
        raise UsdValidationFailed("no USD validators are registered (usd-core too old?)")
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    return [
        f"{e.GetName() or e.GetValidator().GetMetadata().name}: {e.GetErrorAsString()}"
        for e in errors
        if not e.HasNoError()
    ]


def _outside(p: np.ndarray, e: np.ndarray, rtol: float) -> float | None:
    """How far points p (n, 3) lie outside the box e (2, 3), or None when inside up to rtol x size."""
    tol = rtol * max(float(np.max(e[1] - e[0])), 1e-12)
    worst = max(float(np.max(e[0] - p)), float(np.max(p - e[1])))
    return worst if worst > tol else None


def check_extents(stage_or_path, *, rtol: float = 1e-6) -> list[str]:
    """Check that every authored extent contains its prim's points at each time sample.

    For each UsdGeom.PointBased prim with an authored extent, at the union of the time samples of
    ``points`` and ``extent`` (or the default time when neither is animated), the points must lie
    inside [min, max] up to ``rtol`` x the extent's size (float32 storage). For each SkelRoot with
    an ``extentsHint``, the blend-shape meshes under it, deformed by UsdSkel at every time sample
    of their animation's weights (``blendshape_points``) and placed by their ``geomBindTransform``,
    must lie inside the hint.

    Returns:
        One line per violation (prim, time, how far outside); empty when all is well.
    """
    from pxr import Usd, UsdGeom

    stage = _open(stage_or_path)
    problems = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.PointBased):
            continue
        geom = UsdGeom.PointBased(prim)
        ext_attr, pts_attr = geom.GetExtentAttr(), geom.GetPointsAttr()
        if not ext_attr.HasAuthoredValue():
            if pts_attr.HasAuthoredValue():
                problems.append(f"{prim.GetPath()}: points authored without an extent")
            continue
        times = sorted(set(pts_attr.GetTimeSamples()) | set(ext_attr.GetTimeSamples()))
        for t in times or [Usd.TimeCode.Default()]:
            pts = pts_attr.Get(t)
            ext = ext_attr.Get(t)
            if pts is None or len(pts) == 0:
                continue
            label = "default" if not times else f"{t:g}"
            if ext is None or len(ext) != 2:
                problems.append(f"{prim.GetPath()} at time {label}: extent missing or malformed")
                continue
            worst = _outside(np.asarray(pts, dtype=np.float64), np.asarray(ext, dtype=np.float64), rtol)
            if worst is not None:
                problems.append(f"{prim.GetPath()} at time {label}: points lie {worst:.3g} m outside the extent")
    problems += _check_skel_extents_hints(stage, rtol)
    return problems


def _check_skel_extents_hints(stage, rtol: float) -> list[str]:
    from pxr import Usd, UsdGeom, UsdSkel

    problems = []
    xf = UsdGeom.XformCache()
    for root in stage.Traverse():
        if not root.IsA(UsdSkel.Root):
            continue
        hint_attr = UsdGeom.ModelAPI(root).GetExtentsHintAttr()
        if not hint_attr.HasAuthoredValue():
            continue
        hint = np.asarray(hint_attr.Get(), dtype=np.float64)[:2]  # the default purpose's box
        for prim in Usd.PrimRange(root):
            if not (prim.IsA(UsdGeom.Mesh) and prim.HasAPI(UsdSkel.BindingAPI)):
                continue
            binding = UsdSkel.BindingAPI(prim)
            if not binding.GetBlendShapeTargetsRel().GetTargets():
                continue
            skel = binding.GetInheritedSkeleton()
            src = UsdSkel.BindingAPI(skel.GetPrim()).GetAnimationSourceRel().GetTargets() if skel else []
            anim = UsdSkel.Animation(stage.GetPrimAtPath(src[0])) if src else None
            times = anim.GetBlendShapeWeightsAttr().GetTimeSamples() if anim else []
            m = np.asarray(xf.ComputeRelativeTransform(prim, root)[0])
            bind = binding.GetGeomBindTransformAttr().Get()
            if bind is not None:  # UsdSkel skins G-transformed points (a render mesh in its own units)
                m = np.asarray(bind) @ m
            for t in times or [Usd.TimeCode.Default().GetValue()]:
                pts = blendshape_points(stage, str(prim.GetPath()), t)
                worst = _outside(pts @ m[:3, :3] + m[3, :3], hint, rtol)
                if worst is not None:
                    problems.append(
                        f"{prim.GetPath()} at time {t:g}: blend-shape points lie {worst:.3g} m outside "
                        f"{root.GetPath()}.extentsHint"
                    )
    return problems


def blendshape_points(stage_or_path, mesh_path: str, time: float) -> np.ndarray:
    """Points of a blend-shape mesh at ``time`` as USD itself computes them (UsdSkel queries).

    Uses UsdSkel.Cache -> SkinningQuery -> the SkelAnimation's blendShapeWeights, remapped to the
    mesh's ``skel:blendShapes`` order, and UsdSkel.BlendShapeQuery.ComputeDeformedPoints.

    Returns:
        (n, 3) float64 deformed points (neutral + sum of weighted offsets).
    """
    from pxr import Usd, UsdSkel, Vt

    stage = _open(stage_or_path)
    prim = stage.GetPrimAtPath(mesh_path)
    if not prim:
        raise UsdValidationFailed(f"no prim at {mesh_path}")
    skel_root = UsdSkel.Root.Find(prim)
    if not skel_root:
        raise UsdValidationFailed(f"{mesh_path} is not under a SkelRoot")
    cache = UsdSkel.Cache()
    cache.Populate(skel_root, Usd.PrimDefaultPredicate)
    skinning = cache.GetSkinningQuery(prim)
    if not skinning:
        raise UsdValidationFailed(f"{mesh_path}: no skinning query (SkelBindingAPI / skel:skeleton missing)")
    skel_query = cache.GetSkelQuery(UsdSkel.BindingAPI(prim).GetInheritedSkeleton())
    anim_query = skel_query.GetAnimQuery()
    if not anim_query:
        raise UsdValidationFailed(f"{mesh_path}: skeleton has no animationSource")
    weights = anim_query.ComputeBlendShapeWeights(Usd.TimeCode(time))
    mapper = skinning.GetBlendShapeMapper()
    if mapper is not None and not mapper.IsNull():
        weights = mapper.Remap(weights)
    query = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(prim))
    sub_w, shape_idx, sub_idx = query.ComputeSubShapeWeights(weights)
    points = Vt.Vec3fArray(prim.GetAttribute("points").Get(Usd.TimeCode(time)))
    ok = query.ComputeDeformedPoints(
        sub_w, shape_idx, sub_idx, query.ComputeBlendShapePointIndices(), query.ComputeSubShapePointOffsets(), points
    )
    if not ok:
        raise UsdValidationFailed(f"{mesh_path}: UsdSkel.BlendShapeQuery.ComputeDeformedPoints failed")
    return np.asarray(points, dtype=np.float64)


def assert_stage_valid(stage_or_path) -> None:
    """Raise ``UsdValidationFailed`` listing every UsdValidation error and extent violation."""
    problems = validate_stage(stage_or_path) + check_extents(stage_or_path)
    if problems:
        name = stage_or_path if isinstance(stage_or_path, (str, Path)) else "stage"
        raise UsdValidationFailed(f"{name}: {len(problems)} problem(s):\n  " + "\n  ".join(problems))


def _numeric(v):
    """A float array for numeric USD values (arrays, vectors, matrices, quaternions), else None."""
    from pxr import Gf

    if isinstance(v, (bool, str)) or v is None:
        return None
    if isinstance(v, (Gf.Quatf, Gf.Quatd, Gf.Quath)):
        return np.array([v.GetReal(), *v.GetImaginary()], dtype=np.float64)
    try:
        if hasattr(v, "__len__") and len(v) and isinstance(v[0], (Gf.Quatf, Gf.Quatd, Gf.Quath)):
            return np.array([[q.GetReal(), *q.GetImaginary()] for q in v], dtype=np.float64)
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return a


def _same_value(a, b, rtol: float, atol: float) -> bool:
    """Equality with a tolerance for floats, recursing into dicts and lists (layer metadata)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same_value(a[k], b[k], rtol, atol) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same_value(x, y, rtol, atol) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) or isinstance(b, float):
        try:
            return bool(np.isclose(float(a), float(b), rtol=rtol, atol=atol))
        except (TypeError, ValueError):
            return False
    return a == b


def _compare_sparse_offsets(aa: dict, ab: dict, rtol: float, atol: float) -> str:
    """'' when two blend shapes' offsets agree as dense arrays (absent points: zero offset), else why."""
    dense = []
    for attrs in (aa, ab):
        idx = np.asarray(attrs["pointIndices"].Get(), dtype=np.int64)
        off = np.asarray(attrs["offsets"].Get(), dtype=np.float64).reshape(-1, 3)
        if idx.size != len(off):
            return f"{len(off)} offsets for {idx.size} point indices"
        dense.append(dict(zip(idx.tolist(), off, strict=True)))
    points = sorted(set(dense[0]) | set(dense[1]))
    zero = np.zeros(3)
    va = np.array([dense[0].get(i, zero) for i in points]).reshape(-1, 3)
    vb = np.array([dense[1].get(i, zero) for i in points]).reshape(-1, 3)
    if np.allclose(va, vb, rtol=rtol, atol=atol):
        return ""
    return f"max |difference| {np.max(np.abs(va - vb)):.3g} (as dense offsets over {len(points)} points)"


def compare_stages(
    a,
    b,
    *,
    rtol: float = 1e-5,
    atol: float = 1e-7,
    atol_by_attribute: dict[str, float] | None = None,
    metadata_rtol: float | None = None,
    max_report: int = 20,
) -> list[str]:
    """Differences in authored content between two stages (e.g. a committed scene and a fresh one).

    Compares stage metadata (timeCodesPerSecond, start/end, upAxis, metersPerUnit, defaultPrim,
    customLayerData), the prim paths and types, applied API schemas, attribute names, time samples
    and values (numbers with ``rtol`` / ``atol``: float32 round-off across platforms), and
    relationship targets. ``atol_by_attribute`` gives other absolute tolerances to attributes whose
    name contains a key (e.g. ``{"wface:activation": 1e-3}`` for the curves of a tracked take,
    which the tracker determines only to its stopping tolerance). ``metadata_rtol``: the relative
    tolerance of numbers in customLayerData (default ``rtol``). A sparse blend shape (``offsets`` with
    ``pointIndices``) is compared as the dense offsets it stands for, so a point whose offset lies at
    the writer's sparsity threshold may be listed in one stage and not the other.

    Returns:
        Up to ``max_report`` lines describing differences; empty when the stages match.
    """
    from pxr import UsdGeom

    sa, sb = _open(a), _open(b)
    out: list[str] = []

    def note(msg: str) -> bool:
        out.append(msg)
        return len(out) >= max_report

    for label, get in (
        ("timeCodesPerSecond", lambda s: s.GetTimeCodesPerSecond()),
        ("startTimeCode", lambda s: s.GetStartTimeCode()),
        ("endTimeCode", lambda s: s.GetEndTimeCode()),
        ("upAxis", UsdGeom.GetStageUpAxis),
        ("metersPerUnit", UsdGeom.GetStageMetersPerUnit),
        ("defaultPrim", lambda s: str(s.GetDefaultPrim().GetPath()) if s.GetDefaultPrim() else None),
        ("customLayerData", lambda s: dict(s.GetRootLayer().customLayerData)),
    ):
        tol = metadata_rtol if label == "customLayerData" and metadata_rtol is not None else rtol
        if not _same_value(get(sa), get(sb), tol, atol) and note(f"stage {label}: {get(sa)!r} != {get(sb)!r}"):
            return out
    prims_a = {str(p.GetPath()): p for p in sa.TraverseAll()}
    prims_b = {str(p.GetPath()): p for p in sb.TraverseAll()}
    for path in sorted(set(prims_a) ^ set(prims_b)):
        if note(f"prim {path} only in {'first' if path in prims_a else 'second'} stage"):
            return out
    for path in sorted(set(prims_a) & set(prims_b)):
        pa, pb = prims_a[path], prims_b[path]
        if pa.GetTypeName() != pb.GetTypeName() and note(f"{path}: type {pa.GetTypeName()} != {pb.GetTypeName()}"):
            return out
        if list(pa.GetAppliedSchemas()) != list(pb.GetAppliedSchemas()) and note(f"{path}: applied schemas differ"):
            return out
        ra = {r.GetName(): r.GetTargets() for r in pa.GetRelationships() if r.HasAuthoredTargets()}
        rb = {r.GetName(): r.GetTargets() for r in pb.GetRelationships() if r.HasAuthoredTargets()}
        if ra != rb and note(f"{path}: relationships differ ({sorted(ra)} vs {sorted(rb)})"):
            return out
        aa = {x.GetName(): x for x in pa.GetAttributes() if x.HasAuthoredValue()}
        ab = {x.GetName(): x for x in pb.GetAttributes() if x.HasAuthoredValue()}
        for name in sorted(set(aa) ^ set(ab)):
            if note(f"{path}.{name} authored only in {'first' if name in aa else 'second'} stage"):
                return out
        dense = {"offsets", "pointIndices"} <= set(aa) & set(ab) and pa.GetTypeName() == "BlendShape"
        if dense:
            tol = next((v for k, v in (atol_by_attribute or {}).items() if k in "offsets"), atol)
            why = _compare_sparse_offsets(aa, ab, rtol, tol)
            if why and note(f"{path}.offsets: {why}"):
                return out
        for name in sorted(set(aa) & set(ab)):
            if dense and name in ("offsets", "pointIndices"):
                continue
            xa, xb = aa[name], ab[name]
            ta, tb = xa.GetTimeSamples(), xb.GetTimeSamples()
            if ta != tb:
                if note(f"{path}.{name}: time samples differ ({len(ta)} vs {len(tb)})"):
                    return out
                continue
            for t in ta or [None]:
                va, vb = (xa.Get(t), xb.Get(t)) if t is not None else (xa.Get(), xb.Get())
                na, nb = _numeric(va), _numeric(vb)
                when = "" if t is None else f" at time {t:g}"
                if na is not None and nb is not None:
                    if na.shape != nb.shape:
                        same, why = False, f"shape {na.shape} != {nb.shape}"
                    else:
                        tol = next((v for k, v in (atol_by_attribute or {}).items() if k in name), atol)
                        same = bool(np.allclose(na, nb, rtol=rtol, atol=tol, equal_nan=True))
                        why = "" if same else f"max |difference| {np.max(np.abs(na - nb)):.3g}"
                else:
                    same, why = va == vb, f"{str(va)[:60]!r} != {str(vb)[:60]!r}"
                if not same:
                    if note(f"{path}.{name}{when}: {why}"):
                        return out
                    break
    return out
