"""Fit a template face to a subject: a neutral scan or artist head, and/or a neutral marker frame.

One map carries the whole template (docs/design.md, "Template fitting"; Sifakis et al. 2005,
section 3, morph an anatomical template to a subject's scan the same way):

1. Frame and scale. A similarity S(x) = s R x + t takes the template onto the target: from the
   landmarks (marker names the template shares with the target's landmark map or the capture;
   Umeyama 1991), refined by closest-point iterations onto the target surface. The fitted model
   lives in the target's frame turned back by R^T, z = R^T (y - t), so the template enters as
   s x and keeps wface's axes (+x left, +y up, +z forward) while the subject keeps its own size.
2. Skin. ``wface.faces.registration.register_surface`` moves the skin onto the target: landmarks,
   then non-rigid closest-point registration with a thin-plate smoothness term.
3. Interior. An elastic relaxation with wface's own inversion-safe FEM (a compressible
   Mooney-Rivlin material, rest shape s x) with the registered skin as the only Dirichlet
   condition, in load steps: the flesh, bone side included, follows the skin with the least
   distortion, so every tet stays positive and the tissue keeps its thickness where it can.
   The least distortion per unit volume is not the best worst tet: where the relaxation leaves
   tets worse than the template's worst (in smallest dihedral sine or in volume ratio), the free
   interior nodes of those tets are smoothed (``wface.mesh.improve``, smoothing alone: a compass
   search maximising min(sine angle, goal q / q_goal) over the node's tets, Klingner & Shewchuk
   2007). Skin, attached nodes and the rest of the boundary stay, tets and node ids are unchanged.
4. Bones are similarity-fitted: per bone, the similarity that best maps its attached nodes from
   s x to their relaxed places (Umeyama 1991) carries its meshes and teeth; the cranium's carries
   the jaw joint (axes turned, lengths scaled). The attached nodes keep their relaxed places and
   their attachment (the report gives their distance to the bone's similarity). Attachments and
   surface groups keep their node ids, fibre fractions their tets; fibre directions turn with
   the deformation gradient of their tet (d' = F d / |F d|); markers keep their skin embedding
   (triangle, barycentric weights, normal offset), or become the capture's own markers when a
   neutral frame was given.

Report (``FitReport.as_dict``): surface distance to the target (mean / max mm, template -> target
over the paired skin), landmark residuals, min dihedral angle and volume ratio before (the
template), after the relaxation and after the smoothing, inverted tets (0, or the fit raises).
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass, field, replace
from importlib import resources

import numpy as np

from wface.faces.registration import DEFAULT_SCHEDULE, register_surface
from wface.files import without_timings
from wface.mesh.align import FACE_SCALE_RANGE, Similarity, align_to_surface, embed_markers, umeyama
from wface.mesh.closest import SurfaceQuery
from wface.mesh.improve import improve_tets, tet_sine_quality_deg
from wface.mesh.meshfile import SurfaceMesh
from wface.mesh.quality import quality_report, signed_volumes, volume_ratio_quality
from wface.model import BoneMesh, FaceModel, JawJoint, Material, ModelError
from wface.physics import Simulator

__all__ = ["FitReport", "FitResult", "fit_template", "ict_feature_landmarks", "select_target_faces"]

#: material groups of an artist head that are not skin (eyes, mouth interior, hair cards)
NON_SKIN_GROUP_WORDS = ("eye", "iris", "sclera", "lacrimal", "lash", "teeth", "tooth", "gum", "tongue", "occlusion")
_SMOOTH_MAX_ROUNDS = 40  # interior smoothing: passes over the tets worse than the template's worst ...
_SMOOTH_STALL_ROUNDS = 2  # ... ending once two passes in a row leave the worst tet where it was
_RELAX_MATERIAL = Material(mu10_pa=1.0e3, mu01_pa=0.0, kappa_pa=3.0e3)  # nu ~ 0.29: thickness may change


@dataclass
class FitReport:
    """Numbers of a fit (see module docstring)."""

    scale: float
    surface_distance_mm: dict | None
    landmark_residual_mm: dict
    quality_before: dict
    quality_after: dict
    bones: dict
    relaxation_steps: int
    seconds: float
    registration_history: list = field(default_factory=list)
    quality_relaxed: dict | None = None
    interior_smoothing: dict | None = None

    def as_dict(self) -> dict:
        return {
            "scale": self.scale,
            "surface_distance_mm": self.surface_distance_mm,
            "landmark_residual_mm": self.landmark_residual_mm,
            "landmark_rms_mm": _rms(list(self.landmark_residual_mm.values())),
            "quality_before": self.quality_before,
            "quality_relaxed": self.quality_relaxed,
            "quality_after": self.quality_after,
            "interior_smoothing": self.interior_smoothing,
            "inverted_tets": self.quality_after["inverted"],
            "bones": self.bones,
            "relaxation_steps": self.relaxation_steps,
            "seconds": self.seconds,
        }


@dataclass
class FitResult:
    model: FaceModel
    report: FitReport
    target_to_model: np.ndarray  # (4, 4): target file coordinates (its units) -> fitted model metres


def _rms(v) -> float | None:
    v = [x for x in v if x is not None and np.isfinite(x)]
    return float(np.sqrt(np.mean(np.square(v)))) if v else None


def ict_feature_landmarks() -> dict[str, int]:
    """{marker name: ICT-FaceKit vertex} for 18 facial features (eye and mouth corners, lip midpoints,
    brows, nose), the dlib-68 landmark vertices of ICT's ``vertex_indices.json`` under the AnimFace
    names of ``wface.basis.landmarks.ANIMFACE_DLIB_SEEDS``. Unlike the 41-marker AnimFace map (where
    one actor's markers sit on the ICT head), these are anatomical features, which is what a fit
    needs as correspondences."""
    text = resources.files("wface").joinpath("data", "ict_feature_landmarks.json").read_text()
    return {str(k): int(v) for k, v in json.loads(text).items()}


def select_target_faces(mesh: SurfaceMesh, groups: list[str] | None = None) -> np.ndarray:
    """Face ids of the skin of a head: the named material groups, else every group whose name is
    not an eye, mouth-interior or lash part (``NON_SKIN_GROUP_WORDS``), else all faces."""
    if groups:
        return mesh.faces_of(groups)
    keep = [g for g in mesh.face_groups if not any(w in g.lower() for w in NON_SKIN_GROUP_WORDS)]
    if keep:
        return mesh.faces_of(keep)
    return np.arange(mesh.n_faces, dtype=np.int32)


def _initial_similarity(template_pts, target_pts, skin_x, target_v, target_t) -> Similarity:
    """Template -> target similarity: landmarks (>= 3 pairs), refined by projecting the template
    skin onto the target surface when there is one."""
    ok = np.isfinite(target_pts).all(axis=1)
    start = umeyama(template_pts[ok], target_pts[ok]) if ok.sum() >= 3 else None
    if target_v is None:
        if start is None:
            raise ValueError("a fit to markers alone needs at least 3 markers named like the template's")
        return start
    rng = np.random.default_rng(0)
    sub = skin_x[rng.choice(len(skin_x), size=min(800, len(skin_x)), replace=False)]
    if start is None:  # no landmarks: principal axes and closest points alone
        al = align_to_surface(sub, target_v, target_t, trim_fraction=0.2)
    else:  # the skin sample and the landmarks, both through the landmark similarity first
        pts = start.apply(np.vstack([sub, template_pts[ok]]))
        lm = np.vstack([np.full((len(sub), 3), np.nan), target_pts[ok]])
        al = align_to_surface(pts, target_v, target_t, landmark_points_m=lm, landmark_weight=5.0, trim_fraction=0.2)
    return al.transform if start is None else al.transform.compose(start)


def _relax(template: FaceModel, rest_m, pinned, pinned_m, *, device, solver, progress):
    """Elastic relaxation: nodes ``pinned`` moved to ``pinned_m`` in load steps; returns (x, steps)."""
    relax = FaceModel(
        rest_positions_m=rest_m,
        tets=template.tets,
        skin_triangles=template.skin_triangles,
        muscle_names=[],
        fibre_tet=np.zeros(0, np.int32),
        fibre_muscle=np.zeros(0, np.int32),
        fibre_fraction=np.zeros(0),
        fibre_direction=np.zeros((0, 3)),
        attached_nodes=pinned,
        attached_bone=np.zeros(len(pinned), np.int8),
        jaw_joint=template.jaw_joint,
        material=_RELAX_MATERIAL,
    )
    sim = Simulator(relax, device=device, solver=solver)
    move = pinned_m - rest_m[pinned]
    h = float(np.median(np.cbrt(np.abs(signed_volumes(rest_m, template.tets)) * 6.0)))
    steps = int(np.clip(np.ceil(np.abs(move).max() / (0.5 * h)), 1, 8))
    x = rest_m.copy()
    for k in range(1, steps + 1):
        eq = sim.solve(None, rest_m[pinned] + move * (k / steps), x0=x, tol=1e-6, max_iterations=60)
        x = eq.x
        if progress is not None:
            progress(f"relaxation step {k}/{steps}: residual {eq.residual_rel:.2g}, inverted {eq.inverted_elements}")
    return x, steps


def _volume(template, rest_s, skin_x, *, device, solver, progress):
    """Every node's place for the registered skin (module docstring, step 3): an elastic relaxation
    with the skin as the only Dirichlet condition. Returns (x, load steps)."""
    skin = np.unique(template.skin_triangles).astype(np.int32)
    x, steps = _relax(template, rest_s, skin, skin_x[skin], device=device, solver=solver, progress=progress)
    n_bad = int(np.count_nonzero(signed_volumes(x, template.tets) <= 0))
    if n_bad:
        raise ModelError(
            f"template fit: {n_bad} tet(s) inverted after the interior relaxation (the registered skin folds "
            "or passes through itself): check the target's units, its skin groups and the landmarks"
        )
    return x, steps


def _smooth_interior(template: FaceModel, x: np.ndarray) -> tuple[np.ndarray, dict]:
    """The relaxed flesh's tets worse than the template's worst tet (in smallest dihedral sine or in
    volume ratio) raised by moving their free interior nodes (module docstring, step 3): per node a
    compass search maximising the smallest quality of its tets (``wface.mesh.improve``, smoothing
    alone). The skin, the attached nodes and the rest of the boundary stay; tets and node ids are
    unchanged. Returns (x, what it did)."""
    x_t = template.rest_positions_m
    goal_deg = float(tet_sine_quality_deg(x_t[template.tets]).min())
    volume_ratio_goal = float(volume_ratio_quality(x_t, template.tets).min())
    locked = np.zeros(len(x), dtype=bool)
    locked[template.attached_nodes] = True
    x_new, tets, _, rep = improve_tets(
        x,
        template.tets,
        goal_deg=goal_deg,
        volume_ratio_goal=volume_ratio_goal,
        locked=locked,
        operations=("smooth",),
        max_rounds=_SMOOTH_MAX_ROUNDS,
        stall_rounds=_SMOOTH_STALL_ROUNDS,
    )
    if len(x_new) != len(x) or not np.array_equal(tets, template.tets):  # smoothing never edits the tets
        raise ModelError("template fit: the interior smoothing changed the mesh's topology")
    return x_new, {
        "method": "compass search of free interior nodes (wface.mesh.improve, smoothing alone)",
        "goal_sine_deg": goal_deg,
        "goal_volume_ratio": volume_ratio_goal,
        "below_goal_before": rep.below_goal_before,
        "below_goal_after": rep.below_goal_after,
        "min_dihedral_before_deg": rep.min_dihedral_before_deg,
        "min_dihedral_after_deg": rep.min_dihedral_after_deg,
        "moved_nodes": rep.moved_nodes,
        "moves": rep.operations["smooth"],
        "rounds": rep.rounds,
        "seconds": rep.seconds,
    }


def _interior(template: FaceModel, rest_s, skin_x, smooth: bool, device, solver, say):
    """(x, load steps, quality after the relaxation, smoothing report or None): the interior's place for
    the registered skin ``skin_x`` (module docstring, step 3), then its smoothing."""
    x, steps = _volume(template, rest_s, skin_x, device=device, solver=solver, progress=say)
    skin = np.unique(template.skin_triangles)
    x[skin] = skin_x[skin]
    quality_relaxed = quality_report(x, template.tets).as_dict()
    smoothing = None
    if smooth:
        x, smoothing = _smooth_interior(template, x)
        say(
            f"interior smoothing: {smoothing['moved_nodes']} free node(s) moved, worst dihedral "
            f"{smoothing['min_dihedral_before_deg']:.1f} -> {smoothing['min_dihedral_after_deg']:.1f} deg; "
            f"tets below the template's worst quality {smoothing['below_goal_before']} -> "
            f"{smoothing['below_goal_after']} (raising a node's worst tet can add some), {smoothing['seconds']:.1f} s"
        )
    return x, steps, quality_relaxed, smoothing


def _bone_similarities(template: FaceModel, rest_s: np.ndarray, x: np.ndarray) -> dict[str, Similarity]:
    """Per bone, the similarity that best maps its attached nodes from the scaled template to the
    fitted flesh (Umeyama 1991); the identity for a bone without attached nodes."""
    out = {}
    for bone in ("cranium", "jaw"):
        nodes = template.nodes_of_bone(bone)
        out[bone] = umeyama(rest_s[nodes], x[nodes]) if len(nodes) >= 3 else Similarity()
    return out


def _carry_fibres(template: FaceModel, x_new: np.ndarray) -> np.ndarray:
    """Fibre directions turned by the deformation gradient of their tet."""
    p = x_new[template.tets[template.fibre_tet]]
    ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    F = ds @ template.dm_inv[template.fibre_tet]
    d = np.einsum("kij,kj->ki", F, template.fibre_direction)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _landmark_point(spec, surface: SurfaceMesh) -> np.ndarray:
    """A landmark in metres: a vertex id of ``surface`` or a point in its units."""
    if np.ndim(spec) == 0:
        return surface.points_m[int(spec)]
    return np.asarray(spec, dtype=np.float64).reshape(3) * surface.meters_per_unit


def _check_scale(scale: float, surface: SurfaceMesh | None) -> None:
    """Refuse a target far from a face's size: wrong units (a cm head read as mm is 10x too small)."""
    lo, hi = FACE_SCALE_RANGE
    if not lo <= scale <= hi:
        units = f" (read at {surface.meters_per_unit:g} m per unit: check --units)" if surface is not None else ""
        raise ValueError(
            f"the target is {scale:.3g} times the template's size (plausible: {lo:g} to {hi:g}){units}; or the "
            "alignment failed: give --landmarks"
        )


def _check_landmark_names(template: FaceModel, names: list[str], used: list[str]) -> None:
    """Refuse landmarks none of which the template has; warn of those it lacks (they are not used)."""
    if not names:
        return
    unknown = [n for n in names if n not in set(template.marker_names)]
    if not used:
        raise ValueError(
            f"none of the landmark names ({', '.join(names[:8])}) is one of the template's markers (e.g. "
            f"{', '.join(template.marker_names[:8])}): name each landmark after the template marker it stands for"
        )
    if unknown:
        warnings.warn(f"landmarks that are not the template's markers, not used: {', '.join(unknown)}", stacklevel=3)


def _landmark_pairs(template: FaceModel, names: list[str], target_points_m: np.ndarray):
    """(names, template skin embedding, template points, target points) of the shared marker names."""
    known = dict(zip(template.marker_names, template.marker_positions_m, strict=True))
    pairs = [(n, known[n], p) for n, p in zip(names, target_points_m, strict=True) if n in known]
    if not pairs:
        return [], None, np.zeros((0, 3)), np.zeros((0, 3))
    shared, tpl, tgt = zip(*pairs, strict=True)
    tpl, tgt = np.array(tpl), np.array(tgt)
    emb = embed_markers(tpl, template.rest_positions_m, template.skin_triangles)
    return list(shared), emb, tpl, tgt


def _carry_model(
    template: FaceModel, x: np.ndarray, s: float, bone_sim: dict, marker_names, marker_positions, metadata
):
    joint = template.jaw_joint
    cr = bone_sim["cranium"]  # the joint's fossae are on the cranium
    u = cr.rotation @ np.asarray(joint.u)
    v = cr.rotation @ np.asarray(joint.v)
    v = v - (v @ u) * u
    jj = JawJoint(
        u=tuple(float(c) for c in u / np.linalg.norm(u)),
        v=tuple(float(c) for c in v / np.linalg.norm(v)),
        midpoint_m=tuple(float(c) for c in cr.apply(s * np.asarray(joint.midpoint_m))),
        condyle_distance_m=cr.scale * s * joint.condyle_distance_m,
        track_length_m=cr.scale * s * joint.track_length_m,
        max_opening_sine=joint.max_opening_sine,
        max_closing_sine=joint.max_closing_sine,
    )
    bones = {
        k: BoneMesh(bone_sim[b.bone].apply(s * b.vertices_m), b.triangles.copy(), b.bone)
        for k, b in template.bone_meshes.items()
    }
    return replace(
        template,
        rest_positions_m=x,
        fibre_direction=_carry_fibres(template, x),
        jaw_joint=jj,
        bone_meshes=bones,
        marker_names=list(marker_names),
        marker_positions_m=np.asarray(marker_positions, dtype=np.float64),
        metadata=metadata,
    ).validate()


def _deviation_mm(sim: Similarity, rest_s, x, nodes) -> dict:
    """How far the fitted attached nodes lie from their bone's similarity (mean / max mm)."""
    if len(nodes) == 0:
        return {"mean": 0.0, "max": 0.0}
    d = np.linalg.norm(sim.apply(rest_s[nodes]) - x[nodes], axis=1) * 1e3
    return {"mean": float(d.mean()), "max": float(d.max())}


def _surface_distance_mm(x, skin_tri, target_v, target_t, used) -> dict:
    skin = np.unique(skin_tri)
    d = SurfaceQuery(target_v, target_t).closest(x[skin]).distance_m * 1e3
    paired = used[skin]
    return {
        "mean": float(d[paired].mean()),
        "max": float(d[paired].max()),
        "p95": float(np.percentile(d[paired], 95)),
        "paired_skin_vertices": int(paired.sum()),
        "skin_vertices": int(len(skin)),
    }


def fit_template(
    template: FaceModel,
    *,
    surface: SurfaceMesh | None = None,
    surface_faces: np.ndarray | None = None,
    landmarks: dict[str, int] | None = None,
    markers_m: np.ndarray | None = None,
    marker_names: list[str] | None = None,
    schedule: tuple[tuple[float, int], ...] = DEFAULT_SCHEDULE,
    smooth_interior: bool = True,
    device: str = "cpu",
    solver: str = "auto",
    progress=None,
) -> FitResult:
    """Fit ``template`` to a target surface and/or a neutral marker frame (module docstring).

    Args:
        template: the face to morph (built-in, imported, or an earlier fit).
        surface: the target head (``wface.mesh.meshfile.read_surface_mesh``; its units are used).
        surface_faces: face ids of ``surface`` that are skin (default ``select_target_faces``).
        landmarks: {marker name: surface vertex id, or a point in the surface's units} (e.g. the
            ICT AnimFace map).
        markers_m: (k, 3) the actor's neutral marker frame in metres (NaN = missing).
        marker_names: the k marker names; with ``surface`` they only replace the template's
            markers (rigidly aligned to the fitted skin), without it they drive the fit.
        schedule: the registration's (alpha, iterations) stages.
        smooth_interior: move free interior nodes after the relaxation to raise the worst tets
            (module docstring, step 3); False keeps the relaxed places.
        device, solver: of the interior relaxation (``wface.physics.Simulator``).
        progress: optional callable(str) for progress lines.

    Returns:
        ``FitResult``: the fitted, validated model (``metadata["fit"]`` holds the report), the
        report and ``target_to_model``.
    """
    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    if surface is None and markers_m is None:
        raise ValueError("fit_template needs a target: a surface, a neutral marker frame, or both")
    if markers_m is not None and (marker_names is None or len(marker_names) != len(markers_m)):
        raise ValueError("markers_m needs one name per marker (marker_names)")
    skin_tri = template.skin_triangles
    skin = np.unique(skin_tri)
    x_t = template.rest_positions_m
    target_v = target_t = None
    if surface is not None:
        faces = select_target_faces(surface) if surface_faces is None else np.asarray(surface_faces)
        tri, face_of = surface.triangles(), surface.triangle_faces()
        target_t = tri[np.isin(face_of, faces)]
        target_v = surface.points_m
        names = list(landmarks or {})
        pts = np.array([_landmark_point(landmarks[n], surface) for n in names]).reshape(-1, 3)
    else:
        names = list(marker_names)
        pts = np.asarray(markers_m, dtype=np.float64)
    lm_names, lm_emb, lm_tpl, lm_tgt = _landmark_pairs(template, names, pts)
    _check_landmark_names(template, names if surface is not None else [], lm_names)
    S = _initial_similarity(lm_tpl, lm_tgt, x_t[skin], target_v, target_t)
    to_fit = Similarity(1.0, S.rotation.T, -S.rotation.T @ S.translation_m)  # z = R^T (y - t)
    say(f"similarity: scale {S.scale:.4f} from {len(lm_names)} landmark(s)")
    _check_scale(float(S.scale), surface)
    rest_s = S.scale * x_t
    reg = register_surface(
        rest_s,
        skin_tri,
        target_vertices_m=None if target_v is None else to_fit.apply(target_v),
        target_triangles=target_t,
        landmark_triangles=None if lm_emb is None else lm_emb.triangle,
        landmark_barycentric=None if lm_emb is None else lm_emb.barycentric,
        landmark_targets_m=None if lm_emb is None else to_fit.apply(lm_tgt),
        schedule=schedule,
        progress=say,
    )
    x, steps, quality_relaxed, smoothing = _interior(
        template, rest_s, reg.vertices_m, smooth_interior, device, solver, say
    )
    bone_sim = _bone_similarities(template, rest_s, x)
    emb = embed_markers(template.marker_positions_m, x_t, skin_tri)
    mk_names, mk_pos = list(template.marker_names), emb.marker_positions(x, skin_tri)
    if markers_m is not None:
        mk_names, mk_pos = _capture_markers(x, skin_tri, template, mk_pos, marker_names, markers_m, to_fit, surface)
    report = FitReport(
        scale=float(S.scale),
        surface_distance_mm=None
        if target_v is None
        else _surface_distance_mm(x, skin_tri, to_fit.apply(target_v), target_t, reg.used),
        landmark_residual_mm=dict(zip(lm_names, (reg.landmark_residual_m * 1e3).tolist(), strict=True)),
        quality_before=quality_report(x_t, template.tets).as_dict(),
        quality_after=quality_report(x, template.tets).as_dict(),
        bones={
            b: {
                "scale": float(S.scale * sim.scale),
                "attachment_deviation_mm": _deviation_mm(sim, rest_s, x, template.nodes_of_bone(b)),
            }
            for b, sim in bone_sim.items()
        },
        relaxation_steps=steps,
        seconds=time.perf_counter() - t0,
        registration_history=reg.history,
        quality_relaxed=quality_relaxed,
        interior_smoothing=smoothing,
    )
    if report.quality_after["inverted"]:
        raise ModelError(f"template fit left {report.quality_after['inverted']} inverted tet(s)")
    units = 1.0 if surface is None else surface.meters_per_unit
    to_model = to_fit.as_matrix() @ np.diag([units, units, units, 1.0])
    meta = dict(template.metadata)
    meta["name"] = f"{template.metadata.get('name', 'face')} fitted"
    meta["fit"] = {
        "template": template.metadata.get("name", ""),
        "surface": None if surface is None else surface.source,
        "surface_vertices": None if surface is None else surface.n_points,
        "surface_meters_per_unit": None if surface is None else surface.meters_per_unit,
        "markers": len(markers_m) if markers_m is not None else 0,
        "target_to_model": to_model.tolist(),
        "bones": "similarity per bone, fitted to the relaxed flesh at its attached nodes",
        **without_timings(report.as_dict()),
    }
    model = _carry_model(template, x, float(S.scale), bone_sim, mk_names, mk_pos, meta)
    return FitResult(model, report, to_model)


def _capture_markers(x, skin_tri, template, mk_pos, names, markers_m, to_fit, surface):
    """The capture's own markers on the fitted face: mapped by the fit's frame (markers drove the
    fit), or rigidly aligned to the fitted skin with the model's markers as landmarks (a surface fit)."""
    m = np.asarray(markers_m, dtype=np.float64)
    ok = np.isfinite(m).all(axis=1)  # a marker missing at the neutral frame has no rest place
    names, m = [n for n, k in zip(names, ok, strict=True) if k], m[ok]
    if surface is None:
        return list(names), to_fit.apply(m)
    known = dict(zip(template.marker_names, mk_pos, strict=True))
    lm = np.array([known.get(n, np.full(3, np.nan)) for n in names])
    al = align_to_surface(
        m, x, skin_tri, landmark_points_m=lm, landmark_weight=1.0, with_scale=False, trim_fraction=0.1
    )
    return list(names), al.aligned_m
