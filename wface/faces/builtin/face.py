"""Build the built-in face: a deterministic, procedurally generated anatomical face model.

``build_face(target_tets=N)`` meshes the soft tissue between the bone surface and the skin of
``FaceShape`` as a structured, mirror-symmetric tet grid (``grid.build_grid``), cuts the mouth,
attaches tissue to cranium and jaw, embeds the muscles of ``anatomy.MUSCLES`` with per-tet
volume fractions and fibre directions, places the skin markers and records the jaw joint and the
FACS table. The same N always gives bit-identical output.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from tqdm.auto import tqdm

from wface import facs
from wface.faces.builtin.anatomy import MARKERS, MUSCLES, VESTIBULE_TOP_M, bone_region, muscle_paths
from wface.faces.builtin.bones import bone_meshes
from wface.faces.builtin.grid import build_grid, graded_axis
from wface.faces.builtin.shape import THETA_MAX, THETA_MOUTH, Y_BOTTOM, Y_MOUTH, Y_TOP, FaceShape
from wface.mesh.closest import SurfaceQuery
from wface.mesh.quality import quality_report, signed_volumes
from wface.mesh.surface import boundary_faces
from wface.model import FaceModel, JawJoint, Material

__all__ = ["build_face", "BUILDER_VERSION", "JAW_JOINT"]

BUILDER_VERSION = 1
MIN_TETS, MAX_TETS = 1_000, 2_000_000

# Temporomandibular joint of the built-in face: condyles 10.4 cm apart, just in front of the ears;
# sliding tracks inclined 22 degrees down toward the front (articular eminence); 35 degrees max opening.
# The rest pose is the postural rest (lips together, incisal edges 1.6 mm apart), from which the jaw
# closes by the freeway space, 2-4 mm at the incisors (the upper end; the lower incisal edge lies
# 100 mm from the hinge axis): 2.3 degrees closing past rest (docs/design.md, "Controls and the jaw
# joint"; captures need it, README "Your actor, your head").
FREEWAY_SPACE_M, INCISOR_TO_HINGE_M = 0.004, 0.100
JAW_JOINT = JawJoint(
    u=(1.0, 0.0, 0.0),
    v=tuple(np.array([0.0, -0.4, 1.0]) / np.linalg.norm([0.0, -0.4, 1.0])),
    midpoint_m=(0.0, -0.018, -0.004),
    condyle_distance_m=0.104,
    track_length_m=0.012,
    max_opening_sine=float(np.sin(np.radians(35.0))),
    max_closing_sine=float(np.sin(FREEWAY_SPACE_M / INCISOR_TO_HINGE_M)),
)

LIP_BAND_M = 0.010  # height of the lip contact regions above / below the mouth line
_LIP_CORNER_RAD = 0.15  # and how far (azimuth) they reach past the mouth corners

_W_ARC_M, _H_M, _T_MEAN_M = 0.23, Y_TOP - Y_BOTTOM, 0.011
# The procedural muscles are tubes of 4-12 mm radius, thinner than real facial muscles, so each
# carries a strength multiplier of sigma_max: at 5, full zygomaticus major moves the mouth corner
# ~9 mm (up, back and outward), the excursion of a broad smile.
MUSCLE_STRENGTH = 5.0
# Intra-oral pressure (a pressure actuator on the wall of the free vestibule, docs/design.md,
# "Intra-oral pressure"): at full pressure the cheek wall beside the mouth corners (the
# Lcheek_Down marker) puffs out ~8 mm, the largest puff of the AnimFace cheek take. The built-in
# flesh (mu10 + mu01 = 80 kPa) is ~30 times stiffer than real cheek tissue (ArtiSynth's Badin face:
# C10 = 2.5 kPa), so the pressure that does it is ~30 times a real puffed mouth's few kPa, as the
# muscles' MUSCLE_STRENGTH scales sigma_max.
INTRAORAL_PRESSURE = "intraoral_pressure"
INTRAORAL_PRESSURE_MAX_PA = 1.5e5
_BUCCAL_THETA_RAD = 0.30  # the pressure's wall starts this far from the midline (the canines)


def _resolution(target_tets: int) -> tuple[int, int, int]:
    """(theta cells, y cells, layers) with about ``target_tets`` = 6 * product tets and near-cubic cells."""
    h = (6 * _W_ARC_M * _H_M * _T_MEAN_M / target_tets) ** (1 / 3)
    layers = int(max(2, round(_T_MEAN_M / h)))
    cells = target_tets / (6 * layers)
    n_theta = int(round(np.sqrt(cells * _W_ARC_M / _H_M)))
    n_y = int(round(cells / n_theta))
    return max(n_theta, 8), max(n_y, 8), layers


def _embed_muscles(shape: FaceShape, x: np.ndarray, tets: np.ndarray, cell_size_m: float):
    """Per-tet muscle entries (tet, muscle, fraction, unit fibre direction), fractions summing to <= 1 per tet."""
    centroids = x[tets].mean(axis=1)
    tree = cKDTree(centroids)
    names, rows = [], []
    for spec in MUSCLES:
        for name, path in muscle_paths(spec):
            pts = shape.point(path[:, 0], path[:, 1], path[:, 2])
            tangent = np.gradient(pts, axis=0)
            if spec.closed:  # periodic central differences
                tangent = 0.5 * (np.roll(pts, -1, axis=0) - np.roll(pts, 1, axis=0))
            tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
            r = max(spec.radius_m, 0.55 * cell_size_m)
            r_in, r_out = 0.6 * r, 1.3 * r
            near = np.unique(np.concatenate(tree.query_ball_point(pts, r_out)).astype(np.int64))
            if near.size == 0:
                raise RuntimeError(f"muscle {name} contains no tets at this resolution")
            d, j = cKDTree(pts).query(centroids[near])
            frac = np.clip((r_out - d) / (r_out - r_in), 0.0, 1.0)
            keep = frac > 1e-3
            m_id = len(names)
            names.append(name)
            rows.append((near[keep], np.full(keep.sum(), m_id), frac[keep], tangent[j[keep]]))
    tet = np.concatenate([r[0] for r in rows])
    mus = np.concatenate([r[1] for r in rows])
    frac = np.concatenate([r[2] for r in rows])
    dirs = np.concatenate([r[3] for r in rows])
    total = np.bincount(tet, weights=frac, minlength=len(tets))
    frac = frac / np.maximum(total[tet], 1.0)
    order = np.lexsort((mus, tet))
    return names, tet[order], mus[order], frac[order], dirs[order] / np.linalg.norm(dirs[order], axis=1, keepdims=True)


def _surface_groups(grid, tets: np.ndarray, n0: int, region: np.ndarray, intraoral_pressure: bool) -> dict:
    """The face's named surfaces: skin, lips (contact and cut), the bone side, and the intra-oral
    pressure's wall. ``n0``: the first lower-lip duplicate node id; ``region``: per node bone id, -1 free."""
    faces = boundary_faces(tets)
    on_skin = np.all(grid.w[faces] == 1.0, axis=1)
    on_bone = np.all(grid.w[faces] == 0.0, axis=1)
    at_cut = np.all(np.abs(grid.y[faces] - Y_MOUTH) < 1e-12, axis=1) & ~on_skin & ~on_bone
    upper = at_cut & np.all(faces < n0, axis=1)
    skin = faces[on_skin]
    # Lip contact regions: every outer face of a lip (cut, skin and vestibule side) within
    # LIP_BAND_M of the mouth line, out a little past the corners (``wface.physics.contact``).
    near_mouth = np.abs(grid.theta[faces]).max(axis=1) <= THETA_MOUTH + _LIP_CORNER_RAD
    y_f = grid.y[faces]
    upper_lip = near_mouth & (y_f.min(axis=1) >= Y_MOUTH - 1e-12) & (y_f.max(axis=1) <= Y_MOUTH + LIP_BAND_M)
    lower_lip = near_mouth & (y_f.max(axis=1) <= Y_MOUTH + 1e-12) & (y_f.min(axis=1) >= Y_MOUTH - LIP_BAND_M)
    # The buccal wall that the intra-oral pressure pushes: bone-side faces of the free vestibule
    # (touching a free node up to its fornix, however far up the bone side is free) lateral of the
    # central lips, which orbicularis oris holds sealed in a puff (on these free-edged lips the
    # pressure would part them by ~16 mm at full pressure).
    vestibule = (region < 0) & (grid.y <= Y_MOUTH + VESTIBULE_TOP_M + 1e-12)
    buccal = np.isin(faces, np.flatnonzero(vestibule)).any(axis=1)
    buccal &= np.abs(grid.theta[faces]).mean(axis=1) >= _BUCCAL_THETA_RAD
    surfaces = {
        "skin": skin,
        "upper_lip_contact": faces[upper],
        "lower_lip_contact": faces[at_cut & ~upper],
        "inner": faces[on_bone],
        "upper_lip": faces[upper_lip & ~(at_cut & ~upper)],
        "lower_lip": faces[lower_lip & ~upper],
    }
    if intraoral_pressure:
        surfaces[INTRAORAL_PRESSURE] = faces[on_bone & buccal]
    return surfaces


def build_face(
    target_tets: int = 20_000,
    *,
    progress: bool = False,
    material: Material | None = None,
    intraoral_pressure: bool = True,
    free_to_mm: float = 1e3 * VESTIBULE_TOP_M,
) -> FaceModel:
    """Build the built-in face with about ``target_tets`` tetrahedra (1K .. 2M).

    Args:
        target_tets: desired number of tets; the structured grid lands within a few percent.
        progress: show a progress bar over the build stages.
        material: flesh/muscle material (defaults to ``Material()``, docs/design.md, "Flesh").
        intraoral_pressure: give the face its intra-oral pressure actuator (the last channel,
            docs/design.md "Intra-oral pressure"); False builds the muscles alone.
        free_to_mm: how far above the mouth line the bone side of lips and cheeks is free (not
            attached to the maxilla): the oral vestibule's fornix, 18 mm, by default; up to 40 mm
            frees the deep surface of the midface as well (docs/design.md, "Built-in face
            attachments"; the intra-oral pressure stays on the vestibule's wall).

    Returns:
        A validated ``FaceModel`` in metres.
    """
    if not (MIN_TETS <= int(target_tets) <= MAX_TETS):
        raise ValueError(f"target_tets must be within [{MIN_TETS}, {MAX_TETS}], got {target_tets}")
    if not (np.isfinite(free_to_mm) and 5.0 <= free_to_mm <= 40.0):
        raise ValueError(f"free_to_mm must be within [5, 40] mm above the mouth line, got {free_to_mm}")

    bar = tqdm(total=6, desc=f"building face (~{target_tets} tets)", disable=not progress, unit="stage")
    shape = FaceShape()
    n_theta, n_y, layers = _resolution(int(target_tets))
    theta_axis = graded_axis(
        [-THETA_MAX, -THETA_MOUTH, 0.0, THETA_MOUTH, THETA_MAX],
        n_theta,
        lambda s: 1.0 + 1.2 * np.exp(-((s / 0.6) ** 2)),
    )
    y_axis = graded_axis([Y_BOTTOM, Y_MOUTH, Y_TOP], n_y, lambda s: 1.0 + 1.0 * np.exp(-(((s - Y_MOUTH) / 0.035) ** 2)))
    grid = build_grid(theta_axis, y_axis, layers, THETA_MOUTH, Y_MOUTH)
    bar.update()

    x = shape.point(grid.theta, grid.y, grid.w)
    tets = grid.tets.copy()
    neg = signed_volumes(x, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    bar.update()

    # Bone attachments: the bone-side layer by region; the top and side borders of the patch whole.
    region = np.full(len(x), -1, dtype=np.int8)
    inner = grid.w == 0.0
    region[inner] = bone_region(grid.theta[inner], grid.y[inner], free_to_m=float(free_to_mm) / 1e3)
    n0 = grid.index.size  # lower-lip duplicates (ids >= n0) sit in the free vestibule
    region[n0:][inner[n0:]] = -1
    border = (np.abs(grid.y - Y_TOP) < 1e-12) | (np.abs(np.abs(grid.theta) - THETA_MAX) < 1e-12)
    region[border] = np.where(grid.y[border] < -0.035, 1, 0)
    attached = np.flatnonzero(region >= 0).astype(np.int32)
    attached_bone = region[attached].astype(np.int8)
    bar.update()

    cell_size = float(np.median(np.cbrt(6.0 * signed_volumes(x, tets))))
    names, f_tet, f_mus, f_frac, f_dir = _embed_muscles(shape, x, tets, cell_size)
    bar.update()

    surfaces = _surface_groups(grid, tets, n0, region, intraoral_pressure)
    skin = surfaces["skin"]
    # Markers: analytic skin points snapped onto the skin triangles.
    mk_names = list(MARKERS)
    mk_param = np.array([MARKERS[k] for k in mk_names])
    mk = SurfaceQuery(x, skin).closest(shape.point(mk_param[:, 0], mk_param[:, 1], 1.0)).point_m
    bar.update()

    if intraoral_pressure:
        names = [*names, INTRAORAL_PRESSURE]  # an actuator without fibres: the last channel
    facs_table = {}
    for au in facs.ACTION_UNITS:
        acts, _ = facs.muscle_activations({au: 1.0}, muscle_names=names)
        if acts:
            facs_table[au] = acts
    model = FaceModel(
        rest_positions_m=x,
        tets=tets,
        skin_triangles=skin,
        muscle_names=names,
        fibre_tet=f_tet,
        fibre_muscle=f_mus,
        fibre_fraction=f_frac,
        fibre_direction=f_dir,
        muscle_strength=np.where(np.array(names) == INTRAORAL_PRESSURE, 1.0, MUSCLE_STRENGTH),
        attached_nodes=attached,
        attached_bone=attached_bone,
        jaw_joint=JAW_JOINT,
        material=material or Material(),
        bone_meshes=bone_meshes(shape),
        surface_groups=surfaces,
        marker_names=mk_names,
        marker_positions_m=mk,
        facs=facs_table,
        pressure_actuators={INTRAORAL_PRESSURE: INTRAORAL_PRESSURE_MAX_PA} if intraoral_pressure else {},
        metadata={
            "name": "wface built-in face",
            "builder_version": BUILDER_VERSION,
            "target_tets": int(target_tets),
            "grid": {"theta_cells": len(theta_axis) - 1, "y_cells": len(y_axis) - 1, "layers": layers},
            "frame": "+x subject's left, +y up, +z forward; metres",
        },
    )
    if free_to_mm != 1e3 * VESTIBULE_TOP_M:  # recorded when not the default: the default face's content
        model.metadata["free_to_mm"] = float(free_to_mm)  # (and its fingerprint) stays as before the option
    model.validate()
    q = quality_report(x, tets)
    model.metadata["quality"] = q.as_dict()
    bar.update()
    bar.close()
    return model
