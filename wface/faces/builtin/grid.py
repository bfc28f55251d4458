"""Structured hexahedral grid over the (theta, y, w) parameter box, split into tetrahedra.

Each hex is split into six tets along its main diagonal (Kuhn / Freudenthal subdivision), which is
conforming across shared faces. Hexes with theta < 0 use the mirrored split, so the mesh is
mirror-symmetric about the midsagittal plane (the midline is a grid line, and faces there are
split identically from both sides). The mouth is a cut along the grid line y = Y_MOUTH between
the mouth corners: nodes on the cut are duplicated so upper and lower lips can separate.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import permutations

import numpy as np

__all__ = ["ParamGrid", "graded_axis", "build_grid"]

_PERMS = list(permutations(range(3)))


def graded_axis(breaks: list[float], n_total: int, density) -> np.ndarray:
    """Grid coordinates through every breakpoint, spacing inversely proportional to ``density(s)``.

    Args:
        breaks: increasing breakpoints that must be grid lines.
        n_total: total number of cells (at least one per segment).
        density: callable, relative node density (> 0) as a function of the coordinate.
    """
    breaks = np.asarray(breaks, dtype=float)
    fine = [np.linspace(breaks[i], breaks[i + 1], 400) for i in range(len(breaks) - 1)]
    mass = np.array([np.trapezoid(density(s), s) for s in fine])
    counts = np.maximum(1, np.round(n_total * mass / mass.sum()).astype(int))
    coords = [breaks[:1]]
    for s, n in zip(fine, counts, strict=True):
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (density(s[1:]) + density(s[:-1])) * np.diff(s))])
        targets = np.linspace(0.0, cum[-1], n + 1)[1:]
        coords.append(np.interp(targets, cum, s))
    out = np.concatenate(coords)
    for b in breaks:  # snap exactly onto breakpoints
        out[np.argmin(np.abs(out - b))] = b
    return out


@dataclass
class ParamGrid:
    """Tet mesh of the parameter box, with the parameters of every node."""

    theta: np.ndarray  # (n,) node azimuth
    y: np.ndarray  # (n,) node height
    w: np.ndarray  # (n,) node depth fraction
    tets: np.ndarray  # (m, 4) int32 (orientation not yet fixed: the map to 3D decides)
    index: np.ndarray  # (ni, nj, nk) node id of grid point (i, j, k) (the upper-lip copy on the cut)
    duplicated_from: np.ndarray  # (d,) original node of each lower-lip duplicate (ids n0, n0+1, ...)
    lip_copy: dict[tuple[int, int], int]  # (i, k) -> node id of the lower-lip duplicate on the cut
    j_mouth: int
    tet_cell: np.ndarray  # (m, 3) grid cell (i, j, k) of each tet


def build_grid(
    theta_axis: np.ndarray, y_axis: np.ndarray, n_layers: int, theta_mouth: float, y_mouth: float
) -> ParamGrid:
    """Kuhn-split tet grid of the box with a duplicated cut at y = y_mouth, |theta| < theta_mouth."""
    ni, nj, nk = len(theta_axis), len(y_axis), n_layers + 1
    w_axis = np.linspace(0.0, 1.0, nk)
    index = np.arange(ni * nj * nk).reshape(ni, nj, nk)
    T, Y, W = np.meshgrid(theta_axis, y_axis, w_axis, indexing="ij")
    theta, y, w = T.ravel(), Y.ravel(), W.ravel()

    j_mouth = int(np.argmin(np.abs(y_axis - y_mouth)))
    cut_i = np.flatnonzero(np.abs(theta_axis) < theta_mouth - 1e-12)
    lip_copy: dict[tuple[int, int], int] = {}
    extra = []
    next_id = ni * nj * nk
    for i in cut_i:
        for k in range(nk):
            lip_copy[(int(i), k)] = next_id
            extra.append(index[i, j_mouth, k])
            next_id += 1
    extra = np.asarray(extra, dtype=np.int64)
    theta = np.concatenate([theta, theta[extra]])
    y = np.concatenate([y, y[extra]])
    w = np.concatenate([w, w[extra]])

    # Corner node ids of every cell, (ci, cj, ck, 2, 2, 2).
    ci, cj, ck = ni - 1, nj - 1, nk - 1
    corners = np.empty((ci, cj, ck, 2, 2, 2), dtype=np.int64)
    for a in (0, 1):
        for b in (0, 1):
            for c in (0, 1):
                corners[:, :, :, a, b, c] = index[a : a + ci, b : b + cj, c : c + ck]
    # Cells just below the cut use the lower-lip copies on their top face.
    jb = j_mouth - 1
    for (i, k), node in lip_copy.items():
        for a in (0, 1):
            for c in (0, 1):
                ii, kk = i - a, k - c
                if 0 <= ii < ci and 0 <= kk < ck:
                    corners[ii, jb, kk, a, 1, c] = node
    # Mirror the split for theta < 0 so the mesh is symmetric about the midline.
    cell_theta = 0.5 * (theta_axis[:-1] + theta_axis[1:])
    mirror = cell_theta < 0
    corners[mirror] = corners[mirror][:, :, :, ::-1, :, :]

    tets = []
    for p in _PERMS:
        v = np.zeros(3, dtype=int)
        verts = [tuple(v)]
        for axis in p:
            v[axis] = 1
            verts.append(tuple(v))
        tets.append(np.stack([corners[:, :, :, a, b, c] for a, b, c in verts], axis=-1))
    tets = np.stack(tets, axis=3).reshape(-1, 4)
    cell = np.stack(np.meshgrid(np.arange(ci), np.arange(cj), np.arange(ck), indexing="ij"), axis=-1)
    tet_cell = np.repeat(cell.reshape(-1, 3), len(_PERMS), axis=0)
    return ParamGrid(theta, y, w, tets.astype(np.int32), index, extra, lip_copy, j_mouth, tet_cell)
