"""Dynamic re-simulation of a take: per-frame muscle activations and bone motion played back
through the implicit dynamic FEM (``wface.physics.dynamics``), so the flesh gets inertia and
secondary motion that a frame-by-frame quasistatic solve cannot have.

A take is (T, M) activations and (T, 24) bone controls (``wface.controls``) or directly the
(T, a, 3) attached-node positions, at a frame rate. Each frame interval is split into
``substeps`` equal time steps. Between frames, activations (and given attached positions) are
interpolated linearly, and bone controls with their rotations by slerp (``interpolate_bones``),
so the attached nodes move rigidly. Frame 0 starts from its quasistatic equilibrium at rest
velocity.

Simulation frame: "world" (default) places the attached nodes with the full head motion (cranium
affine times jaw affine), so head accelerations shake the flesh; "cranium" simulates in the
cranium's frame as the tracker does (no inertia from head motion; positions are mapped to the
world afterwards with the cranium affine).

Reading: ``load_take(dir, model)`` reads what ``wface track`` / ``wface demo`` wrote
(controls.npz, else frames/frame_*.npz; the tracked quasistatic world positions of
frames/*.npz become the reference). Writing: ``write_resim_usd`` (skin mesh with time samples,
``wface.io.usd.write_mesh_animation``) and ``write_resim_npz``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wface.physics.dynamics import Damping, DynamicSimulator, StepStats

__all__ = [
    "ResimResult",
    "cranium_to_world",
    "interpolate_bones",
    "skin_mesh",
    "Take",
    "deviation_mm",
    "load_take",
    "quasistatic_frames",
    "resimulate",
    "step_overshoot_mm",
    "take_attached_positions",
    "take_from_drives",
    "take_from_poses",
    "write_resim_npz",
    "write_resim_usd",
]

FRAMES = ("world", "cranium")


@dataclass
class Take:
    """Controls of a performance, one row per frame.

    Attributes:
        activations: (T, M) muscle activations in [0, 1].
        fps: frame rate, frames per second.
        bones: (T, 24) bone controls (``wface.controls``: cranium affine, jaw affine relative to the
            cranium), or None when ``attached_positions_m`` is given instead.
        attached_positions_m: (T, a, 3) positions of ``model.attached_nodes`` (in the simulation
            frame), or None (computed from ``bones``).
        frames: (T,) frame numbers (default 0..T-1).
        reference_positions_m: (T, n, 3) quasistatic world positions of the same frames (e.g. the
            tracked equilibria), or None.
        source: where the take came from.
        activation_ramp: how activations go from one frame to the next: "linear" (default) or
            "step" (the next frame's values from the first substep on: a sudden onset).
        force_length_scale: (M,) per-muscle scale of the active force-length curve for the whole
            take (``Simulator.force_length_scale``), or None (all 1). An exaggerated edit drives
            muscles past full activation (drive e = s a > 1, ``wface.editing``); a take keeps
            activations in [0, 1] and one scale per muscle, S = max(1, max_t e), with a = e / S,
            so activations still interpolate linearly in drive between frames
            (``take_from_poses``, ``load_take``).
    """

    activations: np.ndarray
    fps: float
    bones: np.ndarray | None = None
    attached_positions_m: np.ndarray | None = None
    frames: np.ndarray | None = None
    reference_positions_m: np.ndarray | None = None
    source: str = ""
    activation_ramp: str = "linear"
    force_length_scale: np.ndarray | None = None

    def __post_init__(self):
        if self.activation_ramp not in ("linear", "step"):
            raise ValueError(f"activation_ramp must be 'linear' or 'step', got {self.activation_ramp!r}")
        self.activations = np.asarray(self.activations, dtype=np.float64)
        if self.activations.ndim != 2 or self.activations.shape[0] < 1:
            raise ValueError(f"activations must have shape (frames, muscles), got {self.activations.shape}")
        T = self.activations.shape[0]
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be finite and > 0, got {self.fps}")
        self.fps = float(self.fps)
        if self.bones is not None:
            self.bones = np.asarray(self.bones, dtype=np.float64)
            if self.bones.shape != (T, 24):
                raise ValueError(f"bones must have shape ({T}, 24), got {self.bones.shape}")
        if self.attached_positions_m is not None:
            self.attached_positions_m = np.asarray(self.attached_positions_m, dtype=np.float64)
            if self.attached_positions_m.ndim != 3 or self.attached_positions_m.shape[0] != T:
                raise ValueError(
                    f"attached_positions_m must have shape ({T}, a, 3), got {self.attached_positions_m.shape}"
                )
        self.frames = np.arange(T) if self.frames is None else np.asarray(self.frames, dtype=np.int64)
        if self.frames.shape != (T,):
            raise ValueError(f"frames must have shape ({T},), got {self.frames.shape}")
        if self.reference_positions_m is not None:
            self.reference_positions_m = np.asarray(self.reference_positions_m, dtype=np.float64)
            if self.reference_positions_m.ndim != 3 or self.reference_positions_m.shape[0] != T:
                raise ValueError(
                    f"reference_positions_m must have shape ({T}, n, 3), got {self.reference_positions_m.shape}"
                )
        if self.force_length_scale is not None:
            s = np.asarray(self.force_length_scale, dtype=np.float64)
            if s.shape != (self.activations.shape[1],) or not np.all(np.isfinite(s)) or np.any(s < 0):
                raise ValueError(
                    f"force_length_scale must be ({self.activations.shape[1]},) finite and >= 0, got shape {s.shape}"
                )
            self.force_length_scale = None if np.all(s == 1.0) else s
        for name in ("activations", "bones", "attached_positions_m"):
            value = getattr(self, name)
            if value is not None and not np.all(np.isfinite(value)):
                raise ValueError(f"take {name} contain NaN or inf")

    @property
    def n_frames(self) -> int:
        return int(self.activations.shape[0])


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
            "seconds_per_step_median": float(np.median(self.seconds[1:]) / self.substeps)
            if len(self.seconds) > 1
            else 0.0,
            **self.info,
        }


# ---------------------------------------------------------------------- takes in and out
def take_attached_positions(model, take: Take, *, frame: str = "world") -> np.ndarray:
    """(T, a, 3) attached-node positions of a take in the simulation ``frame``."""
    from wface.controls import attached_positions

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


def _split_take_drives(drives: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(T, M) drives e = s a >= 0 -> (activations e / S in [0, 1], per-muscle S = max(1, max_t e) or None)."""
    e = np.asarray(drives, dtype=np.float64)
    S = np.maximum(1.0, e.max(axis=0, initial=0.0))
    return np.clip(e / S, 0.0, 1.0), (None if np.all(S == 1.0) else S)


def take_from_drives(drives: np.ndarray, fps: float, **kwargs) -> Take:
    """A ``Take`` from (T, M) muscle drives e = s a (activations times force-length scales, may
    exceed 1): activations e / S and one force-length scale S = max(1, max_t e) per muscle.
    Keyword arguments go to ``Take`` (bones, frames, source, ...)."""
    acts, scale = _split_take_drives(drives)
    return Take(activations=acts, fps=fps, force_length_scale=scale, **kwargs)


def take_from_poses(model, take, *, reference_positions_m: np.ndarray | None = None) -> Take:
    """The dynamic-simulation ``Take`` of an edited take (``wface.editing.Take``: a list of poses).

    Activations and per-frame force-length scales become drives (``take_from_drives``), so an
    exaggerated edit keeps its exaggeration; bones are the poses' 24 parameters (jaw clamped into
    the joint, as ``wface.editing.simulate_poses`` simulates them).
    """
    if list(take.muscle_names) != list(model.muscle_names):
        raise ValueError("the take's muscles are not the model's")
    bones = np.stack([p.bones(model.jaw_joint) for p in take.poses])
    return take_from_drives(
        take.drives, take.fps, bones=bones, reference_positions_m=reference_positions_m, source=take.source
    )


def _polar(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """M = R P with R a rotation and P symmetric (None for R when det M <= 0)."""
    U, S, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) <= 0:
        return None, M
    return R, Vt.T @ np.diag(S) @ Vt


def interpolate_bones(b0: np.ndarray, b1: np.ndarray, s: float) -> np.ndarray:
    """Bone controls (24,) at the fraction ``s`` of the way from ``b0`` to ``b1``.

    Each 3x3 part M = R P (polar decomposition) has its rotation R interpolated by slerp and its
    stretch P and the translation linearly, so a rigid bone stays rigid between frames (a linear
    blend of positions or matrices would shrink it along the chord of each rotation).
    """
    from scipy.spatial.transform import Rotation, Slerp

    out = (1.0 - s) * b0 + s * b1
    for off in (0, 12):
        R0, P0 = _polar(b0[off : off + 9].reshape(3, 3))
        R1, P1 = _polar(b1[off : off + 9].reshape(3, 3))
        if R0 is None or R1 is None:
            continue  # an improper matrix: keep the linear blend
        R = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([R0, R1])))([s]).as_matrix()[0]
        out[off : off + 9] = (R @ ((1.0 - s) * P0 + s * P1)).ravel()
    return out


def cranium_to_world(take: Take, positions: np.ndarray) -> np.ndarray:
    """(T, n, 3) positions in the cranium frame -> world, with each frame's cranium affine."""
    from wface.controls import bone_affines

    out = np.empty_like(positions)
    for k, b in enumerate(take.bones):
        cranium, _ = bone_affines(b)
        out[k] = positions[k] @ cranium[:, :3].T + cranium[:, 3]
    return out


def load_take(
    path: str | Path, model, *, fps: float | None = None, frames: slice | None = None, reference: bool = True
) -> Take:
    """Read the take that ``wface track`` / ``wface demo`` wrote under ``path``.

    Controls come from ``path/controls.npz`` (activations (T, M), bones (T, 24), frames), or, for an
    interrupted run, from ``path/frames/frame_*.npz``. The tracked world positions in
    ``frames/*.npz`` (when present for every frame) become ``reference_positions_m``.

    Args:
        path: the tracking output directory.
        model: the face the take was tracked on (muscle count and node count are checked).
        fps: frame rate; default: the ``fps`` stored in controls.npz, else ``timeCodesPerSecond``
            of ``path/animation.usdc`` when readable, else 30.
        frames: optional slice of the take's frames (e.g. ``slice(0, 60)``).
        reference: also read the tracked positions (T x n x 3 floats; False skips them when
            controls.npz is there).
    """
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"take directory not found: {path}")
    frame_files = sorted((path / "frames").glob("frame_*.npz"))
    controls = path / "controls.npz"
    records = {}
    if frame_files and (reference or not controls.exists()):
        from wface.tracking.sequence import load_frame_records

        numbers = [int(p.stem.split("_")[1]) for p in frame_files]
        records = load_frame_records(path, numbers)
    scale, stored_fps = None, None
    if controls.exists():
        with np.load(controls) as d:
            acts, bones, numbers = d["activations"], d["bones"], d["frames"]
            if "fps" in d.files:  # written by `wface track` / `wface edit`
                stored_fps = float(d["fps"])
            if "force_length_scale" in d.files:  # written by `wface edit` (exaggeration past full activation)
                scale = np.asarray(d["force_length_scale"], dtype=np.float64)
            if "muscle_names" in d.files and list(d["muscle_names"]) != list(model.muscle_names):
                raise ValueError(f"{controls}: muscle names differ from the model's (was it tracked on another face?)")
    elif records:
        numbers = np.array(sorted(records))
        C = np.array([records[f].controls for f in numbers])
        acts, bones = C[:, : model.n_muscles], C[:, model.n_muscles :]
    else:
        raise FileNotFoundError(f"{path}: no controls.npz and no frames/frame_*.npz: not a tracking output directory")
    if acts.shape[1] != model.n_muscles or bones.shape[1] != 24:
        raise ValueError(
            f"{path}: controls have {acts.shape[1]} activations and {bones.shape[1]} bone parameters per frame; "
            f"the model has {model.n_muscles} muscles (and 24 bone parameters)"
        )
    tracked = None
    if reference and records and all(int(f) in records for f in numbers):
        tracked = np.array([records[int(f)].x_m for f in numbers])
        if tracked.shape[1] != model.n_nodes:
            raise ValueError(
                f"{path}: tracked frames have {tracked.shape[1]} nodes, the model {model.n_nodes}: wrong model?"
            )
    if fps is None:
        fps = stored_fps or _usd_fps(path / "animation.usdc") or 30.0
    sl = frames or slice(None)
    acts = np.clip(acts[sl], 0.0, 1.0)  # tracked activations may overshoot [0, 1] by round-off
    acts, flscale = (acts, None) if scale is None else _split_take_drives(acts * scale[sl])
    return Take(
        activations=acts,
        force_length_scale=flscale,
        fps=fps,
        bones=bones[sl],
        frames=np.asarray(numbers)[sl],
        reference_positions_m=None if tracked is None else tracked[sl],
        source=str(path),
    )


def _usd_fps(path: Path) -> float | None:
    if not path.exists():
        return None
    try:
        from pxr import Usd

        stage = Usd.Stage.Open(str(path))
        return float(stage.GetTimeCodesPerSecond())
    except Exception:  # noqa: BLE001 - optional hint only
        return None


def skin_mesh(model) -> tuple[np.ndarray, np.ndarray]:
    """(node ids (s,), triangles (t, 3) over those s points) of the skin, or the boundary of the
    tet mesh when the model has no skin triangles."""
    from wface.mesh.surface import boundary_faces

    tri = model.skin_triangles if model.skin_triangles.size else boundary_faces(model.tets)
    nodes, local = np.unique(tri.ravel(), return_inverse=True)
    return nodes, local.reshape(-1, 3).astype(np.int32)


def write_resim_usd(
    path: str | Path, model, positions_m: np.ndarray, fps: float, *, name: str = "Face", take: Take | None = None
) -> Path:
    """The skin of a re-simulated take as an animated USD stage (time code f = frame f).

    Without ``take``: one animated mesh ``/<name>/Mesh`` (``wface.io.usd.write_mesh_animation``).
    With ``take`` (the ``Take`` that was re-simulated) and a model with skin triangles: the layout
    of ``wface.io.usd.write_take``, as ``wface track`` and ``wface edit`` write it (``/<name>/Skin``
    with model node ids, ``Bones/Cranium`` and ``Bones/Cranium/Jaw`` from the take's bones, the
    ``Muscles`` activations, min(drive, 1) as in ``wface edit`` stages, the take's force-length
    scales in the layer metadata), so ``wface.io.usd.read_take`` reads it back and the tracked,
    edited and dynamic stages of one take line up prim for prim.

    Args:
        path: ``.usdc`` (binary) or ``.usda`` (text).
        model: the face.
        positions_m: (T, n, 3) node positions, metres.
        fps: frame rate (the stage's timeCodesPerSecond).
        take: optional, the re-simulated take (T frames).
    """
    from wface.io.usd import write_mesh_animation

    positions_m = np.asarray(positions_m)
    if positions_m.ndim != 3 or positions_m.shape[1:] != (model.n_nodes, 3):
        raise ValueError(f"positions_m must have shape (frames, {model.n_nodes}, 3), got {positions_m.shape}")
    if take is not None and model.skin_triangles.size:
        from wface.controls import bone_affines
        from wface.io.usd import write_take

        if take.n_frames != positions_m.shape[0]:
            raise ValueError(f"take has {take.n_frames} frames, positions_m {positions_m.shape[0]}")
        affines = {}
        if take.bones is not None:
            cranium, jaw = (np.stack(a) for a in zip(*(bone_affines(b) for b in take.bones), strict=True))
            affines = {"cranium_affines": cranium, "jaw_affines": jaw}
        meta = {"dynamic": True, "source": take.source}
        acts = take.activations
        if take.force_length_scale is not None:
            meta["force_length_scale"] = take.force_length_scale.tolist()
            # activation curves as `wface edit` writes them, min(drive, 1), so the stages compare
            acts = np.minimum(acts * take.force_length_scale, 1.0)
        return write_take(
            path,
            model=model,
            node_positions_m=positions_m,
            fps=fps,
            activations=acts,
            name=name,
            metadata=meta,
            **affines,
        )
    nodes, tri = skin_mesh(model)
    return write_mesh_animation(
        path, points_m=positions_m[:, nodes], face_vertex_counts=None, face_vertex_indices=tri, fps=fps, name=name
    )


def write_resim_npz(path: str | Path, result: ResimResult, *, reference_positions_m: np.ndarray | None = None) -> Path:
    """positions_m (T, n, 3), fps, scheme, the per-frame stats (and the quasistatic reference)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "positions_m": result.positions_m,
        "fps": np.float64(result.fps),
        "kinetic_energy_j": result.kinetic_energy_j,
        "newton_iterations": result.newton_iterations,
        "residual_rel": result.residual_rel,
        "inverted_elements": result.inverted_elements,
        "summary_json": np.frombuffer(
            json.dumps({k: v for k, v in result.summary().items() if not isinstance(v, list)}).encode(), dtype=np.uint8
        ),
    }
    if reference_positions_m is not None:
        arrays["reference_positions_m"] = reference_positions_m
    np.savez(path, **arrays)
    return path


# ---------------------------------------------------------------------- simulation
def quasistatic_frames(
    sim,
    activations: np.ndarray,
    attached_positions_m: np.ndarray,
    *,
    progress: bool = False,
    tol: float = 1e-6,
    contact=None,
) -> np.ndarray:
    """(T, n, 3) quasistatic equilibria of every frame (warm-started from the previous frame),
    with the optional ``contact`` (``wface.physics.contact.Contact``)."""
    from tqdm.auto import tqdm

    out, x = [], None
    for a, xc in tqdm(
        list(zip(activations, attached_positions_m, strict=True)),
        desc="quasistatic",
        disable=not progress,
        unit="frame",
    ):
        eq = sim.solve(a, xc, x, tol=tol, contact=contact)
        x = eq.x
        out.append(x)
    return np.array(out)


def resimulate(
    model,
    take: Take,
    *,
    frame: str = "world",
    scheme: str = "midpoint",
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
        take: activations and bone motion per frame (``Take`` / ``load_take``).
        frame: "world" (default, head motion drives inertia) or "cranium" (see module docstring).
        scheme: "midpoint" (second order, default) or "be" (backward Euler).
        substeps: time steps per frame interval (dt = 1 / (fps substeps)).
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
    from tqdm.auto import tqdm

    from wface.controls import attached_positions
    from wface.physics import Simulator

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
    acts = np.array([model.activation_vector(a) for a in take.activations])
    xc = take_attached_positions(model, take, frame=frame)
    T = take.n_frames
    from wface.physics.simulator import count_inverted

    saved_scale = sim.force_length_scale  # restored below, also when a solve fails
    if take.force_length_scale is not None:
        sim.force_length_scale = take.force_length_scale
    t0 = time.perf_counter()
    try:
        if x0_m is None:
            eq = sim.solve(acts[0], xc[0], tol=tol, contact=contact)
            x0, its0, res0 = eq.x, eq.iterations, eq.residual_rel
        else:
            x0, its0, res0 = x0_m, 0, 0.0
        state = dyn.initial_state(x0, None, acts[0])
        first = StepStats(
            newton_iterations=its0,
            residual_rel=res0,
            elastic_energy_j=sim.energy(x0, acts[0]),
            inverted_elements=count_inverted(model, x0),
            seconds=time.perf_counter() - t0,
        )
    except BaseException:
        dyn.free()
        sim.force_length_scale = saved_scale
        raise
    positions = np.empty((T, model.n_nodes, 3))
    positions[0] = state.x_m
    stats = [first]
    bar = tqdm(total=T - 1, desc=f"resim {scheme}", disable=not progress, unit="frame")
    try:
        for k in range(1, T):
            path = xc[k]
            if take.bones is not None and take.attached_positions_m is None:
                b0, b1 = take.bones[k - 1], take.bones[k]

                def path(s, b0=b0, b1=b1):
                    return attached_positions(model, interpolate_bones(b0, b1, s), frame=frame)

            state, st = dyn.advance(
                state, 1.0 / take.fps, substeps, acts[k], path, activation_ramp=take.activation_ramp, on_step=on_step
            )
            if not np.all(np.isfinite(state.x_m)):
                raise FloatingPointError(f"the dynamic solve produced NaN/inf at frame {k}")
            positions[k] = state.x_m
            stats.append(st)
            bar.update(1)
            bar.set_postfix(newton=st.newton_iterations, ke=f"{st.kinetic_energy_j:.2e}")
    finally:
        bar.close()
        dyn.free()
        sim.force_length_scale = saved_scale
    if frame == "cranium":
        positions = cranium_to_world(take, positions)
    return ResimResult(
        positions_m=positions,
        fps=take.fps,
        scheme=scheme,
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
