"""Calibrate Waters muscle parameters against reference displacement fields (e.g. artist-made shapes).

For one muscle (and its mirror partner ``_l`` <-> ``_r``), bounded Powell search over its
geometry and strength minimises the relative squared error of the displacement an action-unit
set produces against a reference field on the same mesh:

    E = sum_v |d_v(params) - d_ref_v|^2 / sum_v |d_ref_v|^2

Linear muscle parameters: bone offset (3), insertion offset (3; re-snapped to the skin when a
surface is given), zone angle, Rs / |V2 - V1|, Rf / Rs and K. Sphincter: centre offset (3),
semi-axis scales (3), tension and, when ranges are given, the protrusion along the ring's normal
and the lower vertical semi-axis (an egg-shaped ring). ``ICT_SHAPES`` pairs action units with the
ICT-FaceKit shapes (``ict_expressions.npz``) that show the same facial action.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize

from wface.mesh.closest import SurfaceQuery
from wface.waters.expressions import pose_from_action_units
from wface.waters.layout import MuscleLayout
from wface.waters.muscles import LinearMuscle
from wface.waters.rig import WatersRig

__all__ = [
    "ICT_SHAPES",
    "Agreement",
    "CalibrationResult",
    "calibrate_muscle",
    "mirror_name",
    "reference_agreement",
    "relative_error",
]

# action unit, ICT-FaceKit shape, muscle to calibrate (the action unit's main muscle)
ICT_SHAPES: tuple[tuple[str, str, str], ...] = (
    ("AU12L", "mouthSmile_L", "zygomaticus_major_l"),
    ("AU1L", "browInnerUp_L", "frontalis_medial_l"),
    ("AU2L", "browOuterUp_L", "frontalis_lateral_l"),
    ("AU4L", "browDown_L", "corrugator_l"),
    ("AU15L", "mouthFrown_L", "depressor_anguli_oris_l"),
    ("AU20L", "mouthStretch_L", "risorius_l"),
    ("AU10L", "mouthUpperUp_L", "levator_labii_superioris_l"),
    ("AU9L", "noseSneer_L", "levator_labii_superioris_alaeque_nasi_l"),
    ("AU6L", "cheekSquint_L", "orbicularis_oculi_l"),
    ("AU7L", "eyeSquint_L", "orbicularis_oculi_palpebral_l"),
    ("AU18", "mouthPucker", "incisivus_labii_superioris"),
    ("AU18", "mouthPucker", "incisivus_labii_inferioris"),
    ("AU14L", "mouthDimple_L", "buccinator_l"),
    ("AU16L", "mouthLowerDown_L", "depressor_labii_inferioris_l"),
    ("AU17", "mouthShrugLower", "mentalis_l"),
    ("AU5L", "eyeWide_L", "levator_palpebrae_l"),
)


def mirror_name(name: str) -> str | None:
    """``zygomaticus_major_l`` -> ``zygomaticus_major_r`` (and back); None for midline muscles."""
    if name.endswith("_l"):
        return name[:-2] + "_r"
    if name.endswith("_r"):
        return name[:-2] + "_l"
    return None


def relative_error(d: np.ndarray, ref: np.ndarray) -> float:
    """sum |d - ref|^2 / sum |ref|^2 over all rows."""
    return float(((d - ref) ** 2).sum() / max((ref**2).sum(), 1e-300))


@dataclass
class Agreement:
    """How an action unit's displacement compares with a reference shape.

    Attributes:
        relative_error: sum |d - ref|^2 / sum |ref|^2 over the rows compared.
        cosine: <d, ref> / (|d| |ref|) over the same rows (direction of the whole field).
        reference_mm: mean |ref| over the strongly moving vertices (|ref| above half its maximum).
        along_mm: mean of d projected on the local ref direction there (the motion the right way).
        magnitude_mm: mean |d| there.
        vertices: how many strongly moving vertices.
    """

    relative_error: float
    cosine: float
    reference_mm: float
    along_mm: float
    magnitude_mm: float
    vertices: int


def reference_agreement(
    rig: WatersRig,
    reference_m: np.ndarray,
    action_units: Mapping[str, float],
    *,
    rows: np.ndarray | None = None,
    jaw_opening_deg: float | None = None,
) -> Agreement:
    """Compare the displacement of ``action_units`` on ``rig`` with ``reference_m`` (n, 3) metres.

    Args:
        rows: vertices compared (default all; e.g. the ICT face region 0-9408).
        jaw_opening_deg: jaw angle (default the action units' own).
    """

    pose = pose_from_action_units(action_units, rig.muscle_names)
    jaw = pose.jaw_opening_deg if jaw_opening_deg is None else jaw_opening_deg
    d = rig.deform(pose.contractions, jaw_opening_deg=jaw) - rig.rest_positions_m
    ref = np.asarray(reference_m, dtype=np.float64)
    if rows is not None:
        d, ref = d[rows], ref[rows]
    size = np.linalg.norm(ref, axis=1)
    strong = size > 0.5 * size.max()
    unit = ref[strong] / size[strong, None]
    den = np.linalg.norm(d) * np.linalg.norm(ref)
    return Agreement(
        relative_error(d, ref),
        float((d * ref).sum() / den) if den > 0 else 0.0,
        float(size[strong].mean() * 1e3),
        float(np.einsum("ij,ij->i", d[strong], unit).mean() * 1e3),
        float(np.linalg.norm(d[strong], axis=1).mean() * 1e3),
        int(strong.sum()),
    )


@dataclass
class CalibrationResult:
    layout: MuscleLayout
    muscle: str
    error_before: float
    error_after: float
    evaluations: int


_FLIP = np.array([-1.0, 1.0, 1.0])


def _mirror(m):
    other = mirror_name(m.name)
    if isinstance(m, LinearMuscle):
        return replace(m, name=other, bone_m=m.bone_m * _FLIP, insertion_m=m.insertion_m * _FLIP)
    return replace(
        m, name=other, centre_m=m.centre_m * _FLIP, horizontal=m.horizontal * _FLIP * -1, vertical=m.vertical * _FLIP
    )


def calibrate_muscle(
    layout: MuscleLayout,
    rest_positions_m: np.ndarray,
    reference_m: np.ndarray,
    *,
    muscle: str,
    action_units: Mapping[str, float],
    jaw_opening_deg: float = 0.0,
    vertices: np.ndarray | None = None,
    surface: tuple[np.ndarray, np.ndarray] | None = None,
    mirror: bool = True,
    max_evaluations: int = 400,
    bone_range_m: float = 0.012,
    insertion_range_m: float = 0.006,
    centre_range_m: float = 0.005,
    axis_scale_range: tuple = (0.8, 1.25),
    protrusion_range_m: tuple[float, float] | None = None,
    lower_axis_scale_range: tuple[float, float] | None = None,
    bounds_from: MuscleLayout | None = None,
) -> CalibrationResult:
    """Fit one muscle's parameters so the action units reproduce ``reference_m``.

    Args:
        layout: layout to start from (metres); returned as a new layout, the input is unchanged.
        rest_positions_m: (n, 3) mesh rest positions.
        reference_m: (n, 3) reference displacement of the same action, metres.
        muscle: the muscle to calibrate (its mirror partner follows when ``mirror``).
        action_units: the action units whose displacement is compared (e.g. ``{"AU12L": 1.0}``).
        jaw_opening_deg: jaw angle used with them.
        vertices: rows of the mesh that count (default: all); the muscle vertex mask also applies.
        surface: (vertices_m, triangles) of the skin, to keep insertions on it.
        max_evaluations: objective evaluations of the Powell search.
        bone_range_m, insertion_range_m: how far bone / insertion may move.
        centre_range_m, axis_scale_range: how far a sphincter's centre may move and how much its
            semi-axes may scale (kept tight: a ring muscle stays around its orifice); the scale
            bounds are numbers or one per axis (horizontal, vertical, depth).
        protrusion_range_m: (low, high) bounds of a sphincter's protrusion (metres); None keeps
            the layout's value.
        lower_axis_scale_range: (low, high) scale of a sphincter's vertical semi-axis below its
            centre relative to the start layout's (an egg-shaped ring); None keeps the ellipse's
            own proportion.
        bounds_from: the layout whose muscle the bounds are measured from (default ``layout``):
            repeated calibrations (restarts) then stay within one set of bounds instead of
            compounding them.
    """

    x = np.asarray(rest_positions_m, dtype=np.float64)
    ref = np.asarray(reference_m, dtype=np.float64)
    if ref.shape != x.shape:
        raise ValueError(f"reference has shape {ref.shape}, expected {x.shape}")
    rows = np.arange(len(x)) if vertices is None else np.asarray(vertices, dtype=np.int64)
    mask = layout.muscle_vertex_mask(len(x))
    if mask is not None:
        rows = rows[mask[rows]]
    pose = pose_from_action_units(action_units, layout.muscle_names)
    if muscle not in pose.contractions:
        raise ValueError(f"action units {dict(action_units)} do not contract {muscle!r}")
    used = [m for m in layout.muscles if m.name in pose.contractions]
    m0 = layout.muscle(muscle)  # the start
    mb = m0 if bounds_from is None else bounds_from.muscle(muscle)  # the origin of the bounds
    if type(mb) is not type(m0):
        raise ValueError(f"bounds_from has {muscle!r} as a different kind of muscle")
    query = None
    if surface is not None:
        query = SurfaceQuery(*surface)

    if isinstance(m0, LinearMuscle):
        lo, hi, p0, build = _linear_space(m0, mb, query, bone_range_m, insertion_range_m)
    else:
        lo, hi, p0, build = _sphincter_space(
            m0, mb, centre_range_m, axis_scale_range, protrusion_range_m, lower_axis_scale_range
        )

    partner = mirror_name(muscle) if mirror else None
    error, count = _objective(layout, used, muscle, partner, build, lo, hi, x[rows], ref[rows], pose, jaw_opening_deg)
    q0 = np.clip((p0 - lo) / np.maximum(hi - lo, 1e-300), 0.0, 1.0)
    before = error(q0)
    res = minimize(
        error,
        q0,
        method="Powell",
        bounds=[(0.0, 1.0)] * len(q0),
        options={"maxfev": max_evaluations, "xtol": 1e-3, "ftol": 1e-4},
    )
    best = res.x if res.fun < before else q0
    fitted = build(lo + np.clip(best, 0, 1) * (hi - lo))
    muscles = [fitted if u.name == muscle else u for u in layout.muscles]
    if mirror and partner is not None and any(u.name == partner for u in layout.muscles):
        muscles = [_mirror(fitted) if u.name == partner else u for u in muscles]
    return CalibrationResult(replace(layout, muscles=muscles), muscle, before, min(float(res.fun), before), count[0])


def _linear_space(m0: LinearMuscle, mb: LinearMuscle, query, bone_range_m: float, insertion_range_m: float):
    """(low bounds, high bounds, start, parameters -> muscle) of a linear muscle's search: bone and insertion
    offsets from ``mb``, zone angle, fall-off start (a fraction of the length) and finish, spring constant."""
    length = float(np.linalg.norm(m0.insertion_m - m0.bone_m))
    lo = np.r_[-np.ones(3) * bone_range_m, -np.ones(3) * insertion_range_m, 8.0, 0.6, 1.1, 0.0]
    hi = np.r_[np.ones(3) * bone_range_m, np.ones(3) * insertion_range_m, 60.0, 1.4, 2.5, 3.0 * mb.spring_constant_m]
    p0 = np.r_[
        m0.bone_m - mb.bone_m, m0.insertion_m - mb.insertion_m, m0.zone_deg, m0.fall_start_m / length,
        m0.fall_finish_m / m0.fall_start_m, m0.spring_constant_m,
    ]  # fmt: skip

    def build(p):
        bone = mb.bone_m + p[0:3]
        ins = mb.insertion_m + p[3:6]
        if query is not None:
            ins = query.closest(ins[None]).point_m[0]
        rs = p[7] * float(np.linalg.norm(ins - bone))
        return replace(
            m0,
            bone_m=bone,
            insertion_m=ins,
            zone_deg=float(p[6]),
            fall_start_m=rs,
            fall_finish_m=rs * p[8],
            spring_constant_m=float(p[9]),
        )

    return lo, hi, p0, build


def _sphincter_space(m0, mb, centre_range_m, axis_scale_range, protrusion_range_m, lower_axis_scale_range):
    """(low bounds, high bounds, start, parameters -> muscle) of a sphincter's search: centre offset from
    ``mb``, semi-axis scales, tension, and optionally protrusion and the lower semi-axis scale."""
    scale_lo = np.broadcast_to(np.asarray(axis_scale_range[0], dtype=np.float64), (3,))
    scale_hi = np.broadcast_to(np.asarray(axis_scale_range[1], dtype=np.float64), (3,))
    lo = np.r_[-np.ones(3) * centre_range_m, scale_lo, 0.02]
    hi = np.r_[np.ones(3) * centre_range_m, scale_hi, 0.9]
    p0 = np.r_[m0.centre_m - mb.centre_m, m0.semi_axes_m / mb.semi_axes_m, m0.tension]
    free = []  # optional parameters after the 7 fixed ones: (name, low, high, start)
    if protrusion_range_m is not None:
        free.append(("protrusion", min(protrusion_range_m[0], mb.protrusion_m),
                     max(protrusion_range_m[1], mb.protrusion_m), m0.protrusion_m))  # fmt: skip
    if lower_axis_scale_range is not None:
        start = m0.below_m / (mb.below_m * m0.semi_axes_m[1] / mb.semi_axes_m[1])
        free.append(("lower", lower_axis_scale_range[0], lower_axis_scale_range[1], start))
    lo = np.r_[lo, [f[1] for f in free]]
    hi = np.r_[hi, [f[2] for f in free]]
    p0 = np.r_[p0, [f[3] for f in free]]

    def build(p):
        extra = {}
        for k, (name, *_) in enumerate(free):
            if name == "protrusion":
                extra["protrusion_m"] = float(p[7 + k])
            else:  # the lower semi-axis scales with the vertical one and by its own factor
                extra["lower_semi_axis_m"] = float(mb.below_m * p[4] * p[7 + k])
        if "lower_semi_axis_m" not in extra and mb.lower_semi_axis_m:
            extra["lower_semi_axis_m"] = float(mb.lower_semi_axis_m * p[4])
        return replace(m0, centre_m=mb.centre_m + p[0:3], semi_axes_m=mb.semi_axes_m * p[3:6],
                       tension=float(p[6]), **extra)  # fmt: skip

    return lo, hi, p0, build


def _objective(layout, used, muscle, partner, build, lo, hi, pts, target, pose, jaw_opening_deg):
    """The search's objective of normalised parameters q in [0, 1]^d (the relative error of the displacement
    on ``pts`` against ``target``, 1e3 for an invalid muscle) and its evaluation counter ([count])."""

    def layout_with(m):
        muscles = [m if u.name == muscle else u for u in used]
        if partner is not None and any(u.name == partner for u in used):
            muscles = [_mirror(m) if u.name == partner else u for u in muscles]
        return replace(layout, muscles=muscles, mesh_vertex_count=None, muscle_vertex_ranges=[])

    count = [0]

    def error(q):
        count[0] += 1
        p = lo + np.clip(q, 0.0, 1.0) * (hi - lo)
        try:
            lay = layout_with(build(p))
        except ValueError:
            return 1e3
        rig = WatersRig(lay, pts, muscle_mask=np.ones(len(pts), bool))
        d = rig.deform(pose.contractions, jaw_opening_deg=jaw_opening_deg) - pts
        return relative_error(d, target)

    return error, count
