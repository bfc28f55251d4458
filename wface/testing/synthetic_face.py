"""A small synthetic face for pictures, USD scenes and tests of io/viz (no real anatomy).

``synthetic_face`` builds a valid ``FaceModel``: a thick spherical cap (a "face" looking down +z,
+y up, metres) cut into positively oriented tets, its outer surface as skin, three fake muscles
(left and right "zygomatic" pulling the mouth corners up and out, a "frontalis" lifting the
brow), inner nodes attached to the cranium and (lower part) the jaw, bone meshes, markers.
``synthetic_take`` animates it: activations over time, a jaw opening and a small head turn,
with captured markers = simulated + noise and a missing marker. The motion is a hand-made
displacement field, not physics: it exists to exercise writers and renderers.
"""

from __future__ import annotations

import numpy as np

from wface.io.usd import BlendShapeBasis
from wface.model import BoneMesh, FaceModel, JawJoint

__all__ = ["synthetic_face", "synthetic_take", "muscle_displacement_fields", "rotation_about"]

_R_IN, _R_OUT = 0.075, 0.09  # cap radii (m)
_THETA, _PHI = 0.95, 0.85  # half-angles in azimuth (x) and elevation (y), radians


def _cap_point(th, ph, r):
    return np.stack([r * np.cos(ph) * np.sin(th), r * np.sin(ph), r * np.cos(ph) * np.cos(th) - _R_OUT], axis=-1)


def synthetic_face(*, nx: int = 12, ny: int = 12, nz: int = 2):
    """A thick spherical-cap face with three muscles, bones and markers.

    Args:
        nx, ny: cells across (azimuth) and up (elevation); nz: cells through the thickness.

    Returns:
        A validated ``wface.model.FaceModel`` (about 6 nx ny nz tets).
    """

    if min(nx, ny, nz) < 1:
        raise ValueError(f"nx, ny, nz must be >= 1, got {nx, ny, nz}")
    th = np.linspace(-_THETA, _THETA, nx + 1)
    ph = np.linspace(-_PHI, _PHI, ny + 1)
    rr = np.linspace(_R_IN, _R_OUT, nz + 1)
    T, P, R = np.meshgrid(th, ph, rr, indexing="ij")
    x = _cap_point(T, P, R).reshape(-1, 3)

    def nid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    tets = _kuhn_tets(x, nx, ny, nz, nid)
    skin = _cap_surface(x, nx, ny, nz, +1.0, nid)
    muscles = _fake_muscles(x, tets)
    fibre_tet, fibre_muscle, fibre_fraction, fibre_direction = _fibre_entries(muscles)

    inner = np.array([nid(i, j, 0) for i in range(nx + 1) for j in range(ny + 1)])
    inner_ph = np.array([ph[j] for i in range(nx + 1) for j in range(ny + 1)])
    jaw = inner_ph < -0.3
    attached_nodes = inner.astype(np.int32)
    attached_bone = jaw.astype(np.int8)
    bone_meshes = _bone_meshes(x, _cap_surface(x, nx, ny, 0, -1.0, nid), inner[jaw])

    skin_nodes = np.unique(skin)
    rng = np.random.default_rng(7)
    marker_nodes = np.sort(rng.choice(skin_nodes, size=min(16, skin_nodes.size), replace=False))
    model = FaceModel(
        rest_positions_m=x,
        tets=tets.astype(np.int32),
        skin_triangles=skin.astype(np.int32),
        muscle_names=list(muscles),
        fibre_tet=fibre_tet,
        fibre_muscle=fibre_muscle,
        fibre_fraction=fibre_fraction,
        fibre_direction=fibre_direction,
        attached_nodes=attached_nodes,
        attached_bone=attached_bone,
        jaw_joint=JawJoint(
            u=(1.0, 0.0, 0.0),
            v=(0.0, 0.0, 1.0),
            midpoint_m=(0.0, -0.01, -0.07),
            condyle_distance_m=0.1,
            track_length_m=0.01,
            max_opening_sine=0.5,
        ),
        bone_meshes=bone_meshes,
        marker_names=[f"M{i:02d}" for i in range(marker_nodes.size)],
        marker_positions_m=x[marker_nodes],
        metadata={"synthetic": True, "marker_nodes": marker_nodes.tolist()},
    )
    return model.validate()


def _kuhn_tets(x: np.ndarray, nx: int, ny: int, nz: int, nid) -> np.ndarray:
    """Positively oriented tets of the nx by ny by nz cells (node ids ``nid(i, j, k)``)."""
    # Kuhn split of each hexahedral cell into 6 tets along the main diagonal.
    cube = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 1), (1, 1, 1)]
    kuhn = [(0, 1, 3, 7), (0, 3, 2, 7), (0, 2, 6, 7), (0, 6, 4, 7), (0, 4, 5, 7), (0, 5, 1, 7)]
    tets = []
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                corner = [nid(i + a, j + b, k + c) for a, b, c in cube]
                for t in kuhn:
                    tets.append([corner[q] for q in t])
    tets = np.asarray(tets, dtype=np.int64)
    e = x[tets[:, 1:]] - x[tets[:, :1]]
    neg = np.linalg.det(e) < 0
    tets[neg, 2], tets[neg, 3] = tets[neg, 3].copy(), tets[neg, 2].copy()
    return tets


def _cap_surface(x: np.ndarray, nx: int, ny: int, k: int, outward_sign: float, nid) -> np.ndarray:
    """Triangles of the grid layer k, wound to face away from the cap centre (``outward_sign`` +1) or to it."""
    tri = []
    for i in range(nx):
        for j in range(ny):
            a, b, c, d = nid(i, j, k), nid(i + 1, j, k), nid(i + 1, j + 1, k), nid(i, j + 1, k)
            tri += [[a, b, c], [a, c, d]]
    tri = np.asarray(tri)
    n = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])
    radial = x[tri].mean(axis=1) + [0, 0, _R_OUT]
    flip = np.sum(n * radial, axis=1) * outward_sign < 0
    tri[flip, 1], tri[flip, 2] = tri[flip, 2].copy(), tri[flip, 1].copy()
    return tri


def _fake_muscles(x: np.ndarray, tets: np.ndarray) -> dict[str, np.ndarray]:
    """{muscle: tet mask} of the two zygomatics and the frontalis, by the tet centres' angles."""
    # Muscles: sets of cells (tets) with unit fibre directions.
    cen = x[tets].mean(axis=1)
    tth = np.arctan2(cen[:, 0], cen[:, 2] + _R_OUT)
    tph = np.arcsin(np.clip(cen[:, 1] / np.linalg.norm(cen + [0, 0, _R_OUT], axis=1), -1, 1))
    return {
        "zygomatic_major_L": (np.abs(tph - (-0.05 + 0.6 * (tth - 0.25))) < 0.09) & (tth > 0.2) & (tth < 0.8),
        "zygomatic_major_R": (np.abs(tph - (-0.05 - 0.6 * (tth + 0.25))) < 0.09) & (tth < -0.2) & (tth > -0.8),
        "frontalis": (tph > 0.45) & (np.abs(tth) < 0.55),
    }


def _fibre_entries(muscles: dict[str, np.ndarray]):
    """(fibre_tet, fibre_muscle, fibre_fraction, fibre_direction): whole tets, one direction per muscle."""
    fdir = {"zygomatic_major_L": (0.85, 0.5, 0.0), "zygomatic_major_R": (-0.85, 0.5, 0.0), "frontalis": (0.0, 1.0, 0.0)}
    entries = []
    for m, (name, mask) in enumerate(muscles.items()):
        d = np.asarray(fdir[name]) / np.linalg.norm(fdir[name])
        for t in np.flatnonzero(mask):
            entries.append((t, m, 1.0, d))
    entries.sort(key=lambda r: (r[0], r[1]))
    fibre_tet = np.array([r[0] for r in entries], dtype=np.int32)
    fibre_muscle = np.array([r[1] for r in entries], dtype=np.int32)
    fibre_fraction = np.array([r[2] for r in entries])
    fibre_direction = np.array([r[3] for r in entries]).reshape(-1, 3)
    return fibre_tet, fibre_muscle, fibre_fraction, fibre_direction


def _bone_meshes(x: np.ndarray, inner_tri: np.ndarray, jaw_nodes: np.ndarray) -> dict[str, BoneMesh]:
    """Skull and mandible under the inner surface (its triangles on ``jaw_nodes`` follow the jaw)."""
    tri_jaw = np.all(np.isin(inner_tri, jaw_nodes), axis=1)
    bone_meshes = {}
    for bname, bone, sel in (("skull", "cranium", ~tri_jaw), ("mandible", "jaw", tri_jaw)):
        tri = inner_tri[sel]
        used = np.unique(tri)
        remap = np.full(x.shape[0], -1)
        remap[used] = np.arange(used.size)
        # Bone surface slightly inside the flesh (scaled towards the cap centre).
        centre = np.array([0.0, 0.0, -_R_OUT])
        v = centre + 0.97 * (x[used] - centre)
        bone_meshes[bname] = BoneMesh(v, remap[tri].astype(np.int32), bone)
    return bone_meshes


def rotation_about(axis, angle_rad: float) -> np.ndarray:
    """3x3 rotation by ``angle_rad`` about unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * K @ K


def muscle_displacement_fields(model, *, amplitude_m: float = 0.008) -> np.ndarray:
    """(M, n, 3) displacement of every node at full activation of each muscle (a smooth made-up field)."""
    cen = model.rest_positions_m[model.tets[model.fibre_tet]].mean(axis=1)
    out = np.zeros((model.n_muscles, model.n_nodes, 3))
    for m in range(model.n_muscles):
        sel = model.fibre_muscle == m
        if not np.any(sel):
            continue
        c = np.average(cen[sel], axis=0, weights=model.fibre_fraction[sel])
        d = np.average(model.fibre_direction[sel], axis=0)
        d /= np.linalg.norm(d)
        spread = np.sqrt(np.mean(np.sum((cen[sel] - c) ** 2, axis=1))) + 1e-3
        w = np.exp(-np.sum((model.rest_positions_m - c) ** 2, axis=1) / (2 * spread**2))
        out[m] = amplitude_m * w[:, None] * d
    out[:, model.attached_nodes] = 0.0
    return out


def synthetic_take(model, *, n_frames: int = 24, fps: float = 24.0, seed: int = 0) -> dict:
    """Animate ``model``: activations, jaw opening up to ~12 degrees and a small head turn.

    Returns:
        dict with ``node_positions_m`` (F, n, 3), ``activations`` (F, M), ``jaw_angle_deg`` (F,),
        ``cranium_affines`` (F, 3, 4) rest to world, ``jaw_affines`` (F, 3, 4) relative to the
        cranium (as ``wface.controls``' bone parameters), ``simulated_markers_m`` (F, k, 3),
        ``captured_markers_m`` (F, k, 3; noise ~0.5 mm, marker 0 missing in some frames),
        ``basis`` (a ``wface.io.usd.BlendShapeBasis``: muscles + jaw opening) and its
        ``basis_weights`` (F, B), and ``fps``.
    """

    t = np.arange(n_frames) / fps
    s = np.linspace(0.0, 1.0, n_frames)
    act = np.stack(
        [
            np.clip(np.sin(np.pi * s) ** 2, 0, 1),
            np.clip(np.sin(np.pi * np.clip(1.4 * s - 0.2, 0, 1)) ** 2, 0, 1),
            np.clip(0.5 - 0.5 * np.cos(4 * np.pi * s), 0, 1) * (s > 0.5),
        ],
        axis=1,
    )[:, : model.n_muscles]
    jaw_deg = 12.0 * np.sin(np.pi * s) ** 4
    head_deg = 6.0 * np.sin(2 * np.pi * s)
    fields = muscle_displacement_fields(model)
    x0 = model.rest_positions_m
    jj = model.jaw_joint
    mid = np.asarray(jj.midpoint_m)
    # Jaw weight: 1 on jaw-attached nodes, smooth above them (lower face follows the jaw).
    y_jaw = x0[model.nodes_of_bone("jaw"), 1].max() if model.nodes_of_bone("jaw").size else -np.inf
    wj = np.clip((y_jaw + 0.012 - x0[:, 1]) / 0.024, 0, 1)
    wj[model.nodes_of_bone("cranium")] = 0.0
    wj[model.nodes_of_bone("jaw")] = 1.0
    frames, cran, jaw = [], [], []
    for f in range(n_frames):
        xf = x0 + np.tensordot(act[f], fields, axes=(0, 0))
        Rj = rotation_about(jj.u, np.radians(jaw_deg[f]))
        xj = (xf - mid) @ Rj.T + mid
        xf = xf + wj[:, None] * (xj - xf)
        Rh = rotation_about((0, 1, 0), np.radians(head_deg[f]))
        th = np.array([0.004 * np.sin(2 * np.pi * s[f]), 0.0, 0.0])
        frames.append(xf @ Rh.T + th)
        cran.append(np.hstack([Rh, th[:, None]]))
        jaw.append(np.hstack([Rj, (mid - Rj @ mid)[:, None]]))  # relative to the cranium (wface.controls)
    x = np.asarray(frames)
    nodes = np.asarray(model.metadata.get("marker_nodes", []), dtype=np.int64)
    sim = x[:, nodes]
    rng = np.random.default_rng(seed)
    cap = sim + rng.normal(scale=0.0005, size=sim.shape)
    if cap.shape[1]:
        cap[n_frames // 3 : n_frames // 2, 0] = np.nan
    skin_nodes = np.unique(model.skin_triangles)
    jaw_delta = np.zeros_like(x0)
    Rj = rotation_about(jj.u, np.radians(12.0))
    jaw_delta = wj[:, None] * (((x0 - mid) @ Rj.T + mid) - x0)
    basis = BlendShapeBasis(x0, np.concatenate([fields, jaw_delta[None]]), [*model.muscle_names, "jaw_open"])
    weights = np.concatenate([act, (jaw_deg / 12.0)[:, None]], axis=1)
    del skin_nodes
    return {
        "fps": float(fps),
        "time_s": t,
        "node_positions_m": x,
        "activations": act,
        "jaw_angle_deg": jaw_deg,
        "cranium_affines": np.asarray(cran),
        "jaw_affines": np.asarray(jaw),
        "simulated_markers_m": sim,
        "captured_markers_m": cap,
        "basis": basis,
        "basis_weights": weights,
    }
