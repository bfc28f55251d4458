"""Readers for the ANSYS / APDL / OBJ files of the ArtiSynth face, and a conforming hex -> tet split.

File formats (as found in the ArtiSynth "Badin" face data):

- ``.node``: rows ``number x y z``; numbers are 1-based ANSYS node numbers.
- ``.elem``: rows of 8 node numbers of an 8-node hexahedron (ANSYS SOLID185 order I J K L M N O P,
  face I J K L opposite face M N O P) followed by ANSYS attributes. Degenerate hexes repeat nodes
  (a wedge: K = L and O = P; the readers and the split handle any repetition).
- ``.nodenum`` / ``.txt``: whitespace-separated integers (node numbers or 0-based positions: the
  file does not say; see ``wface.faces.artisynth``).
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

from wface.mesh.quality import dihedral_angles_deg

__all__ = [
    "hex_boundary_triangles",
    "hexes_to_tets",
    "read_ansys_elements",
    "read_ansys_nodes",
    "read_apdl_fibres",
    "read_int_list",
    "read_obj",
]

# Faces of an ANSYS 8-node brick (local ids I..P = 0..7), each listed cyclically.
_HEX_FACES = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])


_FLOAT = r"\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)"
_NODE_ROW = re.compile(r"^\s*(\d+)" + _FLOAT * 3)


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
        tris += _face_triangles([int(cell[k]) for k in face], split)
    return tris


def _face_triangles(corners: list[int], split: dict[tuple[int, ...], int] | None = None) -> list[list[int]]:
    """Triangles of one brick face (its 4 corner node ids, cyclic; see ``_cell_triangles``)."""
    ring: list[int] = []
    for i in corners:  # drop repeated nodes (degenerate faces), cyclically
        if not ring or ring[-1] != i:
            ring.append(i)
    while len(ring) > 1 and ring[0] == ring[-1]:
        ring.pop()
    if len(set(ring)) < 3:
        return []
    if len(ring) == 3:
        return [ring]
    key = tuple(sorted(ring))
    if split is not None and key in split:
        c = split[key]
        return [[ring[j], ring[(j + 1) % 4], c] for j in range(4)]
    k = ring.index(min(ring))
    a, b, c, d = ring[k:] + ring[:k]
    return [[a, b, c], [a, c, d]]


def hex_boundary_triangles(hexes: np.ndarray) -> np.ndarray:
    """(t, 3) outward triangles of the boundary of a brick mesh (hexes (h, 8), ANSYS order; wedges and
    other degenerate bricks repeat nodes). A face is on the boundary when no other brick has the same
    nodes; each boundary quad is cut by the diagonal through its smallest node id."""
    cells = np.asarray(hexes, dtype=np.int64).reshape(-1, 8)
    rings: dict[tuple[int, ...], list[int]] = {}
    count: dict[tuple[int, ...], int] = {}
    for cell in cells:
        for face in _HEX_FACES:
            ring = [int(cell[k]) for k in face]
            key = tuple(sorted(set(ring)))
            if len(key) < 3:
                continue
            count[key] = count.get(key, 0) + 1
            rings[key] = ring
    out = [t for key, n in count.items() if n == 1 for t in _face_triangles(rings[key])]  # boundary faces only
    return np.asarray(out, dtype=np.int64).reshape(-1, 3)


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


def _batch_cones(pts: np.ndarray, apexes: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Score the cones of many cells at once.

    Args:
        pts: (p, 3) points.
        apexes: (c, k) candidate apex ids per cell, -1 for none.
        tris: (c, t, 3) outward boundary triangles per cell, rows of -1 for padding.

    Returns:
        (score (c, k): smallest dihedral angle of the cone in degrees, -1 when a tet is flat or
        inverted, -inf for no apex; skip (c, k, t): triangle not used by the cone (contains the apex
        or padding); flip (c, k): the cone's tets need reorienting.)
    """

    c, k = apexes.shape
    t = tris.shape[1]
    a = np.maximum(apexes, 0)
    tr = np.maximum(tris, 0)
    skip = np.any(tris[:, None, :, :] == apexes[:, :, None, None], axis=3) | (tris[:, None, :, 0] < 0)
    tets = np.concatenate(
        [np.broadcast_to(a[:, :, None, None], (c, k, t, 1)), np.broadcast_to(tr[:, None], (c, k, t, 3))], axis=3
    ).reshape(-1, 4)
    vol = np.where(skip, 0.0, _signed_volume(pts, tets).reshape(c, k, t))
    total = vol.sum(axis=2)
    flip = total < 0
    vol = np.where(flip[:, :, None], -vol, vol)
    ok = skip | (vol > 1e-9 * np.abs(total)[:, :, None])
    with np.errstate(invalid="ignore", divide="ignore"):
        dmin = dihedral_angles_deg(pts, tets).min(axis=1).reshape(c, k, t)
    dmin = np.where(skip, np.inf, np.nan_to_num(dmin, nan=-1.0))
    score = np.where(ok.all(axis=2) & (np.abs(total) > 0), dmin.min(axis=2), -1.0)
    score = np.where(apexes < 0, -np.inf, score)
    return score, skip, flip


def _cone(apex: int, tris: np.ndarray, skip: np.ndarray, flip: bool) -> np.ndarray:
    tt = tris[~skip]
    tets = np.concatenate([np.full((len(tt), 1), apex), tt], axis=1)
    return tets[:, [0, 2, 1, 3]] if flip else tets


def _padded_triangles(cells: np.ndarray, split: dict) -> np.ndarray:
    lists = [_cell_triangles(cell, split) for cell in cells]
    t = max(len(tr) for tr in lists)
    out = np.full((len(cells), t, 3), -1, dtype=np.int64)
    for i, tr in enumerate(lists):
        out[i, : len(tr)] = tr
    return out


_GRID5 = np.stack(np.meshgrid(*(np.linspace(0.15, 0.85, 5),) * 3, indexing="ij"), axis=-1).reshape(-1, 3)


def hexes_to_tets(
    hexes: np.ndarray,
    x: np.ndarray,
    *,
    steiner_below_deg: float = 10.0,
    split_below_deg: float = 3.0,
    max_rounds: int = 4,
    return_sources: bool = False,
):
    """Split (possibly degenerate) 8-node hexahedra into positively oriented, conforming tetrahedra.

    The boundary of every cell is triangulated by the smallest-id diagonal rule, which neighbours
    share (conforming). The interior is the best cone over the cell's boundary triangles: from one of
    its vertices (no new node), else, when no vertex cone has all dihedral angles above
    ``steiner_below_deg``, from a new node inside the cell (the vertex mean, or the best point of a
    5^3 lattice of the trilinear cell) if that does better. Cells still below ``split_below_deg``
    (inverted, or twisted so that no interior point sees all the boundary triangles well) have their
    quad faces split through a new face-centre node (four triangles, shared with the neighbour, so
    still conforming) and every cell touching those faces is redone, up to ``max_rounds`` times.

    Args:
        hexes: (m, 8) int 0-based node ids in ANSYS brick order; repeated ids make wedges, pyramids, tets.
        x: (n, 3) node positions.
        steiner_below_deg: cells whose best vertex cone has a smaller dihedral angle may get a new node.
        split_below_deg: cells whose best cone stays below this get their faces split.
        max_rounds: rounds of face splitting.
        return_sources: also return, per added node, the original node ids it stands for (a face
            centre: the quad's 4 nodes; a cell node: the cell's nodes).

    Returns:
        (tets (k, 4) int32, parent (k,) int32 element of each tet, new_points (s, 3) added nodes,
        which get ids n, n + 1, ... in this order[, sources: list of s tuples]).
    """
    hexes = np.asarray(hexes, dtype=np.int64)
    x = np.asarray(x, dtype=np.float64)
    n, m = len(x), len(hexes)
    split: dict[tuple[int, ...], int] = {}
    face_points: list[np.ndarray] = []  # face-centre nodes, ids n, n + 1, ... in order
    cell_point: dict[int, np.ndarray] = {}  # cell-centre nodes, numbered after the face centres
    cell_tets: list[np.ndarray] = [np.zeros((0, 4), np.int64)] * m
    cell_score = np.full(m, -np.inf)
    quad_cells: dict[tuple[int, ...], list[int]] = {}
    for e, cell in enumerate(hexes):
        for q in _quads(cell):
            quad_cells.setdefault(q, []).append(e)
    todo = np.arange(m)
    placeholder = -2  # apex id of a cell's own centre node until the final numbering
    for _round in range(max_rounds + 1):
        pts = np.vstack([x, *face_points]) if face_points else x
        cells = hexes[todo]
        tris = _padded_triangles(cells, split)
        # vertex cones (the cell's nodes and its face-centre nodes)
        cands = [np.unique(np.concatenate([cell, tris[i][tris[i] >= n]])) for i, cell in enumerate(cells)]
        apex = np.full((len(todo), max(len(c) for c in cands)), -1, dtype=np.int64)
        for i, cand in enumerate(cands):
            apex[i, : len(cand)] = cand
        score, skip, flip = _batch_cones(pts, apex, tris)
        best = np.argmax(score, axis=1)
        best_score = score[np.arange(len(todo)), best]
        # a new node at the vertex mean, for cells without a good vertex cone
        centres = np.array([x[np.unique(c)].mean(axis=0) for c in cells])
        c_score, c_skip, c_flip = _batch_cones(
            np.vstack([pts, centres]), (len(pts) + np.arange(len(todo)))[:, None], tris
        )
        for i, e in enumerate(todo):
            cell_point.pop(int(e), None)
            if best_score[i] >= steiner_below_deg or max(c_score[i, 0], best_score[i]) == best_score[i]:
                if best_score[i] < steiner_below_deg:  # the centre did not help: try a lattice of points
                    grid = _trilinear(x[cells[i]], _GRID5)
                    g_score, g_skip, g_flip = _batch_cones(
                        np.vstack([pts, grid]), (len(pts) + np.arange(len(grid)))[None, :], tris[i : i + 1]
                    )
                    j = int(np.argmax(g_score[0]))
                    if g_score[0, j] > best_score[i]:
                        cell_point[int(e)] = grid[j]
                        cell_tets[e] = _cone(placeholder, tris[i], g_skip[0, j], bool(g_flip[0, j]))
                        cell_score[e] = g_score[0, j]
                        continue
                cell_tets[e] = _cone(int(apex[i, best[i]]), tris[i], skip[i, best[i]], bool(flip[i, best[i]]))
                cell_score[e] = best_score[i]
            else:
                cell_point[int(e)] = centres[i]
                cell_tets[e] = _cone(placeholder, tris[i], c_skip[i, 0], bool(c_flip[i, 0]))
                cell_score[e] = c_score[i, 0]
        bad = np.flatnonzero(cell_score < split_below_deg)
        if bad.size == 0 or _round == max_rounds:
            break
        touched: set[int] = set()
        for e in bad:
            for q in _quads(hexes[e]):
                if q not in split:
                    split[q] = n + len(face_points)
                    face_points.append(x[list(q)].mean(axis=0, keepdims=True))
                    touched.update(quad_cells[q])
        if not touched:
            break
        todo = np.asarray(sorted(touched), dtype=np.int64)
    # final numbering: face centres first, then cell centres in cell order
    n_face = len(face_points)
    centre_cells = sorted(cell_point)
    centre_id = {e: n + n_face + i for i, e in enumerate(centre_cells)}
    for e in centre_cells:
        t = cell_tets[e].copy()
        t[t == placeholder] = centre_id[e]
        cell_tets[e] = t
    tets = np.concatenate(cell_tets)
    parent = np.repeat(np.arange(m), [len(t) for t in cell_tets])
    new = [*face_points, *(cell_point[e][None] for e in centre_cells)]
    new = np.vstack(new) if new else np.zeros((0, 3))
    if return_sources:
        by_id = sorted(split, key=split.get)
        sources = [tuple(q) for q in by_id] + [tuple(np.unique(hexes[e]).tolist()) for e in centre_cells]
        return tets.astype(np.int32), parent.astype(np.int32), new, sources
    return tets.astype(np.int32), parent.astype(np.int32), new
