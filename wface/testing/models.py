"""Small synthetic ``FaceModel``s on box meshes, for tests, benchmarks and examples of the physics.

A box of tets with an optional muscle whose fibres run along x, nodes on chosen faces attached
to the "cranium" (bone 0) or the "jaw" (bone 1).
"""

from __future__ import annotations

import numpy as np

from wface.model import FaceModel, JawJoint, Material
from wface.testing.box import box_tet_mesh

__all__ = ["box_model", "single_tet_model"]

_JAW = JawJoint(
    u=(1.0, 0.0, 0.0),
    v=(0.0, 0.0, 1.0),
    midpoint_m=(0.0, 0.0, 0.0),
    condyle_distance_m=0.1,
    track_length_m=0.01,
    max_opening_sine=0.5,
)


def box_model(
    cells: tuple[int, int, int] = (4, 2, 2),
    size_m: tuple[float, float, float] = (0.04, 0.02, 0.02),
    *,
    cranium_faces: tuple[str, ...] = ("x-",),
    jaw_faces: tuple[str, ...] = (),
    muscles: int = 1,
    fibre_fraction: float = 0.8,
    fibre_direction=(1.0, 0.0, 0.0),
    material: Material | None = None,
) -> FaceModel:
    """A box face model.

    Args:
        cells: hexahedral cells along x, y, z (6 tets each).
        size_m: box size in metres (corner at the origin).
        cranium_faces, jaw_faces: box faces whose nodes are attached: "x-", "x+", "y-", "y+", "z-", "z+".
        muscles: number of muscles; muscle k occupies the tets whose centroid lies in the k-th slab
            along y (all tets for one muscle), with the given fibre fraction and direction.
        fibre_fraction: volume fraction of the muscle in its tets.
        fibre_direction: unit fibre direction (rest space).
        material: the material (default ``Material()``).
    """
    x, tets = box_tet_mesh(cells, size_m)
    bone = np.full(len(x), -1, dtype=np.int8)
    for faces, b in ((cranium_faces, 0), (jaw_faces, 1)):
        for face in faces:
            axis = "xyz".index(face[0])
            value = 0.0 if face[1] == "-" else size_m[axis]
            bone[np.abs(x[:, axis] - value) < 1e-12 * max(size_m)] = b
    attached = np.flatnonzero(bone >= 0).astype(np.int32)
    centroid_y = x[tets].mean(axis=1)[:, 1]
    slab = np.minimum((centroid_y / size_m[1] * muscles).astype(int), muscles - 1) if muscles else None
    fibre_tet = np.arange(len(tets)) if muscles else np.zeros(0, int)
    d = np.asarray(fibre_direction, dtype=float)
    d = d / np.linalg.norm(d)
    return FaceModel(
        rest_positions_m=x,
        tets=tets,
        skin_triangles=np.zeros((0, 3), dtype=np.int32),
        muscle_names=[f"muscle_{k}" for k in range(muscles)],
        fibre_tet=fibre_tet,
        fibre_muscle=slab if muscles else np.zeros(0, int),
        fibre_fraction=np.full(fibre_tet.size, fibre_fraction),
        fibre_direction=np.tile(d, (fibre_tet.size, 1)),
        attached_nodes=attached,
        attached_bone=bone[attached],
        jaw_joint=_JAW,
        material=material or Material(),
    ).validate()


def single_tet_model(
    *, edge_m: float = 0.01, fibre_direction=(0.6, 0.8, 0.0), fibre_fraction: float = 0.7, material=None
) -> FaceModel:
    """One right-corner tet with one muscle entry and no attached nodes."""
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) * edge_m
    d = np.asarray(fibre_direction, dtype=float)
    return FaceModel(
        rest_positions_m=x,
        tets=np.array([[0, 1, 2, 3]]),
        skin_triangles=np.zeros((0, 3), dtype=np.int32),
        muscle_names=["muscle_0"],
        fibre_tet=[0],
        fibre_muscle=[0],
        fibre_fraction=[fibre_fraction],
        fibre_direction=(d / np.linalg.norm(d))[None],
        attached_nodes=np.zeros(0, np.int32),
        attached_bone=np.zeros(0, np.int8),
        jaw_joint=_JAW,
        material=material or Material(),
    ).validate()
