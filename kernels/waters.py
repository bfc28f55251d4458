"""Waters (1987) vector muscles evaluated directly on the current points (float64), one thread per vertex.

Linear muscle j (bony attachment V1, unit axis a, zone Omega, fall-start Rs, fall-finish Rf, K, e):
    D = |p - V1|, mu = angle(p - V1, a); A = cos(mu/Omega pi/2) for mu <= Omega else 0;
    R = cos((1 - D/Rs) pi/2) (D <= Rs), cos((D - Rs)/(Rf - Rs) pi/2) (Rs < D <= Rf), 0 beyond;
    b_j = K (A R)^e (V1 - p)/D.
Sphincter j (centre c, frame h, v, n, semi-axes s, tension T, e):
    rho = |((p-c).h/s0, (p-c).v/s1, (p-c).n/s2)| (s1 -> lower semi-axis where (p-c).v < 0 and it is > 0);
    R = cos(rho pi/2) (rho <= 1);
    b_j = R^e (T P_n (c - p) + K_n n) (K_n: protrusion, metres).
Region factor: 1 (any), 1 - w_jaw (upper), w_jaw (lower). Sum d = sum_j c_j b_j, then the per-vertex
limit L = min(max_displacement, overlap_factor max_j |b_j|): d <- d L/|d| where |d| > L.
Same formulas as wface.waters.muscles / wface.waters.rig (Waters 1987; docs/design.md, "Waters muscles").
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

HALF_PI = wp.constant(wp.float64(1.5707963267948966))


@wp.kernel
def waters_displacement(
    # Model:
    kind: wp.array(dtype=wp.int32),  # 0 linear, 1 sphincter
    region: wp.array(dtype=wp.int32),  # 0 any, 1 upper, 2 lower
    origin: wp.array(dtype=wp.vec3d),  # V1 (linear) or centre (sphincter)
    axis: wp.array(dtype=wp.vec3d),  # unit V1 -> V2 (linear) or horizontal (sphincter)
    vertical: wp.array(dtype=wp.vec3d),
    normal: wp.array(dtype=wp.vec3d),
    semi_axes: wp.array(dtype=wp.vec3d),
    zone_rad: wp.array(dtype=wp.float64),
    fall_start: wp.array(dtype=wp.float64),
    fall_finish: wp.array(dtype=wp.float64),
    strength: wp.array(dtype=wp.float64),  # K in metres (linear) or tension (sphincter)
    elasticity: wp.array(dtype=wp.float64),
    protrusion: wp.array(dtype=wp.float64),  # K_n in metres (sphincter), 0 (linear)
    lower_semi_axis: wp.array(dtype=wp.float64),  # vertical semi-axis below the centre (0: s1)
    max_displacement: wp.float64,
    overlap_factor: wp.float64,
    # State in:
    contraction: wp.array(dtype=wp.float64),
    points: wp.array(dtype=wp.vec3d),
    jaw_weight: wp.array(dtype=wp.float64),
    movable: wp.array(dtype=wp.int32),
    apply_limit: wp.int32,
    # Out:
    displacement_out: wp.array(dtype=wp.vec3d),
):
    i = wp.tid()
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    d = wp.vec3d(zero, zero, zero)
    strongest = zero
    if movable[i] != 0:
        p = points[i]
        w = jaw_weight[i]
        for j in range(kind.shape[0]):
            b = wp.vec3d(zero, zero, zero)
            if kind[j] == 0:
                rel = p - origin[j]
                dist = wp.length(rel)
                if dist > zero and dist <= fall_finish[j]:
                    cos_mu = wp.clamp(wp.dot(rel, axis[j]) / dist, -one, one)
                    mu = wp.acos(cos_mu)
                    if mu <= zone_rad[j]:
                        ang = wp.cos(wp.min(mu / zone_rad[j], one) * HALF_PI)
                        rs = fall_start[j]
                        rad = zero
                        if dist <= rs:
                            rad = wp.cos((one - wp.min(dist / rs, one)) * HALF_PI)
                        else:
                            rad = wp.cos(wp.clamp((dist - rs) / (fall_finish[j] - rs), zero, one) * HALF_PI)
                        f = wp.max(ang, zero) * wp.max(rad, zero)
                        if f > zero:
                            b = (strength[j] * wp.pow(f, elasticity[j]) / dist) * (origin[j] - p)
            else:
                rel = p - origin[j]
                s = semi_axes[j]
                lu = wp.dot(rel, axis[j]) / s[0]
                lv = wp.dot(rel, vertical[j])
                if lv < zero and lower_semi_axis[j] > zero:
                    lv = lv / lower_semi_axis[j]
                else:
                    lv = lv / s[1]
                lw = wp.dot(rel, normal[j]) / s[2]
                rho = wp.sqrt(lu * lu + lv * lv + lw * lw)
                if rho <= one:
                    rad = wp.max(wp.cos(rho * HALF_PI), zero)
                    toward = origin[j] - p
                    in_plane = toward - wp.dot(toward, normal[j]) * normal[j]
                    fall = wp.pow(rad, elasticity[j])
                    b = (strength[j] * fall) * in_plane + (protrusion[j] * fall) * normal[j]
            if region[j] == 1:
                b = (one - w) * b
            elif region[j] == 2:
                b = w * b
            strongest = wp.max(strongest, wp.length(b))
            d = d + contraction[j] * b
        if apply_limit != 0:
            cap = wp.min(max_displacement, overlap_factor * strongest)
            size = wp.length(d)
            if size > cap and size > zero:
                d = (cap / size) * d
    displacement_out[i] = d
