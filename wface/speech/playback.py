"""Play an ArtiSynth speech gesture on a face model: excitations -> quasistatic equilibria -> lip opening.

For each frame time t_f = t_start + f / fps (f = 0 .. F-1, the last frame at the gesture's end),
the activations a(t_f) come from the gesture's excitation curves (``wface.speech.gestures``),
mapped to the model's muscles (both sides). Each frame solves the quasistatic equilibrium
f(x, a(t_f)) = 0 with the bones at rest (the gestures drive lip muscles only; the jaw stays
closed), warm-started from the previous frame's equilibrium: successive frames differ by a small
activation step, so Newton converges in a few iterations where a cold start from rest needs many
(measured on the Badin face at a = 0.3: 26 iterations cold, 2 warm).

This quasistatic playback is the default: a sequence of equilibria, in which the curves' timing
only sets which activation each frame sees. ``dynamics=GestureDynamics()`` (``wface speech
--dynamic``) plays the curves through the implicit dynamic FEM instead (``wface.speech.dynamic``:
inertia, ArtiSynth's damping and gravity, the curves sampled at every time step).

Lip opening area (``lip_opening_area_mm2``): the mouth aperture seen in an orthographic view, in
mm^2, measured as speech scientists and ArtiSynth's ``BadinFaceDemoLipOpening`` measure it
(``wface.speech.aperture``; the occluders are the face's boundary triangles, bones and teeth are not,
and only apertures near the lip surfaces count). The view is ``ApertureView.for_model``: ArtiSynth's
camera and green plane for the Badin face.

Lip opening: the distance between the upper- and lower-lip midline skin markers (``Mouth_Up``,
``Mouth_Down``), in millimetres. It is the marker-to-marker distance across both lips' vermilion,
not the gap between the lips, and not the original's lip-opening *area*. ``lip_vertical_mm`` is its
signed vertical part (model +y is up): it would turn negative if the markers crossed when the
lips interpenetrate, which they do without contact.

Contact (``contact=``, ``wface speech --contact lips``): each frame is solved with lip self-contact on
ArtiSynth's lip collision surfaces (``wface.physics.contact``); every frame reports the smallest
signed distance between the lip surfaces (``lip_gap_mm``: negative = overlap) and the deepest
penetration (``max_penetration_mm``), with or without contact, so the two runs compare.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from wface.controls import IDENTITY_BONES, jaw_from_intuitive
from wface.mesh.align import align_to_surface
from wface.mesh.closest import SurfaceQuery
from wface.mesh.surface import boundary_faces
from wface.physics.contact import Contact
from wface.physics.contact_solve import solve_restarted
from wface.physics.simulator import Simulator
from wface.speech.aperture import ApertureView, aperture_area
from wface.speech.dynamic import GestureDynamics, play_dynamic
from wface.speech.gestures import map_gesture_to_model
from wface.tracking.sequence import embed_model_markers

__all__ = [
    "GestureResult",
    "compare_with_reference",
    "gesture_times",
    "lip_area_points",
    "lip_opening_mm",
    "performance_controls",
    "select_capture_markers",
    "simulate_controls",
    "simulate_gesture",
    "summarize",
]


@dataclass
class GestureResult:
    """A played gesture. Shapes: F frames, M muscles, n nodes, k markers."""

    gesture: str
    fps: float
    times_s: np.ndarray  # (F,)
    activations: np.ndarray  # (F, M)
    node_positions_m: np.ndarray  # (F, n, 3)
    markers_m: np.ndarray  # (F, k, 3)
    marker_names: list[str]
    lip_opening_mm: np.ndarray  # (F,)
    lip_vertical_mm: np.ndarray  # (F,) signed (Mouth_Up - Mouth_Down) . up: negative once the markers cross
    newton_iterations: np.ndarray  # (F,)
    residual_rel: np.ndarray  # (F,)
    converged: np.ndarray  # (F,) bool
    inverted_elements: np.ndarray  # (F,)
    seconds: np.ndarray  # (F,) per-frame solve time
    mapping: dict = field(default_factory=dict)
    lip_gap_mm: np.ndarray | None = None  # (F,) smallest signed lip-lip distance (negative: overlap)
    max_penetration_mm: np.ndarray | None = None  # (F,) deepest lip-lip penetration
    contact: str | None = None  # the contact regions used, or None
    notes: list[str] = field(default_factory=list)
    lip_opening_area_mm2: np.ndarray | None = None  # (F,) mouth aperture, wface.speech.aperture
    lip_opening_area_error_mm2: np.ndarray | None = None  # (F,) its discretisation error estimate
    lip_opening_width_mm: np.ndarray | None = None  # (F,) its extent across the image
    lip_opening_height_mm: np.ndarray | None = None  # (F,) and up the image
    window_seen_mm2: np.ndarray | None = None  # (F,) all of the window seen, mouth or not: what
    # ArtiSynth's BadinFaceDemoLipOpening measures (it counts every green pixel of its viewer)
    area_view: dict | None = None  # the ApertureView, as a dict
    area_resolution_m: float | None = None
    mode: str = "quasistatic"  # or "dynamic"
    dynamics: dict | None = None  # the GestureDynamics (and density) of a dynamic playback
    kinetic_energy_j: np.ndarray | None = None  # (F,) dynamic playback only


def gesture_times(t_start: float, t_end: float, fps: float, *, max_frames: int | None = None) -> np.ndarray:
    """Frame times at ``fps`` from ``t_start`` through ``t_end`` (the end is always a frame).

    With ``max_frames``, the frames are subsampled to at most that many, evenly over the duration
    (first and last kept), e.g. for a short test.
    """
    if not (fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    n = int(np.floor((t_end - t_start) * fps + 1e-9)) + 1
    t = t_start + np.arange(n) / fps
    if t[-1] < t_end - 1e-9:
        t = np.append(t, t_end)
    if max_frames is not None and len(t) > max_frames:
        if max_frames < 2:
            raise ValueError("max_frames must be at least 2")
        t = t[np.unique(np.round(np.linspace(0, len(t) - 1, max_frames)).astype(int))]
    return t


def lip_opening_mm(
    markers_m: np.ndarray, marker_names, *, upper: str = "Mouth_Up", lower: str = "Mouth_Down"
) -> np.ndarray:
    """Distance (mm) between the ``upper`` and ``lower`` markers; ``markers_m`` is (F, k, 3) or (k, 3)."""
    names = list(marker_names)
    for n in (upper, lower):
        if n not in names:
            raise KeyError(f"marker {n!r} not in the model's markers {names}")
    m = np.asarray(markers_m, dtype=np.float64)
    return 1e3 * np.linalg.norm(m[..., names.index(upper), :] - m[..., names.index(lower), :], axis=-1)


def lip_area_points(model) -> np.ndarray | None:
    """Node ids of the lip surfaces (``upper_lip`` / ``lower_lip``), near which apertures count as
    the mouth's (``aperture_area(near_points_m=...)``), or None for a model without them."""
    groups = [g for g in ("upper_lip", "lower_lip") if g in model.surface_groups]
    return np.unique(np.concatenate([model.surface_groups[g] for g in groups])) if groups else None


def simulate_gesture(
    model,
    gesture,
    *,
    fps: float = 100.0,
    max_frames: int | None = None,
    mapping=None,
    tol: float = 1e-4,
    simulator=None,
    progress: bool = False,
    contact=None,
    max_iterations: int = 40,
    dynamics: GestureDynamics | None = None,
    view: ApertureView | None = None,
    area_resolution_m: float = 5e-5,
) -> GestureResult:
    """Drive ``model`` through ``gesture`` (a ``SpeechGesture``) at ``fps``: warm-started equilibria,
    or the dynamic FEM with ``dynamics``.

    Args:
        model: a ``FaceModel`` with the gesture's muscles (the imported Badin face).
        gesture: from ``wface.speech.gestures.read_gesture``.
        fps: frame rate (ArtiSynth records this gesture's output every 0.01 s, i.e. 100 fps).
        max_frames: subsample to at most this many frames (first and last kept).
        mapping: a ``GestureMapping`` (default ``map_gesture_to_model(gesture, model)``).
        tol: relative force residual of each quasistatic solve.
        simulator: a ``wface.physics.simulator.Simulator`` to reuse.
        progress: print one line per frame.
        contact: a ``wface.physics.contact.Contact`` used in every solve (or step), or None.
        max_iterations: Newton iteration cap per quasistatic frame.
        dynamics: a ``wface.speech.dynamic.GestureDynamics`` to play the curves dynamically; None
            (default): quasistatic.
        view: the lip-opening-area camera and window (default ``ApertureView.for_model(model)``).
        area_resolution_m: scanline spacing of the area measure (m).
    """

    mapping = mapping or map_gesture_to_model(gesture, model)
    t0, t1 = gesture.duration_s
    times = gesture_times(t0, t1, fps, max_frames=max_frames)
    sim = simulator or Simulator(model)
    if dynamics is not None:
        run = play_dynamic(sim, gesture, mapping, times, dynamics=dynamics, contact=contact, progress=progress)
    else:
        run = _play_quasistatic(sim, gesture, mapping, times, tol, max_iterations, contact, progress)
    return _result(model, gesture, mapping, fps, times, run, contact, dynamics, view, area_resolution_m)


def _play_quasistatic(sim, gesture, mapping, times, tol, max_iterations, contact, progress) -> dict:
    """Warm-started equilibria at ``times`` (module docstring), as per-frame arrays."""
    model = sim.model
    A = mapping.activations(gesture, model, times)
    F = len(times)
    run = {
        "x_m": np.empty((F, model.n_nodes, 3)),
        "activations": A,
        "newton_iterations": np.zeros(F, dtype=int),
        "residual_rel": np.zeros(F),
        "converged": np.zeros(F, dtype=bool),
        "inverted_elements": np.zeros(F, dtype=int),
        "seconds": np.zeros(F),
    }
    x_prev = None
    for f in range(F):
        if contact is None:
            eq = sim.solve(activations=A[f], x0=x_prev, tol=tol, max_iterations=max_iterations)
        else:  # Newton restarted every few iterations (wface.physics.contact_solve)
            eq = solve_restarted(sim, A[f], None, x_prev, tol=tol, max_iterations=max_iterations, contact=contact)
        run["x_m"][f] = x_prev = eq.x
        for key in ("iterations", "residual_rel", "converged", "inverted_elements", "seconds"):
            run["newton_iterations" if key == "iterations" else key][f] = getattr(eq, key)
        if progress:
            print(
                f"{gesture.name} frame {f + 1}/{F} t={times[f]:.3f}s: {eq.iterations} Newton its, "
                f"residual {eq.residual_rel:.1e}, {eq.seconds:.1f} s",
                flush=True,
            )
    return run


def _result(model, gesture, mapping, fps, times, run, contact, dynamics, view, resolution_m) -> GestureResult:
    """The ``GestureResult`` of a playback: markers, lip opening and area, lip gap per frame."""
    X = run["x_m"]
    F = len(times)
    markers = embed_model_markers(model)
    Mk = np.stack([markers.positions(x) for x in X])
    lips = None
    if "upper_lip" in model.surface_groups and "lower_lip" in model.surface_groups:
        lips = contact if contact is not None and contact.self_contact else Contact(model, regions="lips")
    gap = np.array([lips.self_distance_m(x) * 1e3 for x in X]) if lips is not None else np.full(F, np.nan)
    view = view or ApertureView.for_model(model)
    occluders = boundary_faces(model.tets)
    near = lip_area_points(model)
    area = [
        aperture_area(x, occluders, view, resolution_m=resolution_m, near_points_m=None if near is None else x[near])
        for x in X
    ]
    up, down = model.marker_names.index("Mouth_Up"), model.marker_names.index("Mouth_Down")
    return GestureResult(
        gesture=gesture.name,
        fps=float(fps),
        times_s=times,
        activations=run["activations"],
        node_positions_m=X,
        markers_m=Mk,
        marker_names=list(model.marker_names),
        lip_opening_mm=lip_opening_mm(Mk, model.marker_names),
        lip_vertical_mm=1e3 * (Mk[:, up, 1] - Mk[:, down, 1]),
        newton_iterations=run["newton_iterations"],
        residual_rel=run["residual_rel"],
        converged=run["converged"],
        inverted_elements=run["inverted_elements"],
        seconds=run["seconds"],
        mapping=dict(mapping.muscles),
        notes=list(mapping.notes),
        lip_gap_mm=gap,
        max_penetration_mm=np.maximum(-gap, 0.0),
        contact=None if contact is None else ",".join(contact.regions) or "obstacles",
        lip_opening_area_mm2=np.array([a.area_mm2 for a in area]),
        lip_opening_area_error_mm2=np.array([a.error_mm2 for a in area]),
        lip_opening_width_mm=np.array([a.width_mm for a in area]),
        lip_opening_height_mm=np.array([a.height_mm for a in area]),
        window_seen_mm2=np.array([a.window_seen_mm2 for a in area]),
        area_view=view.to_dict(),
        area_resolution_m=float(resolution_m),
        mode="quasistatic" if dynamics is None else "dynamic",
        dynamics=None if dynamics is None else dynamics.to_dict(model),
        kinetic_energy_j=run.get("kinetic_energy_j"),
    )


def summarize(result: GestureResult) -> dict:
    """JSON-ready summary of a played gesture."""
    lo = result.lip_opening_mm
    return {
        "gesture": result.gesture,
        "frames": int(len(result.times_s)),
        "fps": result.fps,
        "duration_s": [float(result.times_s[0]), float(result.times_s[-1])],
        "lip_opening_mm": {
            "first": float(lo[0]),
            "last": float(lo[-1]),
            "min": float(lo.min()),
            "max": float(lo.max()),
            "change": float(lo[-1] - lo[0]),
        },
        "lip_vertical_mm": {
            "first": float(result.lip_vertical_mm[0]),
            "last": float(result.lip_vertical_mm[-1]),
            "min": float(result.lip_vertical_mm.min()),
        },
        "mode": result.mode,
        "dynamics": result.dynamics,
        "lip_opening_area_mm2": _list(result.lip_opening_area_mm2),
        "lip_opening_area_summary_mm2": _stats(result.lip_opening_area_mm2),
        "lip_opening_area_error_mm2_max": _num(np.max(result.lip_opening_area_error_mm2))
        if result.lip_opening_area_error_mm2 is not None
        else None,
        "lip_opening_width_mm": _list(result.lip_opening_width_mm),
        "lip_opening_height_mm": _list(result.lip_opening_height_mm),
        "window_seen_mm2": _list(result.window_seen_mm2),
        "lip_opening_area_view": result.area_view,
        "lip_opening_area_resolution_m": result.area_resolution_m,
        "kinetic_energy_j": _list(result.kinetic_energy_j),
        "probe_to_muscles": result.mapping,
        "notes": result.notes,
        "newton_iterations": result.newton_iterations.tolist(),
        "residual_rel_max": float(result.residual_rel.max()),
        "all_converged": bool(result.converged.all()),
        "inverted_elements_max": int(result.inverted_elements.max()),
        "seconds_per_frame": result.seconds.tolist(),
        "seconds_total": float(result.seconds.sum()),
        "contact": result.contact,
        "lip_gap_mm": None if result.lip_gap_mm is None else [_num(v) for v in result.lip_gap_mm],
        "lip_gap_mm_min": _num(np.nanmin(result.lip_gap_mm)) if _any(result.lip_gap_mm) else None,
        "max_penetration_mm": None
        if result.max_penetration_mm is None
        else [_num(v) for v in result.max_penetration_mm],
        "max_penetration_mm_max": _num(np.nanmax(result.max_penetration_mm))
        if _any(result.max_penetration_mm)
        else None,
    }


def _list(a) -> list | None:
    return None if a is None else [_num(v) for v in a]


def _stats(a) -> dict | None:
    if a is None or not len(a):
        return None
    return {"first": _num(a[0]), "last": _num(a[-1]), "min": _num(np.min(a)), "max": _num(np.max(a))}


def _any(a) -> bool:
    return a is not None and bool(np.isfinite(a).any())


def _num(v) -> float | None:
    v = float(v)
    return v if np.isfinite(v) else None


def select_capture_markers(
    model,
    positions_m: np.ndarray,
    marker_names,
    *,
    max_distance_mm: float = 5.0,
    reference_frame: int = 0,
) -> dict:
    """Capture markers that land on a partial face's skin (e.g. the lower-face Badin model).

    A capture of the whole face (AnimFace: forehead, eyes, cheeks, nose, mouth, chin) on a model
    that covers only part of it: the markers whose names the model also has (``Mouth_Up``,
    ``Chin``, ...) give a similarity transform (``wface.mesh.align.align_to_surface`` on those markers
    alone, landmarks pulled to the model's markers, iterated with projection onto the skin); every
    marker of ``reference_frame`` is mapped by it and kept when it lies within ``max_distance_mm``
    of the skin. The kept markers then go to ``wface.tracking.capture.prepare_capture``.

    Args:
        model: the face.
        positions_m: (F, k, 3) capture in metres.
        marker_names: k names.
        max_distance_mm: largest distance from the aligned marker to the skin.
        reference_frame: the frame used for the alignment.

    Returns:
        dict with ``indices`` (kept, ascending), ``names`` (kept), ``distance_mm`` (k,) of every
        marker, ``landmarks`` (names used for the alignment), ``scale`` and ``landmark_rms_mm``.
    """

    names = list(marker_names)
    ref = np.asarray(positions_m, dtype=np.float64)[reference_frame]
    known = dict(zip(model.marker_names, model.marker_positions_m, strict=True))
    idx = [i for i, n in enumerate(names) if n in known and np.isfinite(ref[i]).all()]
    if len(idx) < 3:
        raise ValueError(f"need at least 3 capture markers named like the model's {list(known)}; found {len(idx)}")
    skin_nodes = np.unique(model.skin_triangles)
    tree = cKDTree(model.rest_positions_m[skin_nodes])
    landmarks = np.array([skin_nodes[tree.query(known[names[i]])[1]] for i in idx])
    al = align_to_surface(
        ref[idx],
        model.rest_positions_m,
        model.skin_triangles,
        landmark_vertices=landmarks,
        with_scale=True,
        landmark_weight=1.0,
    )
    mapped = al.transform.apply(ref)
    dist = np.full(len(names), np.inf)
    ok = np.isfinite(mapped).all(axis=1)
    dist[ok] = SurfaceQuery(model.rest_positions_m, model.skin_triangles).closest(mapped[ok]).distance_m * 1e3
    keep = np.flatnonzero(dist <= max_distance_mm)
    lm_err = mapped[idx] - np.array([known[names[i]] for i in idx])
    return {
        "indices": keep,
        "names": [names[i] for i in keep],
        "distance_mm": dist,
        "landmarks": [names[i] for i in idx],
        "scale": float(al.transform.scale),
        "landmark_rms_mm": float(np.sqrt((lm_err**2).sum(axis=1).mean()) * 1e3),
        "max_distance_mm": float(max_distance_mm),
    }


def performance_controls(
    model,
    frames: int,
    *,
    muscles: tuple[str, ...],
    max_activation: float = 0.5,
    max_jaw_deg: float = 6.0,
    seed: int = 0,
) -> np.ndarray:
    """(F, M + 24) controls of a smooth synthetic performance: muscle bumps and a jaw opening.

    Each listed muscle rises and falls once (sin^2 bump at a random start and length, peak in
    [0.5, 1] x ``max_activation``); the jaw opens by up to ``max_jaw_deg`` about the condyles
    (``wface.controls.jaw_from_intuitive``) with a little protrusion; the cranium stays at rest.
    """

    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, frames) if frames > 1 else np.zeros(1)
    C = np.tile(np.concatenate([np.zeros(model.n_muscles), IDENTITY_BONES]), (frames, 1))
    for name in muscles:
        start, length = rng.uniform(-0.3, 0.3), rng.uniform(0.8, 1.3)
        peak = rng.uniform(0.5, 1.0) * max_activation
        C[:, model.muscle_index(name)] = peak * np.sin(np.pi * np.clip((s - start) / length, 0.0, 1.0)) ** 2
    jaw = max_jaw_deg * np.sin(np.pi * np.clip(0.15 + 0.85 * s, 0.0, 1.0)) ** 2
    M = model.n_muscles
    for f in range(frames):
        C[f, M + 12 :] = jaw_from_intuitive(model.jaw_joint, jaw[f], 0.001 * jaw[f] / max(max_jaw_deg, 1e-9), 0.0)
    return C


def simulate_controls(rig, markers, controls: np.ndarray, *, substeps: int = 3, progress: bool = False) -> dict:
    """Equilibria of a control sequence by continuation: each frame is reached from the previous
    one (the first from rest) in ``substeps`` linear control steps, each warm-started.

    A cold Newton solve from rest to a large jaw opening plus several active muscles can stall on
    the Badin face (measured: residual 0.1 after 40 iterations); small control steps converge in a
    few iterations each.

    Returns:
        dict with ``x_m`` (F, n, 3), ``markers_m`` (F, k, 3), ``converged`` (F,), ``residual_rel`` (F,)
        and ``seconds`` (F,).
    """

    C = np.asarray(controls, dtype=np.float64)
    F = len(C)
    X = np.empty((F, rig.model.n_nodes, 3))
    Mk = np.empty((F, len(markers.embedding.triangle), 3))
    conv, res, secs = np.zeros(F, dtype=bool), np.zeros(F), np.zeros(F)
    c_prev, y = rig.rest_controls(), None
    for f in range(F):
        t0 = time.perf_counter()
        for k in range(1, substeps + 1):
            state = rig.equilibrium(c_prev + (C[f] - c_prev) * k / substeps, y)
            y = state.y_m
        X[f], Mk[f] = state.x_m, markers.positions(state.x_m)
        conv[f], res[f], secs[f] = state.converged, state.residual_rel, time.perf_counter() - t0
        c_prev = C[f]
        if progress:
            print(f"simulated frame {f + 1}/{F}: residual {state.residual_rel:.1e}, {secs[f]:.1f} s", flush=True)
    return {"x_m": X, "markers_m": Mk, "converged": conv, "residual_rel": res, "seconds": secs}


def compare_with_reference(result: GestureResult, reference: np.ndarray | None) -> dict | None:
    """wface's lip opening area against the original's recorded curve ((k, 2) time, area in mm^2).

    Returns None without a reference or an area; else the RMS difference over the reference times
    inside the played span (wface's curve interpolated linearly), and the "settled" (largest value
    before the excitation starts, t <= 0.22 s, where the original has settled under gravity) and
    "final" (mean over t >= 0.6 s) values of both, with their ratios final / settled.
    """
    if reference is None or not len(reference) or result.lip_opening_area_mm2 is None:
        return None
    t, a = result.times_s, result.lip_opening_area_mm2
    ref = np.asarray(reference, dtype=np.float64)
    inside = (ref[:, 0] >= t[0] - 1e-9) & (ref[:, 0] <= t[-1] + 1e-9)
    ours = np.interp(ref[inside, 0], t, a)
    out = {"rms_mm2": float(np.sqrt(np.mean((ours - ref[inside, 1]) ** 2))) if inside.any() else None}
    for name, tt, vv in (("wface", t, a), ("original", ref[:, 0], ref[:, 1])):
        early, late = tt <= 0.22 + 1e-9, tt >= 0.6 - 1e-9
        settled = float(vv[early].max()) if early.any() else None
        final = float(vv[late].mean()) if late.any() else None
        out[name] = {
            "settled_mm2": settled,
            "final_mm2": final,
            "ratio": final / settled if settled and final is not None else None,
        }
    return out
