"""Waters (1987) vector muscles: linear (pulling) and sphincter (squeezing) muscles on a surface.

Linear muscle (Waters 1987; docs/design.md, "Waters muscles"). Bony attachment V1, skin insertion V2, zone of
influence half-angle Omega, fall-start Rs, fall-finish Rf, spring constant K. For a point p with
D = |p - V1| and mu = angle between p - V1 and the muscle axis V2 - V1:

    A = cos(mu / Omega * pi/2)                     for mu <= Omega, else 0   (angular factor)
    R = cos((1 - D/Rs) * pi/2)                     for 0 <= D <= Rs        (radial, rising)
    R = cos((D - Rs) / (Rf - Rs) * pi/2)           for Rs < D <= Rf        (radial, falling)
    R = 0                                          for D > Rf
    p' = p + c * K * (A R)^e * (V1 - p) / |V1 - p|

with contraction c in [0, 1]. K is a length here (metres): the pull at full contraction where
A = R = 1, the slide's "muscle spring constant" in model units. The skin elasticity e shapes the
falloff ((A R)^e; e = 1 is the slide's cosine falloff, larger e keeps the pull closer to the
point of maximum effect). Waters 1987 gives "elasticity = 1.0 and 10.0" without a formula: this
exponent is our reading of it.

Sphincter muscle: a centre, two in-plane unit axes (horizontal, vertical) with semi-axes a, b, and
a depth semi-axis c along their normal. With the elliptical radius
rho = sqrt((u/a)^2 + (v/b)^2 + (w/c)^2) of p in that frame (b -> b_low below the centre, v < 0,
when a lower semi-axis is given: an egg-shaped ring such as orbicularis oculi, whose orbital part
spreads far down over the cheek but hardly above the brow), there is no angular term:

    R = cos(rho * pi/2) for rho <= 1, else 0;   p' = p + c_t R^e (T P (centre - p) + K_n n)

with T the tension (dimensionless: the fraction of the in-plane distance to the centre removed at
full contraction), P the projection onto the sphincter plane (the ring squeezes within its
plane; it does not pull the skin into the head), n the plane's unit normal (horizontal x
vertical, out of the face) and K_n the protrusion (metres at full contraction where R = 1; 0 by
default, Waters' in-plane ring). A ring drawn tight over a convex support (the lips over the
teeth, the cheek over the zygoma) bunches the skin outward: a lip pucker is mostly this forward
push (ICT-FaceKit mouthPucker: ~8.5 mm forward, ~1.5 mm in-plane), which P alone removes.

Reference: K. Waters, "A muscle model for animating three-dimensional facial expression",
SIGGRAPH 1987.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "REGIONS",
    "LinearMuscle",
    "SphincterMuscle",
    "linear_muscle_displacement",
    "linear_muscle_factors",
    "sphincter_muscle_displacement",
    "sphincter_radius",
]

REGIONS = ("any", "upper", "lower")  # which side of the jaw line a muscle moves (see WatersRig)


def _vec3(name: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{name} must be 3 numbers, got shape {np.shape(value)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf: {a.tolist()}")
    return a


def _positive(name: str, value: float, *, allow_zero: bool = False) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'} and finite, got {value!r}")
    return v


def _points(points_m) -> np.ndarray:
    p = np.asarray(points_m, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"points contain NaN or inf ({int((~np.isfinite(p)).any(axis=1).sum())} rows)")
    return p


@dataclass
class LinearMuscle:
    """A linear (parallel) Waters muscle. Lengths in metres, angles in degrees.

    Attributes:
        name: canonical muscle name (wface.facs), e.g. ``zygomaticus_major_l``.
        bone_m: (3,) bony attachment V1.
        insertion_m: (3,) skin insertion V2.
        zone_deg: zone of influence half-angle Omega (slide: 35).
        fall_start_m: Rs, where the radial factor peaks (slide: 7.0 model units).
        fall_finish_m: Rf > Rs, where it reaches zero (slide: 14.0).
        spring_constant_m: K, pull at full contraction where A = R = 1 (slide: 0.75 model units).
        elasticity: skin elasticity exponent e (slide: 1.0 and 10.0).
        region: "any", "upper" or "lower": the side of the jaw line the muscle moves.
    """

    name: str
    bone_m: np.ndarray
    insertion_m: np.ndarray
    zone_deg: float = 35.0
    fall_start_m: float = 0.0  # 0: use |V2 - V1|
    fall_finish_m: float = 0.0  # 0: use 1.5 Rs
    spring_constant_m: float = 0.005
    elasticity: float = 1.0
    region: str = "any"
    kind: str = field(default="linear", init=False)

    def __post_init__(self) -> None:
        self.bone_m = _vec3(f"{self.name}: bone_m", self.bone_m)
        self.insertion_m = _vec3(f"{self.name}: insertion_m", self.insertion_m)
        length = float(np.linalg.norm(self.insertion_m - self.bone_m))
        if length <= 0:
            raise ValueError(f"{self.name}: bone_m and insertion_m coincide")
        if not self.fall_start_m:
            self.fall_start_m = length
        if not self.fall_finish_m:
            self.fall_finish_m = 1.5 * float(self.fall_start_m)
        self.fall_start_m = _positive(f"{self.name}: fall_start_m", self.fall_start_m)
        self.fall_finish_m = _positive(f"{self.name}: fall_finish_m", self.fall_finish_m)
        if self.fall_finish_m <= self.fall_start_m:
            raise ValueError(
                f"{self.name}: fall_finish_m ({self.fall_finish_m}) must exceed fall_start_m ({self.fall_start_m})"
            )
        z = float(self.zone_deg)
        if not (0 < z <= 180):
            raise ValueError(f"{self.name}: zone_deg must lie in (0, 180], got {self.zone_deg}")
        self.zone_deg = z
        self.spring_constant_m = _positive(f"{self.name}: spring_constant_m", self.spring_constant_m, allow_zero=True)
        self.elasticity = _positive(f"{self.name}: elasticity", self.elasticity)
        if self.region not in REGIONS:
            raise ValueError(f"{self.name}: region must be one of {REGIONS}, got {self.region!r}")

    @property
    def axis(self) -> np.ndarray:
        """(3,) unit vector from V1 to V2."""
        d = self.insertion_m - self.bone_m
        return d / np.linalg.norm(d)

    @property
    def reach_m(self) -> float:
        """Distance from V1 beyond which the muscle has no effect (Rf)."""
        return self.fall_finish_m


@dataclass
class SphincterMuscle:
    """An elliptical Waters sphincter. Lengths in metres.

    Attributes:
        name: canonical muscle name, e.g. ``orbicularis_oris_upper``.
        centre_m: (3,) centre of the ring.
        horizontal: (3,) direction of the first semi-axis (orthonormalised against nothing).
        vertical: (3,) direction of the second semi-axis (made orthogonal to ``horizontal``).
        semi_axes_m: (a, b, c): horizontal, vertical and depth semi-axes.
        tension: T, fraction of the in-plane distance to the centre removed at full contraction.
        elasticity: exponent e on the radial factor.
        region: "any", "upper" or "lower" (an upper / lower half of orbicularis oris).
        protrusion_m: K_n, push along the plane normal at full contraction where R = 1 (metres;
            negative pulls inward, 0: the classic in-plane sphincter).
        lower_semi_axis_m: b_low, the vertical semi-axis below the centre (v < 0); 0: the same as
            ``semi_axes_m[1]`` (a symmetric ellipse).
    """

    name: str
    centre_m: np.ndarray
    horizontal: np.ndarray
    vertical: np.ndarray
    semi_axes_m: np.ndarray
    tension: float = 0.3
    elasticity: float = 1.0
    region: str = "any"
    protrusion_m: float = 0.0
    lower_semi_axis_m: float = 0.0
    kind: str = field(default="sphincter", init=False)

    def __post_init__(self) -> None:
        self.centre_m = _vec3(f"{self.name}: centre_m", self.centre_m)
        h = _vec3(f"{self.name}: horizontal", self.horizontal)
        v = _vec3(f"{self.name}: vertical", self.vertical)
        if np.linalg.norm(h) == 0:
            raise ValueError(f"{self.name}: horizontal axis is zero")
        if abs(np.linalg.norm(h) - 1.0) > 1e-14:
            h = h / np.linalg.norm(h)
        if abs(v @ h) > 1e-14:
            v = v - (v @ h) * h
        if np.linalg.norm(v) < 1e-9:
            raise ValueError(f"{self.name}: vertical axis is parallel to the horizontal axis")
        if abs(np.linalg.norm(v) - 1.0) > 1e-14:
            v = v / np.linalg.norm(v)
        self.horizontal, self.vertical = h, v  # unchanged when already orthonormal (exact JSON round trip)
        s = _vec3(f"{self.name}: semi_axes_m", self.semi_axes_m)
        if np.any(s <= 0):
            raise ValueError(f"{self.name}: semi_axes_m must be > 0, got {s.tolist()}")
        self.semi_axes_m = s
        self.tension = _positive(f"{self.name}: tension", self.tension, allow_zero=True)
        if self.tension > 1:
            raise ValueError(f"{self.name}: tension must be <= 1 (a fraction of the distance), got {self.tension}")
        self.elasticity = _positive(f"{self.name}: elasticity", self.elasticity)
        if self.region not in REGIONS:
            raise ValueError(f"{self.name}: region must be one of {REGIONS}, got {self.region!r}")
        self.protrusion_m = float(self.protrusion_m)
        if not np.isfinite(self.protrusion_m):
            raise ValueError(f"{self.name}: protrusion_m must be finite, got {self.protrusion_m!r}")
        self.lower_semi_axis_m = _positive(f"{self.name}: lower_semi_axis_m", self.lower_semi_axis_m, allow_zero=True)

    @property
    def normal(self) -> np.ndarray:
        """(3,) unit normal of the sphincter plane (horizontal x vertical)."""
        return np.cross(self.horizontal, self.vertical)

    @property
    def below_m(self) -> float:
        """The vertical semi-axis below the centre (b_low, else b)."""
        return self.lower_semi_axis_m or float(self.semi_axes_m[1])

    @property
    def reach_m(self) -> float:
        """Radius of a ball about the centre outside which the muscle has no effect."""
        return float(max(self.semi_axes_m.max(), self.lower_semi_axis_m))


def linear_muscle_factors(points_m: np.ndarray, muscle: LinearMuscle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angular factor A, radial factor R and distance D for each point.

    Args:
        points_m: (n, 3) rest positions.
        muscle: the linear muscle.

    Returns:
        ``(A, R, D)``, each (n,): A and R in [0, 1] (zero outside the zone of influence and
        beyond Rf), D = |p - V1| in metres.
    """
    p = _points(points_m)
    rel = p - muscle.bone_m
    dist = np.linalg.norm(rel, axis=1)
    safe = np.where(dist > 0, dist, 1.0)
    cos_mu = np.clip(rel @ muscle.axis / safe, -1.0, 1.0)
    mu = np.where(dist > 0, np.arccos(cos_mu), 0.0)
    omega = np.radians(muscle.zone_deg)
    angular = np.where(mu <= omega, np.cos(np.minimum(mu / omega, 1.0) * np.pi / 2), 0.0)
    rs, rf = muscle.fall_start_m, muscle.fall_finish_m
    rising = np.cos((1.0 - np.minimum(dist / rs, 1.0)) * np.pi / 2)
    falling = np.cos(np.clip((dist - rs) / (rf - rs), 0.0, 1.0) * np.pi / 2)
    radial = np.where(dist <= rs, rising, np.where(dist <= rf, falling, 0.0))
    return np.maximum(angular, 0.0), np.maximum(radial, 0.0), dist


def linear_muscle_displacement(points_m: np.ndarray, muscle: LinearMuscle, contraction: float = 1.0) -> np.ndarray:
    """Displacement (n, 3) in metres of each point by one linear muscle at ``contraction`` in [0, 1].

    The pull points from p toward the bony attachment V1; its size is c K (A R)^e. At V1 itself
    (D = 0) the radial factor is zero, so the attachment never moves.
    """
    c = _contraction(muscle.name, contraction)
    angular, radial, dist = linear_muscle_factors(points_m, muscle)
    p = np.asarray(points_m, dtype=np.float64)
    toward = muscle.bone_m - p
    unit = toward / np.where(dist > 0, dist, 1.0)[:, None]
    size = c * muscle.spring_constant_m * (angular * radial) ** muscle.elasticity
    return size[:, None] * unit


def sphincter_radius(points_m: np.ndarray, muscle: SphincterMuscle) -> np.ndarray:
    """(n,) elliptical radius rho of each point in the sphincter's frame (1 on the ellipsoid)."""
    p = _points(points_m)
    rel = p - muscle.centre_m
    frame = np.stack([muscle.horizontal, muscle.vertical, muscle.normal])  # rows
    local = rel @ frame.T
    axes = np.broadcast_to(muscle.semi_axes_m, local.shape).copy()
    axes[local[:, 1] < 0, 1] = muscle.below_m
    return np.linalg.norm(local / axes, axis=1)


def sphincter_muscle_displacement(
    points_m: np.ndarray, muscle: SphincterMuscle, contraction: float = 1.0
) -> np.ndarray:
    """Displacement (n, 3) in metres by one sphincter at ``contraction`` in [0, 1].

    In-plane pull toward the centre plus the push along the normal, R^e (T P(centre - p) + K_n n),
    R = cos(rho pi/2) inside the ellipsoid.
    """
    c = _contraction(muscle.name, contraction)
    rho = sphincter_radius(points_m, muscle)
    radial = np.where(rho <= 1.0, np.cos(np.minimum(rho, 1.0) * np.pi / 2), 0.0)
    toward = muscle.centre_m - np.asarray(points_m, dtype=np.float64)
    n = muscle.normal
    in_plane = toward - np.outer(toward @ n, n)
    fall = c * np.maximum(radial, 0.0) ** muscle.elasticity
    out = (fall * muscle.tension)[:, None] * in_plane
    if muscle.protrusion_m:
        out += np.outer(fall * muscle.protrusion_m, n)
    return out


def _contraction(name: str, value: float) -> float:
    c = float(value)
    if not np.isfinite(c) or c < 0 or c > 1:
        raise ValueError(f"{name}: contraction must lie in [0, 1], got {value!r}")
    return c
