"""The lip opening area of ArtiSynth's own runs of the Badin lip-opening demo, measured by wface.

``examples/artisynth_reference/RunLipOpening.java`` runs ArtiSynth's ``BadinFaceDemoLipOpening``
headless and writes the face's FEM nodes every 0.01 s. This script measures the mouth aperture of each
frame with wface's measure (``wface.speech.aperture``: ArtiSynth's orthographic camera and green plane,
the occluders the boundary of ArtiSynth's own hex mesh) and sets each run's curve beside the original's
recorded output (``speech/approximant/lip_opening_area.txt``) and, optionally, wface's own curves
(``lip_opening.csv`` from ``wface speech --out DIR``). wface's own play on ArtiSynth's hexes
(``states.npz`` from ``examples/badin_hexes_play.py``, ``--hexes``) is measured as ArtiSynth's runs are,
on the same nodes and boundary, and so is a ``wface speech`` run on the import's tets (its ``states.npz``,
``--tets``: the node file's nodes, which the import keeps first, measured on ArtiSynth's hex boundary);
``--lip-nodes`` gives the mean distance of the lip collision surfaces' nodes between every two runs at chosen
times. See README.md, "ArtiSynth itself, run headless".

    python examples/artisynth_lip_area.py as_shipped=nodes_all.txt no_contact=nodes_none.txt \\
        --data ../shared/data/artisynth-face --out out/artisynth_runs
    python examples/artisynth_lip_area.py demo=nodes_all.txt --wface "wface demo setup"=appr/lip_opening.csv \\
        --data ../shared/data/artisynth-face --out out/artisynth_runs
    python examples/artisynth_lip_area.py demo=nodes_all.txt --hexes "wface, hexes"=hexplay/states.npz \\
        --lip-nodes 0.28 0.44 0.6 --data ../shared/data/artisynth-face --out out/hexes
    python examples/artisynth_lip_area.py fricative=nodes_fricative.txt --tets "wface, tets"=fricative/states.npz \\
        --lip-nodes 0.4 0.6 --gesture fricative --data ../shared/data/artisynth-face --out out/tets

Writes ``artisynth_lip_area.json`` (per run and frame: area, its discretisation error, the aperture's
width and height; per run: area at rest, before the excitation and over t >= 0.6 s, when it first falls
below 20 and 0.5 mm^2, RMS from the original; with ``--lip-nodes``, the lip-node distances) and
``artisynth_lip_area.png``.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import meshio
import numpy as np
from scipy.spatial import cKDTree

from wface.faces.ansys import hex_boundary_triangles, read_ansys_elements, read_ansys_nodes
from wface.faces.artisynth import BADIN_TO_WFACE, MESH_PREFIX, badin_to_wface
from wface.speech.aperture import ApertureView, aperture_area
from wface.speech.gestures import read_gesture
from wface.speech.playback import compare_with_reference

LIP_SURFACES = ("face_collisionSurf_upperLip_reduced2.ply", "face_collisionSurf_lowerLip_reduced.ply")
NODE_MATCH_TOL_M = 1e-5  # the lip surfaces' vertices are FEM nodes (their files print fewer digits): as the import


def read_node_dump(path: str | Path, n_nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times (F,) s, OOP excitation (F,), node positions (F, n, 3) m, Badin frame) of a RunLipOpening dump.

    A last frame cut short (a run stopped mid-write) is dropped with a note; a first frame with another
    node count than the mesh's is an error, as it belongs to another mesh."""
    lines = Path(path).read_text().splitlines()
    times, oop, frames = [], [], []
    i = 0
    while i < len(lines) and lines[i].startswith("T "):
        block = lines[i + 1 : i + 1 + n_nodes]
        complete = len(block) == n_nodes and all(len(b.split()) == 3 for b in block)
        nxt = i + 1 + n_nodes
        if complete and nxt < len(lines) and lines[nxt].strip() and not lines[nxt].startswith("T "):
            complete = False  # more node lines than the mesh has
        if not complete:
            if not frames:
                raise ValueError(f"{path}: the first frame does not hold {n_nodes} node lines (another mesh?)")
            print(f"{path}: frame {len(frames)} (t = {lines[i].split()[1]} s) is incomplete; read to there")
            break
        _, t, e = lines[i].split()
        times.append(float(t))
        oop.append(float(e))
        frames.append(np.array([b.split() for b in block], dtype=np.float64))
        i = nxt
    if not frames:
        raise ValueError(f"{path}: no frame (a RunLipOpening dump starts with a line 'T <time> <excitation>')")
    return np.array(times), np.array(oop), np.stack(frames)


def read_hex_states(path: str | Path, n_nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times (F,) s, OOP (F,) NaN, node positions (F, n, 3) m, Badin frame) of wface's play on the hexes
    (``examples/badin_hexes_play.py``'s states.npz: hex nodes in the node file's order, wface's frame)."""
    with np.load(path) as s:
        if "x_hex_m" not in s:
            raise ValueError(f"{path}: no x_hex_m (a states.npz from examples/badin_hexes_play.py?)")
        x, t = s["x_hex_m"], s["time_s"]
    if x.shape[1] != n_nodes:
        raise ValueError(f"{path}: {x.shape[1]} hex nodes, the mesh has {n_nodes}")
    return np.asarray(t, dtype=np.float64), np.full(len(t), np.nan), x @ BADIN_TO_WFACE  # the inverse rotation


def read_speech_states(path: str | Path, n_nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times (F,) s, OOP (F,) NaN, node positions (F, n, 3) m, Badin frame) of a ``wface speech`` run on the
    import's tets (its states.npz): the first ``n_nodes`` nodes, the node file's, which the import keeps first in
    the file's order."""
    with np.load(path) as s:
        if "node_positions_m" not in s:
            raise ValueError(f"{path}: no node_positions_m (a states.npz from wface speech?)")
        x, t = s["node_positions_m"], s["times_s"]
    if x.shape[1] < n_nodes:
        raise ValueError(f"{path}: {x.shape[1]} nodes, fewer than the node file's {n_nodes}: not a Badin import")
    return np.asarray(t, dtype=np.float64), np.full(len(t), np.nan), x[:, :n_nodes] @ BADIN_TO_WFACE


def lip_node_distances(runs: dict, near: np.ndarray, times_s) -> dict:
    """{"A / B": {time: mean distance (mm) of the lip nodes ``near``}} for every two runs (label: (times,
    positions)) at each of ``times_s`` both have a frame at (within 1 ms)."""
    out = {}
    labels = list(runs)
    for i, a in enumerate(labels):
        for b in labels[i + 1 :]:
            row = {}
            for t in times_s:
                (ta, xa), (tb, xb) = runs[a], runs[b]
                fa, fb = int(np.argmin(np.abs(ta - t))), int(np.argmin(np.abs(tb - t)))
                if abs(ta[fa] - t) < 1e-3 and abs(tb[fb] - t) < 1e-3:
                    row[f"{t:g}"] = 1e3 * float(np.linalg.norm(xa[fa][near] - xb[fb][near], axis=1).mean())
            out[f"{a} / {b}"] = row
    return out


def lip_node_ids(data_dir: Path, x_rest_badin: np.ndarray) -> np.ndarray:
    """Node ids of the two lip collision surfaces' vertices (near which an aperture is the mouth's)."""
    tree = cKDTree(x_rest_badin)
    ids = []
    for name in LIP_SURFACES:
        pts = np.asarray(meshio.read(data_dir / name).points, dtype=np.float64)
        dist, idx = tree.query(pts)
        if dist.max() > NODE_MATCH_TOL_M:
            raise ValueError(f"{name}: a vertex lies {dist.max() * 1e3:.4f} mm from the nearest FEM node")
        ids.append(idx)
    return np.unique(np.concatenate(ids))


def measure_run(x_badin: np.ndarray, triangles: np.ndarray, near: np.ndarray, resolution_m: float) -> np.ndarray:
    """(F, 4) area and its discretisation error (mm^2), the aperture's width and height (mm) per frame."""
    view = ApertureView.artisynth_badin()
    out = np.zeros((len(x_badin), 4))
    for f, xb in enumerate(x_badin):
        x = badin_to_wface(xb)
        r = aperture_area(x, triangles, view, resolution_m=resolution_m, near_points_m=x[near])
        out[f] = r.area_mm2, r.error_mm2, r.width_mm, r.height_mm
    return out


def first_below(times: np.ndarray, area: np.ndarray, level_mm2: float, after_s: float = 0.22) -> float | None:
    """First time after ``after_s`` at which the area is below ``level_mm2`` (None: never)."""
    hit = np.flatnonzero((times > after_s) & (area < level_mm2))
    return float(times[hit[0]]) if hit.size else None


def summarise(times: np.ndarray, area: np.ndarray, reference: np.ndarray | None) -> dict:
    """Rest, before-excitation and late areas, closing times and the comparison with the original."""
    cmp = compare_with_reference(SimpleNamespace(times_s=times, lip_opening_area_mm2=area), reference)
    late = times >= 0.6 - 1e-9
    return {
        "rest_mm2": float(area[0]),
        "before_excitation_mm2": float(area[times <= 0.22 + 1e-9].max()),
        "mean_after_0.6s_mm2": float(area[late].mean()) if late.any() else None,
        "below_20_from_s": first_below(times, area, 20.0),
        "shut_from_s": first_below(times, area, 0.5),
        "end_s": float(times[-1]),
        "rms_from_original_mm2": None if cmp is None else cmp["rms_mm2"],
    }


def read_wface_curve(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(times, area) of a ``lip_opening.csv`` written by ``wface speech``."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows or "time_s" not in rows[0] or "lip_opening_area_mm2" not in rows[0]:
        raise ValueError(f"{path}: expected the columns time_s and lip_opening_area_mm2 (wface speech's CSV)")
    return (
        np.array([float(r["time_s"]) for r in rows]),
        np.array([float(r["lip_opening_area_mm2"]) for r in rows]),
    )


def plot(runs: dict, wface_curves: dict, reference: np.ndarray | None, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8.0, 4.6))
    if reference is not None:
        ax.plot(reference[:, 0], reference[:, 1], "k--", lw=1.6, label="original (ArtiSynth's recorded output)")
    for label, run in runs.items():
        if run.get("source") == "wface on the hexes":
            ax.plot(run["times_s"], run["area_mm2"], "-.", lw=1.8, label=f"wface: {label}")
        elif run.get("source") == "wface on its tets":
            ax.plot(run["times_s"], run["area_mm2"], "--", lw=1.6, label=f"wface: {label}")
        else:
            ax.plot(run["times_s"], run["area_mm2"], lw=1.6, label=f"ArtiSynth run here: {label}")
    for label, (t, a) in wface_curves.items():
        ax.plot(t, a, ":", lw=1.6, label=f"wface: {label}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("lip opening area (mm$^2$)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    n_curves = len(ax.get_lines())
    if n_curves > 4:  # many curves: the legend goes below the axes, where it covers none of them
        fig.set_figheight(4.6 + 0.2 * ((n_curves + 1) // 2))
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
    else:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _labelled(spec: str, what: str) -> tuple[str, Path]:
    """(label, path) of LABEL=PATH, or of a bare PATH labelled by its file name."""
    label, sep, path = spec.rpartition("=")
    if not sep or not label:
        label, path = Path(spec).stem, spec
    if not Path(path).is_file():
        raise SystemExit(f"{what} {spec!r}: no file {path}")
    return label, Path(path)


_SOURCES = {read_node_dump: "ArtiSynth", read_hex_states: "wface on the hexes", read_speech_states: "wface on its tets"}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="[LABEL=]NODES.txt: RunLipOpening dumps (label: the file name)")
    ap.add_argument("--data", type=Path, required=True, help="the ArtiSynth Badin face data folder")
    ap.add_argument("--wface", action="append", default=[], help="[LABEL=]lip_opening.csv from wface speech")
    ap.add_argument("--hexes", action="append", default=[], help="[LABEL=]states.npz from badin_hexes_play.py")
    ap.add_argument(
        "--tets", action="append", default=[], help="[LABEL=]states.npz from wface speech on the Badin import"
    )
    ap.add_argument("--lip-nodes", type=float, nargs="+", default=[], help="times (s) of lip-node distances")
    ap.add_argument("--resolution-mm", type=float, default=0.05, help="scanline spacing of the area measure")
    ap.add_argument(
        "--gesture",
        default="approximant",
        help="the gesture the runs played (its recorded curve, where the data has samples, is the original's)",
    )
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    runs_in = [(*_labelled(s, "run"), read_node_dump) for s in args.runs]
    runs_in += [(*_labelled(s, "--hexes"), read_hex_states) for s in args.hexes]
    runs_in += [(*_labelled(s, "--tets"), read_speech_states) for s in args.tets]
    wface_curves = {label: read_wface_curve(p) for label, p in (_labelled(s, "--wface") for s in args.wface)}
    numbers, x_rest = read_ansys_nodes(args.data / f"{MESH_PREFIX}.node")
    index_of = np.full(int(numbers.max()) + 1, -1, dtype=np.int64)
    index_of[numbers] = np.arange(len(numbers))
    hexes = index_of[read_ansys_elements(args.data / f"{MESH_PREFIX}.elem")]
    triangles = hex_boundary_triangles(hexes)
    near = lip_node_ids(args.data, x_rest)
    gesture_dir = args.data / "speech" / args.gesture
    reference = read_gesture(gesture_dir).reference_lip_area if gesture_dir.is_dir() else None
    args.out.mkdir(parents=True, exist_ok=True)
    report: dict = {"mesh": {"nodes": len(x_rest), "hexes": len(hexes), "boundary_triangles": len(triangles)}}
    runs, positions = {}, {}
    for label, path, read in runs_in:
        times, oop, X = read(path, len(x_rest))
        positions[label] = (times, X)
        rest_err = float(np.abs(X[0] - x_rest).max()) if times[0] == 0 else None
        area = measure_run(X, triangles, near, args.resolution_mm * 1e-3)
        runs[label] = {
            "dump": str(path),
            "times_s": times.tolist(),
            "oop": None if np.isnan(oop).all() else oop.tolist(),
            "source": _SOURCES[read],
            "area_mm2": area[:, 0].tolist(),
            "error_mm2": area[:, 1].tolist(),
            "width_mm": area[:, 2].tolist(),
            "height_mm": area[:, 3].tolist(),
            "rest_node_difference_m": rest_err,
            **summarise(times, area[:, 0], reference),
        }
        s = runs[label]
        print(
            f"{label}: rest {s['rest_mm2']:.2f}, before the excitation {s['before_excitation_mm2']:.2f}, "
            f"mean over t >= 0.6 s {s['mean_after_0.6s_mm2']}, below 20 from {s['below_20_from_s']} s, "
            f"shut from {s['shut_from_s']} s, RMS from the original {s['rms_from_original_mm2']} mm^2"
        )
    report["runs"] = runs
    if args.lip_nodes:
        report["lip_node_distance_mm"] = lip_node_distances(positions, near, args.lip_nodes)
        for pair, row in report["lip_node_distance_mm"].items():
            print(f"lip nodes {pair}: " + ", ".join(f"{d:.3f} mm at {t} s" for t, d in row.items()))
    if reference is not None:
        report["original"] = summarise(reference[:, 0], reference[:, 1], None)
    (args.out / "artisynth_lip_area.json").write_text(json.dumps(report, indent=1))
    title = {"approximant": "Approximant (OOP to 0.3)"}.get(args.gesture, args.gesture.capitalize())
    plot(
        runs,
        wface_curves,
        reference,
        args.out / "artisynth_lip_area.png",
        f"{title}: ArtiSynth's demo run headless, measured by wface",
    )
    print(f"wrote {args.out / 'artisynth_lip_area.json'} and artisynth_lip_area.png")
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
