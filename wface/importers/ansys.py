"""Readers for the ANSYS / APDL / OBJ files of the ArtiSynth face, and a conforming hex -> tet split.

File formats (as found in the ArtiSynth "Badin" face data):

- ``.node``: rows ``number x y z``; numbers are 1-based ANSYS node numbers.
- ``.elem``: rows of 8 node numbers of an 8-node hexahedron (ANSYS SOLID185 order I J K L M N O P,
  face I J K L opposite face M N O P) followed by ANSYS attributes. Degenerate hexes repeat nodes
  (a wedge: K = L and O = P; the readers and the split handle any repetition).
- ``.nodenum`` / ``.txt``: whitespace-separated integers (node numbers or 0-based positions: the
  file does not say; see ``wface.importers.artisynth``).
- APDL ``.mac``: ``NB_FIBERS(m)= k``, ``NB_NODES_FIBER(m,f)= k``, ``FIBER(m,f,i)= id`` assignments,
  ``!`` starts a comment.

Hex split (after Dompierre et al. 1999, "How to subdivide pyramids, prisms and hexahedra into
tetrahedra"): every quadrilateral face is cut by the diagonal through its smallest global node id,
so two elements sharing a face cut it the same way (the tet mesh is conforming). Each cell is then
coned from its smallest-id vertex over the boundary triangles that do not contain it. On every face
through that vertex the chosen diagonal passes through it, so no flat tet is made; for a convex
cell every cone tet is positive. A hex gives 6 tets, a wedge 3, a pyramid 2.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

__all__ = [
    "hexes_to_tets",
    "read_ansys_elements",
    "read_ansys_nodes",
    "read_apdl_fibres",
    "read_int_list",
    "read_obj",
]

# Faces of an ANSYS 8-node brick (local ids I..P = 0..7), each listed cyclically.
_HEX_FACES = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])


_NODE_ROW = re.compile(r"^\s*(\d+)\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)")


def read_ansys_nodes(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an ANSYS node file. Returns (numbers (n,) int64, positions (n, 3) float64) in file order.

    Handles the fixed-width form where a negative coordinate touches the node number
    (``1204-0.365E-05  78.8 ...``).
    """
    numbers: list[int] = []
    xyz: list[tuple[float, float, float]] = []
    for k, line in enumerate(Path(path).read_text().splitlines()):
        if not line.strip():
            continue
        m = _NODE_ROW.match(line)
        if not m:
            raise ValueError(f"{path}:{k + 1}: expected 'number x y z', got {line.strip()!r}")
        numbers.append(int(m.group(1)))
        xyz.append((float(m.group(2)), float(m.group(3)), float(m.group(4))))
    return np.asarray(numbers, dtype=np.int64), np.asarray(xyz, dtype=np.float64).reshape(-1, 3)


def read_ansys_elements(path: str | Path) -> np.ndarray:
    """Read an ANSYS element file: (m, 8) int64 node numbers of 8-node hexahedra (attributes dropped)."""
    data = np.loadtxt(path, ndmin=2, dtype=np.int64)
    if data.shape[1] < 8:
        raise ValueError(f"{path}: expected at least 8 node numbers per row, got {data.shape[1]} columns")
    return data[:, :8]


def read_int_list(path: str | Path) -> np.ndarray:
    """All integers of a whitespace-separated list file, in order, as int64."""
    return np.array(Path(path).read_text().split(), dtype=np.int64)


def read_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (k, 3) float64 and triangles (t, 3) int32 of a Wavefront OBJ (polygons fan-split)."""
    verts: list[list[float]] = []
    tris: list[tuple[int, int, int]] = []
    for line in Path(path).read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append([float(a) for a in parts[1:4]])
        elif parts[0] == "f":
            ids = [int(a.split("/")[0]) for a in parts[1:]]
            ids = [i - 1 if i > 0 else len(verts) + i for i in ids]  # OBJ is 1-based; negatives count back
            tris.extend((ids[0], ids[k], ids[k + 1]) for k in range(1, len(ids) - 1))
    return np.asarray(verts, dtype=np.float64).reshape(-1, 3), np.asarray(tris, dtype=np.int32).reshape(-1, 3)


_ASSIGN = re.compile(r"^\s*(NB_FIBERS|NB_NODES_FIBER|FIBER)\s*\(([\d\s,]+)\)\s*=\s*(\d+)", re.IGNORECASE)


def read_apdl_fibres(path: str | Path) -> dict[int, list[list[int]]]:
    """Fibres of an APDL muscle topology script.

    Returns ``{muscle number (1-based): [fibre point ids in order, one list per fibre]}``. Only the
    first ``NB_FIBERS(m)`` fibres and first ``NB_NODES_FIBER(m, f)`` points of each are kept, as the
    ArtiSynth reader does; commented lines (``!``) are ignored.
    """
    nb_fibres: dict[int, int] = {}
    nb_nodes: dict[tuple[int, int], int] = {}
    points: dict[tuple[int, int, int], int] = {}
    for raw in Path(path).read_text(errors="replace").splitlines():
        line = raw.split("!", 1)[0]
        m = _ASSIGN.match(line)
        if not m:
            continue
        key = m.group(1).upper()
        idx = tuple(int(s) for s in m.group(2).split(","))
        value = int(m.group(3))
        if key == "NB_FIBERS" and len(idx) == 1:
            nb_fibres[idx[0]] = value
        elif key == "NB_NODES_FIBER" and len(idx) == 2:
            nb_nodes[idx] = value
        elif key == "FIBER" and len(idx) == 3:
            points[idx] = value
    out: dict[int, list[list[int]]] = {}
    for mi in sorted(nb_fibres):
        fibres = []
        for fi in range(1, nb_fibres[mi] + 1):
            k = nb_nodes.get((mi, fi), 0)
            ids = [points[(mi, fi, ni)] for ni in range(1, k + 1) if (mi, fi, ni) in points]
            fibres.append(ids)
        out[mi] = fibres
    return out


def _signed_volume(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    p = x[t]
    return np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])) / 6.0


def _cell_triangles(cell: np.ndarray, split: dict[tuple[int, ...], int] | None = None) -> list[list[int]]:
    """Outward boundary triangles of one (possibly degenerate) brick.

    A quad face is cut by the diagonal through its smallest node id, or, when its sorted node ids
    are a key of ``split``, into four triangles around the node ``split[key]`` (its centre).
    """
    tris: list[list[int]] = []
    for face in _HEX_FACES:
        ring: list[int] = []
        for i in (int(cell[k]) for k in face):  # drop repeated nodes (degenerate faces), cyclically
            if not ring or ring[-1] != i:
                ring.append(i)
        while len(ring) > 1 and ring[0] == ring[-1]:
            ring.pop()
        if len(set(ring)) < 3:
            continue
        if len(ring) == 3:
            tris.append(ring)
            continue
        key = tuple(sorted(ring))
        if split is not None and key in split:
            c = split[key]
            tris += [[ring[j], ring[(j + 1) % 4], c] for j in range(4)]
        else:
            k = ring.index(min(ring))
            a, b, c, d = ring[k:] + ring[:k]
            tris += [[a, b, c], [a, c, d]]
    return tris


def _quads(cell: np.ndarray) -> list[tuple[int, ...]]:
    out = []
    for face in _HEX_FACES:
        ids = {int(cell[k]) for k in face}
        if len(ids) == 4:
            out.append(tuple(sorted(ids)))
    return out


def _trilinear(p: np.ndarray, uvw: np.ndarray) -> np.ndarray:
    """Points of the trilinear map of brick corners p (8, 3) (ANSYS order) at parameters uvw (k, 3)."""
    u, v, w = uvw[:, 0:1], uvw[:, 1:2], uvw[:, 2:3]
    bottom = (1 - u) * (1 - v) * p[0] + u * (1 - v) * p[1] + u * v * p[2] + (1 - u) * v * p[3]
    top = (1 - u) * (1 - v) * p[4] + u * (1 - v) * p[5] + u * v * p[6] + (1 - u) * v * p[7]
    return (1 - w) * bottom + w * top


def _cone_scores(pts: np.ndarray, apexes: np.ndarray, tris: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Cones from each apex (k,) over triangles (t, 3): oriented tets per apex, and min dihedral (k,).

    Triangles that contain the apex are skipped; a cone with a tet of volume <= 0 scores -1.
    """
    from wface.mesh.quality import dihedral_angles_deg

    k, t = len(apexes), len(tris)
    tets = np.concatenate([np.repeat(np.asarray(apexes)[:, None, None], t, axis=1), np.broadcast_to(tris, (k, t, 3))], axis=2)
    member = np.any(tris[None, :, :] == np.asarray(apexes)[:, None, None], axis=2)  # (k, t)
    flat = tets.reshape(-1, 4)
    vol = _signed_volume(pts, flat).reshape(k, t)
    vol = np.where(member, 0.0, vol)
    sign = np.where(vol.sum(axis=1) < 0, -1.0, 1.0)
    vol = vol * sign[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        dmin = dihedral_angles_deg(pts, flat).min(axis=1).reshape(k, t)
    total = np.maximum(vol.sum(axis=1, keepdims=True), 1e-300)
    ok = member | (vol > 1e-9 * total)
    dmin = np.where(member, np.inf, np.nan_to_num(dmin, nan=-1.0))
    scores = np.where(ok.all(axis=1), dmin.min(axis=1), -1.0)
    cones = []
    for a in range(k):
        c = tets[a][~member[a]]
        cones.append(c[:, [0, 2, 1, 3]] if sign[a] < 0 else c)
    return cones, scores


_GRID5 = np.stack(np.meshgrid(*(np.linspace(0.15, 0.85, 5),) * 3, indexing="ij"), axis=-1).reshape(-1, 3)


def hexes_to_tets(
    hexes: np.ndarray, x: np.ndarray, *, steiner_below_deg: float = 10.0, max_rounds: int = 4
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split (possibly degenerate) 8-node hexahedra into positively oriented, conforming tetrahedra.

    The boundary of every cell is triangulated by the smallest-id diagonal rule, which neighbours
    share (conforming). The interior is the best cone over the cell's boundary triangles: from one of
    its vertices (no new node), else, when no vertex cone has all dihedral angles above
    ``steiner_below_deg``, from a new node inside the cell (the vertex mean, or the best point of a
    5^3 lattice of the trilinear cell) if that does better. Cells that remain inverted or worse than
    the bound have their quad faces split through a new face-centre node (four triangles, shared with
    the neighbour, so still conforming) and all cells touching those faces are redone, up to
    ``max_rounds`` times.

    Args:
        hexes: (m, 8) int 0-based node ids in ANSYS brick order; repeated ids make wedges, pyramids, tets.
        x: (n, 3) node positions.
        steiner_below_deg: cells whose best vertex cone has a smaller dihedral angle get a new node.
        max_rounds: rounds of face splitting.

    Returns:
        (tets (k, 4) int32, parent (k,) int32 element of each tet, new_points (s, 3) added nodes,
        which get ids n, n + 1, ... in this order).
    """
    hexes = np.asarray(hexes)
    x = np.asarray(x, dtype=np.float64)
    n, m = len(x), len(hexes)
    split: dict[tuple[int, ...], int] = {}
    new_points: list[np.ndarray] = []
    cell_tets: list[np.ndarray] = [np.zeros((0, 4), np.int64)] * m
    cell_score = np.full(m, -np.inf)
    todo = np.arange(m)
    quad_cells: dict[tuple[int, ...], list[int]] = {}
    for e, cell in enumerate(hexes):
        for q in _quads(cell):
            quad_cells.setdefault(q, []).append(e)
    for _round in range(max_rounds + 1):
        pts = np.vstack([x, *new_points]) if new_points else x
        pending_points: list[np.ndarray] = []
        for e in todo:
            cell = hexes[e]
            verts = np.unique(cell)
            tris = np.asarray(_cell_triangles(cell, split))
            extra = np.unique(tris[tris >= n]) if np.any(tris >= n) else np.zeros(0, np.int64)
            cones, scores = _cone_scores(pts, np.concatenate([verts, extra]), tris)
            best = int(np.argmax(scores))
            if scores[best] < steiner_below_deg:
                cand = pts[verts].mean(axis=0, keepdims=True)
                base = len(pts)
                s_cones, s_scores = _cone_scores(np.vstack([pts, cand]), np.array([base]), tris)
                if s_scores[0] < steiner_below_deg:  # the vertex mean is not good enough: search a lattice
                    cand = np.vstack([cand, _trilinear(x[cell], _GRID5)])
                    s_cones, s_scores = _cone_scores(np.vstack([pts, cand]), base + np.arange(len(cand)), tris)
                sb = int(np.argmax(s_scores))
                if s_scores[sb] > scores[best]:
                    new_id = n + sum(len(p) for p in new_points) + len(pending_points)
                    tets = s_cones[sb].copy()
                    tets[tets == base + sb] = new_id
                    pending_points.append(cand[sb])
                    cell_tets[e], cell_score[e] = tets, s_scores[sb]
                    continue
            cell_tets[e], cell_score[e] = cones[best], scores[best]
        if pending_points:
            new_points.append(np.asarray(pending_points))
        bad = np.flatnonzero(cell_score < min(steiner_below_deg, 1.0))
        if bad.size == 0 or _round == max_rounds:
            break
        touched: set[int] = set()
        for e in bad:
            for q in _quads(hexes[e]):
                if q not in split:
                    split[q] = n + sum(len(p) for p in new_points)
                    new_points.append(x[list(q)].mean(axis=0, keepdims=True))
                    touched.update(quad_cells[q])
        # Redone cells drop their old cell-centre nodes: rebuild the numbering afterwards.
        todo = np.asarray(sorted(touched), dtype=np.int64)
        if todo.size == 0:
            break
    tets = np.concatenate(cell_tets)
    parent = np.repeat(np.arange(m), [len(t) for t in cell_tets])
    pts_new = np.vstack(new_points) if new_points else np.zeros((0, 3))
    used = np.unique(tets[tets >= n]) - n  # compact: drop added nodes no tet uses any more
    remap = np.full(len(pts_new), -1)
    remap[used] = n + np.arange(len(used))
    big = tets >= n
    tets[big] = remap[tets[big] - n]
    return tets.astype(np.int32), parent.astype(np.int32), pts_new[used]
