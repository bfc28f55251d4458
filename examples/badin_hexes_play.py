"""The approximant (or another gesture, ``--gesture``) played on ArtiSynth's own hexes, with lip and skull contact
and inertia.

ArtiSynth's lip-opening demo, run from its source (README, "The elements, not the contact"), keeps
11 mm^2 of the mouth open at the approximant's end on its trilinear hexes and 1.5 mm^2 on wface's
linear tets, the same contact on both. wface on its tets keeps 0.99. This plays the approximant on
the demo's 6,342 hexes in wface (``wface.physics.hex_solve``): the demo setup
(``wface.speech.artisynth_demo``: material, OOP rings, held nodes), each hex Gauss point carrying the
fibre entries of the tet that holds it (``quadrature_model``), backward Euler at ArtiSynth's 5 ms
steps, Rayleigh damping and gravity as the demo, and wface's lip (smooth lips) and skull contact
acting on the tet model's boundary, whose nodes follow the hexes' trilinear field
(``embedding_matrix``): the contact surfaces lie on the hexes' faces. As ``wface speech ... --contact
lips,skull --contact-inside-at-rest push``, frame 0 is the contact equilibrium at rest, pushed out of
the bones. The lip opening area of every frame is measured as wface speech does (ArtiSynth's view).

Writes OUT/lip_opening.csv (the columns of ``wface speech``'s, which ``examples/artisynth_lip_area.py
--wface`` reads), OUT/report.json and OUT/states.npz (hex-node positions per frame):

    python examples/badin_hexes_play.py --model badin.npz --out hexplay          # about 1 hour on 2 cores
    python examples/badin_hexes_play.py --model badin.npz --contact skull --out hexplay_skull
    python examples/badin_hexes_play.py --model badin.npz --end 0.1 --out short  # the first 0.1 s
    python examples/badin_hexes_play.py --model badin.npz --gesture fricative --muscle-curves artisynth \\
        --muscle-elements artisynth --lower-oom lower --out fricative   # another gesture, ArtiSynth's muscles

Data: ../shared/data/artisynth-face (ArtiSynth Models, BSD-style; cite Nazari et al. 2010 and
Stavness et al.).
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

from wface.physics.hexes import WEDGE_RULES
from wface.speech.gestures import LOWER_OOM_CHOICES

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "artisynth-face"
BULKS = ("point", "element-quadratic", "element-log")
DYNAMICS = {"max_step_s": 0.005, "alpha_per_s": 19.0, "beta_s": 0.055, "gravity_m_s2": (0.0, -9.8, 0.0)}


class HexDemo:
    """The lip-opening demo on its hexes: the body (flesh, contact, masses) and the tet model's view of it."""

    def __init__(
        self,
        base,
        data: Path,
        contact_regions: str,
        *,
        ring_directions="nearest",
        mass_lumping="equal",
        stiffness_n_per_m=None,
        smoothing_m=1e-4,
        bulk="point",
        lip_surface="smooth",
        lip_points="nodes_and_edges",
        fibre_stress="deviatoric",
        idle_muscles="passive",
        muscle_curves="wface",
        muscle_elements="import",
        lower_oom="whole",
        wedges="collapsed",
    ):
        from dataclasses import replace

        import scipy.sparse as sp

        from wface.physics import Simulator
        from wface.physics.contact import Contact
        from wface.physics.hex_dilatation import MeanDilatation
        from wface.physics.hex_solve import HexBody
        from wface.physics.hexes import embedding_matrix, hex_quadrature, quadrature_model
        from wface.speech.artisynth_demo import (
            face_hexes,
            lip_opening_demo_model,
            ooml_exciter_tets,
            without_idle_fibres,
        )
        from wface.speech.gestures import with_lower_oom

        curves = "artisynth" if muscle_curves == "artisynth" else "law"
        demo = lip_opening_demo_model(
            base,
            data,
            ring_directions=ring_directions,
            fibre_stress=fibre_stress,
            muscle_curves=curves,
            muscle_elements=muscle_elements,
        )
        if lower_oom in ("lower", "exciter"):  # the OOMl exciter's own muscles, OOM's lower-lip part
            demo = with_lower_oom(demo, ooml_exciter_tets(demo, data) if lower_oom == "exciter" else None)
        if idle_muscles == "off":  # ArtiSynth's GenericMuscle passive is 0.05 Pa: every muscle but OOP carries nothing
            demo = without_idle_fibres(demo, ["OOP"])
        self.demo = demo
        hexes = face_hexes(data)
        n = int(hexes.max()) + 1
        self.quad = quad = hex_quadrature(demo.rest_positions_m[:n], hexes, wedges=wedges)
        # the tet split's face and cell centres follow the trilinear field of their hex
        self.embedding = sp.vstack(
            [sp.identity(n, format="csr"), embedding_matrix(quad, demo.rest_positions_m[n:])], format="csr"
        )
        self.contact = None
        if contact_regions:
            self.contact = Contact.from_spec(
                demo,
                contact_regions,
                (),
                stiffness_n_per_m=stiffness_n_per_m,
                smoothing_m=smoothing_m,
                surface=lip_surface,
                inside_at_rest="push",
                edge_midpoints=lip_points == "nodes_and_edges",  # "nodes": as ArtiSynth's vertex penetrations
            )
        free = demo.free_nodes[demo.free_nodes < n]
        flesh, dilatation = demo, None
        if bulk != "point":  # one volume ratio per hex, the kernels' per-point bulk term off
            dilatation = MeanDilatation(quad, demo.material.kappa_pa, bulk.split("-")[1])
            flesh = replace(demo, material=replace(demo.material, kappa_pa=0.0))
        self.body = HexBody(
            Simulator(quadrature_model(flesh, quad)),
            quad,
            free,
            contact=self.contact,
            embedding=self.embedding,
            mass_lumping=mass_lumping,
            dilatation=dilatation,
        )

    def model_positions(self, x_hex: np.ndarray) -> np.ndarray:
        return np.asarray(self.embedding @ x_hex)


def play(
    base,
    data: Path,
    *,
    contact: str = "lips,skull",
    fps: float = 25.0,
    end_s=None,
    tol: float = 1e-4,
    max_iterations: int = 25,
    exact_damping: bool = False,
    ring_directions: str = "nearest",
    fibre_stress: str = "deviatoric",
    idle_muscles: str = "passive",
    muscle_curves: str = "wface",
    muscle_elements: str = "import",
    gesture_name: str = "approximant",
    lower_oom: str = "whole",
    mass_lumping: str = "equal",
    start_from: str = "pushed",
    bulk: str = "point",
    lip_surface: str = "smooth",
    lip_points: str = "nodes_and_edges",
    wedges: str = "collapsed",
    progress=print,
) -> dict:
    """Per-frame times, areas, lip gaps, solver statistics and hex-node positions of the played approximant."""
    from wface.mesh.surface import boundary_faces
    from wface.physics.contact import Contact
    from wface.physics.hex_solve import HexSolve
    from wface.speech.aperture import ApertureView, aperture_area
    from wface.speech.gestures import map_gesture_to_model, read_gesture
    from wface.speech.playback import gesture_times, lip_area_points

    face = HexDemo(
        base,
        data,
        contact,
        ring_directions=ring_directions,
        mass_lumping=mass_lumping,
        bulk=bulk,
        lip_surface=lip_surface,
        lip_points=lip_points,
        fibre_stress=fibre_stress,
        idle_muscles=idle_muscles,
        muscle_curves=muscle_curves,
        muscle_elements=muscle_elements,
        lower_oom=lower_oom,
        wedges=wedges,
    )
    demo = face.demo
    gesture = read_gesture(data / "speech" / gesture_name)
    mapping = map_gesture_to_model(gesture, demo, lower_oom=lower_oom)
    t0, t1 = gesture.duration_s
    times = gesture_times(t0, t1 if end_s is None else end_s, fps)  # past t1 the curves hold their last values
    acts = lambda t: mapping.activations(gesture, demo, np.atleast_1d(t))[0]  # noqa: E731
    if idle_muscles == "off":
        driven = mapping.driven_muscles(gesture, demo)
        if set(driven) - {"OOP"}:
            raise SystemExit(f"--idle-muscles off: the gesture also drives {sorted(set(driven) - {'OOP'})}")
    view, occluders, near = ApertureView.for_model(demo), boundary_faces(demo.tets), lip_area_points(demo)
    lips = Contact(demo, regions="lips")
    oop = demo.muscle_names.index("OOP")
    rows, states = [], []

    def record(t, x_hex, r, seconds, steps):
        z = face.model_positions(x_hex)
        area = aperture_area(z, occluders, view, near_points_m=z[near])
        rows.append(
            {
                "time_s": round(float(t), 6),
                "lip_opening_area_mm2": area.area_mm2,
                "lip_opening_width_mm": area.width_mm,
                "lip_opening_height_mm": area.height_mm,
                "lip_gap_mm": 1e3 * lips.self_distance_m(z),
                "a_OOP": float(acts(t)[oop]),
                "newton_iterations": r["iterations"],
                "residual_rel": r["residual_rel"],
                "max_penetration_mm": 1e3 * r["penetration_m"],
                "steps": steps,
                "seconds": seconds,
            }
        )
        states.append(x_hex.copy())
        progress(
            f"t={t:.3f} s: area {area.area_mm2:.2f} mm^2, gap {rows[-1]['lip_gap_mm']:.3f} mm, "
            f"{r['iterations']} Newton its, residual {r['residual_rel']:.1e}, {seconds:.1f} s"
        )

    start = time.perf_counter()
    if start_from == "pushed":  # the contact equilibrium at the first frame, as wface speech starts
        eq = face.body.solve(acts(times[0]), face.quad.rest_m, tol=tol, max_iterations=80)
    else:  # the rest shape: the first steps push the flesh out of the bones, as ArtiSynth's contact does
        eq = HexSolve(face.quad.rest_m.copy(), 0, 0.0, True, 0.0)
    record(times[0], eq.x_m, _stats([eq]), time.perf_counter() - start, 0)
    x, v = eq.x_m, np.zeros_like(eq.x_m)
    for f in range(1, len(times)):
        t_frame = time.perf_counter()
        span = times[f] - times[f - 1]
        n = max(1, int(np.ceil(span / DYNAMICS["max_step_s"] - 1e-9)))
        solves = []
        for k in range(1, n + 1):
            t = times[f - 1] + span * k / n
            x_new, v, r = face.body.step(
                x,
                v,
                span / n,
                acts(t),
                activations_start=acts(t - span / n),
                alpha_per_s=DYNAMICS["alpha_per_s"],
                beta_s=DYNAMICS["beta_s"],
                gravity_m_s2=DYNAMICS["gravity_m_s2"],
                tol=tol,
                max_iterations=max_iterations,
                exact_damping=exact_damping,
            )
            x = x_new
            solves.append(r)
        record(times[f], x, _stats(solves), time.perf_counter() - t_frame, n)
    mesh = {
        "hexes": int(len(face.quad.hexes)),
        "hex_nodes": int(face.quad.n_nodes),
        "free_hex_nodes": int(face.body.free.size),
        "tet_model_nodes": int(demo.n_nodes),
        "mass_kg": float(face.body.masses_kg.sum()),
    }
    return {
        "rows": rows,
        "states": np.array(states),
        "rest_hex_m": face.quad.rest_m,
        "mesh": mesh,
        "wall_seconds": time.perf_counter() - start,
    }


def _stats(solves) -> dict:
    return {
        "iterations": int(sum(r.iterations for r in solves)),
        "residual_rel": float(max(r.residual_rel for r in solves)),
        "penetration_m": float(max(r.max_penetration_m for r in solves)),
        "converged": bool(all(r.converged for r in solves)),
    }


def summarise(rows: list[dict]) -> dict:
    t = np.array([r["time_s"] for r in rows])
    area = np.array([r["lip_opening_area_mm2"] for r in rows])
    late = t >= 0.6 - 1e-9
    below = np.flatnonzero((area < 20.0) & (t >= 0.22))
    return {
        "area_before_excitation_mm2": float(area[np.argmin(np.abs(t - 0.2))]),
        "mean_area_t_ge_0p6_mm2": float(area[late].mean()) if late.any() else None,
        "below_20_mm2_from_s": float(t[below[0]]) if below.size else None,
        "newton_iterations": int(sum(r["newton_iterations"] for r in rows)),
        "residual_rel_max": float(max(r["residual_rel"] for r in rows)),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--data", type=Path, default=DATA, help="the artisynth-face data folder")
    p.add_argument("--model", type=Path, help="a saved Badin import (wface model import artisynth); default: import")
    p.add_argument("--contact", default="lips,skull", help="contact regions (lips, skull; '' for none)")
    p.add_argument("--fps", type=float, default=25.0, help="output frames per second (steps are 5 ms at most)")
    p.add_argument(
        "--end",
        type=float,
        help="stop at this time (s); default: the gesture's end; later, the curves hold their last values, as "
        "ArtiSynth's probes do",
    )
    p.add_argument(
        "--ring-directions",
        choices=("nearest", "delaunay"),
        default="nearest",
        help="the OOP ring's fibre directions: the 7M polyline's nearest segment or ArtiSynth's Delaunay blend",
    )
    p.add_argument(
        "--mass-lumping",
        choices=("equal", "rows"),
        default="equal",
        help="node masses: equal shares of each element's (ArtiSynth's) or the consistent mass's row sums",
    )
    p.add_argument(
        "--start",
        choices=("pushed", "rest"),
        default="pushed",
        help="frame 0: the contact equilibrium (flesh pushed out of the bones, as wface speech) or the rest shape",
    )
    p.add_argument(
        "--bulk",
        choices=BULKS,
        default="point",
        help="the bulk term: at each Gauss point, kappa/2 (ln J)^2 (wface's flesh law), or one volume ratio per hex "
        "(ArtiSynth's ELEMENT soft incompressibility) with ArtiSynth's quadratic potential kappa/2 (J - 1)^2 "
        "or the log one",
    )
    p.add_argument(
        "--lip-surface",
        choices=("smooth", "smooth_through_nodes", "faceted"),
        default="smooth",
        help="the lips' contact surfaces: the blend of their Loop refinement (wface speech's), which lies up to "
        "0.5 mm inside the faceted lips' nodes, that blend offset to pass through the nodes, or the faceted "
        "surfaces themselves (as ArtiSynth's lips collide; Newton converges worse on them)",
    )
    p.add_argument(
        "--lip-points",
        choices=("nodes_and_edges", "nodes"),
        default="nodes_and_edges",
        help="the lips' contact points: their nodes and edge midpoints (wface's), or their nodes only (as "
        "ArtiSynth's vertex penetrations)",
    )
    p.add_argument("--tol", type=float, default=1e-4, help="relative residual of each solve (wface speech's default)")
    p.add_argument(
        "--max-iterations",
        type=int,
        default=25,
        help="Newton iterations per time step at most (1: one linearised solve a step, as ArtiSynth's "
        "backward Euler makes; default 25, to --tol)",
    )
    p.add_argument(
        "--exact-damping",
        action="store_true",
        help="stiffness damping with the exact tangent at the step's start, as ArtiSynth's (default: projected)",
    )
    p.add_argument(
        "--fibre-stress",
        choices=("deviatoric", "blemker"),
        default="deviatoric",
        help="the muscles' law: deviatoric with wface's curves (the demo setup's) or with ArtiSynth's BlemkerMuscle "
        "curves (Material.fibre_stress)",
    )
    p.add_argument(
        "--idle-muscles",
        choices=("passive", "off"),
        default="passive",
        help="every muscle but OOP (the approximant drives OOP alone): passive fibres as wface's, or none "
        "(ArtiSynth's GenericMuscle passive is 0.05 Pa; wface speech --idle-muscles)",
    )
    p.add_argument(
        "--muscle-curves",
        choices=("wface", "artisynth"),
        default="wface",
        help="the muscles' curves: wface's on every muscle, or the demo's own (BlemkerMuscle's on OOP, "
        "GenericMuscle's, with no passive stress, on the others; wface speech --muscle-curves)",
    )
    p.add_argument("--gesture", default="approximant", help="the gesture played (closure, fricative, approximant)")
    p.add_argument(
        "--muscle-elements",
        choices=("import", "artisynth"),
        default="import",
        help="every muscle but OOP as the import embeds it, or on the demo's whole hexes "
        "(wface speech --muscle-elements)",
    )
    p.add_argument(
        "--lower-oom",
        choices=LOWER_OOM_CHOICES,
        default="whole",
        help="what the OOMl exciter drives (wface speech --lower-oom)",
    )
    p.add_argument(
        "--wedges",
        choices=WEDGE_RULES,
        default="collapsed",
        help="the 318 hexes collapsed to wedges: the 2x2x2 rule of a collapsed hex (default) or ArtiSynth's "
        "WedgeElement rule (wface.physics.hexes.wedge_rule)",
    )
    a = p.parse_args(argv)
    if not a.data.is_dir():
        p.error(f"no ArtiSynth face data at {a.data} (--data)")
    from wface.faces.artisynth import import_artisynth
    from wface.model import load_model

    base = load_model(a.model) if a.model else import_artisynth(a.data, progress=False)
    run = play(
        base,
        a.data,
        contact=a.contact,
        fps=a.fps,
        end_s=a.end,
        tol=a.tol,
        max_iterations=a.max_iterations,
        exact_damping=a.exact_damping,
        ring_directions=a.ring_directions,
        mass_lumping=a.mass_lumping,
        start_from=a.start,
        bulk=a.bulk,
        lip_surface=a.lip_surface,
        lip_points=a.lip_points,
        fibre_stress=a.fibre_stress,
        idle_muscles=a.idle_muscles,
        muscle_curves=a.muscle_curves,
        muscle_elements=a.muscle_elements,
        gesture_name=a.gesture,
        lower_oom=a.lower_oom,
        wedges=a.wedges,
    )
    a.out.mkdir(parents=True, exist_ok=True)
    with open(a.out / "lip_opening.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(run["rows"][0]))
        w.writeheader()
        w.writerows(run["rows"])
    np.savez_compressed(
        a.out / "states.npz",
        x_hex_m=run["states"],
        rest_hex_m=run["rest_hex_m"],
        time_s=[r["time_s"] for r in run["rows"]],
    )
    report = {
        "contact": a.contact,
        "ring_directions": a.ring_directions,
        "mass_lumping": a.mass_lumping,
        "start": a.start,
        "bulk": a.bulk,
        "lip_surface": a.lip_surface,
        "lip_points": a.lip_points,
        "wedges": a.wedges,
        "fps": a.fps,
        "tol": a.tol,
        "max_iterations": a.max_iterations,
        "exact_damping": a.exact_damping,
        "fibre_stress": a.fibre_stress,
        "idle_muscles": a.idle_muscles,
        "muscle_curves": a.muscle_curves,
        "muscle_elements": a.muscle_elements,
        "gesture": a.gesture,
        "lower_oom": a.lower_oom,
        "dynamics": DYNAMICS,
        "mesh": run["mesh"],
        "summary": summarise(run["rows"]),
        "wall_seconds": run["wall_seconds"],
    }
    (a.out / "report.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report["summary"], indent=2))
    print(f"wrote {a.out / 'lip_opening.csv'}, report.json and states.npz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
