"""AnimFace-named markers on the ArtiSynth Badin skin, placed from anatomy (``wface.faces.artisynth``)."""

from __future__ import annotations

import numpy as np

from wface.mesh.closest import SurfaceQuery

__all__ = ["default_markers"]


def _ray_hits(origin: np.ndarray, direction: np.ndarray, v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Ray parameters s >= 0 where origin + s direction crosses triangles (Moller-Trumbore); sorted."""
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    e1, e2 = b - a, c - a
    pvec = np.cross(direction, e2)
    det = e1 @ pvec if e1.ndim == 1 else np.einsum("ij,ij->i", e1, pvec)
    ok = np.abs(det) > 1e-18
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = origin - a
    u = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    w = (qvec @ direction) * inv
    s = np.einsum("ij,ij->i", e2, qvec) * inv
    hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (s >= 0)
    return np.sort(s[hit])


def _front_point(v: np.ndarray, t: np.ndarray, x: float, y: float) -> np.ndarray | None:
    """Outermost skin crossing of the ray from (x, y, -1 m) along +Z (wface frame), or None."""
    origin = np.array([x, y, -1.0])
    s = _ray_hits(origin, np.array([0.0, 0.0, 1.0]), v, t)
    return None if s.size == 0 else origin + s[-1] * np.array([0.0, 0.0, 1.0])


def _polyline_midpoint(p: np.ndarray) -> np.ndarray:
    """The point halfway along a polyline (by arc length)."""
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    half = s[-1] / 2
    i = min(int(np.searchsorted(s, half, side="right")) - 1, len(seg) - 1)
    return p[i] + (half - s[i]) / max(seg[i], 1e-300) * (p[i + 1] - p[i])


def default_markers(
    x: np.ndarray, skin: np.ndarray, fibres_l: dict[str, list[np.ndarray]]
) -> tuple[list[str], np.ndarray, dict[str, str]]:
    """AnimFace-named markers that the Badin skin covers, placed from anatomy (wface frame)."""
    names: list[str] = []
    pos: list[np.ndarray] = []
    how: dict[str, str] = {}
    used = np.unique(skin)
    tip = used[np.argmax(x[used, 2])]
    names.append("NoseHead")
    pos.append(x[tip])
    how["NoseHead"] = "most anterior skin node (pronasale)"
    oom = fibres_l.get("OOM", [])
    if len(oom) >= 2:
        upper_mid, corner, lower_mid = oom[0][0], oom[0][-1], oom[1][-1]
        q = SurfaceQuery(x, skin)
        hit = q.closest(np.array([corner, corner * [-1.0, 1.0, 1.0]]))
        names += ["Mouth_Lend", "Mouth_Rend"]
        pos += [hit.point_m[0], hit.point_m[1]]
        how["Mouth_Lend"] = how["Mouth_Rend"] = "skin point closest to the OOM upper/lower fibre junction (modiolus)"
        for name, p in (("Mouth_Up", upper_mid), ("Mouth_Down", lower_mid)):
            fp = _front_point(x, skin, 0.0, p[1])
            if fp is not None:
                names.append(name)
                pos.append(fp)
                how[name] = "midline skin point in front of the OOM midline fibre point"
        for name, fibre in (("Mouth_UpL", oom[0]), ("Mouth_DownL", oom[1])):
            p = _polyline_midpoint(fibre)
            for nm, px in ((name, p[0]), (name[:-1] + "R", -p[0])):
                fp = _front_point(x, skin, px, p[1])
                if fp is not None:
                    names.append(nm)
                    pos.append(fp)
                    how[nm] = "skin point in front of the middle of the OOM upper/lower fibre"
        if "Mouth_Down" in names:
            y_down = pos[names.index("Mouth_Down")][1]
            best = None
            for y in np.arange(y_down - 0.045, y_down - 0.008, 0.0005):
                fp = _front_point(x, skin, 0.0, y)
                if fp is not None and (best is None or fp[2] > best[2]):
                    best = fp
            if best is not None:
                names.append("Chin")
                pos.append(best)
                how["Chin"] = "most anterior midline skin point 8-45 mm below Mouth_Down (pogonion)"
    return names, np.array(pos).reshape(-1, 3), how
