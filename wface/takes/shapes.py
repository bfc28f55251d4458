"""The FEM face's own blend shapes: each muscle's skin displacement alone, and how far the skin follows the jaw.

``muscle_shapes`` is the physics of ``wface basis from-face`` (``wface.basis.physical``): shape i is
the skin displacement of the quasistatic FEM face (Sifakis et al. 2005) with muscle i alone at
activation ``activation``, divided by it, so a weight of 1 reproduces that equilibrium exactly and
a sum of weights linearises the face about rest (Choe & Ko 2001).

A pressure actuator (``FaceModel.pressure_actuators``) is signed: it has its shape at +1 under its
own name and a second one at -1 (suction) named ``<name>_suction`` (``SUCTION_SUFFIX``), each
weighted by the positive part of its control, so a rig's weights stay in [0, 1].

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
lives, one muscle at a time, every node's displacement kept. ``render_mesh_rig`` gives a render mesh
bound to the face (``wface.faces.render_mesh``) the same rig from those same solves: its binding is
linear in the node positions, so shape i is the mesh's own motion in muscle i's equilibrium, and the
jaw weights and corrective follow the formulas above on its vertices (docs/design.md, "Take rig").
"""

from __future__ import annotations

import warnings
import weakref

import numpy as np
from tqdm.auto import tqdm

from wface.controls import attached_positions_from_affines, jaw_limits, jaw_opening_affine
from wface.io.usd.rig import SkinRig
from wface.model import FaceModel
from wface.physics.simulator import Simulator

__all__ = [
    "JAW_SHAPE",
    "SUCTION_SUFFIX",
    "jaw_corrective",
    "jaw_skin_weights",
    "muscle_shapes",
    "render_mesh_rig",
    "shape_channel",
    "shape_names",
    "shape_weights",
    "skin_rig",
]

JAW_SHAPE = "jaw_open"  # name of the corrective shape, after the muscle shapes
SUCTION_SUFFIX = "_suction"  # a pressure actuator's shape at control -1
_PROBE_DEG = 5.0  # the jaw opening that measures how far each vertex follows the jaw

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
        shape_channel(model, name)
    skin_nodes = np.unique(model.skin_triangles)
    shapes = _node_shapes(model, names, activation, simulator or Simulator(model), progress)
    return skin_nodes, shapes[:, skin_nodes]


def shape_channel(model: FaceModel, name: str) -> tuple[int, float]:
    """(channel index, sign) of a shape name: a muscle's own name (+1), or a pressure actuator's
    ``<name>_suction`` (-1). An unknown name raises the model's KeyError listing the muscles."""
    base = name.removesuffix(SUCTION_SUFFIX)
    if base != name and base in model.pressure_actuators:
        return model.muscle_index(base), -1.0
    return model.muscle_index(name), 1.0


def shape_names(model: FaceModel) -> list[str]:
    """Every shape a rig of ``model`` can have, in order: each muscle, and after a pressure actuator
    its suction shape."""
    return shape_weights(model, np.zeros((1, model.n_muscles)))[0]


def shape_weights(model: FaceModel, activations: np.ndarray, *, active: float | None = None) -> tuple[list, np.ndarray]:
    """(shape names, (T, B) weights >= 0) of a take's (T, M) activations: a muscle's weight is its
    activation, a pressure actuator's splits into its positive and its suction part. With
    ``active``, only the shapes whose weight exceeds it in some frame."""
    a = np.atleast_2d(np.asarray(activations, dtype=np.float64))
    names, columns = [], []
    for i, name in enumerate(model.muscle_names):
        names.append(name)
        columns.append(np.maximum(a[:, i], 0.0))
        if name in model.pressure_actuators:
            names.append(name + SUCTION_SUFFIX)
            columns.append(np.maximum(-a[:, i], 0.0))
    W = np.stack(columns, axis=1) if columns else np.zeros((len(a), 0))
    if active is None:
        return names, W
    keep = W.max(axis=0, initial=0.0) > active
    return [n for n, k in zip(names, keep, strict=True) if k], W[:, keep]


def _node_shapes(model: FaceModel, names: list[str], activation: float, sim: Simulator, progress: bool) -> np.ndarray:
    """(B, N, 3) displacement of every node per unit weight, one muscle alone at ``activation`` each
    (a pressure actuator's suction shape at -``activation``)."""
    rest = model.rest_positions_m
    shapes = np.empty((len(names), model.n_nodes, 3))
    for i, name in enumerate(tqdm(names, desc="muscle shapes", disable=not progress, unit="muscle")):
        channel, sign = shape_channel(model, name)
        eq = sim.solve({model.muscle_names[channel]: sign * activation})
        if eq.inverted_elements:
            raise RuntimeError(f"muscle {name} at activation {activation} inverts {eq.inverted_elements} tets")
        _warn_unconverged(eq, f"muscle {name}'s shape (activation {activation:g})")
        shapes[i] = (eq.x - rest) / activation
    return shapes


def jaw_skin_weights(
    model: FaceModel, *, simulator: Simulator | None = None, probe_deg: float = _PROBE_DEG
) -> np.ndarray:
    """(s,) share of the jaw's motion each skin vertex follows (module docstring), skin order of
    ``np.unique(model.skin_triangles)``."""
    skin_nodes = np.unique(model.skin_triangles)
    jaw = jaw_opening_affine(model, probe_deg)
    x = _jaw_equilibrium(model, jaw, simulator or Simulator(model))
    return _follow_share(model.rest_positions_m[skin_nodes], x[skin_nodes], jaw)


def _jaw_equilibrium(model: FaceModel, jaw: np.ndarray, sim: Simulator) -> np.ndarray:
    """(N, 3) node positions with the jaw at the (3, 4) affine ``jaw`` and no activation."""
    eq = sim.solve(np.zeros(model.n_muscles), attached_positions_from_affines(model, None, jaw))
    _warn_unconverged(eq, "the jaw's equilibrium")
    return eq.x


def _warn_unconverged(eq, what: str) -> None:
    """Say so when a shape's equilibrium stopped short of its tolerance (it is used as it stands)."""
    if not eq.converged:
        warnings.warn(
            f"{what}: the quasistatic solve stopped at relative residual {eq.residual_rel:.1e} after "
            f"{eq.iterations} iterations (not converged); the shape is used as it stands",
            stacklevel=3,
        )


def _follow_share(p: np.ndarray, x: np.ndarray, jaw: np.ndarray) -> np.ndarray:
    """(s,) w = clip(d . r / |r|^2, 0, 1) of points at rest ``p`` moved to ``x`` by the jaw ``jaw``."""
    d = x - p
    r = p @ jaw[:, :3].T + jaw[:, 3] - p
    rr = np.einsum("ij,ij->i", r, r)
    w = np.divide(np.einsum("ij,ij->i", d, r), rr, out=np.zeros(len(p)), where=rr > 1e-24)
    return np.clip(w, 0.0, 1.0)


def jaw_corrective(
    model: FaceModel, jaw_weights: np.ndarray, *, simulator: Simulator | None = None
) -> tuple[np.ndarray, float]:
    """((s, 3) corrective offsets in rest space, theta_max in degrees): the ``jaw_open`` shape of the
    module docstring, solved at the joint's largest opening."""
    theta_max = jaw_limits(model.jaw_joint)["opening_deg"][1]
    skin_nodes = np.unique(model.skin_triangles)
    jaw = jaw_opening_affine(model, theta_max)
    x = _jaw_equilibrium(model, jaw, simulator or Simulator(model))
    return _corrective(model.rest_positions_m[skin_nodes], x[skin_nodes], jaw_weights, jaw), float(theta_max)


def _corrective(p: np.ndarray, x: np.ndarray, jaw_weights: np.ndarray, jaw: np.ndarray) -> np.ndarray:
    """(s, 3) c = M^-1 (x - w t) - p, M = (1 - w) I + w R (module docstring)."""
    w = np.asarray(jaw_weights, dtype=np.float64)[:, None, None]
    M = (1.0 - w) * np.eye(3) + w * jaw[:, :3]
    rhs = x - w[:, :, 0] * jaw[:, 3]
    return np.linalg.solve(M, rhs[..., None])[..., 0] - p


def _solved(model: FaceModel, names: list[str], jaw: bool, simulator, progress: bool) -> dict:
    """The model's solved shapes, kept while it lives: {"shapes": {muscle: (N, 3) node displacement},
    "jaw": (probe affine, (N, 3) nodes there, full-opening affine, (N, 3) nodes there, theta_max)}."""
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
        cache["shapes"].update(zip(todo, _node_shapes(model, todo, 1.0, sim, progress), strict=True))
    if jaw and "jaw" not in cache:
        sim = sim or Simulator(model)
        probe = jaw_opening_affine(model, _PROBE_DEG)
        theta_max = float(jaw_limits(model.jaw_joint)["opening_deg"][1])
        full = jaw_opening_affine(model, theta_max)
        cache["jaw"] = (probe, _jaw_equilibrium(model, probe, sim), full, _jaw_equilibrium(model, full, sim), theta_max)
    return cache


def _rig_on(model: FaceModel, points, names: list[str], jaw: bool, cache: dict) -> tuple:
    """(rest (r, 3), deltas (B, r, 3), jaw weights (r,), names, theta_max or None) of the points that
    ``points`` (a map linear in the (N, 3) node positions) gives: each shape is the points' own motion."""
    x0 = model.rest_positions_m
    rest = points(x0)
    deltas = [points(x0 + cache["shapes"][n]) - rest for n in names]
    if not jaw:
        return rest, deltas, np.zeros(len(rest)), list(names), None
    probe, x_probe, full, x_full, theta_max = cache["jaw"]
    w = _follow_share(rest, points(x_probe), probe)
    deltas.append(_corrective(rest, points(x_full), w, full))
    return rest, deltas, w, [*names, JAW_SHAPE], theta_max


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
    a rig over other muscles of the same model (or of a render mesh on it, ``render_mesh_rig``)
    costs only the muscles not yet solved.

    Args:
        model: the face.
        muscles: the shapes to give (default ``shape_names(model)``: every muscle in the model's
            order, a pressure actuator's suction shape after it).
        jaw: add the jaw weights and corrective (two more solves).
        simulator: a ``Simulator`` of ``model`` to reuse.
        progress: show a progress bar over the muscles' solves.
    """
    names = shape_names(model) if muscles is None else list(muscles)
    cache = _solved(model, names, jaw, simulator, progress)
    skin_nodes = np.unique(model.skin_triangles)
    rest, deltas, weights, names, theta_max = _rig_on(model, lambda x: x[skin_nodes], names, jaw, cache)
    source = f"wface FEM face ({model.n_tets} tets): each muscle alone at activation 1"
    info: dict = {}
    if jaw:
        source += f", jaw weights at {_PROBE_DEG:g} deg, '{JAW_SHAPE}' corrective at {theta_max:.3g} deg"
        info["jaw_open_full_deg"] = theta_max
    return SkinRig(
        rest_m=rest,
        deltas_m=np.stack(deltas) if deltas else np.zeros((0, len(skin_nodes), 3)),
        names=names,
        jaw_weights=weights,
        source=source,
        info=info,
    )


def render_mesh_rig(
    model: FaceModel,
    render_mesh,
    *,
    muscles: list[str] | None = None,
    jaw: bool = True,
    simulator: Simulator | None = None,
    progress: bool = False,
) -> SkinRig:
    """The rig of a render mesh bound to ``model`` (``wface.faces.render_mesh.RenderMesh``), with the
    skin rig's shapes: shape i is the render mesh's own motion (its binding applied to the whole
    tet mesh's equilibrium) with muscle i alone, the jaw weights and corrective follow the same
    formulas on its vertices, so it is exact where the skin rig is. Rest points and shapes are in
    the mesh file's frame and units; ``bind_transform`` is the placement (file -> model metres).
    """
    names = shape_names(model) if muscles is None else list(muscles)
    cache = _solved(model, names, jaw, simulator, progress)
    rest, deltas, weights, names, theta_max = _rig_on(model, render_mesh.binding.positions, names, jaw, cache)
    m = np.asarray(render_mesh.source_to_model, dtype=np.float64)
    to_file = np.linalg.inv(m[:3, :3]).T  # offsets are directions: the linear part alone
    n = render_mesh.mesh.n_points
    return SkinRig(
        rest_m=render_mesh.mesh.points,
        deltas_m=np.stack(deltas) @ to_file if deltas else np.zeros((0, n, 3)),
        names=names,
        jaw_weights=weights,
        source=f"render mesh {render_mesh.name} on the wface FEM face ({model.n_tets} tets): its binding per shape",
        info={} if theta_max is None else {"jaw_open_full_deg": theta_max},
        bind_transform=m,
    )
