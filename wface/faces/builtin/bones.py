"""Bone surfaces of the built-in face: cranium (with the maxilla), mandible and teeth proxies.

All are lofts of the analytic bone surface (``FaceShape.bone``), closed into shells by an inner
offset, so they render as solids and serve as contact surfaces.
"""

from __future__ import annotations

import numpy as np

from wface.faces.builtin.shape import THETA_MAX, Y_BOTTOM, Y_MOUTH, Y_TOP, FaceShape
from wface.model import BoneMesh

__all__ = ["bone_meshes"]


def _grid_triangles(nu: int, nv: int, *, wrap_u: bool = False) -> np.ndarray:
    """Triangles of an nu x nv vertex grid (row-major u, v)."""
    iu = np.arange(nu if wrap_u else nu - 1)
    iv = np.arange(nv - 1)
    U, V = np.meshgrid(iu, iv, indexing="ij")
    a = U * nv + V
    b = ((U + 1) % nu) * nv + V
    c = b + 1
    d = a + 1
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])


def _shell(shape: FaceShape, theta: np.ndarray, y: np.ndarray, depth_m: float, *, wrap_u=False) -> tuple:
    """Closed shell between the bone surface and an inward offset over a (theta, y) grid."""
    T, Y = np.meshgrid(theta, y, indexing="ij")
    outer = shape.bone(T, Y)
    inner = outer - depth_m * shape.bone_normal(T, Y)
    nu, nv = T.shape
    tri = _grid_triangles(nu, nv, wrap_u=wrap_u)
    # Outer faces point outward with this winding if d_y x d_theta is outward: flip to match.
    outer_tri = tri[:, ::-1]
    inner_tri = tri + nu * nv
    verts = np.concatenate([outer.reshape(-1, 3), inner.reshape(-1, 3)])
    faces = [outer_tri, inner_tri]
    # Stitch the open borders: rims along v at u = 0 / u = end, and along u at v = 0 / v = end.
    off = nu * nv
    rims = []
    if not wrap_u:
        rims += [np.arange(nv), (nu - 1) * nv + np.arange(nv)[::-1]]
    rims += [np.arange(nu)[::-1] * nv, np.arange(nu) * nv + nv - 1]
    for rim in rims:
        a, b = rim[:-1], rim[1:]
        faces.append(np.stack([a, b, b + off], -1))
        faces.append(np.stack([a, b + off, a + off], -1))
    return verts, np.concatenate(faces).astype(np.int32)


def bone_meshes(shape: FaceShape, *, resolution: int = 48) -> dict[str, BoneMesh]:
    """Cranium, jaw and teeth meshes at a modest fixed resolution (they are rigid, not simulated)."""
    r = resolution
    out: dict[str, BoneMesh] = {}
    # Cranium: all around the head, from the upper gum line to the top of the forehead patch, plus a dome.
    theta = np.linspace(-np.pi, np.pi, 2 * r, endpoint=False)
    y_cr = np.concatenate(
        [np.linspace(Y_MOUTH + 0.012, Y_TOP, r), Y_TOP + 0.045 * np.sin(np.linspace(0, np.pi / 2, 12)[1:])]
    )
    T, Y = np.meshgrid(theta, y_cr, indexing="ij")
    pts = shape.bone(T, np.minimum(Y, Y_TOP))
    dome = Y > Y_TOP
    scale = np.sqrt(np.clip(1 - ((Y - Y_TOP) / 0.0451) ** 2, 0.02, 1))
    pts[..., 0] = np.where(dome, pts[..., 0] * scale, pts[..., 0])
    pts[..., 2] = np.where(dome, shape.z_centre_m + (pts[..., 2] - shape.z_centre_m) * scale, pts[..., 2])
    pts[..., 1] = Y
    nu, nv = T.shape
    tri = _grid_triangles(nu, nv, wrap_u=True)[:, ::-1]
    top = nu * nv
    verts = np.concatenate([pts.reshape(-1, 3), [[0.0, Y_TOP + 0.045, shape.z_centre_m]]])
    cap = np.stack([np.arange(nu) * nv + nv - 1, ((np.arange(nu) + 1) % nu) * nv + nv - 1, np.full(nu, top)], -1)
    out["cranium"] = BoneMesh(verts, np.concatenate([tri, cap[:, [1, 0, 2]]]).astype(np.int32), "cranium")

    # Mandible: front and sides below the lower gum line, the ramus up to the condyles at the sides.
    theta_j = np.linspace(-THETA_MAX + 0.05, THETA_MAX - 0.05, 2 * r)
    s = np.linspace(0.0, 1.0, r // 2)
    T, S = np.meshgrid(theta_j, s, indexing="ij")
    y_top = Y_MOUTH - 0.012 + (-0.022 - (Y_MOUTH - 0.012)) / (1 + np.exp(-(np.abs(T) - 1.25) / 0.05))
    Yj = Y_BOTTOM + 0.004 + S * (y_top - Y_BOTTOM - 0.004)
    outer = shape.bone(T, Yj)
    inner = outer - 0.009 * shape.bone_normal(T, Yj)
    nu, nv = T.shape
    tri = _grid_triangles(nu, nv)[:, ::-1]
    verts = np.concatenate([outer.reshape(-1, 3), inner.reshape(-1, 3)])
    faces = [tri, tri[:, ::-1] + nu * nv]
    off = nu * nv
    for rim in (
        np.arange(nv),
        (nu - 1) * nv + np.arange(nv)[::-1],
        np.arange(nu)[::-1] * nv,
        np.arange(nu) * nv + nv - 1,
    ):
        a, b = rim[:-1], rim[1:]
        faces += [np.stack([a, b, b + off], -1), np.stack([a, b + off, a + off], -1)]
    out["jaw"] = BoneMesh(verts, np.concatenate(faces).astype(np.int32), "jaw")

    # Teeth proxies: arches just inside the lips, upper on the cranium, lower on the jaw.
    th = np.linspace(-0.55, 0.55, r)
    for name, (y0, y1), bone in (
        ("upper_teeth", (Y_MOUTH + 0.0008, Y_MOUTH + 0.011), "cranium"),
        ("lower_teeth", (Y_MOUTH - 0.011, Y_MOUTH - 0.0008), "jaw"),
    ):
        v, f = _shell(shape, th, np.linspace(y0, y1, 6), 0.008)
        v = v - 0.0004 * np.array([0, 0, 1.0])  # sit a hair behind the lips' inner surface
        out[name] = BoneMesh(v, f, bone)
    return out
