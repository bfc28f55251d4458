"""Exact closest points on a triangle mesh (float64), one thread per query point.

Broad phase in Warp's float32 BVH, exact answer in float64:
  1. ``mesh_query_point_no_sign`` gives a near-closest face f0; its exact distance d0 bounds the answer;
  2. every face whose float32 bounding box meets the box p +- (d0 + pad) is tested exactly. A face
     closer than d0 has a point inside the ball of radius d0, so inside that box; ``pad`` covers
     the float32 rounding of the vertices (``pad_m``) and of the box (``pad_relative`` of the point's
     coordinates; host code: ``wface.mesh.closest``).
The point-triangle test is Ericson's region classification (Real-Time Collision Detection, 5.1.5),
the same arithmetic as ``wface.mesh.closest.closest_point_on_triangles``. Ties go to the lower
face index.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.func
def _ratio(num: wp.float64, den: wp.float64) -> wp.float64:
    tiny = wp.float64(1e-300)
    if wp.abs(den) <= tiny:
        return num / tiny
    return num / den


@wp.func
def closest_weights(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d) -> wp.vec3d:
    """Barycentric weights of the point of triangle (a, b, c) closest to p."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    if d1 <= zero and d2 <= zero:  # vertex a
        return wp.vec3d(one, zero, zero)
    if d3 >= zero and d4 <= d3:  # vertex b
        return wp.vec3d(zero, one, zero)
    if vc <= zero and d1 >= zero and d3 <= zero:  # edge ab
        v = _ratio(d1, d1 - d3)
        return wp.vec3d(one - v, v, zero)
    if d6 >= zero and d5 <= d6:  # vertex c
        return wp.vec3d(zero, zero, one)
    if vb <= zero and d2 >= zero and d6 <= zero:  # edge ac
        w = _ratio(d2, d2 - d6)
        return wp.vec3d(one - w, zero, w)
    if va <= zero and (d4 - d3) >= zero and (d5 - d6) >= zero:  # edge bc
        w = _ratio(d4 - d3, (d4 - d3) + (d5 - d6))
        return wp.vec3d(zero, one - w, w)
    den = va + vb + vc  # interior
    v = _ratio(vb, den)
    w = _ratio(vc, den)
    return wp.vec3d(one - v - w, v, w)


@wp.func
def _face_distance(
    p: wp.vec3d, vertices: wp.array(dtype=wp.vec3d), triangles: wp.array2d(dtype=wp.int32), face: int
) -> wp.float64:
    a = vertices[triangles[face, 0]]
    b = vertices[triangles[face, 1]]
    c = vertices[triangles[face, 2]]
    w = closest_weights(p, a, b, c)
    return wp.length(w[0] * a + w[1] * b + w[2] * c - p)


@wp.kernel
def closest_on_mesh(
    # Surface:
    mesh: wp.uint64,
    vertices: wp.array(dtype=wp.vec3d),
    triangles: wp.array2d(dtype=wp.int32),
    pad_m: wp.float64,
    pad_relative: wp.float64,
    # Query:
    points: wp.array(dtype=wp.vec3d),
    # Out:
    face_out: wp.array(dtype=wp.int32),
    weights_out: wp.array(dtype=wp.vec3d),
    distance_out: wp.array(dtype=wp.float64),
):
    i = wp.tid()
    p = points[i]
    guess = wp.mesh_query_point_no_sign(mesh, wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2])), 1.0e30)
    best = int(0)
    if guess.result:
        best = guess.face
    best_d = _face_distance(p, vertices, triangles, best)
    reach = wp.max(wp.abs(p[0]), wp.max(wp.abs(p[1]), wp.abs(p[2])))
    r = best_d + pad_m + pad_relative * (reach + best_d)  # the box's own float32 rounding
    lo = wp.vec3(wp.float32(p[0] - r), wp.float32(p[1] - r), wp.float32(p[2] - r))
    hi = wp.vec3(wp.float32(p[0] + r), wp.float32(p[1] + r), wp.float32(p[2] + r))
    query = wp.mesh_query_aabb(mesh, lo, hi)
    face = int(0)
    while wp.mesh_query_aabb_next(query, face):
        d = _face_distance(p, vertices, triangles, face)
        if d < best_d or (d == best_d and face < best):
            best_d = d
            best = face
    face_out[i] = best
    weights_out[i] = closest_weights(
        p, vertices[triangles[best, 0]], vertices[triangles[best, 1]], vertices[triangles[best, 2]]
    )
    distance_out[i] = best_d
