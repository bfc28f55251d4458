"""The FEM face's own blend shapes: each muscle's skin displacement alone, and how far the skin follows the jaw.

``muscle_shapes`` is the physics of ``wface basis from-face`` (``wface.basis.physical``): shape i is
the skin displacement of the quasistatic FEM face (Sifakis et al. 2005) with muscle i alone at
activation ``activation``, divided by it, so a weight of 1 reproduces that equilibrium exactly and
a sum of weights linearises the face about rest (Choe & Ko 2001).

``jaw_skin_weights`` gives each skin vertex the share w in [0, 1] of the jaw's rigid motion it
follows, from one equilibrium with the jaw opened by ``probe_deg`` and no activation:

    w_v = clip(d_v . r_v / |r_v|^2, 0, 1)

with d_v the vertex's displacement and r_v the displacement it would have if it were fixed to the
jaw: 1 on the chin, 0 on the forehead, in between on the cheeks, as the flesh carries it.

A scalar weight cannot bend flesh that stretches rather than turns, so ``jaw_corrective`` adds one
corrective shape ``jaw_open``: the rest-space offset c that makes the skinned skin exact at the
joint's largest opening theta_max (equilibrium x_v there, jaw transform R, t):

    c_v = M_v^-1 (x_v - w_v t) - p_v,   M_v = (1 - w_v) I + w_v R

driven by the weight theta / theta_max (so 0 at rest and 1 at theta_max, exact at both).

``skin_rig`` bundles all of it into the ``wface.io.usd.rig.SkinRig`` that ``write_take_usd``
writes as UsdSkel blend shapes and joints; it is computed once per model object and kept while it
lives, one muscle at a time.
"""

from __future__ import annotations

import weakref

import numpy as np
from tqdm.auto import tqdm

from wface.controls import attached_positions_from_affines, jaw_limits, jaw_opening_affine
from wface.io.usd.rig import SkinRig
from wface.model import FaceModel
from wface.physics.simulator import Simulator

__all__ = ["JAW_SHAPE", "jaw_corrective", "jaw_skin_weights", "muscle_shapes", "skin_rig"]

JAW_SHAPE = "jaw_open"  # name of the corrective shape, after the muscle shapes

_RIGS: dict[int, tuple[weakref.ref, dict]] = {}  # id(model) -> (weak reference, solved shapes)


def muscle_shapes(
    model: FaceModel,
    *,
    muscles: list[str] | None = None,
    activation: float = 1.0,
    simulator: Simulator | None = None,
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """(skin node ids (s,), shapes (B, s, 3) in metres per unit weight), one shape per muscle.

    Args:
        model: the face.
        muscles: the muscles (default all, in the model's order).
        activation: the activation each muscle is solved at, in (0, 1].
        simulator: a ``Simulator`` of ``model`` to reuse (default: a new one on the CPU).
        progress: show a progress bar.

    Raises:
        KeyError: an unknown muscle (the message lists the known ones).
        RuntimeError: a muscle's equilibrium inverts tets.
    """
    if not (0.0 < activation <= 1.0):
        raise ValueError(f"activation must be in (0, 1], got {activation}")
    names = list(model.muscle_names) if muscles is None else list(muscles)
    for name in names:
        model.muscle_index(name)
    sim = simulator or Simulator(model)
    rest = model.rest_positions_m
    skin_nodes = np.unique(model.skin_triangles)
    shapes = np.empty((len(names), len(skin_nodes), 3))
    for i, name in enumerate(tqdm(names, desc="muscle shapes", disable=not progress, unit="muscle")):
        eq = sim.solve({name: activation})
        if eq.inverted_elements:
            raise RuntimeError(f"muscle {name} at activation {activation} inverts {eq.inverted_elements} tets")
        shapes[i] = (eq.x[skin_nodes] - rest[skin_nodes]) / activation
    return skin_nodes, shapes


def jaw_skin_weights(model: FaceModel, *, simulator: Simulator | None = None, probe_deg: float = 5.0) -> np.ndarray:
    """(s,) share of the jaw's motion each skin vertex follows (module docstring), skin order of
    ``np.unique(model.skin_triangles)``."""
    sim = simulator or Simulator(model)
    rest = model.rest_positions_m
    skin_nodes = np.unique(model.skin_triangles)
    jaw = jaw_opening_affine(model, probe_deg)
    eq = sim.solve(np.zeros(model.n_muscles), attached_positions_from_affines(model, None, jaw))
    p = rest[skin_nodes]
    d = eq.x[skin_nodes] - p
    r = p @ jaw[:, :3].T + jaw[:, 3] - p
    rr = np.einsum("ij,ij->i", r, r)
    w = np.divide(np.einsum("ij,ij->i", d, r), rr, out=np.zeros(len(p)), where=rr > 1e-24)
    return np.clip(w, 0.0, 1.0)


def jaw_corrective(
    model: FaceModel, jaw_weights: np.ndarray, *, simulator: Simulator | None = None
) -> tuple[np.ndarray, float]:
    """((s, 3) corrective offsets in rest space, theta_max in degrees): the ``jaw_open`` shape of the
    module docstring, solved at the joint's largest opening."""
    sim = simulator or Simulator(model)
    theta_max = jaw_limits(model.jaw_joint)["opening_deg"][1]
    skin_nodes = np.unique(model.skin_triangles)
    jaw = jaw_opening_affine(model, theta_max)
    eq = sim.solve(np.zeros(model.n_muscles), attached_positions_from_affines(model, None, jaw))
    p = model.rest_positions_m[skin_nodes]
    w = np.asarray(jaw_weights, dtype=np.float64)[:, None, None]
    M = (1.0 - w) * np.eye(3) + w * jaw[:, :3]
    rhs = eq.x[skin_nodes] - w[:, :, 0] * jaw[:, 3]
    return np.linalg.solve(M, rhs[..., None])[..., 0] - p, float(theta_max)


def skin_rig(
    model: FaceModel,
    *,
    muscles: list[str] | None = None,
    jaw: bool = True,
    simulator: Simulator | None = None,
    progress: bool = False,
) -> SkinRig:
    """The ``SkinRig`` of a model: its muscle shapes, then (with ``jaw``) the jaw weights and the
    ``jaw_open`` corrective; without ``jaw`` the skin follows the cranium alone.

    Each muscle's shape and the jaw's are solved once per model object and kept while it lives, so
    a rig over other muscles of the same model costs only the muscles not yet solved.

    Args:
        model: the face.
        muscles: the muscles to give shapes (default all, in the model's order).
        jaw: add the jaw weights and corrective (two more solves).
        simulator: a ``Simulator`` of ``model`` to reuse.
        progress: show a progress bar over the muscles' solves.
    """
    names = list(model.muscle_names) if muscles is None else list(muscles)
    hit = _RIGS.get(id(model))
    if hit is None or hit[0]() is not model:
        key = id(model)
        hit = (weakref.ref(model, lambda _ref: _RIGS.pop(key, None)), {"shapes": {}})
        _RIGS[key] = hit
    cache = hit[1]
    sim = simulator
    todo = [n for n in names if n not in cache["shapes"]]
    if todo:
        sim = sim or Simulator(model)
        _, shapes = muscle_shapes(model, muscles=todo, simulator=sim, progress=progress)
        cache["shapes"].update(zip(todo, shapes, strict=True))
    skin_nodes = np.unique(model.skin_triangles)
    deltas = [cache["shapes"][n] for n in names]
    weights = np.zeros(len(skin_nodes))
    source = f"wface FEM face ({model.n_tets} tets): each muscle alone at activation 1"
    info: dict = {}
    if jaw:
        if "jaw" not in cache:
            sim = sim or Simulator(model)
            w = jaw_skin_weights(model, simulator=sim)
            cache["jaw"] = (w, *jaw_corrective(model, w, simulator=sim))
        weights, corrective, theta_max = cache["jaw"]
        deltas.append(corrective)
        names = [*names, JAW_SHAPE]
        source += f", jaw weights at 5 deg, '{JAW_SHAPE}' corrective at {theta_max:.3g} deg"
        info["jaw_open_full_deg"] = theta_max
    return SkinRig(
        rest_m=model.rest_positions_m[skin_nodes],
        deltas_m=np.stack(deltas) if deltas else np.zeros((0, len(skin_nodes), 3)),
        names=names,
        jaw_weights=weights,
        source=source,
        info=info,
    )
