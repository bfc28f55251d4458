"""Play the ArtiSynth speech gestures on the imported Badin face: lip opening area, quasistatic and dynamic.

Each gesture (closure, fricative, approximant) drives the face's muscles through its measured-style
excitation curves (both sides of each muscle). Every variant plays it one way:

- ``quasistatic``: warm-started equilibria, one per frame (``wface speech``'s default);
- ``dynamic``: the implicit dynamic FEM with ArtiSynth's integration (backward Euler, 5 ms steps,
  Rayleigh damping alpha = 19 1/s, beta = 0.055 s, density 1040 kg/m^3, gravity; ``--dynamic``);
- ``..._contact``: the same with lip contact on the smooth lip surfaces (``--contact lips``);
- ``..._skull``: lip contact and the face against the jaw and maxilla meshes, ArtiSynth's lip-skull
  contact (``--contact lips,skull``).

Writes OUT/<gesture>/<variant>/ (lip_opening.{csv,png}, report.json, animation.usdc: ``wface
speech``'s files) and OUT/lip_opening_area_all.png (one panel per gesture, every variant, with the
original's recorded curve where the data has one). ``--compare-artisynth`` also plays the
approximant set up step by step towards ArtiSynth's BadinFaceDemoLipOpening (OOP rings, muscle
stress, boundary, contact, dynamics, material) and writes OUT/artisynth/factors.json and
factors.png: what each difference does to the lip opening area (README, "Speech gestures"); ``--steps``
picks some of its steps (0-3: the quasistatic rows with ArtiSynth's flesh law, 8-11: the same with
the old law, 1175 Pa as mu01; 12: lip contact with the old law; all of 0-12 with wface's uniaxial
fibre stress; 13-15: the demo setup with ArtiSynth's deviatoric fibre stress, quasistatic, old law,
lip contact). ``--held-oop LEVEL ...`` holds the approximant's OOP at each level on the demo setup
with each flesh law, bulk modulus and fibre stress (OUT/held_oop/held_oop.{json,png}, with the OOP
tets' volume ratio J at each level).

With --track-mocap, also tracks an AnimFace take on the Badin face: the capture markers that the
alignment puts within --select-mm of the Badin skin are used (OUT/track/report.json).

Run:
    python examples/badin_speech.py --out badin_speech_out                   # all, 25 fps (hours on 2 cores)
    python examples/badin_speech.py --gestures closure --variants quasistatic --max-frames 3 --out quick
    python examples/badin_speech.py --variants quasistatic dynamic --resume --out badin_speech_out  # go on
    python examples/badin_speech.py --gestures --compare-artisynth --out appr  # the factor study
    python examples/badin_speech.py --gestures --compare-artisynth --steps 0 1 2 3 8 9 10 11 --out appr
    python examples/badin_speech.py --gestures --held-oop 0.01 0.02 0.03 0.05 0.1 0.3 --out appr
    python examples/badin_speech.py --gestures --compare-artisynth --steps 3 13 --held-oop 0.01 0.3 --out fib
    python examples/badin_speech.py --gestures --track-mocap ../shared/data/animface/JawMoCap.c3d \\
        --track-frames 0:300:10 --out jaw_on_badin

Data: ../shared/data/artisynth-face (ArtiSynth Models, BSD-style; cite Nazari et al. 2010 and
Stavness et al.).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "artisynth-face"
VARIANTS = (
    "quasistatic",
    "dynamic",
    "quasistatic_contact",
    "dynamic_contact",
    "quasistatic_skull",
    "dynamic_skull",
    "quasistatic_skullpushed",
    "dynamic_skullpushed",
    "quasistatic_skullteeth",
)
_STYLE = {
    "quasistatic": ("C0", "-"),
    "dynamic": ("C3", "-"),
    "quasistatic_contact": ("C0", "--"),
    "dynamic_contact": ("C3", "--"),
    "quasistatic_skull": ("C2", "-."),
    "dynamic_skull": ("C1", "-."),
    "quasistatic_skullpushed": ("C2", ":"),
    "dynamic_skullpushed": ("C1", ":"),
    "quasistatic_skullteeth": ("C4", "-."),
}
# contact of each variant's suffix (regions, Contact keyword arguments): lip contact; lip contact and ArtiSynth's
# lip-skull contact (the face against the jaw and maxilla meshes, ``--contact lips,skull``); the same with the
# flesh nodes that lie inside the maxilla or jaw in the source data pushed out too, as ArtiSynth does
_CONTACT = {
    "contact": ("lips", {}),
    "skull": ("lips,skull", {}),
    "skullpushed": ("lips,skull", {"inside_at_rest": "push"}),
    "skullteeth": ("lips,skull,teeth", {}),
}


def _contact_of(variant: str) -> tuple[str, dict]:
    return _CONTACT.get(variant.rpartition("_")[2], ("", {}))


def _model(data: Path, model_path: Path | None):
    if model_path is not None:
        from wface.model import load_model

        return load_model(model_path)
    from wface.faces.artisynth import import_artisynth

    return import_artisynth(data, progress=False)


def play(
    model,
    gesture,
    out: Path,
    variant: str,
    *,
    fps: float,
    max_frames: int | None,
    max_step_ms: float,
    sim=None,
    rig="active",
):
    """Play one variant of ``gesture`` on ``model`` and write ``wface speech``'s files to ``out`` (``rig``:
    the USD's UsdSkel rig, as ``write_gesture_usd``; False for none)."""
    from wface.physics.contact import Contact
    from wface.speech import simulate_gesture, summarize
    from wface.speech.dynamic import GestureDynamics
    from wface.speech.output import write_gesture_usd, write_lip_opening
    from wface.speech.playback import compare_with_reference

    regions, options = _contact_of(variant)
    contact = Contact(model, regions=regions, smoothing_m=1e-4, surface="smooth", **options) if regions else None
    dynamics = GestureDynamics(max_step_s=max_step_ms * 1e-3) if variant.startswith("dynamic") else None
    res = simulate_gesture(
        model,
        gesture,
        fps=fps,
        max_frames=max_frames,
        simulator=sim,
        progress=True,
        contact=contact,
        dynamics=dynamics,
        tol=1e-6,
        max_iterations=80,
    )
    out.mkdir(parents=True, exist_ok=True)
    write_lip_opening(out, res, model, reference=gesture.reference_lip_area)
    F = len(res.times_s)
    rate = fps if max_frames is None else max(1.0, (F - 1) / max(res.times_s[-1] - res.times_s[0], 1e-9))
    write_gesture_usd(out / "animation.usdc", res, model, fps=rate, source=str(gesture.directory), rig=rig)
    summary = summarize(res)
    summary["times_s"] = res.times_s.tolist()
    summary["oop_volume_ratio"] = oop_volume_ratio(model, res.node_positions_m)
    summary["reference_comparison"] = compare_with_reference(res, gesture.reference_lip_area)
    (out / "report.json").write_text(json.dumps(summary, indent=2))
    return summary


def oop_volume_ratio(model, positions_m) -> dict | None:
    """J = V / V0 of the OOP muscle's tets (the demo's rings, or the import's OOP_l/OOP_r) in each frame:
    {"min", "mean" (over the tets), "total" (muscle volume ratio, fraction-weighted)}, lists over the
    frames of ``positions_m`` (F, n, 3); None for a model without OOP."""
    import numpy as np

    from wface.mesh.quality import signed_volumes

    idx = [i for i, n in enumerate(model.muscle_names) if n in ("OOP", "OOP_l", "OOP_r")]
    entry = np.isin(model.fibre_muscle, idx)
    if not entry.any():
        return None
    tets, frac = model.fibre_tet[entry], model.fibre_fraction[entry]
    v0 = model.rest_volume_m3[tets]
    J = np.array([signed_volumes(x, model.tets[tets]) / v0 for x in positions_m])  # (F, e)
    return {
        "min": J.min(axis=1).tolist(),
        "mean": J.mean(axis=1).tolist(),
        "total": ((J * v0 * frac).sum(axis=1) / (v0 * frac).sum()).tolist(),
    }


def run(
    out: Path,
    *,
    gestures=("closure", "fricative", "approximant"),
    variants=VARIANTS,
    fps: float = 25.0,
    max_frames: int | None = None,
    max_step_ms: float = 5.0,
    data: Path = DATA,
    model_path: Path | None = None,
    resume: bool = False,
) -> dict:
    """Play ``gestures`` in each of ``variants``; returns {gesture: {variant: summary}}, writes under ``out``.

    With ``resume``, a variant whose OUT/<gesture>/<variant>/report.json exists is read back instead
    of played again (a long run can be stopped and restarted; the figure shows what exists)."""
    from wface.physics.simulator import Simulator
    from wface.speech import read_gesture

    model = sim = None  # loaded when a variant is to be played
    out.mkdir(parents=True, exist_ok=True)
    summaries: dict = {}
    refs = {}
    for name in gestures:
        g = read_gesture(data / "speech" / name)
        refs[name] = g.reference_lip_area
        summaries[name] = {}
        for v in variants:
            done = out / name / v / "report.json"
            if resume and done.exists():
                summaries[name][v] = json.loads(done.read_text())
                continue
            if model is None:
                model = _model(data, model_path)
                sim = Simulator(model)  # one simulator (kernels, sparsity pattern) for all
            summaries[name][v] = play(
                model, g, out / name / v, v, fps=fps, max_frames=max_frames, max_step_ms=max_step_ms, sim=sim
            )
    (out / "summary.json").write_text(json.dumps(summaries, indent=2))
    figure(out / "lip_opening_area_all.png", summaries, refs)
    return summaries


def figure(path: Path, summaries: dict, refs: dict) -> None:
    """One panel per gesture: the lip opening area of every variant, and the original's curve."""
    from wface.viz.plots import _plt

    plt = _plt()
    fig, axes = plt.subplots(1, len(summaries), figsize=(4.2 * len(summaries), 3.6), squeeze=False, sharey=True)
    for ax, (name, per) in zip(axes[0], summaries.items(), strict=True):
        for v, s in per.items():
            colour, style = _STYLE.get(v, ("k", ":"))
            ax.plot(s["times_s"], s["lip_opening_area_mm2"], style, color=colour, lw=1.6, label=v.replace("_", " + "))
        ref = refs.get(name)
        if ref is not None and len(ref):
            ax.plot(ref[:, 0], ref[:, 1], "k:", lw=1.6, label="original (ArtiSynth)")
        ax.set_title(name)
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)  # each panel its own: the variants played may differ per gesture
    axes[0][0].set_ylabel("lip opening area (mm$^2$)")
    fig.suptitle("Badin face (wface import), ArtiSynth's camera and plane", fontsize=10)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


# the approximant, step by step from wface's import towards ArtiSynth's BadinFaceDemoLipOpening:
# (name, setup keyword arguments of lip_opening_demo_model or None, variant, flesh changes or None, excitation).
# The flesh is Material.artisynth() (C10 2500 Pa, C20 1175 Pa on (I1~ - 3)^2) unless a step changes it;
# "old law" is wface's stand-in before the C20 term existed (1175 Pa as mu01). The fibres are wface's
# uniaxial law (UNI) up to step 12; steps 13-15 add ArtiSynth's deviatoric fibre stress, which the demo
# setup itself uses ({}: lip_opening_demo_model's defaults).
OLD_LAW = {"mu01_pa": 1175.0, "mu20_pa": 0.0}
C10_ONLY = {"mu01_pa": 0.0, "mu20_pa": 0.0}
UNI = {"fibre_stress": "uniaxial"}
RINGS_3E5 = {"ring": True, "max_stress_pa": None, "boundary": False, **UNI}
STEPS = (
    ("wface import", None, "quasistatic", None, "file"),
    ("+ OOP rings", RINGS_3E5, "quasistatic", None, "file"),
    ("+ 1e5 Pa", {"ring": True, "boundary": False, **UNI}, "quasistatic", None, "file"),
    ("+ boundary", UNI, "quasistatic", None, "file"),
    ("+ lip contact", UNI, "quasistatic_contact", None, "file"),
    ("+ dynamics, gravity", UNI, "dynamic_contact", None, "file"),
    ("+ C10-only flesh", UNI, "dynamic_contact", C10_ONLY, "file"),
    ("inline excitation (peak 1)", UNI, "dynamic_contact", C10_ONLY, "inline"),
    ("wface import, old law", None, "quasistatic", OLD_LAW, "file"),
    ("+ OOP rings, old law", RINGS_3E5, "quasistatic", OLD_LAW, "file"),
    ("+ 1e5 Pa, old law", {"ring": True, "boundary": False, **UNI}, "quasistatic", OLD_LAW, "file"),
    ("+ boundary, old law", UNI, "quasistatic", OLD_LAW, "file"),
    ("+ lip contact, old law", UNI, "quasistatic_contact", OLD_LAW, "file"),
    ("+ deviatoric fibres (the demo setup)", {}, "quasistatic", None, "file"),
    ("+ deviatoric fibres, old law", {}, "quasistatic", OLD_LAW, "file"),
    ("+ deviatoric fibres, lip contact", {}, "quasistatic_contact", None, "file"),
    ("the demo setup + lip and skull contact", {}, "quasistatic_skull", None, "file"),
    ("the demo setup, dynamic", {}, "dynamic", None, "file"),
    ("the demo setup, dynamic + lip contact", {}, "dynamic_contact", None, "file"),
    ("the demo setup, dynamic + lip and skull contact", {}, "dynamic_skull", None, "file"),
    ("the demo setup + lip and skull contact, pushed out at rest", {}, "quasistatic_skullpushed", None, "file"),
    ("the demo setup, dynamic + lip and skull contact, pushed out at rest", {}, "dynamic_skullpushed", None, "file"),
    ("the demo setup + lip, skull and teeth contact", {}, "quasistatic_skullteeth", None, "file"),
)


def _slug(name: str) -> str:
    return "_".join("".join(c if c.isalnum() else " " for c in name).split())


def _step_model(base, data: Path, setup: dict | None, flesh: dict | None):
    from dataclasses import replace

    from wface.speech.artisynth_demo import lip_opening_demo_model

    model = base if setup is None else lip_opening_demo_model(base, data, **setup)
    return model if not flesh else model.with_material(replace(model.material, **flesh))


def compare_artisynth(
    out: Path,
    *,
    steps=STEPS,
    fps: float = 25.0,
    max_frames: int | None = None,
    max_step_ms: float = 5.0,
    data: Path = DATA,
    model_path: Path | None = None,
) -> dict:
    """The approximant set up step by step as ArtiSynth's lip-opening demo (``STEPS``); writes
    OUT/factors.json and OUT/factors.png and returns {step: summary}."""
    from wface.speech import read_gesture
    from wface.speech.gestures import ExcitationCurve

    base = _model(data, model_path)
    g = read_gesture(data / "speech" / "approximant")
    inline = read_gesture(data / "speech" / "approximant")
    probe = next(p for p in inline.probes if p.name == "OOP")
    inline.curves["OOP"] = ExcitationCurve(
        0.0, 1.0, 1.0, "CubicStep", 1, probe.inline_data[:, 0], probe.inline_data[:, 1:]
    )
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name, setup, variant, flesh, excitation in steps:
        model = _step_model(base, data, setup, flesh)
        gest = g if excitation == "file" else inline
        s = play(model, gest, out / _slug(name), variant, fps=fps, max_frames=max_frames, max_step_ms=max_step_ms)
        material = {
            f: getattr(model.material, f) for f in ("mu10_pa", "mu01_pa", "mu20_pa", "kappa_pa", "fibre_stress")
        }
        results[name] = {"variant": variant, "excitation": excitation, "flesh": material, **s}
        (out / "factors.json").write_text(json.dumps(results, indent=2))
    from wface.viz.plots import _plt

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for k, (name, s) in enumerate(results.items()):
        ax.plot(s["times_s"], s["lip_opening_area_mm2"], color=plt.cm.viridis(k / max(len(results) - 1, 1)), label=name)
    ax.plot(g.reference_lip_area[:, 0], g.reference_lip_area[:, 1], "k:", lw=2, label="original (ArtiSynth)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("lip opening area (mm$^2$)")
    ax.set_title("approximant: from wface's import to ArtiSynth's lip-opening demo", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.savefig(out / "factors.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return results


# the demo setup with each flesh law, bulk modulus (kappa 10x / 100x ArtiSynth's 25 kPa: how much the volume
# matters; ArtiSynth has no hard incompressibility here) and fibre stress, for the held-OOP apertures
HELD_STEPS = (
    ("C10 + C20 (ArtiSynth's law), uniaxial fibres", UNI, "quasistatic", None, "file"),
    ("old law (C20 as mu01), uniaxial", UNI, "quasistatic", OLD_LAW, "file"),
    ("C10 + C20, kappa 10x, uniaxial", UNI, "quasistatic", {"kappa_pa": 2.5e5}, "file"),
    ("C10 + C20, kappa 100x, uniaxial", UNI, "quasistatic", {"kappa_pa": 2.5e6}, "file"),
    ("old law, kappa 100x, uniaxial", UNI, "quasistatic", {**OLD_LAW, "kappa_pa": 2.5e6}, "file"),
    ("C10 + C20, deviatoric fibres (the demo setup)", {}, "quasistatic", None, "file"),
    ("old law, deviatoric fibres", {}, "quasistatic", OLD_LAW, "file"),
)


def held_oop(
    out: Path,
    levels=(0.01, 0.02, 0.03, 0.05, 0.1, 0.3),
    *,
    steps=HELD_STEPS,
    data: Path = DATA,
    model_path: Path | None = None,
) -> dict:
    """The approximant's OOP held at each of ``levels`` in turn (quasistatic, each equilibrium warm-started
    from the one before) on the models of ``steps``; writes OUT/held_oop.json and OUT/held_oop.png (area
    against level) and returns {step: {"levels", "area_mm2", "lip_gap_mm", "converged"}}."""
    from wface.speech import read_gesture
    from wface.speech.gestures import held_gesture

    base = _model(data, model_path)
    held = held_gesture(read_gesture(data / "speech" / "approximant"), levels, probe="OOP")
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name, setup, variant, flesh, _excitation in steps:
        model = _step_model(base, data, setup, flesh)
        # no rig: a held study's USD is for looking at the poses (OOP alone at 1 inverts the ring's tets)
        held_variant = variant if variant.startswith("quasistatic") else "quasistatic"  # held: no dynamics
        s = play(model, held, out / _slug(name), held_variant, fps=1.0, max_frames=None, max_step_ms=5.0, rig=False)
        results[name] = {
            "levels": [float(v) for v in levels],
            "area_mm2": s["lip_opening_area_mm2"],
            "lip_gap_mm": s.get("lip_gap_mm"),
            "converged": s.get("all_converged"),
            "oop_volume_ratio": s.get("oop_volume_ratio"),
        }
        (out / "held_oop.json").write_text(json.dumps(results, indent=2))
    from wface.viz.plots import _plt

    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    for name, r in results.items():
        ax.plot(r["levels"], r["area_mm2"], marker="o", label=name)
    ax.plot([0.3], [15.5], "k*", ms=12, label="original at OOP 0.3 (from 53.2 mm$^2$ after its sag)")
    if min(levels) > 0:
        ax.set_xscale("log")
    ax.set_xlabel("OOP excitation held")
    ax.set_ylabel("lip opening area (mm$^2$)")
    ax.set_title("approximant's OOP held, quasistatic, demo setup (rest: 39.5 mm$^2$)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.savefig(out / "held_oop.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return results


def track_take(
    out: Path,
    mocap: Path,
    *,
    frames: str = "0:300:10",
    select_mm: float = 5.0,
    data: Path = DATA,
    model_path: Path | None = None,
) -> dict:
    """Track frames A:B:STEP of a capture on the Badin face with the markers that land on its skin."""
    import time

    import numpy as np

    from wface.io.mocap import read_mocap
    from wface.speech.playback import select_capture_markers
    from wface.takes.store import take_from_records, write_controls, write_report
    from wface.tracking.capture import prepare_capture
    from wface.tracking.identifiability import rig_identifiability_mm
    from wface.tracking.report import build_report
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import track_sequence

    model = _model(data, model_path)
    a, b, step = (list(map(int, frames.split(":"))) + [1])[:3]
    take = read_mocap(mocap)
    sel = select_capture_markers(model, take.positions_m[a:b], take.marker_names, max_distance_mm=select_mm)
    cap = prepare_capture(model, take.positions_m[a:b:step][:, sel["indices"]], sel["names"])
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    recs = track_sequence(
        model,
        cap.targets_m,
        marker_names=sel["names"],
        markers=cap.markers,
        rig_kwargs={"tol": 1e-6},
        out_dir=out,
        resume=True,
        progress=True,
        first_frame=a,
    )
    wall = time.perf_counter() - t0
    ident = rig_identifiability_mm(FaceRig(model, tol=1e-6), cap.markers)
    rep = build_report(
        model,
        recs,
        markers_data_m=cap.targets_m,
        marker_names=sel["names"],
        rig_info={"device": "cpu", "wall_seconds": wall, "frames_range": [a, b], "frame_stride": step},
        identifiability_mm=ident,
    )
    rep["marker_selection"] = {
        "max_distance_mm": select_mm,
        "landmarks": sel["landmarks"],
        "kept": sel["names"],
        "scale": sel["scale"],
        "landmark_rms_mm": sel["landmark_rms_mm"],
        "distance_mm": dict(zip(take.marker_names, np.round(sel["distance_mm"], 2).tolist(), strict=True)),
    }
    rep["capture_scale"], rep["capture_rest_fit_mm"] = cap.scale, cap.alignment_rms_mm
    write_report(out, rep)
    write_controls(out, model, take_from_records(model, recs, fps=take.rate_hz / step))
    return rep


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--gestures", nargs="*", default=["closure", "fricative", "approximant"])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--max-frames", type=int)
    p.add_argument("--max-step-ms", type=float, default=5.0, help="longest dynamic time step (ms)")
    p.add_argument("--data", type=Path, default=DATA, help="the artisynth-face data folder")
    p.add_argument("--model", type=Path, help="a saved Badin model (.npz) instead of importing")
    p.add_argument("--resume", action="store_true", help="read back the variants already written under --out")
    p.add_argument("--compare-artisynth", action="store_true", help="also the approximant's factor study")
    p.add_argument(
        "--steps",
        nargs="+",
        type=int,
        help="indices into STEPS of the factor study's steps to play (default all): 0-3 the quasistatic "
        "rows with ArtiSynth's flesh, 8-11 the same with the old law (C20 as mu01), 12 lip contact with the old law "
        "(0-12 uniaxial fibres), 13-15 deviatoric fibres (the demo setup): quasistatic, old law, lip contact; "
        "16 the demo setup with lip and skull contact (jaw and maxilla); 17-19 the demo setup played dynamically: "
        "no contact, lip contact, lip and skull contact; 20-21 lip and skull contact with the flesh inside the jaw or "
        "maxilla in the source data pushed out (ArtiSynth's way), quasistatic and dynamic; 22 lip, skull and teeth "
        "contact (flesh inside at rest left out)",
    )
    p.add_argument(
        "--held-oop",
        nargs="+",
        type=float,
        metavar="LEVEL",
        help="also hold the approximant's OOP at these levels on the demo setup, each flesh law and kappa "
        "(HELD_STEPS; with --steps: on those steps), e.g. --held-oop 0.01 0.02 0.03 0.05 0.1 0.3",
    )
    p.add_argument("--track-mocap", type=Path, help="also track this capture (C3D/TRC/CSV) on the Badin face")
    p.add_argument("--track-frames", default="0:300:10", help="A:B:STEP of the capture to track")
    p.add_argument("--select-mm", type=float, default=5.0, help="largest marker distance from the Badin skin")
    a = p.parse_args(argv)
    if a.track_mocap:
        rep = track_take(
            a.out / "track",
            a.track_mocap,
            frames=a.track_frames,
            select_mm=a.select_mm,
            data=a.data,
            model_path=a.model,
        )
        print(
            f"tracked {rep['frames']} frames on {rep['markers']} markers: "
            f"marker RMS {rep['marker_rms_mm_mean']:.3f} mm "
            f"(max {rep['marker_max_mm']:.2f} mm), {rep['seconds_per_frame_median']:.1f} s/frame"
        )
    common = {
        "fps": a.fps,
        "max_frames": a.max_frames,
        "max_step_ms": a.max_step_ms,
        "data": a.data,
        "model_path": a.model,
    }
    if a.gestures:
        summaries = run(a.out, gestures=a.gestures, variants=a.variants, resume=a.resume, **common)
        for name, per in summaries.items():
            for v, s in per.items():
                ar = s["lip_opening_area_summary_mm2"]
                print(
                    f"{name:12s} {v:20s} lip opening area {ar['first']:6.2f} -> {ar['last']:6.2f} mm^2 "
                    f"(min {ar['min']:.2f}, max {ar['max']:.2f}), {s['frames']} frames, {s['seconds_total']:.0f} s"
                )
    steps = STEPS if a.steps is None else tuple(STEPS[i] for i in a.steps)
    if a.compare_artisynth:
        for name, s in compare_artisynth(a.out / "artisynth", steps=steps, **common).items():
            ref = s["reference_comparison"] or {}
            w = ref.get("wface", {})
            print(
                f"{name:28s} settled {w.get('settled_mm2', 0):6.1f} final {w.get('final_mm2', 0):6.1f} mm^2, "
                f"RMS vs original {ref.get('rms_mm2', 0):.1f} mm^2"
            )
    if a.held_oop:
        held_steps = HELD_STEPS if a.steps is None else steps
        for name, h in held_oop(
            a.out / "held_oop", a.held_oop, steps=held_steps, data=a.data, model_path=a.model
        ).items():
            cells = ", ".join(f"{v:g}: {ar:.2f} mm^2" for v, ar in zip(h["levels"], h["area_mm2"], strict=True))
            print(f"{name:28s} OOP held at {cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
