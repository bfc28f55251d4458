"""Skin texture coordinates (wface.mesh.uv): one-to-one, upright, unmirrored."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from wface.mesh.surface import boundary_faces
from wface.mesh.uv import boundary_loops, cylindrical_uv, skin_uv


def _flat_disk(radius: float = 0.05, rings: int = 8, hole: float = 0.0):
    """Points on concentric rings in the z = 0 plane, wound counter-clockwise about +z; triangles
    whose centroid lies within ``hole`` of (0.01, 0.005) are cut out."""
    pts = [np.zeros(2)]
    for r in range(1, rings + 1):
        k = 6 * r
        a = 2 * np.pi * np.arange(k) / k + (0.1 * r if r < rings else 0.0)  # the rim reaches +-x, +-y
        pts += list(radius * r / rings * np.stack([np.cos(a), np.sin(a)], axis=1))
    xy = np.array(pts)
    tri = Delaunay(xy).simplices
    p = xy[tri]
    ccw = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) > 0
    tri[~ccw] = tri[~ccw][:, ::-1]
    if hole:
        keep = np.linalg.norm(xy[tri].mean(axis=1) - [0.01, 0.005], axis=1) > hole
        tri = tri[keep]
    return np.column_stack([xy, np.zeros(len(xy))]), tri


def _signed_areas(uv, tri):
    p = uv[tri]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


@pytest.mark.parametrize("hole", [0.0, 0.012])
def test_a_flat_disk_maps_onto_itself(hole):
    """Mean-value coordinates reproduce linear functions, so a flat disk whose rim is a circle
    sampled evenly maps by a similarity: upright (+y up), unmirrored, into [0, 1]^2. A hole in it,
    closed by its virtual centre vertex, keeps that."""
    x, tri = _flat_disk(hole=hole)
    uv = skin_uv(x, tri)
    used = np.unique(tri)
    np.testing.assert_allclose(uv[used], 0.5 + x[used, :2] / 0.1, atol=1e-9)
    assert len(boundary_loops(tri)) == (2 if hole else 1)


def test_a_bent_face_with_holes_keeps_every_triangle_upright():
    """A cap of a sphere (a face mask: front +z, up +y), bent hard, with three holes; the
    cylindrical projection turns the triangles under the cap's rim over, the disk map none."""
    x, tri = _flat_disk(radius=1.0, rings=14)
    keep = np.ones(len(tri), dtype=bool)
    for c in ([-0.35, 0.3], [0.35, 0.3], [0.0, -0.4]):
        keep &= np.linalg.norm(x[tri].mean(axis=1)[:, :2] - c, axis=1) > 0.15
    tri = tri[keep]
    theta = 1.6 * np.linalg.norm(x[:, :2], axis=1)  # polar angle on a unit sphere, past 90 degrees
    phi = np.arctan2(x[:, 1], x[:, 0])
    bent = 0.1 * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
    uv = skin_uv(bent, tri)
    assert (_signed_areas(uv, tri) > 0).all()
    assert uv.min() >= -1e-12 and uv.max() <= 1 + 1e-12
    assert np.corrcoef(uv[:, 1], bent[:, 1])[0, 1] > 0.9 and np.corrcoef(uv[:, 0], bent[:, 0])[0, 1] > 0.9
    cyl = _signed_areas(cylindrical_uv(bent), tri)
    assert (np.sign(cyl) != np.sign(np.median(cyl))).any()


def test_a_closed_surface_falls_back_to_the_cylinder():
    """No boundary (a tet mesh's whole surface): the cylindrical projection."""
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tri = boundary_faces(np.array([[0, 1, 2, 3]]))
    np.testing.assert_array_equal(skin_uv(x, tri), cylindrical_uv(x))


def test_inconsistent_winding_has_no_loops():
    tri = np.array([[0, 1, 2], [1, 2, 3]])  # edge 1-2 used twice in the same direction
    assert boundary_loops(tri) is None


@pytest.mark.parametrize("tets", [2000, 20000])
def test_the_builtin_skin_has_no_triangle_turned_over(tets):
    from wface.faces.builtin.face import build_face

    face = build_face(tets)
    nodes, local = np.unique(face.skin_triangles, return_inverse=True)
    local = local.reshape(-1, 3)
    uv = skin_uv(face.rest_positions_m[nodes], local)
    assert (_signed_areas(uv, local) > 0).all()


def test_the_badin_skin_has_no_triangle_turned_over(badin_model):
    """The imported Badin face's skin (a sphere with six holes): the cylindrical projection turned
    199 of its 4,204 triangles over (5.1 % of the area), the disk map none."""
    nodes, local = np.unique(badin_model.skin_triangles, return_inverse=True)
    local = local.reshape(-1, 3)
    x = badin_model.rest_positions_m[nodes]
    assert len(boundary_loops(local)) == 6
    cyl = _signed_areas(cylindrical_uv(x), local)
    assert (np.sign(cyl) != np.sign(np.median(cyl))).sum() > 100
    assert (_signed_areas(skin_uv(x, local), local) > 0).all()
