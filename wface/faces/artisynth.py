"""Import the ArtiSynth "Badin" FEM face (Nazari et al. 2010; Stavness et al.) into a ``FaceModel``.

Source data (``../shared/data/artisynth-face``, BSD-style licence of the ArtiSynth Models package;
academic use must cite Nazari, Perrier, Chabanas & Payan 2010, "Simulation of dynamic orofacial
movements using a constitutive law varying with muscle activation", CMBBE 13(4), and the
ArtiSynth face model papers of Stavness, Nazari, Flynn, Perrier, Payan, Lloyd & Fels).

What the importer establishes and does:

- Frame. The data is in metres with z up and y across (midsagittal plane y = 0); the nose tip is
  the node of smallest x and the temporomandibular point (0.13, 0, 0.13) lies behind the face, so
  +x points *backward* (posterior), not forward, and with a right-handed frame +y is the subject's
  right. ArtiSynth's "left side" muscle points have y < 0, which agrees. The model is rotated into
  wface's frame (+x subject's left, +y up, +z forward): X = -y, Y = z, Z = -x (a proper rotation, so
  tet orientation is kept). No translation; ``metadata["frame"]`` records the matrix.
- Mesh. 6,342 ANSYS 8-node hexes (318 of them wedges, K = L and O = P) are split into conforming,
  positively oriented tets (``wface.faces.ansys.hexes_to_tets``).
- Boundary-condition node lists. Established geometrically (pinned in tests/test_artisynth.py):
  ``edge_nodes.nodenum``, ``nose_nodes_to_fix.txt``, ``zygomatic_ligament_attachments.txt`` and the
  ``atlas_*`` lists hold 1-based node *numbers* (read as numbers, every listed node is a boundary
  node; as positions 25 % of the edge nodes would be interior); ``face_jaw_attachments.txt`` holds
  0-based *positions* in the node file (as positions all lie within 10 mm of the jaw or lower teeth,
  90 % within 3 mm; as numbers some are 70 mm away and 3 % are interior). This matches ArtiSynth's
  ``getByNumber`` for the fixed lists and ``getNode(idx)`` for the jaw list.
- Muscles. The APDL script groups the fibre points into 12 muscles; MAS (masseter) is unused, as in
  ArtiSynth. Each left fibre (points 114xxx, y < 0, plus the midline points 134227/134228 that close
  OOP) is mirrored across the midsagittal plane for the right side, as ArtiSynth does (the file's own
  right-side points 134xxx are not used, like in the original). Fibres become per-tet volume fractions
  and directions (``wface.faces.fibres``).
- Flesh. ``Material.artisynth()``: ArtiSynth's ``MooneyRivlinMaterial`` of
  ``BadinFaceDemo.setFaceProperties`` (C10 = 2500 Pa, C20 = 1175 Pa on (I1~ - 3)^2, bulk modulus
  10 C10); wface's bulk term is kappa/2 (ln J)^2 where ArtiSynth's is kappa/2 (J - 1)^2; the FEM-muscle
  demos switch hard incompressibility off (``BadinFemMuscleFaceDemo.setDefaultOOP``:
  ``setIncompressible(IncompMethod.OFF)``; docs/design.md, "Flesh").
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import meshio
import numpy as np
from scipy.spatial import cKDTree

from wface.faces.ansys import (
    hexes_to_tets,
    read_ansys_elements,
    read_ansys_nodes,
    read_apdl_fibres,
    read_int_list,
    read_obj,
)
from wface.faces.artisynth_markers import default_markers
from wface.faces.fibres import embed_fibres
from wface.facs import ACTION_UNITS, STAND_INS
from wface.files import without_timings
from wface.mesh.improve import improve_tets
from wface.mesh.quality import quality_report
from wface.mesh.surface import boundary_faces, triangle_normals, vertex_normals
from wface.model import BoneMesh, FaceModel, JawJoint, Material

__all__ = [
    "BADIN_MUSCLES",
    "BADIN_TO_WFACE",
    "CANONICAL_MUSCLES",
    "MESH_PREFIX",
    "badin_muscle_fibres",
    "badin_to_wface",
    "import_artisynth",
    "read_badin_fibres",
]

MESH_PREFIX = "badinface_oop_csa_midsagittal"

# Rows map Badin (x posterior, y subject's right, z up) to wface (X left, Y up, Z forward).
BADIN_TO_WFACE = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])

# Muscle order of face_muscles_topology_flynn.mac (APDL muscle numbers 1..12).
BADIN_MUSCLES = ("DAO", "BUC", "DLI", "MENT", "MAS", "OOM", "OOP", "LLSAN", "LAO", "RIS", "ZYG", "LLS")
UNUSED_MUSCLES = ("MAS",)  # the masseter fibres are not used by the ArtiSynth face either

# Badin muscle -> canonical wface.facs base names (OOP/OOM each run through both lips).
CANONICAL_MUSCLES: dict[str, tuple[str, ...]] = {
    "DAO": ("depressor_anguli_oris",),
    "BUC": ("buccinator",),
    "DLI": ("depressor_labii_inferioris",),
    "MENT": ("mentalis",),
    "OOM": ("orbicularis_oris_upper", "orbicularis_oris_lower"),
    "OOP": ("orbicularis_oris_upper", "orbicularis_oris_lower"),
    "LLSAN": ("levator_labii_superioris_alaeque_nasi",),
    "LAO": ("levator_anguli_oris",),
    "RIS": ("risorius",),
    "ZYG": ("zygomaticus_major",),
    "LLS": ("levator_labii_superioris",),
}
_MUSCLE_LONG_NAMES = {
    "DAO": "depressor anguli oris",
    "BUC": "buccinator",
    "DLI": "depressor labii inferioris",
    "MENT": "mentalis",
    "OOM": "orbicularis oris marginalis",
    "OOP": "orbicularis oris peripheralis",
    "LLSAN": "levator labii superioris alaeque nasi",
    "LAO": "levator anguli oris",
    "RIS": "risorius",
    "ZYG": "zygomaticus (major)",
    "LLS": "levator labii superioris",
}

BONE_FILES = {  # model bone mesh name -> (file, rigid bone it follows)
    "jaw": ("badinjaw.obj", "jaw"),
    "lower_teeth": ("lowerteeth.obj", "jaw"),
    "maxilla": ("badinmaxilla.obj", "cranium"),
    "cranium": ("badincranium.obj", "cranium"),
    "upper_teeth": ("upperteeth.obj", "cranium"),
}
LIP_SURFACE_FILES = {  # surface group -> ArtiSynth lip collision surface (its vertices are face nodes)
    "upper_lip": "face_collisionSurf_upperLip_reduced2.ply",
    "lower_lip": "face_collisionSurf_lowerLip_reduced.ply",
}
FIXED_NODE_FILES = ("edge_nodes.nodenum", "nose_nodes_to_fix.txt", "zygomatic_ligament_attachments.txt")
JAW_NODE_FILE = "face_jaw_attachments.txt"
FIBRE_POINT_FILE = "face_muscles_CH_with_LLS.node"
FIBRE_TOPOLOGY_FILE = "face_muscles_topology_flynn.mac"
TMJ_POINT_BADIN_M = (0.13, 0.0, 0.13)
MAX_OPENING_DEG = 45.0
MIDLINE_TOL_M = 1e-4  # ArtiSynth's midsagittal tolerance

CITATION = (
    "ArtiSynth Models, Badin face: Nazari M.A., Perrier P., Chabanas M., Payan Y. (2010) Simulation of dynamic "
    "orofacial movements using a constitutive law varying with muscle activation. Computer Methods in "
    "Biomechanics and Biomedical Engineering 13(4):469-482; Stavness I. et al., ArtiSynth (www.artisynth.org)."
)


def badin_to_wface(points: np.ndarray) -> np.ndarray:
    """Rotate (k, 3) points from the Badin data frame into wface's frame (X left, Y up, Z forward)."""
    return np.asarray(points, dtype=np.float64) @ BADIN_TO_WFACE.T


def _log(progress: bool, t0: float, msg: str) -> None:
    if progress:
        print(f"[artisynth {time.perf_counter() - t0:6.2f} s] {msg}", file=sys.stderr, flush=True)


def read_badin_fibres(directory: str | Path) -> dict[str, list[np.ndarray]]:
    """Left-side fibres of the used Badin muscles, in the Badin frame: {name: [polyline (p, 3), ...]}. A fibre
    point id missing from the point file splits the polyline there (ArtiSynth skips the segments that touch it)."""
    directory = Path(directory)
    ids, pts = read_ansys_nodes(directory / FIBRE_POINT_FILE)
    pos = {int(i): p for i, p in zip(ids, pts, strict=True)}
    topology = read_apdl_fibres(directory / FIBRE_TOPOLOGY_FILE)
    out: dict[str, list[np.ndarray]] = {}
    for mi, fibres in topology.items():
        name = BADIN_MUSCLES[mi - 1]
        if name in UNUSED_MUSCLES:
            continue
        polylines = []
        for fibre in fibres:
            run: list[np.ndarray] = []
            for pid in fibre + [None]:
                if pid is not None and pid in pos:
                    run.append(pos[pid])
                    continue
                if len(run) >= 2:
                    polylines.append(np.array(run))
                run = []
        out[name] = polylines
    return out


def badin_muscle_fibres(directory: str | Path) -> dict[str, list[np.ndarray]]:
    """Model muscle -> fibre polylines in wface's frame, both sides, as the import embeds them (``_muscle_sides``)."""
    return _muscle_sides({k: [badin_to_wface(f) for f in v] for k, v in read_badin_fibres(directory).items()})


def _classify_boundary(tris: np.ndarray, external: np.ndarray, internal: np.ndarray) -> dict[str, np.ndarray]:
    """Split boundary triangles: all three nodes outer -> skin, all inner -> inner, the rest -> edge."""
    ext = np.isin(tris, external).all(axis=1)
    inn = np.isin(tris, internal).all(axis=1)
    return {"skin": tris[ext], "inner": tris[inn & ~ext], "edge": tris[~ext & ~inn]}


def _surface_on_nodes(path: Path, x: np.ndarray, boundary: np.ndarray, tol_m: float = 1e-5) -> np.ndarray:
    """Triangles (t, 3) of a surface file whose vertices are mesh nodes, as node ids, each wound to face
    the same way as the mesh's outward boundary at its nodes (for ``wface.physics.contact``)."""

    mesh = meshio.read(path)
    tri = mesh.cells_dict.get("triangle")
    if tri is None or not len(tri):
        raise ValueError(f"{path.name}: no triangles")
    dist, node = cKDTree(x).query(badin_to_wface(np.asarray(mesh.points, dtype=np.float64)))
    if dist.max() > tol_m:
        raise ValueError(f"{path.name}: a vertex lies {dist.max() * 1e3:.3f} mm from the nearest face node")
    tri = node[tri].astype(np.int32)
    outward = vertex_normals(x, boundary)[tri].sum(axis=1)
    flip = np.einsum("ij,ij->i", triangle_normals(x, tri), outward) < 0
    tri[flip] = tri[flip][:, ::-1]
    return tri


def _facs_table(muscle_names: list[str]) -> dict[str, dict[str, float]]:
    """AU -> {model muscle: weight}: every model muscle whose canonical muscle the AU names; a
    canonical muscle the face lacks is driven through its stand-in (``wface.facs.STAND_INS``)."""

    def models_of(base: str) -> list[str]:
        out = []
        for name in muscle_names:
            badin = name.rsplit("_", 1)[0] if name.endswith(("_l", "_r")) else name
            if base in CANONICAL_MUSCLES.get(badin, ()):
                out.append(name)
        return out

    table: dict[str, dict[str, float]] = {}
    for key, au in ACTION_UNITS.items():
        entry: dict[str, float] = {}
        for base, weight in au.muscles.items():
            names = models_of(base)
            if not names and base in STAND_INS:
                stand_in, factor = STAND_INS[base]
                names, weight = models_of(stand_in), weight * factor
            for name in names:
                entry[name] = max(entry.get(name, 0.0), float(weight))
        if entry:
            table[key] = entry
    return table


def import_artisynth(
    directory: str | Path,
    *,
    fibre_radius_m: float = 0.004,
    condyle_distance_m: float = 0.1,
    track_length_m: float = 0.002,
    steiner_below_deg: float = 10.0,
    min_dihedral_goal_deg: float = 8.0,
    progress: bool = True,
    timings: dict | None = None,
) -> FaceModel:
    """Build a ``FaceModel`` from the ArtiSynth Badin face files in ``directory``.

    Args:
        directory: folder with the ``badinface_oop_csa_midsagittal.{node,elem}`` mesh, the bone OBJs,
            the boundary-condition node lists and the muscle fibre files.
        fibre_radius_m: radius of the tube around each fibre polyline that the muscle fills.
        condyle_distance_m: distance between the condyles (the data gives only the hinge point).
        track_length_m: length of the condylar sliding tracks (the original is a pure hinge).
        steiner_below_deg: a cell whose best split without a new node has a dihedral angle below this
            gets a node at its centre when that does better (see ``hexes_to_tets``).
        min_dihedral_goal_deg: tets of the split with a dihedral angle outside [goal, 180 - goal] are
            improved by local operations (``wface.mesh.improve.improve_tets``); 0 turns that off.
        progress: print step timings to stderr.
        timings: a dict that receives the wall-clock seconds of the import ("total") and of its
            sliver removal ("sliver_removal"); the model's metadata keeps no time, so the same files
            import to the same model (``model_sha256``).

    Returns:
        A validated ``FaceModel`` in wface's frame (X subject's left, Y up, Z forward), SI units.
    """
    t0 = time.perf_counter()
    directory = Path(directory)
    if not (directory / f"{MESH_PREFIX}.node").exists():
        raise FileNotFoundError(f"{directory}: no {MESH_PREFIX}.node (is this the ArtiSynth face data folder?)")

    # ---- nodes and elements
    numbers, index_of, x, hexes = _read_mesh(directory)
    n = len(numbers)
    n_wedges = int(sum(len(set(h.tolist())) < 8 for h in hexes))

    # ---- boundary-condition lists: fixed lists are node numbers, the jaw list 0-based positions
    fixed, jaw_pos, external, internal = _boundary_lists(directory, index_of, n)

    # ---- tets: split the hexes, then remove the slivers of the flat cells by local operations
    mesh = _tet_mesh(hexes, x, [fixed, jaw_pos, external, internal], steiner_below_deg, min_dihedral_goal_deg)
    x, tets = mesh.x, mesh.tets
    _log(progress, t0, mesh.summary(len(hexes), n_wedges))

    # ---- surfaces (atlas lists hold node numbers; an added node is on a surface when its sources are)
    groups = _surface_groups(directory, x, tets, mesh.extend(external), mesh.extend(internal))

    # ---- bones
    bone_meshes = _bone_meshes(directory)
    _log(progress, t0, "surfaces and bones read")

    # ---- boundary conditions (a node on both the fixed and the jaw list follows the jaw); an added
    # node whose source nodes all follow one bone follows it too
    attached, attached_bone, overlap, added_on = _attachments(mesh, fixed, jaw_pos)

    # ---- jaw joint: hinge axis along Badin y (wface X), through the TMJ point
    jaw_joint = _jaw_joint(condyle_distance_m, track_length_m)

    # ---- muscles
    fibres_l = {k: [badin_to_wface(f) for f in v] for k, v in read_badin_fibres(directory).items()}
    muscle_fibres = _muscle_sides(fibres_l)  # badin_muscle_fibres; the left fibres also place markers
    muscle_names = list(muscle_fibres)
    fibre_tet, fibre_muscle, fibre_fraction, fibre_direction, n_overfull = _embed_muscles(
        x, tets, muscle_fibres, fibre_radius_m
    )
    embedded = f"{len(muscle_names)} muscles embedded in {np.unique(fibre_tet).size} tets"
    _log(progress, t0, f"{embedded} (radius {fibre_radius_m * 1e3:g} mm; {n_overfull} tets rescaled to sum 1)")

    # ---- markers and FACS
    marker_names, marker_pos, marker_how = default_markers(x, groups["skin"], fibres_l)
    facs = _facs_table(muscle_names)

    metadata = _metadata(
        numbers=numbers,
        mesh=mesh,
        n_hexes=len(hexes),
        n_wedges=n_wedges,
        overlap=overlap,
        added_on=added_on,
        fibre_radius_m=fibre_radius_m,
        muscle_fibres=muscle_fibres,
        marker_how=marker_how,
        condyle_distance_m=condyle_distance_m,
    )
    model = FaceModel(
        rest_positions_m=x,
        tets=tets,
        skin_triangles=groups["skin"],
        muscle_names=muscle_names,
        fibre_tet=fibre_tet,
        fibre_muscle=fibre_muscle,
        fibre_fraction=fibre_fraction,
        fibre_direction=fibre_direction,
        attached_nodes=attached,
        attached_bone=attached_bone,
        jaw_joint=jaw_joint,
        material=Material.artisynth(),
        bone_meshes=bone_meshes,
        surface_groups=groups,
        marker_names=marker_names,
        marker_positions_m=marker_pos,
        facs=facs,
        metadata=metadata,
    )
    model.validate()
    _log(progress, t0, f"done: {len(marker_names)} markers, {len(facs)} FACS action units")
    if timings is not None:
        timings.update(sliver_removal=mesh.improved.seconds, total=time.perf_counter() - t0)
    return model


def _read_mesh(directory: Path):
    """(ANSYS node numbers, number -> node id map, wface-frame positions, hexes as node ids) of the mesh."""
    numbers, xb = read_ansys_nodes(directory / f"{MESH_PREFIX}.node")
    n = len(numbers)
    index_of = np.full(int(numbers.max()) + 1, -1, dtype=np.int64)
    index_of[numbers] = np.arange(n)
    x = badin_to_wface(xb)
    hexes = _by_number(index_of, read_ansys_elements(directory / f"{MESH_PREFIX}.elem"), "element file")
    return numbers, index_of, x, hexes


def _by_number(index_of: np.ndarray, nums: np.ndarray, what: str) -> np.ndarray:
    """Model node ids of ANSYS node numbers (``index_of``: number -> id, -1 where absent)."""
    bad = nums[(nums < 0) | (nums >= len(index_of))]
    if bad.size or np.any(index_of[nums] < 0):
        raise ValueError(f"{what}: node numbers not in the node file: {bad[:5].tolist()}")
    return index_of[nums]


def _boundary_lists(directory: Path, index_of: np.ndarray, n: int):
    """(fixed, jaw positions, atlas external, atlas internal) node ids of the boundary-condition lists."""
    fixed = np.unique(np.concatenate([_by_number(index_of, read_int_list(directory / f), f) for f in FIXED_NODE_FILES]))
    jaw_pos = read_int_list(directory / JAW_NODE_FILE)
    if jaw_pos.min() < 0 or jaw_pos.max() >= n:
        raise ValueError(f"{JAW_NODE_FILE}: positions outside [0, {n})")
    external = _by_number(index_of, read_ansys_nodes(directory / "atlas_external.node")[0], "atlas_external.node")
    internal = _by_number(index_of, read_ansys_nodes(directory / "atlas_internal.node")[0], "atlas_internal.node")
    return fixed, jaw_pos, external, internal


@dataclass
class _TetMesh:
    """The tets of the hex split after the sliver removal, and where the added nodes come from."""

    x: np.ndarray
    tets: np.ndarray
    n_file_nodes: int  # the node file's nodes; added nodes have ids n_file_nodes, n_file_nodes + 1, ...
    sources: list  # per added node: the nodes it stands for
    edge_sources: list
    improved: object
    split_quality: object
    quality: object

    def extend(self, nodes: np.ndarray) -> np.ndarray:
        """A node list plus the added face-centre and edge nodes whose source nodes are all on it."""
        n = self.n_file_nodes
        member = np.zeros(len(self.x), dtype=bool)
        member[nodes] = True
        for k, src in enumerate(self.sources):  # cell-centre nodes (more than 4 sources) are interior
            member[n + k] = len(src) <= 4 and member[list(src)].all()
        return np.flatnonzero(member)

    def summary(self, n_hexes: int, n_wedges: int) -> str:
        """One progress line: sizes and the smallest dihedral angle after the split and the sliver removal."""
        n, x, tets, split_quality, quality = self.n_file_nodes, self.x, self.tets, self.split_quality, self.quality
        return (
            f"{n} nodes, {n_hexes} hexes ({n_wedges} degenerate) -> {len(tets)} tets with "
            f"{len(x) - n} added nodes; min dihedral {split_quality.min_dihedral_deg:.2f} deg after the split, "
            f"{quality.min_dihedral_deg:.2f} deg after {sum(self.improved.operations.values())} local operations; "
            f"inverted {quality.inverted}"
        )


def _tet_mesh(hexes, x, locked_lists, steiner_below_deg: float, min_dihedral_goal_deg: float) -> _TetMesh:
    """Split the hexes into tets, then remove the slivers of the flat cells by local operations; the
    nodes of ``locked_lists`` do not move."""
    n = len(x)
    tets, parent, steiner_points, steiner_sources = hexes_to_tets(
        hexes, x, steiner_below_deg=steiner_below_deg, return_sources=True
    )
    x = np.vstack([x, steiner_points])
    split_quality = quality_report(x, tets)
    locked = np.zeros(len(x), dtype=bool)
    locked[np.concatenate(locked_lists)] = True
    x, tets, edge_sources, improved = improve_tets(x, tets, goal_deg=min_dihedral_goal_deg, locked=locked)
    sources = [*steiner_sources, *edge_sources]  # per added node (ids n, n + 1, ...): the nodes it stands for
    quality = quality_report(x, tets)
    return _TetMesh(x, tets, n, sources, edge_sources, improved, split_quality, quality)


def _surface_groups(directory: Path, x: np.ndarray, tets: np.ndarray, external, internal) -> dict[str, np.ndarray]:
    """Skin / inner / edge boundary triangles, and the lip contact surfaces when the data has them."""
    boundary = boundary_faces(tets)
    groups = _classify_boundary(boundary, external.astype(np.int64), internal.astype(np.int64))
    for group, fname in LIP_SURFACE_FILES.items():  # lip contact surfaces, when the data has them
        if (directory / fname).exists():
            groups[group] = _surface_on_nodes(directory / fname, x, boundary)
    return groups


def _bone_meshes(directory: Path) -> dict[str, BoneMesh]:
    bone_meshes = {}
    for name, (fname, bone) in BONE_FILES.items():
        v, t = read_obj(directory / fname)
        bone_meshes[name] = BoneMesh(badin_to_wface(v), t, bone)
    return bone_meshes


def _attachments(mesh: _TetMesh, fixed: np.ndarray, jaw_pos: np.ndarray):
    """(attached nodes, their bone 0 cranium / 1 jaw, nodes on both lists, added nodes attached per bone)."""
    n = mesh.n_file_nodes
    jaw_orig = np.unique(jaw_pos)
    overlap = np.intersect1d(fixed, jaw_orig)
    cranium_nodes = mesh.extend(np.setdiff1d(fixed, jaw_orig))
    jaw_nodes = mesh.extend(jaw_orig)
    added_on = {0: int(np.count_nonzero(cranium_nodes >= n)), 1: int(np.count_nonzero(jaw_nodes >= n))}
    attached = np.concatenate([cranium_nodes, jaw_nodes])
    attached_bone = np.concatenate([np.zeros(len(cranium_nodes)), np.ones(len(jaw_nodes))]).astype(np.int8)
    order = np.argsort(attached, kind="stable")
    return attached[order], attached_bone[order], overlap, added_on


def _jaw_joint(condyle_distance_m: float, track_length_m: float) -> JawJoint:
    """The jaw hinge through the data's temporomandibular point (``TMJ_POINT_BADIN_M``)."""
    mid = badin_to_wface(np.array(TMJ_POINT_BADIN_M))
    return JawJoint(
        u=(1.0, 0.0, 0.0),  # right -> left condyle
        v=(0.0, 0.0, 1.0),  # back -> front
        midpoint_m=tuple(float(c) for c in mid),
        condyle_distance_m=float(condyle_distance_m),
        track_length_m=float(track_length_m),
        max_opening_sine=float(np.sin(np.radians(MAX_OPENING_DEG))),
    )


def _muscle_sides(fibres_l: dict[str, list[np.ndarray]]) -> dict[str, list[np.ndarray]]:
    """Model muscle -> fibre polylines: ``<badin>_l`` (the left fibres) and ``<badin>_r`` (mirrored)."""
    mirror = np.array([-1.0, 1.0, 1.0])
    muscle_fibres: dict[str, list[np.ndarray]] = {}
    for badin in BADIN_MUSCLES:
        if badin not in fibres_l or not fibres_l[badin]:
            continue
        left = fibres_l[badin]
        right = [f * mirror for f in left]
        if all(np.all(np.abs(f[:, 0]) < MIDLINE_TOL_M) for f in left):
            sides = {badin: left}  # a midline muscle mirrors onto itself
        else:
            sides = {f"{badin}_l": left, f"{badin}_r": right}
        muscle_fibres.update(sides)
    return muscle_fibres


def _embed_muscles(x: np.ndarray, tets: np.ndarray, muscle_fibres: dict[str, list[np.ndarray]], fibre_radius_m):
    """(fibre_tet, fibre_muscle, fibre_fraction, fibre_direction, tets rescaled to sum 1) of the muscles."""
    entries_t, entries_m, entries_f, entries_d = [], [], [], []
    for m, polylines in enumerate(muscle_fibres.values()):
        t_ids, frac, dirs = embed_fibres(x, tets, polylines, fibre_radius_m)
        entries_t.append(t_ids)
        entries_m.append(np.full(len(t_ids), m, dtype=np.int32))
        entries_f.append(frac)
        entries_d.append(dirs)
    fibre_tet = np.concatenate(entries_t)
    fibre_muscle = np.concatenate(entries_m)
    fibre_fraction = np.concatenate(entries_f)
    fibre_direction = np.concatenate(entries_d)
    total = np.bincount(fibre_tet, weights=fibre_fraction, minlength=len(tets))
    n_overfull = int(np.count_nonzero(total > 1.0))
    fibre_fraction = fibre_fraction / np.maximum(total[fibre_tet], 1.0)  # per tet, fractions sum to <= 1
    order = np.lexsort((fibre_muscle, fibre_tet))
    fibre_tet, fibre_muscle = fibre_tet[order], fibre_muscle[order]
    fibre_fraction, fibre_direction = fibre_fraction[order], fibre_direction[order]
    fibre_direction /= np.linalg.norm(fibre_direction, axis=1, keepdims=True)
    return fibre_tet, fibre_muscle, fibre_fraction, fibre_direction, n_overfull


def _canonical_muscles(muscle_names: list[str]) -> dict[str, list[str]]:
    """Model muscle -> the canonical ``wface.facs`` muscles it stands for."""
    canonical = {}
    for name in muscle_names:
        badin, _, side = name.partition("_")
        sides = [side] if side else ["l", "r"]  # a midline muscle stands for both sides
        canonical[name] = sorted(
            {b if b.startswith("orbicularis_oris") else f"{b}_{s}" for b in CANONICAL_MUSCLES[badin] for s in sides}
        )
    return canonical


def _metadata(
    *,
    numbers,
    mesh: _TetMesh,
    n_hexes: int,
    n_wedges: int,
    overlap,
    added_on,
    fibre_radius_m,
    muscle_fibres,
    marker_how,
    condyle_distance_m,
) -> dict:
    """The model's ``metadata``: sources, frame, node lists, mesh provenance and quality, muscles, jaw."""
    n, x, edge_sources, improved = mesh.n_file_nodes, mesh.x, mesh.edge_sources, mesh.improved
    muscle_names = list(muscle_fibres)
    return {
        "source": "ArtiSynth Models, Badin face (artisynth_models src/artisynth/models/face/geometry)",
        "citation": CITATION,
        "licence": "BSD-style (ArtiSynth Models LICENSE; academic publications must cite the original work)",
        "mesh_files": [f"{MESH_PREFIX}.node", f"{MESH_PREFIX}.elem"],
        "frame": {
            "description": "wface: +x subject's left, +y up, +z forward; metres",
            "from_source": "Badin data: +x posterior, +y subject's right, +z up (nose tip has the smallest x)",
            "rotation_source_to_model": BADIN_TO_WFACE.tolist(),
            "translation_m": [0.0, 0.0, 0.0],
        },
        "node_numbers": f"model node i < {n} is ANSYS node number i + 1 (the node file numbers 1..{n} in order)"
        if np.array_equal(numbers, np.arange(1, n + 1))
        else "see importer",
        "node_list_indexing": {
            **{f: "1-based node numbers" for f in FIXED_NODE_FILES},
            "atlas_external.node": "1-based node numbers",
            "atlas_internal.node": "1-based node numbers",
            JAW_NODE_FILE: "0-based positions in the node file",
        },
        "nodes_on_both_fixed_and_jaw_lists": int(overlap.size),
        "added_nodes": {
            "first_id": int(n),
            "count": int(len(x) - n),
            "what": "face-centre and cell nodes of the hex split (twisted or flat cells), then nodes inserted on "
            "edges by the sliver removal; an added node whose source nodes all follow a bone is attached to it",
            "edge_nodes": len(edge_sources),
            "edge_sources": [[int(a), int(b)] for a, b in edge_sources],
            "attached_to_cranium": added_on[0],
            "attached_to_jaw": added_on[1],
        },
        "hex_split": "quad faces cut through their smallest node id, cells coned from their smallest node "
        "(Dompierre et al. 1999); conforming",
        "sliver_removal": {
            "method": "edge removal, 2-3 flips, smoothing of free interior nodes and edge splits "
            "(wface.mesh.improve; Klingner & Shewchuk 2007); boundary and boundary-condition nodes do not move",
            **without_timings(improved.as_dict()),
            "tet_quality_after_split": mesh.split_quality.as_dict(),
        },
        "hexes": int(n_hexes),
        "degenerate_hexes": n_wedges,
        "tet_quality": mesh.quality.as_dict(),
        "surface_classification": "boundary triangles with all nodes in atlas_external -> skin, all in "
        "atlas_internal -> inner, else edge (cut boundary)",
        "fibre_radius_m": float(fibre_radius_m),
        "fibre_embedding": "fraction = share of 35 lattice points of the tet within fibre_radius_m of a fibre; "
        "direction = tangent of the fibre segment nearest the centroid; fractions rescaled to sum <= 1 per tet",
        "muscle_long_names": {m: _MUSCLE_LONG_NAMES[m.partition("_")[0]] for m in muscle_names},
        "canonical_muscles": _canonical_muscles(muscle_names),
        "muscle_sides": "_l: subject's left (+x, the Badin 'left side' fibres); _r: mirrored across x = 0",
        "unused_muscles": list(UNUSED_MUSCLES),
        "muscle_fibres_m": {k: [f.tolist() for f in v] for k, v in muscle_fibres.items()},
        "markers": marker_how,
        "jaw": {
            "hinge_point_source_m": list(TMJ_POINT_BADIN_M),
            "opening_deg": [0.0, MAX_OPENING_DEG],
            "condyle_distance_m": "assumed (not in the data)" if condyle_distance_m == 0.1 else "given",
        },
    }
