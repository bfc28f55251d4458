"""Tetrahedron geometry kernels: signed volumes (float64).

V = det([x1 - x0, x2 - x0, x3 - x0]) / 6, positive for a positively oriented tet.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def tet_signed_volume(
    # State in:
    positions: wp.array(dtype=wp.vec3d),
    tets: wp.array2d(dtype=wp.int32),
    # Out:
    volume_out: wp.array(dtype=wp.float64),
):
    t = wp.tid()
    x0 = positions[tets[t, 0]]
    e1 = positions[tets[t, 1]] - x0
    e2 = positions[tets[t, 2]] - x0
    e3 = positions[tets[t, 3]] - x0
    volume_out[t] = wp.dot(e1, wp.cross(e2, e3)) / wp.float64(6.0)
