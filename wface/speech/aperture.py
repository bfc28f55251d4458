"""Lip opening area: the mouth aperture seen in an orthographic view, in mm^2.

Speech scientists measure the lip opening as the area of the aperture seen from the front. ArtiSynth's
``BadinFaceDemoLipOpening`` (artisynth_models) renders the face in red in an orthographic view with a
green square behind it (0.08 x 0.08 m at x = 0.1 m in the Badin frame, normal along x, every rigid
body hidden, so bones, teeth and the tongue occlude nothing) and counts the green pixels; the area is
pixels x (metres per pixel)^2, i.e. measured in the image plane of the orthographic camera.

Here the same quantity is computed geometrically, without a renderer:

- Camera: orthographic, unit view direction d (from the camera into the scene), image axes e1, e2
  (e2 the up vector made orthogonal to d). A point p projects to (u, v) = (p . e1, p . e2).
- Window: a planar rectangle behind the face (centre c, in-plane axes, half sizes). A window point is
  *seen* when the ray through it toward the camera meets no occluder triangle on the camera's side of
  the window plane. Occluders are triangles (for a face: every boundary triangle of the tet mesh,
  skin and inner surface; bones and teeth are not occluders); each is clipped to the camera's side of
  the window plane first (a triangle that pierces the window hides only its front part).
- The seen region is the projected window minus the union of the projected, clipped occluders. It is
  integrated over scanlines v_k = v_0 + k h: on each line the covered intervals are exact (edge
  crossings) and merged, so the seen length L(v_k) is exact; the area is the trapezoid sum
  h sum_k w_k L(v_k). L is piecewise linear in v between the heights of vertices and edge crossings,
  so the rule is second order: the discretisation error estimate is |A_h - A_2h| / 3 (Richardson,
  A_2h from every other scanline), reported as ``error_mm2``.
- Apertures: the seen intervals of adjacent scanlines that overlap are connected (union-find); a
  connected seen region that touches the window's border is seen *past the face's outline*, not
  through the mouth. ``area_mm2`` sums the regions enclosed by the occluders (the mouth aperture);
  ``window_seen_mm2`` is all the window seen (ArtiSynth's pixel count; equal to ``area_mm2`` when the
  face covers the window's border).

Known answers (``tests/test_lip_aperture.py``): the hole of a flat annulus, an elliptical slot cut
through a slab seen straight on (the slot's polygon area) and at an angle (two offset ellipses:
the lens of their intersection, the slot's walls occluding the rest).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = [
    "ARTISYNTH_VIEW_DIRECTION_BADIN",
    "ApertureResult",
    "ApertureView",
    "aperture_area",
]

# BadinFaceDemoLipOpening.attach: orthographic viewer, eye (-0.521787, 0.0009809, -0.126136), centre
# (0.134664, 0.0009809, 0.117214) in the Badin frame (x posterior, y right, z up): the camera looks
# backward and 20.3 degrees upward, at the lips from below the chin.
ARTISYNTH_VIEW_DIRECTION_BADIN = (0.134664 + 0.521787, 0.0, 0.117214 + 0.126136)
_ARTISYNTH_WINDOW_BADIN = ((0.1, 0.0, 0.1), 0.04)  # green plane: centre (m), half size (m); normal x
_BADIN_TO_WFACE = ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (-1.0, 0.0, 0.0))  # wface.faces.artisynth.BADIN_TO_WFACE
_MIN_SEEN_M = 1e-12  # seen intervals shorter than this are round-off between touching triangles
_CHUNK_PAIRS = 2_000_000  # (triangle, scanline) pairs evaluated at once (memory ~ 200 MB per chunk)


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"{what} must be a finite non-zero 3-vector, got {v}")
    return v / n


@dataclass(frozen=True)
class ApertureView:
    """An orthographic camera and the window behind the occluders (all in the model frame, metres).

    Attributes:
        direction: (3,) view direction, from the camera into the scene (normalised).
        up: (3,) the camera's up vector (made orthogonal to ``direction``).
        window_center_m: (3,) centre of the window rectangle.
        window_axes: ((3,), (3,)) in-plane axes of the window (normalised; the window normal is
            their cross product).
        window_half_m: (2,) half sizes of the window along its axes.
        name: a label for reports.
    """

    direction: tuple
    up: tuple
    window_center_m: tuple
    window_axes: tuple
    window_half_m: tuple
    name: str = "custom"

    def __post_init__(self):
        d = _unit(self.direction, "view direction")
        up = np.asarray(self.up, dtype=np.float64) - d * float(np.dot(self.up, d))
        a0, a1 = (_unit(a, "window axis") for a in self.window_axes)
        normal = np.cross(a0, a1)
        if abs(float(np.dot(normal, d))) < 1e-6:
            raise ValueError("the window plane is parallel to the view direction: it projects to a line")
        half = np.asarray(self.window_half_m, dtype=np.float64).reshape(2)
        if not np.all(np.isfinite(half) & (half > 0)):
            raise ValueError(f"window half sizes must be finite and > 0 m, got {half}")
        centre = np.asarray(self.window_center_m, dtype=np.float64).reshape(3)
        up = _unit(up, "up vector (orthogonal to the view direction)")
        as_tuple = lambda v: tuple(float(c) for c in v)  # noqa: E731
        object.__setattr__(self, "direction", as_tuple(d))
        object.__setattr__(self, "up", as_tuple(up))
        object.__setattr__(self, "window_axes", (as_tuple(a0), as_tuple(a1)))
        object.__setattr__(self, "window_half_m", as_tuple(half))
        object.__setattr__(self, "window_center_m", as_tuple(centre))

    @property
    def image_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """(e1, e2): image right (d x up) and up, unit, orthogonal to the view direction d, so that
        (e1, e2, -d) is right-handed: the image is the one the camera sees, not its mirror."""
        d, e2 = np.asarray(self.direction), np.asarray(self.up)
        return np.cross(d, e2), e2

    def window_corners_m(self) -> np.ndarray:
        """(4, 3) corners of the window rectangle, in order around it."""
        c = np.asarray(self.window_center_m)
        (a0, a1), (h0, h1) = (np.asarray(a) for a in self.window_axes), self.window_half_m
        return np.array([c + s0 * h0 * a0 + s1 * h1 * a1 for s0, s1 in ((-1, -1), (1, -1), (1, 1), (-1, 1))])

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "direction": list(self.direction),
            "up": list(self.up),
            "window_center_m": list(self.window_center_m),
            "window_axes": [list(a) for a in self.window_axes],
            "window_half_m": list(self.window_half_m),
        }

    @classmethod
    def artisynth_badin(cls, *, frontal: bool = False, rotation=_BADIN_TO_WFACE, translation_m=(0.0, 0.0, 0.0)):
        """ArtiSynth's lip-opening measure for the Badin face in the model's frame: the green 0.08 m
        square at Badin x = 0.1 m centred on (y, z) = (0, 0.1) m, normal along Badin x, seen along
        ``ARTISYNTH_VIEW_DIRECTION_BADIN`` (20.3 degrees upward) with Badin z up, or straight back
        along Badin +x with ``frontal=True``. ``rotation`` and ``translation_m`` map Badin to model
        coordinates (p_model = R p + t); the defaults are ``wface.faces.artisynth``'s (X = -y, Y = z,
        Z = -x, no translation), which the import also records in ``metadata["frame"]``."""
        R = np.asarray(rotation, dtype=np.float64)
        t = np.asarray(translation_m, dtype=np.float64)
        d = R @ (np.array([1.0, 0.0, 0.0]) if frontal else np.asarray(ARTISYNTH_VIEW_DIRECTION_BADIN))
        centre, half = _ARTISYNTH_WINDOW_BADIN
        return cls(
            direction=tuple(d),
            up=tuple(R @ np.array([0.0, 0.0, 1.0])),
            window_center_m=tuple(R @ np.asarray(centre) + t),
            window_axes=(tuple(R @ np.array([0.0, 1.0, 0.0])), tuple(R @ np.array([0.0, 0.0, 1.0]))),
            window_half_m=(half, half),
            name="artisynth_frontal" if frontal else "artisynth",
        )

    @classmethod
    def for_model(cls, model, *, frontal: bool = False) -> ApertureView:
        """The view for ``model``: ArtiSynth's (``artisynth_badin``, in the frame the import recorded)
        for an imported Badin face; else a frontal view (along -Z, the model's forward axis) onto a
        window 20 mm behind the lip surfaces (``surface_groups`` upper_lip / lower_lip, else the
        skin), three times their width and height."""
        frame = (model.metadata or {}).get("frame", {})
        if "rotation_source_to_model" in frame and "badinface" in str((model.metadata or {}).get("mesh_files", "")):
            return cls.artisynth_badin(
                frontal=frontal,
                rotation=frame["rotation_source_to_model"],
                translation_m=frame.get("translation_m", (0.0, 0.0, 0.0)),
            )
        groups = [g for g in ("upper_lip", "lower_lip") if g in model.surface_groups]
        tri = np.concatenate([model.surface_groups[g] for g in groups]) if groups else model.skin_triangles
        p = model.rest_positions_m[np.unique(tri)]
        lo, hi = p.min(axis=0), p.max(axis=0)
        centre = 0.5 * (lo + hi)
        centre[2] = lo[2] - 0.02
        return cls(
            direction=(0.0, 0.0, -1.0),
            up=(0.0, 1.0, 0.0),
            window_center_m=tuple(centre),
            window_axes=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
            window_half_m=(1.5 * (hi[0] - lo[0]) + 1e-3, 1.5 * (hi[1] - lo[1]) + 1e-3),
            name="frontal",
        )


@dataclass
class ApertureResult:
    """The seen part of the window (areas in mm^2 in the camera's image plane, lengths in mm).

    Attributes:
        area_mm2: area of the apertures enclosed by the occluders (the mouth opening).
        window_seen_mm2: all of the window that is seen (ArtiSynth's green-pixel area).
        elsewhere_mm2: enclosed apertures away from ``near_points_m`` (not counted in ``area_mm2``).
        error_mm2: discretisation error estimate of ``area_mm2``, |A_h - A_2h| / 3.
        regions: number of enclosed apertures.
        width_mm, height_mm: extent of the enclosed apertures along the image axes (0 when closed).
        resolution_m: scanline spacing h.
        scanlines: number of scanlines.
        intervals: with ``keep_intervals``: the seen intervals, {"v_m", "u_lo_m", "u_hi_m" (image
            coordinates, m), "enclosed" (bool)}; else None.
    """

    area_mm2: float
    window_seen_mm2: float
    elsewhere_mm2: float
    error_mm2: float
    regions: int
    width_mm: float
    height_mm: float
    resolution_m: float
    scanlines: int
    intervals: dict | None = None

    def to_dict(self) -> dict:
        """The scalars, JSON-ready."""
        return {
            k: (float(v) if isinstance(v, float | np.floating) else int(v))
            for k, v in self.__dict__.items()
            if k != "intervals"
        }


def _clip_to_front(p: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Triangles (t, 3, 3) clipped to sigma > 0 (sigma: (t, 3) signed distances of their corners to
    the window plane, positive on the camera's side): (t', 3, 3) triangles."""
    pos = sigma > 0
    count = pos.sum(axis=1)
    out = [p[count == 3]]
    for k in (1, 2):
        sel = count == k
        if not sel.any():
            continue
        q, s = p[sel], sigma[sel]
        # rotate corners so that the odd one out (the lone positive for k = 1, the lone non-positive
        # for k = 2) comes first, keeping the winding
        odd = np.argmax(pos[sel] if k == 1 else ~pos[sel], axis=1)
        idx = (odd[:, None] + np.arange(3)[None]) % 3
        q = np.take_along_axis(q, idx[:, :, None], axis=1)
        s = np.take_along_axis(s, idx, axis=1)

        def cut(i, j, q=q, s=s, k=k):
            # always from the positive end, so that two triangles sharing the edge cut it bitwise alike
            if k == 2:
                i, j = j, i
            t = s[:, i] / (s[:, i] - s[:, j])
            return q[:, i] + t[:, None] * (q[:, j] - q[:, i])

        c01, c02 = cut(0, 1), cut(0, 2)
        if k == 1:
            out.append(np.stack([q[:, 0], c01, c02], axis=1))
        else:  # quad c01, q1, q2, c02
            out.append(np.stack([c01, q[:, 1], q[:, 2]], axis=1))
            out.append(np.stack([c01, q[:, 2], c02], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 3, 3))


def _row_intervals(uv: np.ndarray, v_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intervals cut by each scanline from each convex polygon of projected corners ``uv`` (t, c, 2):
    (polygon index, row index, lo, hi) for every (polygon, row) with a crossing."""
    vmin, vmax = uv[:, :, 1].min(axis=1), uv[:, :, 1].max(axis=1)
    first = np.searchsorted(v_rows, vmin, side="left")
    last = np.searchsorted(v_rows, vmax, side="right")
    n_rows = np.maximum(last - first, 0)
    keep = n_rows > 0
    poly_ids = np.flatnonzero(keep)
    rows_out, lo_out, hi_out, poly_out = [], [], [], []
    counts = n_rows[keep]
    starts = np.concatenate([[0], np.cumsum(counts)])
    # chunks of polygons with at most _CHUNK_PAIRS (polygon, row) pairs
    b = 0
    while b < len(poly_ids):
        e = int(np.searchsorted(starts, starts[b] + _CHUNK_PAIRS, side="right")) - 1
        e = max(e, b + 1)
        ids, cnt = poly_ids[b:e], counts[b:e]
        owner = np.repeat(np.arange(len(ids)), cnt)
        row = first[ids][owner] + (np.arange(cnt.sum()) - np.repeat(starts[b:e] - starts[b], cnt))
        v = v_rows[row]
        corners = uv[ids][owner]  # (P, c, 2)
        a, c = corners, np.roll(corners, -1, axis=1)
        # each edge from its lower (v, u) end, so that the two polygons sharing an edge cross it at
        # bitwise the same u (no round-off slits between neighbours)
        swap = (c[:, :, 1] < a[:, :, 1]) | ((c[:, :, 1] == a[:, :, 1]) & (c[:, :, 0] < a[:, :, 0]))
        a, c = np.where(swap[..., None], c, a), np.where(swap[..., None], a, c)
        va, vb = a[:, :, 1], c[:, :, 1]
        lo_v, hi_v = np.minimum(va, vb), np.maximum(va, vb)
        cross = (lo_v <= v[:, None]) & (v[:, None] <= hi_v) & (hi_v > lo_v)
        t = (v[:, None] - va) / np.where(hi_v > lo_v, vb - va, 1.0)
        u = a[:, :, 0] + t * (c[:, :, 0] - a[:, :, 0])
        lo = np.where(cross, u, np.inf).min(axis=1)
        hi = np.where(cross, u, -np.inf).max(axis=1)
        ok = lo <= hi
        rows_out.append(row[ok])
        lo_out.append(lo[ok])
        hi_out.append(hi[ok])
        poly_out.append(ids[owner[ok]])
        b = e
    if not rows_out:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0)
    return np.concatenate(poly_out), np.concatenate(rows_out), np.concatenate(lo_out), np.concatenate(hi_out)


def _seen_intervals(rows, lo, hi, win_lo, win_hi, n_rows):
    """Per row, the parts of the window interval [win_lo, win_hi] not covered by the intervals
    (rows, lo, hi): (row, lo, hi) of every seen interval, sorted by row then lo."""
    lo = np.maximum(lo, win_lo[rows])
    hi = np.minimum(hi, win_hi[rows])
    ok = hi > lo
    rows, lo, hi = rows[ok], lo[ok], hi[ok]
    span = float(np.nanmax(win_hi - win_lo, initial=0.0)) + 1.0
    base = np.nanmin(win_lo, initial=0.0)
    off = rows * 3.0 * span  # rows never mix after this shift
    order = np.lexsort((lo, rows))
    rows, lo_s, hi_s = rows[order], lo[order] - base + off[order], hi[order] - base + off[order]
    run = np.maximum.accumulate(hi_s) if len(hi_s) else hi_s
    prev = np.concatenate([[-np.inf], run[:-1]])
    new = lo_s > prev  # a merged covered interval starts here
    starts = np.flatnonzero(new)
    ends = np.concatenate([starts[1:] - 1, [len(lo_s) - 1]]) if len(starts) else starts
    m_row = rows[starts]
    m_lo = lo_s[starts] - off[order][starts] + base
    m_hi = run[ends] - off[order][starts] + base
    # gaps: window start .. first merged, between merged, last merged .. window end
    out_r, out_lo, out_hi = [], [], []
    first_of_row = np.ones(len(m_row), bool)
    first_of_row[1:] = m_row[1:] != m_row[:-1]
    last_of_row = np.ones(len(m_row), bool)
    last_of_row[:-1] = m_row[1:] != m_row[:-1]
    out_r.append(m_row[first_of_row])
    out_lo.append(win_lo[m_row[first_of_row]])
    out_hi.append(m_lo[first_of_row])
    inner = ~last_of_row
    out_r.append(m_row[inner])
    out_lo.append(m_hi[inner])
    out_hi.append(m_lo[np.flatnonzero(inner) + 1])
    out_r.append(m_row[last_of_row])
    out_lo.append(m_hi[last_of_row])
    out_hi.append(win_hi[m_row[last_of_row]])
    empty = np.setdiff1d(np.flatnonzero(np.isfinite(win_lo) & (win_hi > win_lo)), m_row)
    out_r.append(empty)
    out_lo.append(win_lo[empty])
    out_hi.append(win_hi[empty])
    r, a, b = (np.concatenate(x) for x in (out_r, out_lo, out_hi))
    ok = b - a > _MIN_SEEN_M
    r, a, b = r[ok], a[ok], b[ok]
    order = np.lexsort((a, r))
    return r[order], a[order], b[order]


def _components(rows, lo, hi, n_rows) -> tuple[int, np.ndarray]:
    """Connected seen regions: intervals of adjacent rows that overlap share a label."""
    k = len(rows)
    if k == 0:
        return 0, np.zeros(0, int)
    span = float(np.max(hi) - np.min(lo)) + 1.0
    base = float(np.min(lo))
    off = rows * 3.0 * span
    glo, ghi = lo - base + off, hi - base + off  # globally sorted (rows ascending, lo ascending)
    # row-k intervals overlapping [lo', hi') of an interval on row k + 1: a contiguous run
    q_off = (rows - 1) * 3.0 * span
    qlo, qhi = lo - base + q_off, hi - base + q_off
    first = np.searchsorted(ghi, qlo, side="right")
    last = np.searchsorted(glo, qhi, side="left")
    has_prev = rows > 0
    n = np.where(has_prev, np.maximum(last - first, 0), 0)
    src = np.repeat(np.arange(k), n)
    dst = np.repeat(first, n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
    good = rows[dst] == rows[src] - 1 if len(dst) else np.zeros(0, bool)
    src, dst = src[good], dst[good]
    graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(k, k))
    return connected_components(graph, directed=False)


def _window_rows(view: ApertureView, e1, e2, h: float):
    """Scanline heights and the window's interval on each (the projected rectangle is convex)."""
    corners = view.window_corners_m()
    uv = np.stack([corners @ e1, corners @ e2], axis=1)[None]  # (1, 4, 2)
    v0, v1 = uv[0, :, 1].min(), uv[0, :, 1].max()
    n = int(np.ceil((v1 - v0) / h - 1e-9)) + 1  # rows span the window exactly, spacing <= h
    v_rows = np.linspace(v0, v1, n)
    _, r, lo, hi = _row_intervals(uv, v_rows)
    win_lo, win_hi = np.full(n, np.nan), np.full(n, np.nan)
    win_lo[r], win_hi[r] = lo, hi
    return v_rows, win_lo, win_hi


def aperture_area(
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    view: ApertureView,
    *,
    resolution_m: float = 5e-5,
    near_points_m: np.ndarray | None = None,
    keep_intervals: bool = False,
) -> ApertureResult:
    """Area of the apertures through which the window behind ``triangles`` is seen (module docstring).

    Args:
        vertices_m: (n, 3) positions, metres.
        triangles: (t, 3) occluder triangles (vertex ids); winding does not matter.
        view: the camera and the window (``ApertureView``).
        resolution_m: scanline spacing h (m); the error estimate is reported with the result
            (Badin face, 0.05 mm: about 0.01 mm^2 on a 40 mm^2 aperture).
        near_points_m: (k, 3) points (e.g. the lip surfaces' vertices): only enclosed apertures that
            meet the image-plane bounding box of their projections count (on the Badin face, seen
            straight from the front, the open nostrils are apertures too); None: all of them.
        keep_intervals: also return the seen intervals (for pictures).

    Returns:
        ``ApertureResult`` (areas in mm^2 in the image plane of the orthographic camera).
    """
    x = np.asarray(vertices_m, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    h = float(resolution_m)
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"resolution_m must be finite and > 0, got {resolution_m}")
    if x.ndim != 2 or x.shape[1] != 3 or not np.all(np.isfinite(x)):
        raise ValueError(f"vertices_m must be a finite (n, 3) array, got shape {x.shape}")
    if t.size and (t.min() < 0 or t.max() >= len(x)):
        raise ValueError(f"triangle vertex ids must lie in [0, {len(x)})")
    d = np.asarray(view.direction)
    e1, e2 = view.image_axes
    a0, a1 = (np.asarray(a) for a in view.window_axes)
    n_w = np.cross(a0, a1)
    n_w = -n_w if float(n_w @ d) > 0 else n_w  # toward the camera
    c = np.asarray(view.window_center_m)
    p = x[t]
    tri = _clip_to_front(p, (p - c) @ n_w)
    v_rows, win_lo, win_hi = _window_rows(view, e1, e2, h)
    h = float(v_rows[1] - v_rows[0]) if len(v_rows) > 1 else h
    if (h_rows := len(v_rows)) > 2_000_000:
        raise ValueError(f"resolution_m = {h:g} m gives {h_rows} scanlines; use a coarser resolution")
    uv = np.stack([tri @ e1, tri @ e2], axis=2)  # (t', 3, 2)
    _, rows, lo, hi = _row_intervals(uv, v_rows)
    r, slo, shi = _seen_intervals(rows, lo, hi, win_lo, win_hi, len(v_rows))
    n_comp, label = _components(r, slo, shi, len(v_rows))
    length = shi - slo
    weight = np.where((r == 0) | (r == len(v_rows) - 1), 0.5, 1.0)  # trapezoid rule
    # a region touching the window's border is seen past the outline of the occluders
    eps = 1e-9 * max(1.0, float(np.nanmax(np.abs(win_hi), initial=1.0)))
    border = (r == 0) | (r == len(v_rows) - 1) | (slo <= win_lo[r] + eps) | (shi >= win_hi[r] - eps)
    open_comp = np.zeros(n_comp, bool)
    open_comp[label[border]] = True
    enclosed = ~open_comp[label] if n_comp else np.zeros(0, bool)
    inside = enclosed
    if near_points_m is not None and n_comp:
        q = np.asarray(near_points_m, dtype=np.float64).reshape(-1, 3)
        bu, bv = q @ e1, q @ e2
        v_r = v_rows[r]
        meets = (v_r >= bv.min()) & (v_r <= bv.max()) & (shi > bu.min()) & (slo < bu.max())
        near = np.zeros(n_comp, bool)
        near[label[meets]] = True
        inside = enclosed & near[label]
    area = h * float(np.sum(weight * length * inside))
    seen = h * float(np.sum(weight * length))
    elsewhere = h * float(np.sum(weight * length * (enclosed & ~inside)))
    coarse = (r % 2 == 0) & inside
    w2 = np.where((r == 0) | (r == 2 * ((len(v_rows) - 1) // 2)), 0.5, 1.0)
    area_2h = 2 * h * float(np.sum(w2[coarse] * length[coarse]))
    if inside.any():
        u_lo, u_hi = float(slo[inside].min()), float(shi[inside].max())
        v_in = v_rows[r[inside]]
        width, height = u_hi - u_lo, float(v_in.max() - v_in.min()) + h
    else:
        width = height = 0.0
    return ApertureResult(
        area_mm2=area * 1e6,
        window_seen_mm2=seen * 1e6,
        elsewhere_mm2=elsewhere * 1e6,
        error_mm2=abs(area - area_2h) / 3.0 * 1e6,
        regions=int(np.unique(label[inside]).size) if inside.any() else 0,
        width_mm=width * 1e3,
        height_mm=height * 1e3,
        resolution_m=h,
        scanlines=len(v_rows),
        intervals={"v_m": v_rows[r], "u_lo_m": slo, "u_hi_m": shi, "enclosed": inside, "elsewhere": enclosed & ~inside}
        if keep_intervals
        else None,
    )
