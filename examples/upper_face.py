"""What limits the upper face on EyebrowsMoCap and JawMoCap? The brow and forehead markers against the model.

    python examples/upper_face.py --out out/upper_face                      # the analysis, 5,000 tets
    python examples/upper_face.py --out out/upper_face --variants           # + the glide-plane faces tracked

The capture (``$WFACE_DATA/animface/<Take>MoCap.c3d``) is aligned and embedded at its neutral frame 0
(``prepare_capture``). The head motion is removed frame by frame with the four eye corners and the
nose-top marker (``remove_head_motion``): the canthal tendons tie the corners to the orbital rims and
NoseTop sits on the nasion, where the forehead markers, which the other examples use, move with the
brows in these takes. Each upper-face marker's displacement from neutral is split into its component
along the model's outward skin normal (out of the face: positive), along the skin's upward tangent, and
the rest. Against it, what the muscles can do: per marker and direction (out, in, up, down), the motion
when every muscle that moves the marker that way at rest (from the rig's Jacobian) is fully active at
once, solved as one nonlinear equilibrium with the jaw closed.

``--variants`` then tracks each take (``--frames`` from 0, every ``--holdout``-th marker by height
hidden, ``wface track`` with its defaults) on the built-in face and on faces whose bone side glides
where the anatomy has glide planes (docs/design.md, "Built-in face attachments"): the deep forehead
over the frontal bone (the subgaleal plane, from ``--forehead-from-mm`` above the eyes' centre to the
top of the patch, between the temporal lines at |theta| <= 0.85 rad), that with the brows' fat pads
too (from ``--brows-from-mm``), each with the patch's top edge (the galea's anchor) held whole or held
at the skin alone, or free. Writes ``upper_face.json``, ``upper_face.png`` and ``variants.md``.
"""

from __future__ import annotations

import argparse
import json
import os
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
DIRECTIONS = ("out", "in", "up", "down")
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


def analyse(model, take, frames: int) -> dict:
    """The capture's out/in and up/down motion of the upper-face markers and the muscles' reach."""
    names = list(take.marker_names)
    cap = prepare_capture(model, take.positions_m[:frames], names, reference_positions_m=take.positions_m[0])
    stable = [names.index(n) for n in STABLE]
    still, _ = remove_head_motion(cap.targets_m, stable, reference_m=cap.targets_m[0])
    fit_mm = np.linalg.norm(still[:, stable] - still[0, stable], axis=2) * 1e3
    upper = [names.index(n) for n in UPPER]
    normal, up = skin_frames(model, cap.markers)
    d = still[:, upper] - still[0, upper]  # (F, k, 3), head motion removed
    out_mm = np.einsum("fkd,kd->fk", d, normal[upper]) * 1e3
    up_mm = np.einsum("fkd,kd->fk", d, up[upper]) * 1e3
    rig = FaceRig(model, tol=1e-6)
    c0 = rig.rest_controls()
    state = rig.equilibrium(c0)
    J = cap.markers.jacobian(rig.jacobian(state, cap.markers.nodes)).reshape(len(names), 3, -1)
    M = model.n_muscles
    fibre = np.array([n not in model.pressure_actuators for n in model.muscle_names])
    rest_m = cap.markers.positions(state.x_m)
    reach: dict = {}
    for j, k in enumerate(upper):
        entry = {}
        for word, axis, sign in (
            ("out", normal[k], 1.0),
            ("in", normal[k], -1.0),
            ("up", up[k], 1.0),
            ("down", up[k], -1.0),
        ):
            per = sign * (axis @ J[k, :, :M]) * fibre  # m per unit activation
            movers = np.flatnonzero(per > 0)
            c = c0.copy()
            c[movers] = 1.0
            moved = cap.markers.positions(rig.equilibrium(c, state.y_m).x_m)[k] - rest_m[k]
            entry[word] = {
                "all_movers_on_mm": float(sign * moved @ axis * 1e3),
                "strongest": [model.muscle_names[i] for i in movers[np.argsort(-per[movers])][:3]],
            }
        reach[UPPER[j]] = entry
    capture = {
        n: {
            "out": float(out_mm[:, j].max()),
            "in": float(-out_mm[:, j].min()),
            "up": float(up_mm[:, j].max()),
            "down": float(-up_mm[:, j].min()),
        }
        for j, n in enumerate(UPPER)
    }
    return {
        "take": take.name if hasattr(take, "name") else "",
        "frames": int(frames),
        "stable_markers": list(STABLE),
        "stable_residual_mm_median": float(np.nanmedian(fit_mm)),
        "stable_residual_mm_max": float(np.nanmax(fit_mm)),
        "capture_max_mm": capture,
        "model_reach": reach,
        "out_mm": out_mm.tolist(),
        "up_mm": up_mm.tolist(),
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


def names_of(take: str) -> list[str]:
    return list(read_mocap(data_dir() / "animface" / f"{take}MoCap.c3d").marker_names)


def used_rms_without_upper(run: Path, report: dict, names: list[str]) -> float:
    """Mean over frames of the RMS error (face mm) of the markers used in the fit, brows and forehead left out."""
    held = set(report["holdout_markers"])
    keep = [i for i, n in enumerate(names) if n not in held and n not in UPPER]
    frames = sorted((run / "frames").glob("frame_*.npz"))
    err_mm = np.array([np.load(f)["marker_error_m"][keep] for f in frames]) * 1e3
    return float(np.mean(np.sqrt(np.nanmean(err_mm**2, axis=1))))


def track_variants(args, out: Path) -> list[dict]:
    """Track every take on the built-in face and the glide-plane variants; one row per run."""
    variants = [("built-in face", None, None)]
    for from_mm, word in ((args.forehead_from_mm, "forehead"), (args.brows_from_mm, "forehead and brows")):
        variants += [(f"{word} glide, top edge {top}", from_mm, top) for top in ("held", "skin", "free")]
    rows = []
    for label, from_mm, top in variants:
        model = build_face(args.tets) if from_mm is None else glide_face(args.tets, from_mm=from_mm, top=top)
        tag = "builtin" if from_mm is None else f"glide{from_mm:g}_{top}"
        path = save_model(model, out / f"{tag}.npz")
        for take in args.takes:
            run = out / f"{take}_{tag}"
            argv = ["track", "--model", str(path), "--mocap", str(data_dir() / "animface" / f"{take}MoCap.c3d")]
            argv += ["--frames", f"0:{args.frames}", "--holdout", str(args.holdout), "--no-pictures", "--no-usd"]
            if wface_main([*argv, "--out", str(run)]) != 0:
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
                    "used_below_the_brows_mm": used_rms_without_upper(run, rep, names_of(take)),
                    "upper_markers_mm": {n: per[n] for n in UPPER if per.get(n) is not None},
                }
            )
    return rows


def plot(path: Path, results: list[dict]) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), 2, figsize=(12, 3.6 * len(results)), squeeze=False)
    x = np.arange(len(UPPER))
    for row, res in zip(axes, results, strict=True):
        for ax, (pos, neg) in zip(row, (("out", "in"), ("up", "down")), strict=True):
            cap = res["capture_max_mm"]
            reach = res["model_reach"]
            ax.bar(x - 0.2, [cap[n][pos] for n in UPPER], 0.4, color="tab:blue", label=f"capture, most {pos}")
            ax.bar(x + 0.2, [-cap[n][neg] for n in UPPER], 0.4, color="tab:orange", label=f"capture, most {neg}")
            ax.scatter(x - 0.2, [reach[n][pos]["all_movers_on_mm"] for n in UPPER], marker="_", s=300, c="k")
            ax.scatter(
                x + 0.2,
                [-reach[n][neg]["all_movers_on_mm"] for n in UPPER],
                marker="_",
                s=300,
                c="k",
                label="muscles' reach",
            )
            ax.axhline(0.0, color="0.5", lw=0.6)
            ax.set_xticks(
                x, [n.replace("eyebrow", "brow").replace("ForeHead", "Fh") for n in UPPER], fontsize=7, rotation=30
            )
            ax.set_ylabel(f"{pos} (+) / {neg} (-) from neutral (mm)", fontsize=8)
            along = "normal" if pos == "out" else "upward tangent"
            ax.set_title(f"{res['take']}MoCap 0:{res['frames']}: along the skin's {along}", fontsize=9)
            ax.grid(alpha=0.3, axis="y")
        row[0].legend(fontsize=7)
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
    p.add_argument("--takes", nargs="+", default=["Eyebrows", "Jaw"], help="AnimFace takes (default Eyebrows Jaw)")
    p.add_argument("--frames", type=int, default=300, help="frames of each take from 0 (default 300)")
    p.add_argument("--variants", action="store_true", help="also track the takes on the glide-plane faces")
    p.add_argument("--holdout", type=int, default=5, help="hide every N-th marker by height (default 5)")
    p.add_argument("--forehead-from-mm", type=float, default=40.0, help="subgaleal glide from this height (40)")
    p.add_argument("--brows-from-mm", type=float, default=22.0, help="with the brows' fat pads, from this height (22)")
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
        for n in UPPER:
            c, r = res["capture_max_mm"][n], res["model_reach"][n]
            print(
                f"{name} {n}: capture out {c['out']:.1f} in {c['in']:.1f} up {c['up']:.1f} down {c['down']:.1f} mm; "
                "muscles " + " ".join(f"{d} {r[d]['all_movers_on_mm']:.1f}" for d in DIRECTIONS)
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
