"""The dynamic replay: a take's muscle activations and bone motion played back through the
implicit dynamic FEM (``wface.physics.dynamics``), so the flesh gets inertia and secondary motion
that the quasistatic replay (``wface.takes.quasistatic``) cannot have. ``wface resim`` runs it.

The take (``wface.takes.take.Take``) gives (T, M) activations and (T, 24) bone controls
(``wface.controls``) or directly the (T, a, 3) attached-node positions, at a frame rate. Each frame
interval is split into ``substeps`` equal time steps. Between frames, muscle drives (and given
attached positions) are interpolated linearly, and bone controls with their rotations by slerp
(``wface.controls.interpolate_bones``), so the attached nodes move rigidly. The drives are split
once per take (``split_drives(per="take")``): the simulator holds one force-length scale per
muscle for the whole replay and the activations stay in [0, 1]. Frame 0 starts from its
quasistatic equilibrium at rest velocity.

Simulation frame: "world" (default) places the attached nodes with the full head motion (cranium
affine times jaw affine), so head accelerations shake the flesh; "cranium" simulates in the
cranium's frame as the tracker does (no inertia from head motion; positions are mapped to the
world afterwards with the cranium affine).

Writing: ``resim.npz`` through ``wface.takes.store.write_resim_npz``; the USD stage through
``wface.takes.usd.write_take_usd``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm.auto import tqdm

from wface.controls import attached_positions, bone_affines, interpolate_bones
from wface.mesh.quality import count_inverted
from wface.physics.dynamics import Damping, DynamicSimulator, StepStats
from wface.physics.simulator import Simulator
from wface.takes.pose import split_drives
from wface.takes.quasistatic import quasistatic_frames
from wface.takes.take import Take

__all__ = [
    "FRAMES",
    "ResimResult",
    "compare_with_quasistatic",
    "cranium_to_world",
    "deviation_mm",
    "quasistatic_reference",
    "resimulate",
    "step_overshoot_mm",
    "take_attached_positions",
]

FRAMES = ("world", "cranium")


@dataclass
class ResimResult:
    """A re-simulated take. Per-frame arrays have T rows; frame 0 is the quasistatic start.

    Attributes:
        positions_m: (T, n, 3) world node positions.
        fps, scheme, substeps, damping, frame: the settings.
        kinetic_energy_j: (T,) kinetic energy of the free nodes (simulation frame).
        elastic_energy_j: (T,) elastic energy.
        newton_iterations: (T,) Newton iterations over the frame's substeps (frame 0: the
            quasistatic solve's).
        residual_rel: (T,) worst relative residual over the frame's substeps.
        converged: (T,) all substeps converged.
        inverted_elements: (T,) tets with det F <= 0.
        seconds: (T,) wall-clock seconds per frame.
        steps: total time steps.
    """

    positions_m: np.ndarray
    fps: float
    scheme: str
    substeps: int
    damping: Damping
    frame: str
    kinetic_energy_j: np.ndarray
    elastic_energy_j: np.ndarray
    newton_iterations: np.ndarray
    residual_rel: np.ndarray
    converged: np.ndarray
    inverted_elements: np.ndarray
    seconds: np.ndarray
    steps: int = 0
    info: dict = field(default_factory=dict)

    @property
    def dt_s(self) -> float:
        """The time step: a capture frame's interval over the substeps (a take of every S-th capture frame
        takes S x substeps steps from one stored frame to the next)."""
        return 1.0 / (self.fps * self.substeps)

    def summary(self) -> dict:
        """JSON-ready per-frame and aggregate statistics."""
        return {
            "frames": int(self.positions_m.shape[0]),
            "fps": self.fps,
            "scheme": self.scheme,
            "substeps": self.substeps,
            "dt_s": self.dt_s,
            "frame": self.frame,
            "damping": {"alpha_per_s": self.damping.alpha_per_s, "beta_s": self.damping.beta_s},
            "steps": self.steps,
            "kinetic_energy_j": self.kinetic_energy_j.tolist(),
            "elastic_energy_j": self.elastic_energy_j.tolist(),
            "newton_iterations": self.newton_iterations.astype(int).tolist(),
            "newton_iterations_per_step_mean": float(self.newton_iterations[1:].sum() / max(self.steps, 1)),
            "residual_rel": self.residual_rel.tolist(),
            "converged": bool(np.all(self.converged)),
            "inverted_elements": self.inverted_elements.astype(int).tolist(),
            "inverted_elements_max": int(self.inverted_elements.max()),
            "seconds_per_frame": self.seconds.tolist(),
            "seconds_per_frame_median": float(np.median(self.seconds[1:])) if len(self.seconds) > 1 else 0.0,
            "seconds_per_step_median": float(np.median(self.seconds[1:]) / (self.steps / (len(self.seconds) - 1)))
            if len(self.seconds) > 1
            else 0.0,
            **self.info,
        }


# ---------------------------------------------------------------------- takes in and out
def take_attached_positions(model, take: Take, *, frame: str = "world") -> np.ndarray:
    """(T, a, 3) attached-node positions of a take in the simulation ``frame``."""
    if frame not in FRAMES:
        raise ValueError(f"frame must be one of {FRAMES}, got {frame!r}")
    if take.attached_positions_m is not None:
        xc = take.attached_positions_m
        if xc.shape[1:] != (model.attached_nodes.size, 3):
            raise ValueError(
                f"attached_positions_m has {xc.shape[1]} nodes per frame; "
                f"the model attaches {model.attached_nodes.size}"
            )
        return xc
    if take.bones is None:
        return np.broadcast_to(
            model.rest_positions_m[model.attached_nodes], (take.n_frames, model.attached_nodes.size, 3)
        )
    return np.stack([attached_positions(model, b, frame=frame) for b in take.bones])


def cranium_to_world(take: Take, positions: np.ndarray) -> np.ndarray:
    """(T, n, 3) positions in the cranium frame -> world, with each frame's cranium affine."""
    out = np.empty_like(positions)
    for k, b in enumerate(take.bones):
        cranium, _ = bone_affines(b)
        out[k] = positions[k] @ cranium[:, :3].T + cranium[:, 3]
    return out


def resimulate(
    model,
    take: Take,
    *,
    frame: str = "world",
    scheme: str = "auto",
    substeps: int = 16,
    damping: Damping | None = None,
    sim=None,
    tol: float = 1e-6,
    solver: str | None = None,
    stiffness: str = "auto",
    gravity_m_s2=None,
    x0_m: np.ndarray | None = None,
    progress: bool = False,
    on_step=None,
    contact=None,
) -> ResimResult:
    """Play a take through the implicit dynamic FEM.

    Args:
        model: the face.
        take: activations and bone motion per frame (``Take``, e.g. ``wface.takes.store.load_take``).
        frame: "world" (default, head motion drives inertia) or "cranium" (see module docstring).
        scheme: "midpoint" (second order), "be" (backward Euler) or "auto" (default): the midpoint rule
            without contact, backward Euler with it (``DynamicSimulator``).
        substeps: time steps per capture frame interval (dt = 1 / (fps substeps)); a take that kept every
            S-th capture frame (``take.frames``) takes S x substeps steps between its stored frames.
        damping: Rayleigh damping (default ``Damping()``).
        sim: a ``Simulator`` of ``model`` to reuse (default: a new float64 CPU one).
        tol, solver, stiffness, gravity_m_s2: see ``DynamicSimulator``.
        x0_m: start positions of frame 0 in the simulation ``frame`` (default: its quasistatic
            equilibrium); the start velocity is zero.
        progress: show a progress bar.
        on_step: optional callable ``on_step(state)`` after every time step (``DynamicState``, in
            the simulation frame), e.g. to record peaks between frames.
        contact: optional ``wface.physics.contact.Contact`` (lips, teeth, bones, obstacles), used by
            the quasistatic start and every time step.

    Returns:
        ``ResimResult`` with world positions per frame.
    """
    if take.activations.shape[1] != model.n_muscles:
        raise ValueError(
            f"take has {take.activations.shape[1]} activations per frame, the model {model.n_muscles} muscles"
        )
    if int(substeps) < 1 or int(substeps) != substeps:
        raise ValueError(f"substeps must be a positive integer, got {substeps}")
    if frame == "cranium" and take.bones is None:
        frame = "world"  # no cranium motion to undo
    sim = sim or Simulator(model, solver=solver or "auto")
    dyn = DynamicSimulator(
        sim,
        scheme=scheme,
        damping=damping,
        tol=tol,
        solver=solver,
        stiffness=stiffness,
        gravity_m_s2=gravity_m_s2,
        contact=contact,
    )
    # one force-length scale per muscle for the whole replay (module docstring)
    acts, scale = (take.activations, None) if take.force_length_scale is None else split_drives(take.drives, per="take")
    acts = np.array([model.activation_vector(a) for a in acts])
    xc = take_attached_positions(model, take, frame=frame)
    saved_scale = sim.force_length_scale  # restored below, also when a solve fails
    if scale is not None:
        sim.force_length_scale = scale
    try:
        state, first = _first_frame(sim, dyn, acts[0], xc[0], x0_m, tol, contact)
    except BaseException:
        dyn.free()
        sim.force_length_scale = saved_scale
        raise
    positions = np.empty((take.n_frames, model.n_nodes, 3))
    positions[0] = state.x_m
    stats = [first]
    try:
        _later_frames(model, take, dyn, state, acts, xc, substeps, frame, on_step, progress, positions, stats)
    finally:
        dyn.free()
        sim.force_length_scale = saved_scale
    if frame == "cranium":
        positions = cranium_to_world(take, positions)
    return _resim_result(take, positions, stats, dyn, sim, substeps=substeps, frame=frame, stiffness=stiffness)


def _first_frame(sim, dyn, a0, xc0, x0_m, tol, contact):
    """(dynamic state, stats) of frame 0: its quasistatic equilibrium (or ``x0_m``) at rest velocity."""
    t0 = time.perf_counter()
    if x0_m is None:
        eq = sim.solve(a0, xc0, tol=tol, contact=contact)
        x0, its0, res0 = eq.x, eq.iterations, eq.residual_rel
    else:
        x0, its0, res0 = x0_m, 0, 0.0
    state = dyn.initial_state(x0, None, a0)
    first = StepStats(
        newton_iterations=its0,
        residual_rel=res0,
        elastic_energy_j=sim.energy(x0, a0),
        inverted_elements=count_inverted(sim.model, x0),
        seconds=time.perf_counter() - t0,
    )
    return state, first


def _later_frames(model, take, dyn, state, acts, xc, substeps, frame, on_step, progress, positions, stats) -> None:
    """Advance frame by frame from ``state``, filling ``positions[1:]`` and appending to ``stats``."""
    bar = tqdm(total=take.n_frames - 1, desc=f"resim {dyn.scheme}", disable=not progress, unit="frame")
    try:
        for k in range(1, take.n_frames):
            path = xc[k]
            if take.bones is not None and take.attached_positions_m is None:
                b0, b1 = take.bones[k - 1], take.bones[k]

                def path(s, b0=b0, b1=b1):
                    return attached_positions(model, interpolate_bones(b0, b1, s), frame=frame)

            gap = int(take.frames[k] - take.frames[k - 1])  # capture frames since the last: 1, or S for every S-th
            state, st = dyn.advance(
                state,
                gap / take.fps,
                gap * substeps,
                acts[k],
                path,
                activation_ramp=take.activation_ramp,
                on_step=on_step,
            )
            positions[k] = state.x_m
            stats.append(st)
            bar.update(1)
            bar.set_postfix(newton=st.newton_iterations, ke=f"{st.kinetic_energy_j:.2e}")
    finally:
        bar.close()


def _resim_result(take, positions, stats, dyn, sim, *, substeps, frame, stiffness) -> ResimResult:
    """The ``ResimResult`` of the per-frame positions and step statistics."""
    return ResimResult(
        positions_m=positions,
        fps=take.fps,
        scheme=dyn.scheme,
        substeps=int(substeps),
        damping=dyn.damping,
        frame=frame,
        kinetic_energy_j=np.array([s.kinetic_energy_j for s in stats]),
        elastic_energy_j=np.array([s.elastic_energy_j for s in stats]),
        newton_iterations=np.array([s.newton_iterations for s in stats]),
        residual_rel=np.array([s.residual_rel for s in stats]),
        converged=np.array([s.converged for s in stats]),
        inverted_elements=np.array([s.inverted_elements for s in stats]),
        seconds=np.array([s.seconds for s in stats]),
        steps=int(sum(s.steps for s in stats)),
        info={
            "solver": dyn.engine,
            "device": sim.device,
            "stiffness": stiffness,
            "exact_failures": int(sum(s.exact_failures for s in stats)),
        },
    )


# ---------------------------------------------------------------------- comparison with quasistatic frames
def deviation_mm(positions_m: np.ndarray, reference_m: np.ndarray, nodes: np.ndarray | None = None) -> np.ndarray:
    """(T,) largest node distance per frame between a dynamic and a quasistatic take, mm."""
    p, r = np.asarray(positions_m), np.asarray(reference_m)
    if p.shape != r.shape:
        raise ValueError(f"positions {p.shape} and reference {r.shape} differ in shape")
    if nodes is not None:
        p, r = p[:, nodes], r[:, nodes]
    return np.linalg.norm(p - r, axis=2).max(axis=1) * 1e3


def step_overshoot_mm(
    positions_m: np.ndarray, start_m: np.ndarray, target_m: np.ndarray, nodes: np.ndarray | None = None
) -> dict:
    """Overshoot of a step response: how far nodes travel past their quasistatic target.

    For each node with quasistatic displacement d = target - start, the excursion along d is
    e(t) = (x(t) - start) . d / |d|; its overshoot is max_t e(t) - |d|. Returns the overshoot at
    the node with the largest |d| (``overshoot_mm``, with ``displacement_mm`` = that |d| and the
    ``overshoot_percent``) and the largest over all nodes whose |d| is at least 10 % of the largest
    (``overshoot_mm_max``), with the node ids.
    """
    x = np.asarray(positions_m)
    s, g = np.asarray(start_m), np.asarray(target_m)
    ids = np.arange(s.shape[0]) if nodes is None else np.asarray(nodes)
    d = (g - s)[ids]
    size = np.linalg.norm(d, axis=1)
    if size.max() <= 0:
        return {"overshoot_mm": 0.0, "displacement_mm": 0.0, "overshoot_percent": 0.0, "overshoot_mm_max": 0.0}
    u = d / np.maximum(size, 1e-300)[:, None]
    excursion = np.einsum("tij,ij->ti", x[:, ids] - s[ids], u)
    over = excursion.max(axis=0) - size
    main = int(np.argmax(size))
    moving = size >= 0.1 * size.max()
    worst = int(np.flatnonzero(moving)[np.argmax(over[moving])])
    return {
        "overshoot_mm": float(over[main] * 1e3),
        "displacement_mm": float(size[main] * 1e3),
        "overshoot_percent": float(100 * over[main] / size[main]),
        "node": int(ids[main]),
        "overshoot_mm_max": float(over[worst] * 1e3),
        "node_max": int(ids[worst]),
    }


def quasistatic_reference(
    sim, model, take: Take, *, frame: str = "world", tol: float = 1e-6, contact=None, progress: bool = False
) -> np.ndarray:
    """(T, n, 3) world positions of the take's frames played quasistatically (the frames a dynamic
    replay is compared with), in the simulation ``frame`` mapped to the world."""
    frame = "world" if take.bones is None else frame
    reference = quasistatic_frames(
        sim,
        take.activations,
        take_attached_positions(model, take, frame=frame),
        force_length_scale=take.force_length_scale,
        progress=progress,
        tol=tol,
        contact=contact,
    )
    return cranium_to_world(take, reference) if frame == "cranium" else reference


def compare_with_quasistatic(
    result: ResimResult,
    reference_m: np.ndarray,
    skin_nodes: np.ndarray,
    *,
    onset_frame: int | None = None,
    substep_skin_m: list | None = None,
) -> dict:
    """Deviation of a dynamic replay from its quasistatic frames on the skin (per frame, max, RMS),
    and for a step take (``onset_frame``: its first frame after rest) the overshoot past the held
    equilibrium, from the skin after every time step (``substep_skin_m``, one (s, 3) array per step)
    and at the frames alone (``overshoot_mm_at_frames``)."""
    dev = deviation_mm(result.positions_m, reference_m, skin_nodes)
    report = {
        "deviation_mm": dev.tolist(),
        "deviation_mm_max": float(dev.max()),
        "deviation_mm_rms": float(np.sqrt(np.mean(dev**2))),
    }
    if onset_frame is None:
        return report
    k = int(onset_frame)
    start_skin, target_skin = reference_m[k - 1, skin_nodes], reference_m[-1, skin_nodes]
    after_onset = np.array((substep_skin_m or [])[(k - 1) * result.substeps :])  # time steps after frame k - 1
    path = np.concatenate([result.positions_m[k - 1 : k, skin_nodes], after_onset.reshape(-1, len(skin_nodes), 3)])
    over = step_overshoot_mm(path, start_skin, target_skin)
    sampled = step_overshoot_mm(result.positions_m[k - 1 :, skin_nodes], start_skin, target_skin)
    if "node" in over:
        over["node"], over["node_max"] = int(skin_nodes[over["node"]]), int(skin_nodes[over["node_max"]])
    report.update(over)
    report["overshoot_mm_at_frames"] = sampled["overshoot_mm"]
    return report
