"""The approximant with and without ArtiSynth's lip-skull contact, beside the original's recorded curve.

Reads what ``examples/badin_speech.py`` wrote (nothing is simulated here) and draws one figure:

- left: the lip opening area with the approximant's OOP held quasistatically at each level, for the demo
  setup with lip contact, with lip and skull contact (the face against the jaw and maxilla meshes), and
  with the flesh that lies inside those meshes in the source data pushed out as well; beside them the
  original's recorded area at the moment its OOP curve passes each level (a dynamic run, so this lags
  behind a held pose: read it as a guide, not as a held measurement);
- right: the played (dynamic) curves and the original's, with each curve's RMS difference from it.

Run (from the repository root, ``badin.npz`` from ``wface model import artisynth``):

    python examples/badin_speech.py --model badin.npz --gestures --steps 15 16 20 \\
        --held-oop 0.01 0.02 0.03 0.05 0.1 0.3 --out held
    python examples/badin_speech.py --model badin.npz --gestures --compare-artisynth --steps 17 19 --out dyn
    python examples/badin_skull_contact.py --held held/held_oop/held_oop.json \\
        --played dyn/artisynth/factors.json --out docs/images/badin_skull_contact.png

Data: ../shared/data/artisynth-face (ArtiSynth Models, BSD-style; cite Nazari et al. 2010 and Stavness et al.).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "artisynth-face"


def original_at_levels(data: Path, levels) -> list[float]:
    """The original's recorded area (mm^2) when its OOP excitation curve first reaches each level."""
    from wface.speech import read_gesture

    g = read_gesture(data / "speech" / "approximant")
    t = np.linspace(0.0, 1.0, 2001)
    oop = g.curves["OOP"].values(t)
    ref = g.reference_lip_area
    out = []
    for level in levels:
        reached = np.flatnonzero(np.asarray(oop).reshape(-1) >= level - 1e-12)
        out.append(float(np.interp(t[reached[0]], ref[:, 0], ref[:, 1])) if reached.size else float("nan"))
    return out


def _colour(name: str) -> str:
    """One colour per contact setting in both panels."""
    return "C2" if "pushed" in name else "C1" if "skull" in name else "C0" if "lip contact" in name else "C7"


def played_numbers(s: dict, ref: np.ndarray) -> dict:
    """The README's columns for one played curve: area before the excitation (t <= 0.22 s, its largest),
    mean over t >= 0.6 s, first time below 20 and below 0.5 mm^2, deepest lip overlap, RMS from the
    original, and the largest difference from the original's curve up to t = 0.32 s (the sag and the
    start of the closing) and after it."""
    t, a = np.asarray(s["times_s"]), np.asarray(s["lip_opening_area_mm2"])
    orig = np.interp(t, ref[:, 0], ref[:, 1])
    diff = np.abs(a - orig)

    def first_below(level):
        below = np.flatnonzero(a < level)
        return float(t[below[0]]) if below.size else None

    return {
        "before_excitation_mm2": round(float(a[t <= 0.22].max()), 1),
        "mean_after_0.6s_mm2": round(float(a[t >= 0.6].mean()), 1),
        "below_20_from_s": first_below(20.0),
        "below_0.5_from_s": first_below(0.5),
        "lip_gap_min_mm": s.get("lip_gap_mm_min"),
        "rms_mm2": round(float((s.get("reference_comparison") or {}).get("rms_mm2", np.nan)), 2),
        "max_difference_to_0.32s_mm2": round(float(diff[t <= 0.32 + 1e-9].max()), 1),
        "max_difference_after_0.32s_mm2": round(float(diff[t > 0.32 + 1e-9].max()), 1),
    }


def figure(held: dict, played: dict, data: Path, out: Path) -> dict:
    """Draw the two panels; returns the numbers drawn (levels, areas, the original's, RMS per curve)."""
    from wface.speech import read_gesture
    from wface.viz.plots import _plt

    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11.5, 4.2))
    numbers: dict = {"held": {}, "played": {}}
    ref = read_gesture(data / "speech" / "approximant").reference_lip_area
    levels = None
    for name, r in held.items():
        levels = r["levels"]
        a.plot(r["levels"], r["area_mm2"], marker="o", color=_colour(name), label=name)
        numbers["held"][name] = [round(v, 2) for v in r["area_mm2"]]
    if levels:
        orig = original_at_levels(data, levels)
        numbers["held"]["original (recorded, when its OOP curve reaches the level)"] = [round(v, 2) for v in orig]
        a.plot(levels, orig, "k*--", ms=9, label="original, when its played OOP reaches the level")
        a.set_xscale("log")
    a.set_xlabel("OOP excitation held")
    a.set_ylabel("lip opening area (mm$^2$)")
    a.set_title("OOP held, quasistatic, demo setup", fontsize=10)
    a.grid(alpha=0.3)
    a.legend(fontsize=7)
    for name, s in played.items():
        rms = (s.get("reference_comparison") or {}).get("rms_mm2")
        numbers["played"][name] = played_numbers(s, ref)
        short = name.replace("the demo setup, dynamic", "demo setup").replace(", pushed out at rest", ", pushed out")
        label = short if rms is None else f"{short} (RMS {rms:.1f} mm$^2$)"
        b.plot(s["times_s"], s["lip_opening_area_mm2"], color=_colour(name), label=label)
    b.plot(ref[:, 0], ref[:, 1], "k:", lw=2, label="original (ArtiSynth's recorded output)")
    b.set_xlabel("time (s)")
    b.set_title("approximant played with inertia (25 fps, 5 ms backward-Euler steps)", fontsize=10)
    b.grid(alpha=0.3)
    b.set_ylim(-2.0, 72.0)  # room for the legend above the sag
    b.legend(fontsize=7, loc="upper right")
    fig.suptitle("Badin face: ArtiSynth's lip-skull contact (jaw and maxilla) in wface", fontsize=10)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return numbers


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--held", type=Path, nargs="+", required=True, help="held_oop.json of badin_speech.py --held-oop")
    p.add_argument("--played", type=Path, nargs="*", default=[], help="factors.json of --compare-artisynth")
    p.add_argument("--data", type=Path, default=DATA, help="the artisynth-face data folder")
    p.add_argument("--out", type=Path, required=True, help="the PNG to write")
    a = p.parse_args(argv)
    held: dict = {}
    for path in a.held:
        held.update(json.loads(path.read_text()))
    played: dict = {}
    for path in a.played:
        played.update(json.loads(path.read_text()))
    print(json.dumps(figure(held, played, a.data, a.out), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
