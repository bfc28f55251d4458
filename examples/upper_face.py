"""What limits the upper face on EyebrowsMoCap and JawMoCap? The brow and forehead markers against the model.

    python examples/upper_face.py --out out/upper_face                      # the analysis, 5,000 tets
    python examples/upper_face.py --out out/upper_face --variants           # + the glide-plane faces tracked

The capture (``$WFACE_DATA/animface/<Take>MoCap.c3d``) is aligned and embedded at its neutral frame 0
(``prepare_capture``). The head motion is removed frame by frame with the four eye corners and the
nose-top marker (``remove_head_motion``): the canthal tendons tie the corners to the orbital rims and
NoseTop sits on the nasion, where the forehead markers, which the other examples use, move with the
brows in these takes (on CheeksMoCap the eye corners move with the cheeks, 2 mm median about their
rigid fit, and the example warns that they do not hold the head there). Each upper-face marker's
displacement from neutral is split into its component along the model's outward skin normal (out of
the face: positive), along the skin's upward tangent and, off the midline, along its tangent toward
the midline (medial). Against it, what the muscles can do: per marker and direction (out, in, up,
down, medial), the motion when every muscle that moves the marker that way at rest (from the rig's
Jacobian) is fully active at once, solved as one nonlinear equilibrium with the jaw closed.

``--variants`` then tracks each take (``--frames`` from 0, every ``--holdout``-th marker by height
hidden, ``wface track`` with its defaults) on the built-in face and on faces whose bone side glides
where the anatomy has glide planes (docs/design.md, "Built-in face attachments"): the deep forehead
over the frontal bone (the subgaleal plane, from ``--forehead-from-mm`` above the eyes' centre to the
top of the patch, between the temporal lines at |theta| <= 0.85 rad), that with the brows' fat pads
too (from ``--brows-from-mm``), each with the patch's top edge (the galea's anchor) held whole or held
at the skin alone, or free; and the built-in face and the forehead glide with the edge held at the skin
with both frontalis parts ``--frontalis-strength`` times as strong. Writes ``upper_face.json``,
``upper_face.png`` and ``variants.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

from wface.cli import main as wface_main
from wface.faces.builtin import build_face
from wface.io.mocap import read_mocap
from wface.mesh.align import remove_head_motion
from wface.mesh.surface import vertex_normals
from wface.model import load_model, save_model
from wface.tracking.capture import prepare_capture
from wface.tracking.rig import FaceRig

STABLE = ("Leye_Inside", "Reye_Inside", "Leye_Outside", "Reye_Outside", "NoseTop")
UPPER = (
    "ForeHead_L",
    "ForeHead_M",
    "ForeHead_R",
    "Eyebrow_Center",
    "Leyebrow_Inside",
    "Leyebrow_M",
    "Leyebrow_Outside",
    "Reyebrow_Inside",
    "Reyebrow_M",
    "Reyebrow_Outside",
)
# (word, axis, sign): along the skin's outward normal, its upward tangent, and its tangent toward the midline
DIRECTIONS = (
    ("out", "out", 1.0),
    ("in", "out", -1.0),
    ("up", "up", 1.0),
    ("down", "up", -1.0),
    ("medial", "medial", 1.0),
)
TAKES = ("Eyebrows", "Jaw", "Nose", "Cheeks")
STABLE_RESIDUAL_LIMIT_MM = 1.0  # median motion of the stable markers about their rigid fit that still holds the head
TEMPORAL_LINE_RAD = 0.85  # |theta| of the temporal lines, the subgaleal plane's sides
TOP_EDGE_M = 0.084  # nodes above this height form the patch's top edge (Y_TOP = 0.085 m)


def data_dir() -> Path:
    return Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))


def skin_frames(model, markers) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) outward unit skin normals and (k, 3) unit upward skin tangents at the embedded markers."""
    emb = markers.embedding
    n = vertex_normals(model.rest_positions_m, model.skin_triangles)
    tri = model.skin_triangles[emb.triangle]
    normal = np.einsum("kj,kjd->kd", emb.barycentric, n[tri])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    up = np.array([0.0, 1.0, 0.0]) - normal[:, 1:2] * normal  # the face's +y on the tangent plane
    return normal, up / np.linalg.norm(up, axis=1, keepdims=True)


def side_of(name: str) -> int:
    """+1 for a marker on the subject's left (+x), -1 on the right, 0 on the midline (AnimFace names)."""
    if name.endswith("_L") or name.startswith("L"):
        return 1
    if name.endswith("_R") or name.startswith("R"):
        return -1
    return 0


def medial_tangents(names: list[str], normal: np.ndarray) -> np.ndarray:
    """(k, 3) unit skin tangents toward the face's midplane (x = 0) at the markers; NaN on the midline."""
    side = np.array([side_of(n) for n in names], dtype=float)
    toward = -side[:, None] * np.array([1.0, 0.0, 0.0])
    t = toward - np.sum(toward * normal, axis=1, keepdims=True) * normal
    with np.errstate(invalid="ignore"):
        t /= np.linalg.norm(t, axis=1, keepdims=True)
    t[side == 0] = np.nan
    return t


def analyse(model, take, frames: int) -> dict:
    """The capture's out/in and up/down motion of the upper-face markers and the muscles' reach."""
    names = list(take.marker_names)
    cap = prepare_capture(model, take.positions_m[:frames], names, reference_positions_m=take.positions_m[0])
    stable = [names.index(n) for n in STABLE]
    still, _ = remove_head_motion(cap.targets_m, stable, reference_m=cap.targets_m[0])
    fit_mm = np.linalg.norm(still[:, stable] - still[0, stable], axis=2) * 1e3
    upper = [names.index(n) for n in UPPER]
    normal, up = skin_frames(model, cap.markers)
    rig = FaceRig(model, tol=1e-6)
    c0 = rig.rest_controls()
    state = rig.equilibrium(c0)
    rest_m = cap.markers.positions(state.x_m)
    axes = {"out": normal, "up": up, "medial": medial_tangents(names, normal)}
    d = still[:, upper] - still[0, upper]  # (F, k, 3), head motion removed
    along_mm = {key: np.einsum("fkd,kd->fk", d, axis[upper]) * 1e3 for key, axis in axes.items()}
    J = cap.markers.jacobian(rig.jacobian(state, cap.markers.nodes)).reshape(len(names), 3, -1)
    M = model.n_muscles
    fibre = np.array([n not in model.pressure_actuators for n in model.muscle_names])
    reach: dict = {}
    capture: dict = {}
    for j, k in enumerate(upper):
        reach[UPPER[j]], capture[UPPER[j]] = {}, {}
        for word, key, sign in DIRECTIONS:
            axis = axes[key][k]
            if not np.all(np.isfinite(axis)):
                continue  # a marker on the midline has no medial direction
            capture[UPPER[j]][word] = float(np.nanmax(sign * along_mm[key][:, j]))
            per = sign * (axis @ J[k, :, :M]) * fibre  # m per unit activation
            movers = np.flatnonzero(per > 0)
            c = c0.copy()
            c[movers] = 1.0
            moved = cap.markers.positions(rig.equilibrium(c, state.y_m).x_m)[k] - rest_m[k]
            reach[UPPER[j]][word] = {
                "all_movers_on_mm": float(sign * moved @ axis * 1e3),
                "strongest": [model.muscle_names[i] for i in movers[np.argsort(-per[movers])][:3]],
            }
    return {
        "frames": int(frames),
        "stable_markers": list(STABLE),
        "stable_residual_mm_median": float(np.nanmedian(fit_mm)),
        "stable_residual_mm_max": float(np.nanmax(fit_mm)),
        "head_motion_removed_reliably": bool(np.nanmedian(fit_mm) <= STABLE_RESIDUAL_LIMIT_MM),
        "capture_max_mm": capture,
        "model_reach": reach,
        "out_mm": along_mm["out"].tolist(),
        "up_mm": along_mm["up"].tolist(),
        "fps": take.rate_hz,
    }


def glide_face(tets: int, *, from_mm: float, top: str) -> object:
    """The built-in face with its bone side free (gliding) above ``from_mm`` between the temporal lines.

    ``top``: the patch's top edge there held whole (``"held"``), held at the skin alone
    (``"skin"``: the galea's deep side slides), or free (``"free"``)."""
    model = build_face(tets)
    x = model.rest_positions_m
    theta = np.arctan2(x[:, 0], x[:, 2])
    a = model.attached_nodes
    skin = np.zeros(len(x), dtype=bool)
    skin[np.unique(model.skin_triangles)] = True
    within = np.abs(theta[a]) <= TEMPORAL_LINE_RAD
    edge = x[a, 1] > TOP_EDGE_M
    deep = ~skin[a] & ~edge & within & (x[a, 1] >= from_mm / 1e3)
    if top == "skin":
        deep |= edge & within & ~skin[a]
    elif top == "free":
        deep |= edge & within
    model.attached_nodes = a[~deep]
    model.attached_bone = model.attached_bone[~deep]
    model.metadata["glide"] = {"from_mm": from_mm, "top_edge": top, "freed_nodes": int(deep.sum())}
    model.validate()
    return model


def used_rms_without_upper(run: Path, report: dict, names: list[str]) -> float:
    """Mean over frames of the RMS error (face mm) of the markers used in the fit, brows and forehead left out."""
    held = set(report["holdout_markers"])
    keep = [i for i, n in enumerate(names) if n not in held and n not in UPPER]
    frames = sorted((run / "frames").glob("frame_*.npz"))
    err_mm = np.array([np.load(f)["marker_error_m"][keep] for f in frames]) * 1e3
    return float(np.mean(np.sqrt(np.nanmean(err_mm**2, axis=1))))


def track_variants(args, out: Path) -> list[dict]:
    """Track every take on the built-in face and the glide-plane variants; one row per run."""
    k = args.frontalis_strength
    variants = [("built-in face", None, None, 1.0)]
    for from_mm, word in ((args.forehead_from_mm, "forehead"), (args.brows_from_mm, "forehead and brows")):
        variants += [(f"{word} glide, top edge {top}", from_mm, top, 1.0) for top in ("held", "skin", "free")]
    if k != 1.0:
        variants += [(f"built-in face, frontalis x{k:g}", None, None, k)]
        variants += [(f"forehead glide, top edge skin, frontalis x{k:g}", args.forehead_from_mm, "skin", k)]
    names = {take: list(read_mocap(data_dir() / "animface" / f"{take}MoCap.c3d").marker_names) for take in args.takes}
    rows = []
    for label, from_mm, top, strength in variants:
        model = build_face(args.tets) if from_mm is None else glide_face(args.tets, from_mm=from_mm, top=top)
        tag = "builtin" if from_mm is None else f"glide{from_mm:g}_{top}"
        if strength != 1.0:
            frontalis = np.array([n.startswith("frontalis") for n in model.muscle_names])
            model.muscle_strength = np.where(frontalis, strength, 1.0) * model.muscle_strength
            tag += f"_frontalis{strength:g}"
        path = save_model(model, out / f"{tag}.npz")
        for take in args.takes:
            run = out / f"{take}_{tag}"
            argv = ["track", "--model", str(path), "--mocap", str(data_dir() / "animface" / f"{take}MoCap.c3d")]
            argv += ["--frames", f"0:{args.frames}", "--holdout", str(args.holdout), "--no-pictures", "--no-usd"]
            if wface_main([*argv, "--overwrite", "--out", str(run)]) != 0:  # a rerun measures again
                raise SystemExit(f"wface track failed on {take} with {label}")
            rep = json.loads((run / "report.json").read_text())
            per = rep["marker_rms_mm_per_marker"] | rep["holdout_rms_mm_per_marker"]
            rows.append(
                {
                    "take": take,
                    "face": label,
                    "capture_to_model_scale": rep["capture_to_model_scale"],
                    "used_mm": rep["marker_rms_mm_mean"],
                    "held_out_mm": rep["holdout_rms_mm_mean"],
                    "used_below_the_brows_mm": used_rms_without_upper(run, rep, names[take]),
                    "upper_markers_mm": {n: per[n] for n in UPPER if per.get(n) is not None},
                }
            )
    return rows


PANELS = (("out", "in", "normal"), ("up", "down", "upward tangent"), ("medial", None, "tangent toward the midline"))


def plot(path: Path, results: list[dict]) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), len(PANELS), figsize=(16, 3.6 * len(results)), squeeze=False)
    x = np.arange(len(UPPER))
    labels = [n.replace("eyebrow", "brow").replace("ForeHead", "Fh") for n in UPPER]
    for row, res in zip(axes, results, strict=True):
        cap, reach = res["capture_max_mm"], res["model_reach"]
        for ax, (pos, neg, along) in zip(row, PANELS, strict=True):
            for word, sign, dx, colour in ((pos, 1.0, -0.2, "tab:blue"), (neg, -1.0, 0.2, "tab:orange")):
                if word is None:
                    continue
                got = [sign * cap[n].get(word, np.nan) for n in UPPER]
                ax.bar(x + dx, got, 0.4, color=colour, label=f"capture, most {word}")
                can = [sign * reach[n][word]["all_movers_on_mm"] if word in reach[n] else np.nan for n in UPPER]
                ax.scatter(
                    x + dx, can, marker="_", s=300, c="k", label="muscles' reach" if sign < 0 or not neg else None
                )
            ax.axhline(0.0, color="0.5", lw=0.6)
            ax.set_xticks(x, labels, fontsize=7, rotation=30)
            ax.set_ylabel(f"{pos} (+)" + (f" / {neg} (-)" if neg else "") + " from neutral (mm)", fontsize=8)
            ax.set_title(f"{res['take']}MoCap 0:{res['frames']}: along the skin's {along}", fontsize=9)
            ax.grid(alpha=0.3, axis="y")
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def variants_table(rows: list[dict]) -> str:
    """The runs as a Markdown table, in the face's millimetres."""
    lines = [
        "| take | face | marker RMS used (mm) | used, brows and forehead left out | held-out RMS (mm) | "
        "ForeHead_M | Reyebrow_M | Reyebrow_Inside (held out) |"
    ]
    lines.append("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        m = r["upper_markers_mm"]
        cells = [f"{m[n]:.2f}" if n in m else "-" for n in ("ForeHead_M", "Reyebrow_M", "Reyebrow_Inside")]
        lines.append(
            f"| {r['take']} | {r['face']} | {r['used_mm']:.3f} | {r['used_below_the_brows_mm']:.3f} | "
            f"{r['held_out_mm']:.3f} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--model", help="face model (.npz) for the analysis; default the built-in face with --tets")
    p.add_argument("--tets", type=int, default=5000, help="size of the built-in face (default 5000)")
    p.add_argument(
        "--takes", nargs="+", default=["Eyebrows", "Jaw"], choices=TAKES, help="AnimFace takes (default Eyebrows Jaw)"
    )
    p.add_argument("--frames", type=int, default=300, help="frames of each take from 0 (default 300)")
    p.add_argument("--variants", action="store_true", help="also track the takes on the glide-plane faces")
    p.add_argument("--holdout", type=int, default=5, help="hide every N-th marker by height (default 5)")
    p.add_argument("--forehead-from-mm", type=float, default=40.0, help="subgaleal glide from this height (40)")
    p.add_argument("--brows-from-mm", type=float, default=22.0, help="with the brows' fat pads, from this height (22)")
    p.add_argument(
        "--frontalis-strength", type=float, default=3.0, help="also both frontalis parts this much stronger (3; 1: not)"
    )
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = load_model(args.model) if args.model else build_face(args.tets)
    results = []
    for name in args.takes:
        take = read_mocap(data_dir() / "animface" / f"{name}MoCap.c3d")
        res = analyse(model, take, min(args.frames, take.positions_m.shape[0]))
        res["take"] = name
        results.append(res)
        if not res["head_motion_removed_reliably"]:
            print(
                f"warning: {name}: the eye corners and NoseTop move {res['stable_residual_mm_median']:.1f} mm (median) "
                "about their rigid fit, so they do not hold the head in this take and the motions below are not "
                "the skin's alone",
                file=sys.stderr,
            )
        for n in UPPER:
            c, r = res["capture_max_mm"][n], res["model_reach"][n]
            print(
                f"{name} {n}: capture " + " ".join(f"{d} {c[d]:.1f}" for d in c) + " mm; "
                "muscles " + " ".join(f"{d} {r[d]['all_movers_on_mm']:.1f}" for d in r)
            )
    summary = [{k: v for k, v in r.items() if k not in ("out_mm", "up_mm")} for r in results]
    plot(out / "upper_face.png", results)
    report = {"analysis": summary}
    if args.variants:
        rows = track_variants(args, out)
        report["variants"] = rows
        (out / "variants.md").write_text(variants_table(rows))
        print(variants_table(rows))
    (out / "upper_face.json").write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
