"""Read the ArtiSynth Badin-face speech gestures: muscle excitation curves and their probes file.

Data: ``../shared/data/artisynth-face/speech/{closure,fricative,approximant}`` (ArtiSynth Models,
BSD-style; cite Nazari et al. 2010 and Stavness et al.). Each folder holds ``0probes.art`` (the
ArtiSynth probe list) and one ``.txt`` file per input probe.

Curve file (ArtiSynth ``NumericProbe`` text format):

- line 1 ``t0 t1 scale``: the probe's start and stop time (s) and a scale factor that multiplies
  every data value;
- line 2 ``ORDER VSIZE explicit|STEP``: the interpolation order (``Step``, ``Linear``, ``Parabolic``,
  ``Cubic``, ``CubicStep``, ...), the vector size of each row (1 here), and whether every row starts
  with its own time (``explicit``) or rows are spaced by a fixed time step ``STEP`` (implicit times);
- then rows ``time value...``; times are local to the probe: absolute time = t0 + time.

Interpolation (maspack ``Interpolation.Order``): ``Step`` holds the previous knot; ``Linear`` is
piecewise linear; ``CubicStep`` is cubic Hermite between neighbouring knots with both slopes set to
zero, i.e. v0 + (v1 - v0) (3 s^2 - 2 s^3), s = (t - ta) / (tb - ta) (smooth plateaus, C1);
``Cubic`` is Catmull-Rom. Outside the knots the end values are held (ArtiSynth extends the data).

Probes file: ``NumericInputProbe [ ... ]`` blocks with ``name``, ``attachedFile``, ``props`` (the
driven property, e.g. ``models/mech/models/badinface/bundles/OOP:excitation``) and an optional
``active=false``. ArtiSynth does not apply an inactive probe, and when a probe has an attached file
the file's data replace the inline ``data=[...]`` (in ``approximant`` they differ: the file peaks at
0.3, the inline copy at 1.0; the file is what ArtiSynth plays).

Mapping to a wface model: the driven bundle ``OOP`` becomes the model muscles ``OOP_l`` and ``OOP_r``
(the Badin face's muscles are bilateral, the original mirrors the left fibres). The exciter ``OOMl``
(probe ``OOMi``: the inferior/lower orbicularis oris marginalis) has no muscle of its own in the
imported model, whose ``OOM_l``/``OOM_r`` run through both lips; it maps to ``OOM_l``/``OOM_r`` as an
approximation (``lower_oom="whole"``, stated in ``GestureMapping.notes``), to the lower lip's part of them
(``lower_oom="lower"`` on a model from ``with_lower_oom``, whose ``OOMl_l``/``OOMl_r`` are that part), or is
left out (``lower_oom="skip"``).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "GESTURES",
    "LOWER_OOM_CHOICES",
    "ExcitationCurve",
    "GestureMapping",
    "Probe",
    "SpeechGesture",
    "held_gesture",
    "interpolate",
    "map_gesture_to_model",
    "read_excitation_curve",
    "read_gesture",
    "read_probes",
    "with_lower_oom",
]

GESTURES = ("closure", "fricative", "approximant")
LOWER_OOM = {"OOM_l": "OOMl_l", "OOM_r": "OOMl_r"}  # with_lower_oom: each side's lower-lip part
LOWER_OOM_CHOICES = ("whole", "lower", "exciter", "skip")  # what the OOMl exciter drives (map_gesture_to_model)
INTERPOLATIONS = ("Step", "Linear", "CubicStep", "Cubic")


@dataclass
class ExcitationCurve:
    """One probe file: knots (probe-local times, raw values), header and interpolation.

    ``values(t)`` gives ``scale * interpolate(t - t0)`` at absolute times ``t`` (s).
    """

    t0: float
    t1: float
    scale: float
    order: str
    vsize: int
    times: np.ndarray  # (k,) probe-local seconds
    data: np.ndarray  # (k, vsize) raw values (before scale)
    path: Path | None = None

    def values(self, t: np.ndarray | float) -> np.ndarray:
        """Scaled value(s) at absolute time(s) ``t``; shape (len(t),) for vsize 1, else (len(t), vsize)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.stack(
            [interpolate(self.times, self.data[:, j], t - self.t0, self.order) for j in range(self.vsize)], 1
        )
        out = self.scale * out
        return out[:, 0] if self.vsize == 1 else out


@dataclass
class Probe:
    """A ``NumericInputProbe`` of ``0probes.art``."""

    name: str
    attached_file: str | None
    target: str  # driven component: bundle or exciter name, e.g. "OOP", "OOMl"
    target_kind: str  # "bundles" or "exciters"
    prop: str
    active: bool
    start_time: float
    stop_time: float
    order: str | None
    inline_data: np.ndarray | None  # (k, 2) time, value from data=[...]


@dataclass
class SpeechGesture:
    """A gesture folder: its probes and the curve each active (or every) probe plays."""

    name: str
    directory: Path
    probes: list[Probe]
    curves: dict[str, ExcitationCurve]  # probe name -> curve (probes that play)
    reference_lip_area: np.ndarray | None = None  # (k, 2) time, lipOpeningArea from the original (if recorded)

    @property
    def duration_s(self) -> tuple[float, float]:
        if not self.curves:
            return 0.0, 0.0
        return min(c.t0 for c in self.curves.values()), max(c.t1 for c in self.curves.values())


@dataclass
class GestureMapping:
    """Probe -> model muscles, and the activation matrix builder."""

    muscles: dict[str, list[str]]  # probe name -> model muscle names
    unmapped: list[str]
    notes: list[str] = field(default_factory=list)

    def activations(self, gesture: SpeechGesture, model, times_s: np.ndarray) -> np.ndarray:
        """(F, M) activations at ``times_s``: each model muscle takes the largest of its probes, clipped to [0, 1]."""
        times_s = np.asarray(times_s, dtype=np.float64)
        A = np.zeros((len(times_s), model.n_muscles))
        for probe, names in self.muscles.items():
            v = gesture.curves[probe].values(times_s)
            for n in names:
                i = model.muscle_index(n)
                A[:, i] = np.maximum(A[:, i], v)
        return np.clip(A, 0.0, 1.0)

    def driven_muscles(self, gesture: SpeechGesture, model) -> list[str]:
        """The model muscles the gesture ever drives above 0 (at its curves' knots and 2,001 times between)."""
        t0, t1 = gesture.duration_s
        knots = [c.t0 + c.times for p, c in gesture.curves.items() if p in self.muscles]
        times = np.concatenate([np.linspace(t0, t1, 2001), *knots])
        drive = self.activations(gesture, model, times).max(axis=0)
        return [model.muscle_names[i] for i in np.flatnonzero(drive > 0)]


def interpolate(knot_t: np.ndarray, knot_v: np.ndarray, t: np.ndarray, order: str) -> np.ndarray:
    """Interpolate knots (ascending times) at ``t`` with ArtiSynth's ``order``; end values held outside."""
    kt = np.asarray(knot_t, dtype=np.float64)
    kv = np.asarray(knot_v, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if order not in INTERPOLATIONS:
        raise ValueError(f"interpolation {order!r} not supported (supported: {', '.join(INTERPOLATIONS)})")
    if kt.size == 1:
        return np.full_like(t, kv[0])
    if np.any(np.diff(kt) < 0):
        raise ValueError("knot times must be ascending")
    tc = np.clip(t, kt[0], kt[-1])
    # segment index i with kt[i] <= t < kt[i+1] (last segment includes its end)
    i = np.clip(np.searchsorted(kt, tc, side="right") - 1, 0, kt.size - 2)
    ta, tb = kt[i], kt[i + 1]
    h = tb - ta
    s = np.where(h > 0, (tc - ta) / np.where(h > 0, h, 1.0), 1.0)
    va, vb = kv[i], kv[i + 1]
    if order == "Step":
        return np.where(tc >= tb, vb, va)
    if order == "Linear":
        return va + s * (vb - va)
    if order == "CubicStep":
        return va + (3.0 * s**2 - 2.0 * s**3) * (vb - va)
    # Catmull-Rom with end knots duplicated
    vp = kv[np.maximum(i - 1, 0)]
    vn = kv[np.minimum(i + 2, kv.size - 1)]
    return 0.5 * (2 * va + (vb - vp) * s + (2 * vp - 5 * va + 4 * vb - vn) * s**2 + (3 * va - vp - 3 * vb + vn) * s**3)


def read_excitation_curve(path: str | Path) -> ExcitationCurve:
    """Parse an ArtiSynth numeric probe file (format in the module docstring)."""
    path = Path(path)
    lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]
    if len(lines) < 2:
        raise ValueError(f"{path}: needs a 't0 t1 scale' line and an interpolation line")
    head = lines[0].split()
    if len(head) != 3:
        raise ValueError(f"{path}: first line must be 't0 t1 scale', got {lines[0]!r}")
    try:
        t0, t1, scale = (float(v) for v in head)
    except ValueError:
        raise ValueError(f"{path}: first line must be 't0 t1 scale' (numbers), got {lines[0]!r}") from None
    spec = lines[1].split()
    if len(spec) < 3:
        raise ValueError(f"{path}: second line must be 'ORDER VSIZE explicit|STEP', got {lines[1]!r}")
    order, vsize = spec[0], int(spec[1])
    rows = []
    for k, ln in enumerate(lines[2:], start=3):
        try:
            rows.append(np.array(ln.split(), dtype=np.float64))
        except ValueError:
            raise ValueError(f"{path}: data row {k} holds a value that is not a number: {ln!r}") from None
        if not np.all(np.isfinite(rows[-1])):
            raise ValueError(f"{path}: data row {k} holds NaN or inf: {ln!r}")
    if spec[2] == "explicit":
        if any(r.size != vsize + 1 for r in rows):
            raise ValueError(f"{path}: explicit rows must hold a time and {vsize} value(s)")
        arr = np.array(rows).reshape(-1, vsize + 1)
        times, data = arr[:, 0], arr[:, 1:]
    else:
        step = float(spec[2])
        if any(r.size != vsize for r in rows):
            raise ValueError(f"{path}: implicit-time rows must hold {vsize} value(s)")
        data = np.array(rows).reshape(-1, vsize)
        times = step * np.arange(len(data))
    if order not in INTERPOLATIONS:
        raise ValueError(f"{path}: interpolation {order!r} not supported")
    return ExcitationCurve(t0, t1, scale, order, vsize, times, data, path)


_BLOCK = re.compile(r"(NumericInputProbe|NumericOutputProbe|WayPointProbe)\s*\[")


def _field(block: str, key: str) -> str | None:
    m = re.search(rf"^\s*{key}=(.*)$", block, flags=re.M)
    return m.group(1).strip() if m else None


def read_probes(path: str | Path) -> tuple[list[Probe], list[dict]]:
    """Parse ``0probes.art``: (input probes, output probes as dicts with name / attachedFile / props)."""
    text = Path(path).read_text()
    starts = [(m.start(), m.group(1)) for m in _BLOCK.finditer(text)]
    inputs, outputs = [], []
    for k, (pos, kind) in enumerate(starts):
        block = text[pos : starts[k + 1][0] if k + 1 < len(starts) else len(text)]
        name = (_field(block, "name") or "").strip('"')
        attached = _field(block, "attachedFile")
        attached = attached.strip('"') if attached else None
        props = re.search(r"props=\[\s*\"([^\"]+)\"", block)
        prop = props.group(1) if props else ""
        if kind == "NumericOutputProbe":
            outputs.append({"name": name, "attachedFile": attached, "props": prop})
            continue
        if kind != "NumericInputProbe":
            continue
        m = re.search(r"/(bundles|exciters)/([^/:]+):excitation$", prop)
        if not m:
            raise ValueError(f"{path}: probe {name!r} drives {prop!r}, not a bundle or exciter excitation")
        data = re.search(r"data=\[(.*?)\]", block, flags=re.S)
        inline = np.array(data.group(1).split(), dtype=np.float64).reshape(-1, 2) if data else None
        inputs.append(
            Probe(
                name=name,
                attached_file=attached,
                target=m.group(2),
                target_kind=m.group(1),
                prop=prop,
                active=(_field(block, "active") or "true").lower() != "false",
                start_time=float(_field(block, "startTime") or 0.0),
                stop_time=float(_field(block, "stopTime") or 0.0),
                order=_field(block, "interpolationOrder"),
                inline_data=inline,
            )
        )
    return inputs, outputs


def read_gesture(directory: str | Path, *, include_inactive: bool = False) -> SpeechGesture:
    """Read a gesture folder. By default only the probes ArtiSynth plays (active ones) are kept in ``curves``."""
    directory = Path(directory)
    probes, outputs = read_probes(directory / "0probes.art")
    curves: dict[str, ExcitationCurve] = {}
    for p in probes:
        if not (p.active or include_inactive):
            continue
        if p.attached_file and (directory / p.attached_file).exists():
            curves[p.name] = read_excitation_curve(directory / p.attached_file)
        elif p.inline_data is not None:
            curves[p.name] = ExcitationCurve(
                p.start_time, p.stop_time, 1.0, p.order or "Linear", 1, p.inline_data[:, 0], p.inline_data[:, 1:]
            )
        else:
            raise ValueError(f"{directory}: probe {p.name!r} has neither an attached file nor inline data")
        e = curves[p.name].scale * curves[p.name].data
        if e.size and (e.min() < 0.0 or e.max() > 1.0):
            warnings.warn(
                f"{directory}: probe {p.name}'s excitation runs from {e.min():.3g} to {e.max():.3g}; it is played "
                "clipped to [0, 1]",
                stacklevel=2,
            )
    ref = None
    for o in outputs:
        f = directory / (o["attachedFile"] or "")
        if o["props"] == "lipOpeningArea" and f.is_file():
            c = read_excitation_curve(f)
            if c.times.size:
                ref = np.column_stack([c.t0 + c.times, c.scale * c.data[:, 0]])
    return SpeechGesture(directory.name, directory, probes, curves, ref)


def held_gesture(gesture: SpeechGesture, levels, *, probe: str = "OOP") -> SpeechGesture:
    """``gesture`` with only ``probe`` playing, held at each of ``levels`` in turn for one second.

    The curve is a Step through (k, levels[k]), k = 0, 1, ..., so played at 1 fps
    (``simulate_gesture(..., fps=1)``) frame k is the equilibrium under ``levels[k]``, warm-started
    from the frame before: the quasistatic response to a held excitation (docs/design.md, "Speech
    gestures").

    Args:
        gesture: from ``read_gesture``.
        levels: excitations in [0, 1], in the order to hold them.
        probe: the probe to hold (its target muscle is driven; every other probe is left out).
    """
    v = np.asarray(levels, dtype=np.float64).ravel()
    if v.size == 0 or not np.all(np.isfinite(v)) or v.min() < 0 or v.max() > 1:
        raise ValueError(f"held levels must be a non-empty list of values in [0, 1], got {list(levels)}")
    if probe not in {p.name for p in gesture.probes}:
        raise ValueError(
            f"gesture {gesture.name!r} has no probe {probe!r} (probes: {[p.name for p in gesture.probes]})"
        )
    k = np.arange(v.size, dtype=np.float64)
    curve = ExcitationCurve(0.0, float(v.size - 1), 1.0, "Step", 1, k, v[:, None])
    return replace(gesture, name=f"{gesture.name} ({probe} held)", curves={probe: curve}, reference_lip_area=None)


def with_lower_oom(model, lower_tets=None):
    """The model with the lower lip's part of ``OOM_l`` and ``OOM_r`` as muscles of their own, ``OOMl_l`` and
    ``OOMl_r``: what ArtiSynth's exciter ``OOMl`` drives (its targets are the OOM bundle's elements in the lower lip,
    ``artisynth_models``' ``face/exciters/OOMl.art``). A fibre entry is the lower lip's when its tet is in
    ``lower_tets`` ((n_tets,) bool; ``wface.speech.artisynth_demo.ooml_exciter_tets`` gives the exciter's own
    targets) or, without it, when its tet's centroid lies nearer a node of the lower lip's collision surface
    (surface group ``lower_lip``) than one of the upper lip's. The new muscles keep their side's strength and own
    curves (``Material.muscle_curves``); the FACS table is not changed. Played with every OOM part at one
    activation the model is the one it was."""
    missing = [
        n for n in (*LOWER_OOM, "upper_lip", "lower_lip") if n not in (*model.muscle_names, *model.surface_groups)
    ]
    if missing:
        raise ValueError(f"with_lower_oom needs the Badin face's OOM_l, OOM_r and lip surfaces; missing {missing}")
    if lower_tets is None:
        x = model.rest_positions_m
        centroid = x[model.tets[model.fibre_tet]].mean(axis=1)
        d_up, _ = cKDTree(x[np.unique(model.surface_groups["upper_lip"])]).query(centroid)
        d_low, _ = cKDTree(x[np.unique(model.surface_groups["lower_lip"])]).query(centroid)
        in_lower = d_low < d_up
    else:
        lower_tets = np.asarray(lower_tets, dtype=bool)
        if lower_tets.shape != (len(model.tets),):
            raise ValueError(f"lower_tets: expected ({len(model.tets)},) bools, one per tet, got {lower_tets.shape}")
        in_lower = lower_tets[model.fibre_tet]
    names, muscle = list(model.muscle_names), model.fibre_muscle.copy()
    strength, curves = list(model.muscle_strength), dict(model.material.muscle_curves)
    for side, lower in LOWER_OOM.items():
        i = names.index(side)
        muscle[(model.fibre_muscle == i) & in_lower] = len(names)
        names.append(lower)
        strength.append(model.muscle_strength[i])
        if side in curves:
            curves[lower] = curves[side]
    meta = dict(model.metadata, lower_oom=dict(LOWER_OOM))
    material = replace(model.material, muscle_curves=curves)
    out = replace(model, muscle_names=names, fibre_muscle=muscle, muscle_strength=np.array(strength), material=material)
    return replace(out, metadata=meta).validate()


def map_gesture_to_model(gesture: SpeechGesture, model, *, lower_oom: str = "whole") -> GestureMapping:
    """Map each playing probe to the model muscles it drives (both sides of a bilateral muscle).

    Args:
        gesture: from ``read_gesture``.
        model: a ``FaceModel`` with Badin muscle names (``OOP_l``, ``OOP_r``, ...).
        lower_oom: what the ``OOMl`` exciter drives: ``"whole"`` (the model's ``OOM_l``/``OOM_r``, an
            approximation: they span both lips), ``"lower"`` (their lower lip's part, ``OOMl_l``/``OOMl_r`` of a
            model from ``with_lower_oom``; the bundle ``OOM`` then drives every part), ``"exciter"`` (the same,
            the model split on the exciter's own targets, ``with_lower_oom(model, ooml_exciter_tets(...))``) or
            ``"skip"``.
    """
    if lower_oom not in LOWER_OOM_CHOICES:
        *first, last = (repr(c) for c in LOWER_OOM_CHOICES)
        raise ValueError(f"lower_oom must be {', '.join(first)} or {last}, got {lower_oom!r}")
    names = list(model.muscle_names)
    split = all(n in names for n in LOWER_OOM.values())
    if lower_oom in ("lower", "exciter") and not split:
        raise ValueError(f"lower_oom={lower_oom!r} drives OOMl_l and OOMl_r: split the model first (with_lower_oom)")
    muscles: dict[str, list[str]] = {}
    unmapped: list[str] = []
    notes: list[str] = []
    by_probe = {p.name: p for p in gesture.probes}
    for probe_name in gesture.curves:
        target = by_probe[probe_name].target
        base = target
        if target == "OOMl":
            if lower_oom == "skip":
                unmapped.append(probe_name)
                notes.append("OOMl (lower orbicularis oris marginalis) left out: the model has no lower-lip-only OOM")
                continue
            if lower_oom in ("lower", "exciter"):
                muscles[probe_name] = list(LOWER_OOM.values())
                notes.append("OOMl (lower orbicularis oris marginalis) drives OOMl_l/OOMl_r, OOM's lower-lip part")
                continue
            base = "OOM"
            notes.append(
                "OOMl (lower orbicularis oris marginalis) drives the model's whole OOM_l/OOM_r, which also run "
                "through the upper lip (approximation)"
            )
        found = [n for n in names if n == base or n.rsplit("_", 1)[0] == base]
        if base == "OOM" and split:  # the bundle drives its lower-lip part too
            found += list(LOWER_OOM.values())
        if found:
            muscles[probe_name] = found
        else:
            unmapped.append(probe_name)
            notes.append(f"probe {probe_name} drives {target}, which the model does not have")
    return GestureMapping(muscles, unmapped, notes)
