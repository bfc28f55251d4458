"""ArtiSynth's hexes beside wface's tets: the approximant's OOP held on the lip-opening demo setup.

ArtiSynth simulates the Badin face on its 6,342 trilinear hexes (full 2x2x2 integration); wface
splits them into 45,496 linear tets. Are the tets why wface's lips close at an OOP excitation six
times lower than the original's (README, "Speech gestures")? This plays both discretisations of the
same face, same nodes, material, muscles (each hex Gauss point carries the fibre entries of the tet
that holds it) and boundary (``wface.speech.artisynth_demo``, the demo setup), each with the ring's
fibre directions taken from the 7M polyline's nearest segment and with ArtiSynth's own Delaunay blend
of them (``delaunay_fibre_directions``), with OOP held at each
level in turn (quasistatic, each equilibrium warm-started from the one before, no contact, no
gravity), and measures the lip opening area in ArtiSynth's view (``wface.speech.aperture``) and the
lip gap (negative: the lips pass through each other).

Writes OUT/hexes_vs_tets.json and OUT/hexes_vs_tets.png. About 5 minutes on 2 cores:

    python examples/badin_hexes.py --out out/badin_hexes
    python examples/badin_hexes.py --model badin.npz --levels 0.01 0.02 --out out/badin_hexes

Data: ../shared/data/artisynth-face (ArtiSynth Models, BSD-style; cite Nazari et al. 2010 and
Stavness et al.).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "artisynth-face"
LEVELS = (0.01, 0.02, 0.03, 0.05, 0.1, 0.3)


class HexFace:
    """The demo face on its hexes: equilibria, and positions of every tet-model node (for the measures)."""

    def __init__(self, demo, data: Path):
        from wface.physics import Simulator
        from wface.physics.hexes import hex_quadrature, quadrature_model, shape_functions, trilinear_points
        from wface.speech.artisynth_demo import face_hexes

        hexes = face_hexes(data)
        n_hex_nodes = int(hexes.max()) + 1
        self.demo, self.n = demo, n_hex_nodes
        self.quad = hex_quadrature(demo.rest_positions_m[:n_hex_nodes], hexes)
        self.sim = Simulator(quadrature_model(demo, self.quad))
        self.free = demo.free_nodes[demo.free_nodes < n_hex_nodes]
        # the nodes the tet split added (face and cell centres) follow the trilinear field
        self.extra = np.arange(n_hex_nodes, demo.n_nodes)
        owner, xi = trilinear_points(self.quad, self.quad.rest_m, demo.rest_positions_m[self.extra])
        self.extra_hex, self.extra_N = owner, shape_functions(xi)[0]

    def model_positions(self, x_hex: np.ndarray) -> np.ndarray:
        x = self.demo.rest_positions_m.copy()
        x[: self.n] = x_hex
        x[self.extra] = np.einsum("ka,kad->kd", self.extra_N, x_hex[self.quad.hexes[self.extra_hex]])
        return x

    def solve(self, a, x0, max_iterations: int):
        from wface.physics.hex_solve import HexBody

        return HexBody(self.sim, self.quad, self.free).solve(a, x0, max_iterations=max_iterations)


VARIANTS = (  # (key, label, elements, ring fibre directions)
    ("tets", "wface's linear tets", "tets", "nearest"),
    ("tets_delaunay", "linear tets, ArtiSynth's fibre directions", "tets", "delaunay"),
    ("hexes", "ArtiSynth's trilinear hexes", "hexes", "nearest"),
    ("hexes_delaunay", "trilinear hexes, ArtiSynth's fibre directions", "hexes", "delaunay"),
)


def held_levels(base, data: Path, levels, *, variants=VARIANTS, max_iterations: int = 150, progress=print) -> dict:
    """{variant key: [per level: area (mm^2), lip gap (mm), Newton iterations, relative residual, seconds]},
    plus "rest" and "mesh"."""
    from wface.mesh.surface import boundary_faces
    from wface.physics import Simulator
    from wface.physics.contact import Contact
    from wface.speech.aperture import ApertureView, aperture_area
    from wface.speech.artisynth_demo import lip_opening_demo_model
    from wface.speech.playback import lip_area_points

    demos = {d: lip_opening_demo_model(base, data, ring_directions=d) for d in {v[3] for v in variants}}
    demo = next(iter(demos.values()))
    view, occluders, near = ApertureView.for_model(demo), boundary_faces(demo.tets), lip_area_points(demo)
    lips = Contact(demo, regions="lips")

    def measures(x):
        area = aperture_area(x, occluders, view, near_points_m=x[near])
        return {"area_mm2": area.area_mm2, "lip_gap_mm": 1e3 * lips.self_distance_m(x)}

    out = {"rest": {"area_mm2": measures(demo.rest_positions_m)["area_mm2"]}, "labels": {}}
    for key, label, elements, directions in variants:
        model = demos[directions]
        if elements == "hexes":
            face = HexFace(model, data)
            out["mesh"] = {
                "hexes": int(len(face.quad.hexes)),
                "wedges": int(sum(len(set(h.tolist())) < 8 for h in face.quad.hexes)),
                "hex_nodes": int(face.n),
                "tets": int(model.n_tets),
                "tet_nodes": int(model.n_nodes),
                "hex_volume_cm3": 1e6 * face.quad.volume_m3,
                "tet_volume_cm3": 1e6 * float(model.rest_volume_m3.sum()),
            }
            x = face.quad.rest_m.copy()
        else:
            sim, x = Simulator(model), model.rest_positions_m.copy()
        rows = []
        for level in levels:
            a = model.activation_vector({"OOP": float(level)})
            t0 = time.perf_counter()
            if elements == "hexes":
                r = face.solve(a, x, max_iterations)
                x, its, res, seen = r.x_m, r.iterations, r.residual_rel, face.model_positions(r.x_m)
            else:
                eq = sim.solve(a, x0=x, max_iterations=max_iterations)
                x, its, res, seen = eq.x, eq.iterations, eq.residual_rel, eq.x
            rows.append({"level": level, **measures(seen), "iterations": its, "residual_rel": res})
            rows[-1]["seconds"] = time.perf_counter() - t0
        out[key], out["labels"][key] = rows, label
        progress(f"{label}: " + ", ".join(f"{r['level']}: {r['area_mm2']:.2f}" for r in rows) + " mm^2")
    return out


def figure(path: Path, result: dict) -> None:
    from wface.viz.plots import _plt

    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    for key, style in zip(result["labels"], ("o-", "o:", "s--", "s-."), strict=False):
        rows = result[key]
        ax.plot([r["level"] for r in rows], [r["area_mm2"] for r in rows], style, label=result["labels"][key])
    ax.plot([0.3], [15.5], "k*", ms=12, label="original at OOP 0.3 (recorded, dynamic)")
    ax.set_xscale("log")
    ax.set_xlabel("OOP excitation held")
    ax.set_ylabel("lip opening area (mm$^2$)")
    ax.set_title(
        f"demo setup, quasistatic, no contact: {result['mesh']['tets']:,} tets vs {result['mesh']['hexes']:,} hexes",
        fontsize=10,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--data", type=Path, default=DATA, help="the artisynth-face data folder")
    p.add_argument("--model", type=Path, help="a saved Badin import (wface model import artisynth); default: import")
    p.add_argument("--levels", type=float, nargs="+", default=list(LEVELS), help="OOP levels held, in turn")
    p.add_argument("--max-iterations", type=int, default=150, help="Newton iteration cap per level")
    a = p.parse_args(argv)
    if not a.data.is_dir():
        p.error(f"no ArtiSynth face data at {a.data} (--data)")
    from wface.faces.artisynth import import_artisynth
    from wface.model import load_model

    base = load_model(a.model) if a.model else import_artisynth(a.data, progress=False)
    result = held_levels(base, a.data, a.levels, max_iterations=a.max_iterations)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "hexes_vs_tets.json").write_text(json.dumps(result, indent=2))
    figure(a.out / "hexes_vs_tets.png", result)
    print(f"wrote {a.out / 'hexes_vs_tets.json'} and {a.out / 'hexes_vs_tets.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
