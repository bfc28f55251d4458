"""The inside of the mouth in pictures: what an open mouth shows instead of the background.

The faces have no oral cavity (no tongue, palate or throat), so the skin alone, drawn over a white
background, showed white through an open mouth. ``wface.viz.render`` draws, in ``INSIDE_RGB``, the
flesh's boundary that is not skin (``inner_surface``: the lips' and cheeks' inner faces, the faces on
the bones) and a quad behind the teeth (``throat_quad``), with the teeth themselves.
"""

from __future__ import annotations

import numpy as np

from wface.mesh.surface import boundary_faces

__all__ = ["INSIDE_RGB", "inner_surface", "throat_quad"]

INSIDE_RGB = (0.30, 0.10, 0.10)


def inner_surface(pv, model, polydata) -> tuple[object, np.ndarray] | None:
    """(PolyData, its model node ids) of the flesh's boundary that is not skin, or None when the skin is
    the whole boundary. ``polydata(pv, points, triangles)`` builds the mesh."""
    faces = boundary_faces(model.tets)
    skin = {tuple(t) for t in np.sort(np.asarray(model.skin_triangles), axis=1).tolist()}
    inner = faces[[tuple(t) not in skin for t in np.sort(faces, axis=1).tolist()]]
    if not len(inner):
        return None
    nodes, local = np.unique(inner, return_inverse=True)
    return polydata(pv, model.rest_positions_m[nodes], local.reshape(-1, 3)), nodes


def throat_quad(pv, model) -> tuple[object, np.ndarray, tuple[str, ...]] | None:
    """(PolyData, rest corners (4, 3), the bone of each corner) of a backdrop behind the teeth, or None
    without upper and lower teeth: a quad at the back of the teeth, 0.8 of their breadth, whose top
    corners ride on the cranium (the upper teeth's top) and bottom corners on the jaw (the lower
    teeth's bottom), so it stretches as the jaw opens. Wider, it pokes through a narrow chin."""
    meshes = model.bone_meshes
    upper = [m.vertices_m for n, m in meshes.items() if "teeth" in n and m.bone == "cranium"]
    lower = [m.vertices_m for n, m in meshes.items() if "teeth" in n and m.bone == "jaw"]
    if not upper or not lower:
        return None
    up, low = np.concatenate(upper), np.concatenate(lower)
    both = np.concatenate([up, low])
    lo, hi = both.min(axis=0), both.max(axis=0)
    mid, half = (lo[0] + hi[0]) / 2, 0.4 * (hi[0] - lo[0])
    top, bottom = up[:, 1].max(), low[:, 1].min()
    corners = np.array([[mid - half, top, lo[2]], [mid + half, top, lo[2]], [mid + half, bottom, lo[2]],
                        [mid - half, bottom, lo[2]]])  # fmt: skip
    return pv.PolyData(corners.copy(), faces=np.array([4, 0, 1, 2, 3])), corners, ("cranium", "cranium", "jaw", "jaw")
