"""Local improvement of tetrahedral meshes: raise the smallest dihedral angle (remove slivers).

A greedy pass over the tets whose smallest dihedral angle is below a goal, worst first, tries the
operations of Klingner & Shewchuk (2007, "Aggressive tetrahedral mesh improvement", 16th IMR) and
keeps one only when it raises the smallest dihedral angle of the tets it replaces:

- edge removal (Shewchuk 2002, "Two discrete optimization algorithms for the topological
  improvement of tetrahedral meshes"): the k tets around an interior edge ab become the 2(k - 2)
  tets of the best triangulation of the ring polygon around ab (dynamic programming over the
  ring, maximising the smallest angle); k = 3 is the 3-2 flip;
- the 2-3 flip: two tets sharing an interior face become three around the edge through their
  apexes;
- vertex smoothing: a free node moves to where the smallest dihedral angle of its star is largest
  (a compass search, Freitag & Ollivier-Gooch 1997 style objective);
- edge split: a node is inserted on an edge (every tet around the edge is cut in two) and then
  smoothed, freely when the edge is interior, along the edge when it is on the boundary.

Boundary nodes and ``locked`` nodes never move, and boundary edges are only split at points of the
edge, so the meshed domain is unchanged. The result is conforming and positively oriented.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from wface.mesh.quality import tet_volume_ratio

__all__ = ["OPERATIONS", "ImproveReport", "improve_tets", "tet_min_dihedral_deg", "tet_sine_quality_deg"]

_PAIRS = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))  # faces opposite vertex i and j share an edge
_TET_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
_COMPASS = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
    + [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
    dtype=np.float64,
)
_COMPASS /= np.linalg.norm(_COMPASS, axis=1, keepdims=True)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    out[..., 0] = u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1]
    out[..., 1] = u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2]
    out[..., 2] = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    return out


def _dihedral_score(p: np.ndarray, sine: bool) -> np.ndarray:
    p0, p1, p2, p3 = p[..., 0, :], p[..., 1, :], p[..., 2, :], p[..., 3, :]
    normals = (  # outward normals of the faces opposite vertices 0..3 of a positive tet
        _cross(p2 - p1, p3 - p1),
        _cross(p3 - p0, p2 - p0),
        _cross(p1 - p0, p3 - p0),
        _cross(p2 - p0, p1 - p0),
    )
    lengths = [np.sqrt(np.einsum("...k,...k->...", nv, nv)) for nv in normals]
    cos_max = np.full(p.shape[:-2], -1.0 if not sine else 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        for i, j in _PAIRS:
            c = -np.einsum("...k,...k->...", normals[i], normals[j]) / (lengths[i] * lengths[j])
            c = np.where(np.isnan(c), 1.0, c)
            cos_max = np.fmax(cos_max, np.abs(c) if sine else c)
    angle = np.degrees(np.arccos(np.clip(cos_max, -1.0, 1.0)))
    vol6 = -np.einsum("...k,...k->...", p3 - p0, normals[3])
    return np.where((vol6 > 0) & (angle > 1e-6), angle, -1.0)


def tet_min_dihedral_deg(p: np.ndarray) -> np.ndarray:
    """Smallest interior dihedral angle (degrees) of tets given by corners p (..., 4, 3).

    Inverted and flat tets (no positive volume, or an angle below 1e-6 deg) score -1.
    """
    return _dihedral_score(p, sine=False)


def tet_sine_quality_deg(p: np.ndarray) -> np.ndarray:
    """The smallest of theta and 180 deg - theta over the six dihedral angles theta, in degrees
    (arcsin of the smallest dihedral sine; Klingner & Shewchuk's objective): small for slivers,
    caps and wedges alike, 70.5 deg for the regular tet. Inverted and flat tets score -1."""
    return _dihedral_score(p, sine=True)


def _parity(perm: list[int]) -> int:
    inversions = sum(1 for i in range(4) for j in range(i + 1, 4) if perm[i] > perm[j])
    return inversions % 2


@dataclass
class ImproveReport:
    """What ``improve_tets`` did."""

    min_dihedral_before_deg: float
    min_dihedral_after_deg: float
    below_goal_before: int
    below_goal_after: int
    goal_deg: float
    objective: str
    quality_before_deg: float
    quality_after_deg: float
    rounds: int
    operations: dict = field(default_factory=dict)
    added_nodes: int = 0
    moved_nodes: int = 0
    seconds: float = 0.0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class _Mesh:
    """A mutable tet mesh with node -> tet incidence, for local operations."""

    def __init__(self, x: np.ndarray, tets: np.ndarray, movable: np.ndarray, score):
        self.score = score  # (..., 4, 3) corners -> (...,) quality in degrees, -1 for flat or inverted
        self.x = np.array(x, dtype=np.float64)
        self.n_orig = len(x)
        self.tets: list[tuple[int, ...] | None] = [tuple(int(v) for v in t) for t in tets]
        self.node_tets: list[set[int]] = [set() for _ in range(len(x))]
        for ti, t in enumerate(self.tets):
            for v in t:
                self.node_tets[v].add(ti)
        self.movable = list(bool(m) for m in movable)
        self.boundary = np.zeros(len(x), dtype=bool)
        self._mark_boundary()
        self.sources: list[tuple[int, int]] = []  # per added node: the edge it split
        self.moved: set[int] = set()
        self.quality: dict[int, float] = {}
        self.clock = 0  # counts edits; node_clock[v]: the edit that last changed a tet at v
        self.node_clock: dict[int, int] = {}

    # ---------------------------------------------------------------- topology
    def _mark_boundary(self) -> None:
        faces: dict[tuple[int, ...], int] = {}
        for t in self.tets:
            if t is None:
                continue
            for f in ((t[1], t[2], t[3]), (t[0], t[2], t[3]), (t[0], t[1], t[3]), (t[0], t[1], t[2])):
                key = tuple(sorted(f))
                faces[key] = faces.get(key, 0) + 1
        for key, count in faces.items():
            if count == 1:
                self.boundary[list(key)] = True

    def q(self, ti: int) -> float:
        if ti not in self.quality:
            self.quality[ti] = float(self.score(self.x[list(self.tets[ti])][None])[0])
        return self.quality[ti]

    def fill_quality(self) -> None:
        todo = [ti for ti, t in enumerate(self.tets) if t is not None and ti not in self.quality]
        if todo:
            qs = self.score(self.x[np.array([self.tets[ti] for ti in todo])])
            self.quality.update(zip(todo, qs.tolist(), strict=True))

    def edge_tets(self, a: int, b: int) -> set[int]:
        return self.node_tets[a] & self.node_tets[b]

    def has_edge(self, a: int, b: int) -> bool:
        return bool(self.edge_tets(a, b))

    def face_tets(self, a: int, b: int, c: int) -> set[int]:
        return self.node_tets[a] & self.node_tets[b] & self.node_tets[c]

    def is_boundary_edge(self, a: int, b: int) -> bool:
        ring = self.ring(a, b)
        return ring is None or not ring[1]

    def ring(self, a: int, b: int) -> tuple[list[int], bool] | None:
        """Vertices around edge ab ordered so that every tet (a, b, v_i, v_i+1) is positive; closed?"""
        nxt: dict[int, int] = {}
        for ti in self.edge_tets(a, b):
            t = self.tets[ti]
            c, d = (v for v in t if v != a and v != b)
            if _parity([t.index(v) for v in (a, b, c, d)]):
                c, d = d, c
            if c in nxt:
                return None  # not a manifold edge
            nxt[c] = d
        if not nxt:
            return None
        starts = set(nxt) - set(nxt.values())
        if len(starts) > 1:
            return None
        start = next(iter(starts)) if starts else next(iter(nxt))
        order = [start]
        while order[-1] in nxt and len(order) <= len(nxt):
            nv = nxt[order[-1]]
            if nv == start:
                break
            order.append(nv)
        closed = not starts
        if len(order) != len(nxt) + (0 if closed else 1):
            return None
        return order, closed

    # ---------------------------------------------------------------- edits
    def touch(self, nodes) -> None:
        self.clock += 1
        for v in nodes:
            self.node_clock[int(v)] = self.clock

    def changed_since(self, ti: int, clock: int) -> bool:
        return any(self.node_clock.get(v, 0) > clock for v in self.tets[ti])

    def replace(self, old: list[int], new: list[tuple[int, ...]]) -> list[int]:
        self.touch({v for ti in old for v in self.tets[ti]} | {v for t in new for v in t})
        for ti in old:
            for v in self.tets[ti]:
                self.node_tets[v].discard(ti)
            self.tets[ti] = None
            self.quality.pop(ti, None)
        ids = []
        for t in new:
            ti = len(self.tets)
            self.tets.append(tuple(int(v) for v in t))
            for v in t:
                self.node_tets[v].add(ti)
            ids.append(ti)
        return ids

    def add_node(self, p: np.ndarray, movable: bool, boundary: bool, source: tuple[int, int]) -> int:
        i = len(self.x)
        self.x = np.vstack([self.x, p[None]])
        self.node_tets.append(set())
        self.movable.append(movable)
        self.boundary = np.append(self.boundary, boundary)
        self.sources.append(source)
        return i

    def set_position(self, v: int, p: np.ndarray) -> None:
        self.touch({u for ti in self.node_tets[v] for u in self.tets[ti]})
        self.x[v] = p
        self.moved.add(v)
        for ti in self.node_tets[v]:
            self.quality.pop(ti, None)


def _star_quality(corners: np.ndarray, slot: np.ndarray, points: np.ndarray, score) -> np.ndarray:
    """Smallest angle over a star with its centre at each of points (c, 3): (c,)."""
    p = np.broadcast_to(corners, (len(points), *corners.shape)).copy()
    k = np.arange(corners.shape[0])
    p[:, k, slot, :] = points[:, None, :]
    return score(p).min(axis=1)


def _compass_search(
    corners: np.ndarray,
    slot: np.ndarray,
    start: np.ndarray,
    step: float,
    directions: np.ndarray,
    score,
    iters: int = 40,
) -> tuple[np.ndarray, float]:
    best_p = start.copy()
    best = float(_star_quality(corners, slot, best_p[None], score)[0])
    h = step
    for _ in range(iters):
        trial = best_p[None] + h * directions
        qs = _star_quality(corners, slot, trial, score)
        j = int(np.argmax(qs))
        if qs[j] > best + 1e-9:
            best, best_p = float(qs[j]), trial[j]
            h *= 1.5
        else:
            h *= 0.5
            if h < 1e-2 * step:
                break
    return best_p, best


#: the local operations, in the order they are tried on a tet
OPERATIONS = ("edge_removal", "flip23", "smooth", "split")


class _Improver:
    def __init__(self, mesh: _Mesh, operations: tuple[str, ...] = OPERATIONS):
        self.m = mesh
        self.enabled = frozenset(operations)
        self.ops = dict.fromkeys(OPERATIONS, 0)

    def quality_of(self, tets: list[tuple[int, ...]]) -> float:
        if not tets:
            return np.inf
        return float(self.m.score(self.m.x[np.array(tets)]).min())

    # ---------------------------------------------------------------- edge removal
    def try_edge_removal(self, a: int, b: int) -> bool:
        m = self.m
        ring = m.ring(a, b)
        if ring is None or not ring[1] or len(ring[0]) < 3 or len(ring[0]) > 10:
            return False
        v, k = ring[0], len(ring[0])
        old = list(m.edge_tets(a, b))
        old_q = min(m.q(t) for t in old)
        triples = [(i, j, l) for i in range(k) for j in range(i + 1, k) for l in range(j + 1, k)]
        cand = []
        for i, j, l in triples:
            cand.append((a, v[i], v[j], v[l]))
            cand.append((b, v[i], v[l], v[j]))
        qs = m.score(m.x[np.array(cand)]).reshape(-1, 2).min(axis=1)
        tri_q = {t: float(q) for t, q in zip(triples, qs, strict=True)}
        best: dict[tuple[int, int], tuple[float, int]] = {}
        for span in range(2, k):
            for i in range(0, k - span):
                j = i + span
                opt = (-np.inf, -1)
                for l in range(i + 1, j):
                    val = min(
                        tri_q[(i, l, j)],
                        best[(i, l)][0] if l - i > 1 else np.inf,
                        best[(l, j)][0] if j - l > 1 else np.inf,
                    )
                    if val > opt[0]:
                        opt = (val, l)
                best[(i, j)] = opt
        q_new = best[(0, k - 1)][0]
        if q_new <= old_q + 1e-6:
            return False
        new: list[tuple[int, ...]] = []
        diagonals = []

        def collect(i: int, j: int) -> None:
            if j - i < 2:
                return
            l = best[(i, j)][1]
            new.append((a, v[i], v[l], v[j]))
            new.append((b, v[i], v[j], v[l]))
            for p, r in ((i, l), (l, j)):
                if r - p > 1:
                    diagonals.append((v[p], v[r]))
            collect(i, l)
            collect(l, j)

        collect(0, k - 1)
        if any(m.has_edge(p, r) for p, r in diagonals):
            return False
        m.replace(old, new)
        self.ops["edge_removal"] += 1
        return True

    # ---------------------------------------------------------------- 2-3 flip
    def try_flip23(self, face: tuple[int, int, int]) -> bool:
        m = self.m
        both = m.face_tets(*face)
        if len(both) != 2:
            return False
        t1, t2 = both
        u = next(v for v in m.tets[t1] if v not in face)
        w = next(v for v in m.tets[t2] if v not in face)
        if m.has_edge(u, w):
            return False
        old_q = min(m.q(t1), m.q(t2))
        p, q_, r = face
        for ring in ((p, q_, r), (p, r, q_)):
            new = [(u, w, ring[i], ring[(i + 1) % 3]) for i in range(3)]
            q_new = self.quality_of(new)
            if q_new > old_q + 1e-6:
                m.replace([t1, t2], new)
                self.ops["flip23"] += 1
                return True
        return False

    # ---------------------------------------------------------------- smoothing
    def _star(self, v: int) -> tuple[list[int], np.ndarray, np.ndarray]:
        m = self.m
        star = list(m.node_tets[v])
        tets = np.array([m.tets[t] for t in star])
        return star, m.x[tets], np.argmax(tets == v, axis=1)

    def try_smooth(self, v: int) -> bool:
        m = self.m
        if not m.movable[v] or m.boundary[v]:
            return False
        star, corners, slot = self._star(v)
        old_q = min(m.q(t) for t in star)
        others = np.unique(np.array([m.tets[t] for t in star]))
        step = 0.1 * float(np.mean(np.linalg.norm(m.x[others] - m.x[v], axis=1)))
        starts = [m.x[v], m.x[others[others != v]].mean(axis=0)]
        best_p, best_q = None, old_q
        for s in starts:
            p, qv = _compass_search(corners, slot, s, step, _COMPASS, m.score)
            if qv > best_q + 1e-6:
                best_p, best_q = p, qv
        if best_p is None:
            return False
        m.set_position(v, best_p)
        self.ops["smooth"] += 1
        return True

    # ---------------------------------------------------------------- edge split
    def try_split(self, a: int, b: int) -> bool:
        m = self.m
        old = list(m.edge_tets(a, b))
        if not old:
            return False
        old_q = min(m.q(t) for t in old)
        boundary = m.is_boundary_edge(a, b)
        new = []
        for ti in old:
            t = m.tets[ti]
            new.append(tuple(-1 if v == a else v for v in t))
            new.append(tuple(-1 if v == b else v for v in t))
        tets = np.array(new)
        slot = np.argmax(tets == -1, axis=1)
        corners = m.x[np.maximum(tets, 0)]
        pa, pb = m.x[a], m.x[b]
        length = float(np.linalg.norm(pb - pa))
        if boundary:
            s = np.linspace(0.2, 0.8, 13)
            pts = pa[None] + s[:, None] * (pb - pa)[None]
            qs = _star_quality(corners, slot, pts, m.score)
            j = int(np.argmax(qs))
            best_p, best_q = pts[j], float(qs[j])
        else:
            best_p, best_q = _compass_search(corners, slot, 0.5 * (pa + pb), 0.1 * length, _COMPASS, m.score)
        if best_q <= old_q + 1e-6:
            return False
        c = m.add_node(best_p, movable=not boundary, boundary=boundary, source=(a, b))
        m.replace(old, [tuple(c if v == -1 else v for v in t) for t in new])
        self.ops["split"] += 1
        return True

    # ---------------------------------------------------------------- driver
    def improve_tet(self, ti: int) -> bool:
        m = self.m
        t = m.tets[ti]
        on = self.enabled
        edges = sorted(((t[i], t[j]) for i, j in _TET_EDGES), key=lambda e: -np.linalg.norm(m.x[e[0]] - m.x[e[1]]))
        if "edge_removal" in on and any(self.try_edge_removal(a, b) for a, b in edges):
            return True
        faces = ((t[1], t[2], t[3]), (t[0], t[2], t[3]), (t[0], t[1], t[3]), (t[0], t[1], t[2]))
        if "flip23" in on and any(self.try_flip23(f) for f in faces):
            return True
        if "smooth" in on and any(self.try_smooth(v) for v in t):
            return True
        return "split" in on and any(self.try_split(a, b) for a, b in edges)


def _with_volume_ratio(angle_score, goal_deg: float, volume_ratio_goal: float | None):
    """The objective: ``angle_score`` alone, or the smaller of it and goal_deg q / volume_ratio_goal."""
    if volume_ratio_goal is None:
        return angle_score
    if not volume_ratio_goal > 0:
        raise ValueError(f"volume_ratio_goal must be positive, got {volume_ratio_goal!r}")
    scale = goal_deg / volume_ratio_goal

    def score(p: np.ndarray) -> np.ndarray:
        a = angle_score(p)
        return np.where(a > 0, np.minimum(a, scale * tet_volume_ratio(p)), -1.0)

    return score


def improve_tets(
    x: np.ndarray,
    tets: np.ndarray,
    *,
    goal_deg: float = 8.0,
    locked: np.ndarray | None = None,
    max_rounds: int = 12,
    objective: str = "sine",
    volume_ratio_goal: float | None = None,
    operations: tuple[str, ...] = OPERATIONS,
    stall_rounds: int | None = None,
) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]], ImproveReport]:
    """Improve the dihedral angles of a positively oriented tet mesh by local operations.

    Args:
        x: (n, 3) node positions.
        tets: (m, 4) positively oriented tets.
        goal_deg: tets whose quality (degrees, see ``objective``) is below this are worked on.
        locked: (n,) bool, nodes that must not move (boundary nodes never move anyway).
        max_rounds: passes over the tets still below the goal.
        objective: "sine" (default): keep every dihedral angle within [goal, 180 - goal]
            (``tet_sine_quality_deg``: removes slivers without making caps); "min": only raise the
            smallest dihedral angle (``tet_min_dihedral_deg``).
        volume_ratio_goal: with it, a tet is also worked on when its volume ratio q (``wface.mesh.
            quality.tet_volume_ratio``) is below this goal: the objective becomes the smaller of the
            angle and goal_deg q / volume_ratio_goal (degrees; q is Klingner & Shewchuk's
            volume-length measure), so raising the worst angle cannot sink the worst volume ratio
            below the same fraction of its goal, and the other way round.
        operations: the local operations allowed (``OPERATIONS``). ``("smooth",)`` moves free
            interior nodes only: the tets, their order and every node id stay as they are.
        stall_rounds: stop once this many rounds in a row have not raised the worst tet (None: go on
            while any operation succeeds, up to ``max_rounds``). Local moves can trade tets near the
            goal against each other for many rounds after the worst one has stopped rising.

    Returns:
        (x (n', 3) with added nodes appended (moved interior nodes keep their ids), tets (m', 4)
        int32, sources: per added node the two node ids of the edge it was inserted on (a boundary
        edge keeps the node on the segment), ImproveReport).
    """
    start = time.perf_counter()
    x = np.asarray(x, dtype=np.float64)
    tets = np.asarray(tets)
    if x.ndim != 2 or x.shape[1] != 3 or tets.ndim != 2 or tets.shape[1] != 4:
        raise ValueError(f"expected x (n, 3) and tets (m, 4), got {x.shape} and {tets.shape}")
    locked = np.zeros(len(x), dtype=bool) if locked is None else np.asarray(locked, dtype=bool)
    if locked.shape != (len(x),):
        raise ValueError(f"locked must have shape ({len(x)},), got {locked.shape}")
    scores = {"sine": tet_sine_quality_deg, "min": tet_min_dihedral_deg}
    if objective not in scores:
        raise ValueError(f"objective must be one of {sorted(scores)}, got {objective!r}")
    unknown = set(operations) - set(OPERATIONS)
    if unknown or not operations:
        raise ValueError(f"operations must be a non-empty subset of {OPERATIONS}, got {tuple(operations)!r}")
    score = _with_volume_ratio(scores[objective], goal_deg, volume_ratio_goal)
    q0 = score(x[tets])
    if np.any(q0 < 0):
        raise ValueError(f"{int(np.sum(q0 < 0))} tets are flat or inverted (e.g. tet {int(np.argmin(q0))})")
    mesh = _Mesh(x, tets, ~locked, score)
    work = _Improver(mesh, tuple(operations))
    rounds = 0
    failed: dict[int, int] = {}  # tet -> mesh.clock when no operation improved it
    worst_so_far, stalled = -np.inf, 0
    for rounds in range(1, max_rounds + 1):
        mesh.fill_quality()
        bad = [ti for ti, t in enumerate(mesh.tets) if t is not None and mesh.q(ti) < goal_deg]
        if not bad:
            rounds -= 1
            break
        bad.sort(key=mesh.q)
        if stall_rounds is not None:  # the worst tet is the first of the round
            stalled = stalled + 1 if mesh.q(bad[0]) <= worst_so_far + 1e-6 else 0
            worst_so_far = max(worst_so_far, mesh.q(bad[0]))
            if stalled >= stall_rounds:
                rounds -= 1
                break
        changed = 0
        for ti in bad:
            if mesh.tets[ti] is None or mesh.q(ti) >= goal_deg:
                continue
            if ti in failed and not mesh.changed_since(ti, failed[ti]):
                continue  # nothing around it changed since every operation failed on it
            if work.improve_tet(ti):
                changed += 1
            else:
                failed[ti] = mesh.clock
        if changed == 0:
            break
    out = np.array([t for t in mesh.tets if t is not None], dtype=np.int32)
    q1 = score(mesh.x[out])
    report = ImproveReport(
        min_dihedral_before_deg=float(tet_min_dihedral_deg(x[tets]).min()),
        min_dihedral_after_deg=float(tet_min_dihedral_deg(mesh.x[out]).min()),
        below_goal_before=int(np.sum(q0 < goal_deg)),
        below_goal_after=int(np.sum(q1 < goal_deg)),
        goal_deg=float(goal_deg),
        objective=objective,
        quality_before_deg=float(q0.min()),
        quality_after_deg=float(q1.min()),
        rounds=rounds,
        operations=dict(work.ops),
        added_nodes=len(mesh.sources),
        moved_nodes=len([v for v in mesh.moved if v < mesh.n_orig]),
        seconds=time.perf_counter() - start,
    )
    return mesh.x, out, list(mesh.sources), report
