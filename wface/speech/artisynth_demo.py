"""ArtiSynth's lip-opening demo on the imported Badin face: its OOP ring, muscle stress, boundary and dynamics.

``BadinFaceDemoLipOpening`` (artisynth_models, ``src/artisynth/models/face``, commit bcda205; it
extends ``BadinFemMuscleFaceDemo`` and ``BadinFaceDemo``) sets the approximant up as follows, and
this module reproduces each choice on the imported face (``wface.faces.artisynth``):

- OOP ring (``oop_ring_entries``): the OOP bundle's elements are replaced by ten rings of hex elements
  of the ``badinface_oop_csa_midsagittal`` mesh, ``LIP_OPENING_RINGS`` (5Du, 6Sl, 6M, 6Du, 7Sl, 7M,
  7Du, 8Su, 8Mu, 8Du: ring 5-8 around the mouth, S/M/D superficial/middle/deep layer, u/l the upper
  or lower lip only), listed in ``geometry/oop/<ring>_elements.txt`` by ANSYS element number (the
  14th column of the .elem file). Each element is muscle over its whole volume (fraction 1); its
  fibre direction is that of the nearest segment of one closed polyline through the centroids of
  the 7M ring's hexes (wedges skipped: ``loadoop("7M")``, ``setFibresFromElementCentroids``,
  ``computeElementDirections``). The element numbers are vendored (``OOP_RING_ELEMENTS``,
  ``wface.speech.artisynth_lists``, with the ArtiSynth Models licence notice): they are not in the face data folder.
- Muscle material: ``BlemkerMuscle`` with ``maxStress`` 1e5 Pa for OOP and the ``GenericMuscle``
  with 1e5 Pa for the others (``ARTISYNTH_MAX_STRESS_PA``; wface's default sigma_max is 3e5 Pa).
  Blemker's active force-length curve (1 - 4 (lam - 1)^2, quadratic tails to 0 at 0.4 and 1.6) is
  close to wface's (``docs/design.md``, "Muscle fibres"). Both are functions of the deviatoric fibre
  stretch J^-1/3 |F d|, so their stress has no hydrostatic part: the setup sets
  ``Material.fibre_stress = "deviatoric"``; the curves are otherwise wface's. ``"blemker"`` has
  BlemkerMuscle's own curves, for every muscle: its passive curve on the other muscles, whose GenericMuscle
  passive is 0.05 Pa, overshoots the sag (README, "Hexes and fibre directions"). ``muscle_curves="artisynth"``
  gives each muscle its own demo material's curves (``Material.muscle_curves``): OOP BlemkerMuscle's, every
  other muscle GenericMuscle's (f_L = 1, no passive stress). The default stays wface's curves on every
  muscle, with which the README's earlier measurements were made.
- Boundary (``demo_attachments``): after the edge, nose and zygomatic-ligament lists that the import
  attaches, ``attachFaceToSkull`` fixes every inner-surface node (``atlas_internal.node``) and frees the lip,
  cheek and nose free lists, 32 of the nose list's nodes among them; the jaw list stays on the jaw.
- Dynamics (``ARTISYNTH_DYNAMICS``): ConstrainedBackwardEuler with steps of at most 5 ms, density
  1040 kg/m^3, Rayleigh damping alpha = 19 1/s (particle damping), beta = 0.055 s (stiffness
  damping), gravity 9.8 m/s^2 down (Badin -z, wface -Y).
- Flesh: ``MooneyRivlinMaterial`` C10 = 2500 Pa, C20 = 1175 Pa, bulk modulus 10 C10
  (``BadinFaceDemo.setFaceProperties``; ``Material.artisynth()``, docs/design.md, "Flesh"), and no
  hard incompressibility: ``BadinFemMuscleFaceDemo.setDefaultOOP`` sets
  ``face.setIncompressible(IncompMethod.OFF)``, so the bulk term alone keeps the volume, as in wface.
- Measure: the green plane at x = 0.1 m and the orthographic camera, ``wface.speech.aperture``.
- Not reproduced: every rigid body of the demo, the tongue among them, is hidden in its picture, so
  nothing but the face occludes the plane; the tongue mesh is not in the face data.

The ArtiSynth Models licence that covers the vendored lists is in ``wface.speech.artisynth_lists``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from wface.faces.ansys import hexes_to_tets, read_ansys_elements, read_ansys_nodes, read_int_list
from wface.faces.artisynth import FIXED_NODE_FILES, JAW_NODE_FILE, MESH_PREFIX, badin_muscle_fibres
from wface.faces.fibres import point_segment_distance
from wface.mesh.closest import SurfaceQuery
from wface.mesh.embed import containing_tets
from wface.mesh.surface import boundary_faces
from wface.model import FaceModel, Material
from wface.speech.artisynth_lists import OOML_EXCITER_TARGETS, OOP_RING_ELEMENTS

__all__ = [
    "ARTISYNTH_DYNAMICS",
    "ARTISYNTH_MAX_STRESS_PA",
    "LIP_OPENING_FIBRE_RING",
    "LIP_OPENING_RINGS",
    "OOP_RING_ELEMENTS",
    "ArtisynthDynamics",
    "delaunay_fibre_directions",
    "demo_attachments",
    "face_hexes",
    "lip_opening_demo_model",
    "ooml_exciter_tets",
    "oop_ring_entries",
    "ring_hexes",
]

ARTISYNTH_MAX_STRESS_PA = 1.0e5
LIP_OPENING_RINGS = ("5Du", "6Sl", "6M", "6Du", "7Sl", "7M", "7Du", "8Su", "8Mu", "8Du")
LIP_OPENING_FIBRE_RING = "7M"
FREE_NODE_FILES = ("lip_free_nodes.nodenum", "cheek_free_nodes.nodenum", "nose_free_nodes.nodenum")


@dataclass(frozen=True)
class ArtisynthDynamics:
    """BadinFaceDemo's time integration (``setFaceProperties``, ``defaultMaxStepSizeSec``)."""

    scheme: str = "be"  # ConstrainedBackwardEuler
    max_step_s: float = 0.005
    density_kg_m3: float = 1040.0
    alpha_per_s: float = 19.0  # particle (mass) damping
    beta_s: float = 0.055  # stiffness damping
    gravity_m_s2: tuple = (0.0, -9.8, 0.0)  # Badin (0, 0, -9.8) in wface's frame


ARTISYNTH_DYNAMICS = ArtisynthDynamics()


def _hex_elements(data_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(ANSYS element numbers (m,), hexes as ANSYS node numbers (m, 8)) of the face mesh."""
    raw = np.loadtxt(data_dir / f"{MESH_PREFIX}.elem", ndmin=2, dtype=np.int64)
    if raw.shape[1] < 14:
        raise ValueError(f"{data_dir / MESH_PREFIX}.elem: expected 14 columns (8 nodes, 5 attributes, number)")
    return raw[:, 13], read_ansys_elements(data_dir / f"{MESH_PREFIX}.elem")


def _node_ids(data_dir: Path, numbers: np.ndarray, what: str) -> np.ndarray:
    """Model node ids of ANSYS node numbers: the import keeps the node file's nodes first, in file order."""
    file_numbers = read_ansys_nodes(data_dir / f"{MESH_PREFIX}.node")[0]
    index_of = np.full(int(max(file_numbers.max(), numbers.max())) + 1, -1, dtype=np.int64)
    index_of[file_numbers] = np.arange(file_numbers.size)
    ids = index_of[numbers]
    if np.any(ids < 0):
        raise ValueError(f"{what}: node numbers not in {MESH_PREFIX}.node: {numbers[ids < 0][:5].tolist()}")
    return ids


def face_hexes(data_dir: str | Path) -> np.ndarray:
    """(m, 8) model node ids of every hex of the face mesh (ANSYS order; wedges repeat nodes), the
    elements ArtiSynth simulates (``wface.physics.hexes`` integrates them as it does)."""
    data_dir = Path(data_dir)
    _, hexes = _hex_elements(data_dir)
    return _node_ids(data_dir, hexes.reshape(-1), MESH_PREFIX).reshape(-1, 8)


def ring_hexes(data_dir: str | Path, rings=LIP_OPENING_RINGS) -> dict[str, np.ndarray]:
    """{ring: (h, 8) model node ids of its hexes, in the file's order}."""
    data_dir = Path(data_dir)
    numbers, hexes = _hex_elements(data_dir)
    row_of = {int(e): k for k, e in enumerate(numbers)}
    out = {}
    for r in rings:
        if r not in OOP_RING_ELEMENTS:
            raise ValueError(f"unknown OOP ring {r!r}; known: {', '.join(OOP_RING_ELEMENTS)}")
        missing = [e for e in OOP_RING_ELEMENTS[r] if e not in row_of]
        if missing:
            raise ValueError(f"OOP ring {r}: element numbers not in the mesh: {missing[:5]}")
        rows = [row_of[e] for e in OOP_RING_ELEMENTS[r]]
        out[r] = _node_ids(data_dir, hexes[rows].reshape(-1), f"ring {r}").reshape(-1, 8)
    return out


def _tets_in_hexes(model: FaceModel, hexes: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(m,) index of the hex (row of ``hexes``) holding each model tet's centroid, -1 for none.

    The hexes are split into tets as the import splits them (``wface.faces.ansys.hexes_to_tets``,
    conforming, so the pieces tile the hexes exactly) and each centroid is located in those pieces
    (barycentric test on the 12 pieces with the nearest centroids)."""
    n_file = int(np.max(hexes)) + 1
    pieces, parent, added = hexes_to_tets(hexes, x[:n_file])[:3]
    px = np.vstack([x[:n_file], added])[pieces]  # (k, 4, 3)
    a = px[:, 0]
    D = np.stack([px[:, i] - a for i in (1, 2, 3)], axis=-1)  # (k, 3, 3)
    Dinv = np.linalg.inv(D)
    cent = x[model.tets].mean(axis=1)
    lo, hi = px.reshape(-1, 3).min(axis=0), px.reshape(-1, 3).max(axis=0)
    near = np.flatnonzero(np.all((cent >= lo) & (cent <= hi), axis=1))
    k = min(12, len(pieces))
    _, cand = cKDTree(px.mean(axis=1)).query(cent[near], k=k)
    cand = cand.reshape(len(near), k)
    owner = np.full(len(cent), -1)
    for j in range(k):
        c = cand[:, j]
        lam = np.einsum("pij,pj->pi", Dinv[c], cent[near] - a[c])
        inside = (lam >= -1e-9).all(axis=1) & (lam.sum(axis=1) <= 1 + 1e-9) & (owner[near] < 0)
        owner[near[inside]] = parent[c[inside]]
    return owner


def delaunay_fibre_directions(points_m: np.ndarray, fibre_mid_m: np.ndarray, fibre_dir: np.ndarray) -> np.ndarray:
    """(k, 3) unit directions at ``points_m`` blended from fibres as ArtiSynth's
    ``MuscleBundle.computeElementDirections`` does (``MuscleElementDesc.interpolateDirection`` with a
    ``DelaunayInterpolator`` over the fibre midpoints): the barycentric weights of the Delaunay
    tetrahedron holding the point, or of the closest point on the convex hull for a point outside it;
    the fibres' directions added from the largest weight down, each sign-flipped to agree with the
    sum so far (a direction and its opposite are the same fibre), then normalised."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    mid, d = np.asarray(fibre_mid_m, dtype=np.float64), np.asarray(fibre_dir, dtype=np.float64)
    tri = Delaunay(mid)
    simplex = tri.find_simplex(p)
    weights, index = np.zeros((len(p), 4)), np.zeros((len(p), 4), dtype=np.int64)
    inside = simplex >= 0
    T = tri.transform[simplex[inside]]
    bc = np.einsum("kij,kj->ki", T[:, :3], p[inside] - T[:, 3])
    weights[inside] = np.column_stack([bc, 1.0 - bc.sum(axis=1)])
    index[inside] = tri.simplices[simplex[inside]]
    if not inside.all():
        hit = SurfaceQuery(mid, tri.convex_hull).closest(p[~inside])
        weights[~inside, :3], index[~inside, :3] = hit.barycentric, tri.convex_hull[hit.triangle]
    out = np.zeros((len(p), 3))
    rows, order = np.arange(len(p)), np.argsort(-weights, axis=1)  # largest weight first, as ArtiSynth sorts
    for j in range(4):
        w = weights[rows, order[:, j]]
        dj = d[index[rows, order[:, j]]]
        sign = np.where(np.einsum("kd,kd->k", out, dj) < 0, -1.0, 1.0)
        out += (sign * w)[:, None] * dj
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def oop_ring_entries(
    model: FaceModel,
    data_dir: str | Path,
    *,
    rings=LIP_OPENING_RINGS,
    fibre_ring: str = LIP_OPENING_FIBRE_RING,
    directions: str = "nearest",
) -> tuple[np.ndarray, np.ndarray]:
    """The OOP of the lip-opening demo: (tet ids (e,), unit fibre directions (e, 3)), fraction 1 each.

    Tets belong to a ring hex when their centroid lies in it (rest shape; ``_tets_in_hexes``: the
    tets chosen hold 16,970 mm^3 on the Badin import, the ring hexes' own volume). Each takes its
    hex's direction from the closed ``fibre_ring`` centroid polyline: ``directions="nearest"``, that
    of the polyline's segment nearest the hex's centroid; ``"delaunay"``, ArtiSynth's own blend of the
    segments around it (``delaunay_fibre_directions``; on the Badin import within 5 degrees of the
    nearest segment's at the median hex, 16 degrees at the 90th percentile, 47 at most).
    """
    if directions not in ("nearest", "delaunay"):
        raise ValueError(f"directions must be 'nearest' or 'delaunay', got {directions!r}")
    x = model.rest_positions_m
    by_ring = ring_hexes(data_dir, tuple(dict.fromkeys([*rings, fibre_ring])))
    poly = by_ring[fibre_ring]
    poly = poly[np.array([len(set(h.tolist())) == 8 for h in poly])]  # wedges skipped
    pts = x[poly].mean(axis=1)
    a, b = pts, np.roll(pts, -1, axis=0)  # closed loop
    tangent = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    hexes = np.unique(np.concatenate([by_ring[r] for r in rings]), axis=0)
    owner = _tets_in_hexes(model, hexes, x)
    tets = np.flatnonzero(owner >= 0)
    centroid = x[hexes].mean(axis=1)
    if directions == "delaunay":
        per_hex = delaunay_fibre_directions(centroid, 0.5 * (a + b), tangent)
    else:
        per_hex = tangent[point_segment_distance(centroid, a, b)[1]]
    return tets.astype(np.int32), per_hex[owner[tets]]


DEMO_MUSCLE_THICKNESS_M = 0.006  # BadinFemMuscleFaceDemo.muscleThickness


def attached_fibres(model: FaceModel, fibres: dict[str, list[np.ndarray]]) -> dict[str, list[np.ndarray]]:
    """The fibres with their points where ArtiSynth attaches them. ``BadinFaceDemo.addMuscles`` makes each fibre
    point a marker with ``FemModel3d.addNumberedMarker(pos, id)``, which projects a point that lies in no element
    onto the nearest element's surface (``findElementForMarker``, project=true); a point inside stays. On the Badin
    face 60 of the 232 fibre points lie in no element, up to 4 mm out (BUC's). Here the surface is the model's
    boundary (the hexes' faces split into triangles), so a projected point lies within 0.5 mm of ArtiSynth's (its
    hex faces are bilinear; ``RunLipOpening -Dlip.directions`` dumps its fibres)."""
    x = model.rest_positions_m
    points = np.concatenate([np.concatenate(polys) for polys in fibres.values()])
    tet, _ = containing_tets(points, x, model.tets)
    out = points.copy()
    outside = np.flatnonzero(tet < 0)
    if outside.size:
        out[outside] = SurfaceQuery(x, boundary_faces(model.tets)).closest(points[outside]).point_m
    pieces = iter(np.split(out, np.cumsum([len(p) for polys in fibres.values() for p in polys])[:-1]))
    return {name: [next(pieces) for _ in polys] for name, polys in fibres.items()}


def _demo_hexes(model: FaceModel, data_dir: Path):
    """(the fibres where ArtiSynth attaches them, (m, 8) face hexes, (m, 3) hex centres: their nodes' mean, a
    wedge's six) of the demo's muscle-element choice."""
    fibres = attached_fibres(model, badin_muscle_fibres(data_dir))
    hexes = face_hexes(data_dir)
    x = model.rest_positions_m
    return fibres, hexes, np.array([x[np.unique(h)].mean(axis=0) for h in hexes])


def _bundle_segments(fibres: dict[str, list[np.ndarray]], bundle: str):
    """(side names, (s,) side of each segment, (s, 3) segment starts, (s, 3) ends) of a bundle's fibres, both sides."""
    sides = [n for n in fibres if n == bundle or n.rsplit("_", 1)[0] == bundle]
    seg = [(n, p[k], p[k + 1]) for n in sides for p in fibres[n] for k in range(len(p) - 1)]
    side = np.array([sides.index(n) for n, _, _ in seg])
    return sides, side, np.array([s[1] for s in seg]), np.array([s[2] for s in seg])


def _near_fibres(centre: np.ndarray, a: np.ndarray, b: np.ndarray, thickness_m: float):
    """(rows of the hexes whose centre lies within ``thickness_m`` of a segment, in the mesh's order (as
    ``MuscleBundle.addElementsNearFibres`` lists them), (h, s) nearest-segment index per hex)."""
    dist, nearest = point_segment_distance(centre, a, b)
    return np.flatnonzero(dist.min(axis=1) < thickness_m), nearest


def ooml_exciter_tets(model: FaceModel, data_dir: str | Path, *, thickness_m: float = DEMO_MUSCLE_THICKNESS_M):
    """(n_tets,) bool: the tets (centroid in a hex) of the demo's ``OOMl`` exciter, its targets
    (``OOML_EXCITER_TARGETS``: positions in the OOM bundle's element list) taken from the OOM hexes that
    ``demo_muscle_entries`` chooses, in the mesh's order (704 on the Badin face, ArtiSynth's own list). On the Badin
    face 232 hexes, all in the lower lip; ``with_lower_oom``'s split by the lips' surfaces takes these and tets of 69
    hexes more, at the mouth's corners."""
    fibres, hexes, centre = _demo_hexes(model, Path(data_dir))
    _, _, a, b = _bundle_segments(fibres, "OOM")
    oom, _ = _near_fibres(centre, a, b, thickness_m)
    if max(OOML_EXCITER_TARGETS) >= len(oom):
        raise ValueError(
            f"the OOMl exciter targets the OOM bundle's element {max(OOML_EXCITER_TARGETS)} (0-based), but this face's "
            f"OOM bundle has {len(oom)} elements: not ArtiSynth's Badin face"
        )
    target = np.zeros(len(hexes), dtype=bool)
    target[oom[list(OOML_EXCITER_TARGETS)]] = True
    owner = _tets_in_hexes(model, hexes, model.rest_positions_m)
    return (owner >= 0) & target[np.maximum(owner, 0)]


def demo_muscle_entries(
    model: FaceModel, data_dir: str | Path, *, thickness_m: float = DEMO_MUSCLE_THICKNESS_M
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The demo's own elements of every muscle but OOP (whose rings ``oop_ring_entries`` gives), as
    ``BadinFemMuscleFaceDemo.setMuscleElements`` makes them: ``MuscleBundle.addElementsNearFibres`` takes every
    hex whose centre (its nodes' mean; a wedge's six) lies within ``thickness_m`` of one of the bundle's fibre
    segments, both sides, whole (fraction 1), and ``computeElementDirections`` gives each the Delaunay blend of the
    bundle's fibre directions (``delaunay_fibre_directions``; the nearest segment's where the fibres are too few
    to span a volume). A hex goes to the side (``_l``, ``_r``) of its nearest segment. Returns {model muscle:
    (tet ids, unit directions)}, the tets those whose centroid lies in a chosen hex.

    The fibres are where ArtiSynth attaches them (``attached_fibres``). Against ArtiSynth's own lists on the Badin
    face (``RunLipOpening -Dlip.muscles``; README, "Speech gestures"), hexes per bundle here / there: OOM 704 / 704,
    MENT 92 / 92, RIS 215 / 216, LLS 102 / 102, LLSAN 152 / 152, DAO 60 / 60, DLI 121 / 120, LAO 76 / 74, ZYG 50 /
    50, BUC 61 / 60, all of theirs here but one RIS and one BUC hex (with the fibres' points as the data has them:
    OOM 698, MENT 90, LLSAN 148, DLI 118, BUC 22). The directions agree (median 0 degrees) but for hexes whose
    Delaunay tet is not unique: mirror-image fibres put four midpoints on one sphere up to rounding, ArtiSynth's
    pick is made by that rounding (docs/design.md) and Qhull's is another (OOM: 120 of 704 hexes more than 5 degrees
    apart, MENT 12, the rest at most 3).
    """
    fibres, hexes, centre = _demo_hexes(model, Path(data_dir))
    owner = _tets_in_hexes(model, hexes, model.rest_positions_m)
    in_hex = np.flatnonzero(owner >= 0)
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    bundles = dict.fromkeys(n.rsplit("_", 1)[0] if n[-2:] in ("_l", "_r") else n for n in fibres)
    for bundle in bundles:
        if bundle == "OOP":
            continue
        sides, side, a, b = _bundle_segments(fibres, bundle)
        chosen, nearest = _near_fibres(centre, a, b, thickness_m)
        tangent = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
        try:
            per_hex = delaunay_fibre_directions(centre[chosen], 0.5 * (a + b), tangent)
        except QhullError:  # fewer fibres than a volume needs: the nearest segment's direction
            per_hex = tangent[nearest[chosen]]
        hex_side = np.full(len(hexes), -1)
        hex_side[chosen] = side[nearest[chosen]]
        direction = np.zeros((len(hexes), 3))
        direction[chosen] = per_hex
        tets = in_hex[hex_side[owner[in_hex]] >= 0]
        for k, name in enumerate(sides):
            mine = tets[hex_side[owner[tets]] == k]
            out[name] = (mine.astype(np.int32), direction[owner[mine]])
    return out


def demo_attachments(model: FaceModel, data_dir: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(attached node ids, bone 0 cranium / 1 jaw) of the import's lists + ``attachFaceToSkull``.

    Original nodes, in ArtiSynth's order: ``BadinFaceDemo.build`` fixes the import's lists (edge, nose and
    zygomatic-ligament nodes), then the lip-opening demo's ``attachFaceToSkull`` fixes every
    ``atlas_internal.node`` node and frees the lip, cheek and nose free lists, so a node on a free list is free
    even where the import's lists fix it (32 nose nodes of the Badin face; ``RunLipOpening -Dlip.fixed`` dumps
    ArtiSynth's set, which this one equals); the jaw list (``face_jaw_attachments.txt``, 0-based positions) on
    the jaw. Nodes the import added follow: a face-centre or edge node on the inner surface whose neighbours on
    that surface are all fixed is fixed too.
    """
    data_dir = Path(data_dir)
    n_file = read_ansys_nodes(data_dir / f"{MESH_PREFIX}.node")[0].size
    fixed = [_node_ids(data_dir, read_int_list(data_dir / f), f) for f in FIXED_NODE_FILES]
    inner = _node_ids(data_dir, read_ansys_nodes(data_dir / "atlas_internal.node")[0], "atlas_internal.node")
    free = np.concatenate([_node_ids(data_dir, read_int_list(data_dir / f), f) for f in FREE_NODE_FILES])
    cranium = np.zeros(model.n_nodes, bool)
    cranium[np.setdiff1d(np.concatenate([*fixed, inner]), free)] = True
    jaw = np.zeros(model.n_nodes, bool)
    jaw[np.unique(read_int_list(data_dir / JAW_NODE_FILE))] = True
    # added nodes on the inner surface: fixed when every inner-surface neighbour is
    tri = model.surface_groups.get("inner", np.zeros((0, 3), int))
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    added = e[:, 0] >= n_file
    src, dst = e[added, 0], e[added, 1]
    bad = np.zeros(model.n_nodes, bool)
    np.logical_or.at(bad, src, ~cranium[dst] & (dst < n_file))
    cand = np.unique(src)
    cranium[cand[~bad[cand]]] = True
    cranium &= ~jaw  # a node on both lists follows the jaw, as in the import
    nodes = np.flatnonzero(cranium | jaw)
    return nodes, jaw[nodes].astype(np.int8)


def without_idle_fibres(model: FaceModel, driven) -> FaceModel:
    """``model`` with every muscle not in ``driven`` at strength 0: no fibres, active or passive.

    ArtiSynth's demo gives the muscles other than OOP ``GenericMuscle``, whose passive stress is
    0.05 Pa (not scaled by maxStress), so a muscle a gesture never drives carries next to nothing
    there, where wface's carries its passive fibres (k f_P). On ArtiSynth's hexes with lip and skull
    contact those fibres close the approximant's floor from 11.3 to 7.9 mm^2 (README, "The other
    muscles' passive fibres close the floor's gap"). A driven muscle keeps its passive fibres.
    """
    driven = set(driven)
    unknown = driven - set(model.muscle_names)
    if unknown:
        raise ValueError(f"driven muscles not in the model: {sorted(unknown)}")
    keep = np.isin(np.asarray(model.muscle_names), sorted(driven))
    meta = dict(model.metadata)
    meta["idle_muscles_without_fibres"] = [n for n, k in zip(model.muscle_names, keep, strict=True) if not k]
    out = replace(model, muscle_strength=np.where(keep, model.muscle_strength, 0.0), metadata=meta)
    out.validate()
    return out


def _with_entries(model: FaceModel, entries: dict[str, tuple[np.ndarray, np.ndarray]]) -> FaceModel:
    """The model with the fibre entries of each muscle named in ``entries`` replaced by (tets, directions),
    fraction 1 each; entries stay sorted by tet."""
    ids = [model.muscle_names.index(n) for n in entries if n in model.muscle_names]
    keep = ~np.isin(model.fibre_muscle, ids)
    named = [(model.muscle_names.index(n), t, d) for n, (t, d) in entries.items() if n in model.muscle_names]
    ft = np.concatenate([model.fibre_tet[keep], *[t for _, t, _ in named]])
    fm = np.concatenate([model.fibre_muscle[keep], *[np.full(len(t), i) for i, t, _ in named]])
    ff = np.concatenate([model.fibre_fraction[keep], *[np.ones(len(t)) for _, t, _ in named]])
    fd = np.concatenate([model.fibre_direction[keep], *[d for _, _, d in named]])
    order = np.argsort(ft, kind="stable")
    return replace(
        model, fibre_tet=ft[order], fibre_muscle=fm[order], fibre_fraction=ff[order], fibre_direction=fd[order]
    )


def lip_opening_demo_model(
    model: FaceModel,
    data_dir: str | Path,
    *,
    ring: bool = True,
    max_stress_pa: float | None = ARTISYNTH_MAX_STRESS_PA,
    boundary: bool = True,
    flesh: bool = True,
    fibre_stress: str | None = "deviatoric",
    ring_directions: str = "nearest",
    muscle_curves: str = "law",
    muscle_elements: str = "import",
    bulk_potential: str = "log",
) -> FaceModel:
    """The imported Badin face set up as ``BadinFaceDemoLipOpening`` (module docstring), each part optional.

    Args:
        model: the face from ``wface.faces.artisynth.import_artisynth``.
        data_dir: the artisynth-face data folder (mesh and node lists).
        ring: replace ``OOP_l``/``OOP_r`` by one muscle ``OOP`` on the demo's ten rings.
        max_stress_pa: sigma_max of every muscle (None: keep the model's).
        boundary: the demo's boundary (``demo_attachments``) instead of the import's.
        flesh: the demo's flesh law, ``Material.artisynth()``'s mu10, mu01, mu20 and kappa (C10, C20
            (I1~ - 3)^2, bulk 10 C10), whatever the model's (an import saved before wface had the C20
            term carries 1175 Pa as mu01); False keeps the model's.
        bulk_potential: with ``flesh``, ``Material.bulk_potential``: "log" (wface's kappa/2 (ln J)^2,
            the default, with which the README's figures were measured) or "quadratic" (the demo's own
            kappa/2 (J - 1)^2, ArtiSynth's default ``BulkPotential``).
        fibre_stress: ``Material.fibre_stress`` of every muscle, "deviatoric" as ArtiSynth's muscle
            materials (module docstring), "blemker" (those with BlemkerMuscle's curves) or "uniaxial"
            (None: keep the model's).
        ring_directions: the ring's fibre directions, "nearest" (the 7M polyline's nearest segment) or
            "delaunay" (ArtiSynth's blend; ``oop_ring_entries``).
        muscle_curves: "law" (every muscle the curves of ``fibre_stress``) or "artisynth" (the demo's own:
            BlemkerMuscle's on OOP, GenericMuscle's on every other muscle; needs ``ring``).
        muscle_elements: "import" (every muscle but OOP as the import embeds it: the tets its fibres pass
            near, by volume fraction) or "artisynth" (the demo's own whole hexes, ``demo_muscle_entries``).

    Returns:
        A new, validated ``FaceModel`` (the input is not changed).
    """
    out = model
    if ring:
        keep = ~np.isin(np.asarray(model.muscle_names)[model.fibre_muscle], ["OOP_l", "OOP_r"])
        names = [n for n in model.muscle_names if n not in ("OOP_l", "OOP_r")] + ["OOP"]
        old_index = {n: i for i, n in enumerate(model.muscle_names)}
        remap = np.array([names.index(n) if n in names else -1 for n in model.muscle_names])
        tets, dirs = oop_ring_entries(model, data_dir, directions=ring_directions)
        ft = np.concatenate([model.fibre_tet[keep], tets])
        fm = np.concatenate([remap[model.fibre_muscle[keep]], np.full(len(tets), len(names) - 1)])
        ff = np.concatenate([model.fibre_fraction[keep], np.ones(len(tets))])
        fd = np.concatenate([model.fibre_direction[keep], dirs])
        order = np.argsort(ft, kind="stable")
        strength = np.array([model.muscle_strength[old_index[n]] for n in names[:-1]] + [1.0])
        facs = {au: {m: w for m, w in ws.items() if m in names} for au, ws in model.facs.items()}
        out = replace(
            out,
            muscle_names=names,
            fibre_tet=ft[order],
            fibre_muscle=fm[order],
            fibre_fraction=ff[order],
            fibre_direction=fd[order],
            muscle_strength=strength,
            facs=facs,
        )
    if muscle_elements not in ("import", "artisynth"):
        raise ValueError(f"muscle_elements must be 'import' or 'artisynth', got {muscle_elements!r}")
    if muscle_elements == "artisynth":
        out = _with_entries(out, demo_muscle_entries(out, data_dir))
    if flesh:
        art = Material.artisynth()
        law = {f: getattr(art, f) for f in ("mu10_pa", "mu01_pa", "mu20_pa", "kappa_pa")}
        out = out.with_material(replace(out.material, **law, bulk_potential=bulk_potential))
    if max_stress_pa is not None:
        out = out.with_material(replace(out.material, sigma_max_pa=float(max_stress_pa)))
    if fibre_stress is not None:
        out = out.with_material(replace(out.material, fibre_stress=fibre_stress))
    if muscle_curves not in ("law", "artisynth"):
        raise ValueError(f"muscle_curves must be 'law' or 'artisynth', got {muscle_curves!r}")
    if muscle_curves == "artisynth":
        if "OOP" not in out.muscle_names:
            raise ValueError(
                "muscle_curves='artisynth' gives the demo's OOP ring BlemkerMuscle's curves: set ring=True"
            )
        own = {m: "blemker" if m == "OOP" else "generic" for m in out.muscle_names if m not in out.pressure_actuators}
        out = out.with_material(replace(out.material, muscle_curves=own))
    if boundary:
        nodes, bone = demo_attachments(model, data_dir)
        out = replace(out, attached_nodes=nodes, attached_bone=bone)
    meta = dict(out.metadata)
    meta["artisynth_lip_opening_demo"] = {
        "ring": list(LIP_OPENING_RINGS) if ring else None,
        "max_stress_pa": max_stress_pa,
        "boundary": "demo" if boundary else "import",
        "flesh": "artisynth" if flesh else "model",
        "bulk_potential": out.material.bulk_potential,
        "fibre_stress": out.material.fibre_stress,
        "muscle_curves": muscle_curves,
        "muscle_elements": muscle_elements,
        "ring_directions": ring_directions if ring else None,
    }
    out = replace(out, metadata=meta)
    out.validate()
    return out
