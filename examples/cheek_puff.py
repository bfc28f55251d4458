"""Can the muscles make the cheek motion of CheeksMoCap? The data against what the model can produce.

    python examples/cheek_puff.py --out out/cheeks                  # built-in face, 5,000 tets
    python examples/cheek_puff.py --out out/cheeks --model actor.npz

The capture (``$WFACE_DATA/animface/CheeksMoCap.c3d``) is aligned and embedded at its neutral
frame 0 (``prepare_capture``), the head motion is removed frame by frame with the forehead and
nose-top markers (``remove_head_motion``), and each cheek marker's displacement from neutral is
split into its component along the model's outward skin normal there (puffing out: positive) and
the rest. Against it, what the muscles can do: the outward motion of each cheek marker when every
muscle that pushes it outward at rest (n . dm/da_i > 0, from the rig's Jacobian) is fully active
at once, solved as one nonlinear equilibrium with the jaw closed; that bounds the outward motion
any combination of activations in [0, 1] makes near rest. With the face's intra-oral pressure
(``intraoral_pressure``, docs/design.md "Intra-oral pressure"; the muscles' bound leaves it out)
also each marker's motion at full pressure (+1) and full suction (-1). Writes ``cheek_puff.png``
(the outward motion per frame against those reaches) and ``cheek_puff.json``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from wface.faces.builtin import build_face
from wface.io.mocap import read_mocap
from wface.mesh.align import remove_head_motion
from wface.mesh.surface import vertex_normals
from wface.model import load_model
from wface.tracking.capture import prepare_capture
from wface.tracking.rig import FaceRig

STABLE = ("ForeHead_L", "ForeHead_M", "ForeHead_R", "NoseTop")


def data_dir() -> Path:
    return Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))


def outward_normals(model, markers) -> np.ndarray:
    """(k, 3) interpolated unit skin normals at the embedded markers (rest)."""
    emb = markers.embedding
    n = vertex_normals(model.rest_positions_m, model.skin_triangles)
    tri = model.skin_triangles[emb.triangle]
    out = np.einsum("kj,kjd->kd", emb.barycentric, n[tri])
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def analyse(model, take, frames: int) -> dict:
    """The numbers of the module docstring."""
    pos = take.positions_m[:frames]
    cap = prepare_capture(model, pos, take.marker_names, reference_positions_m=take.positions_m[0])
    stable = [i for i, n in enumerate(take.marker_names) if n in STABLE]
    still, _ = remove_head_motion(cap.targets_m, stable, reference_m=cap.targets_m[0])
    cheeks = [i for i, n in enumerate(take.marker_names) if "cheek" in n.lower()]
    normals = outward_normals(model, cap.markers)[cheeks]
    d = still[:, cheeks] - still[0, cheeks]  # (F, c, 3) from neutral, head motion removed
    outward_mm = np.einsum("fcd,cd->fc", d, normals) * 1e3
    along_mm = np.linalg.norm(d - outward_mm[..., None] * 1e-3 * normals, axis=2) * 1e3
    rig = FaceRig(model, tol=1e-6)
    c0 = rig.rest_controls()
    state = rig.equilibrium(c0)
    J = cap.markers.jacobian(rig.jacobian(state, cap.markers.nodes)).reshape(len(take.marker_names), 3, -1)
    M = model.n_muscles
    fibre = np.array([n not in model.pressure_actuators for n in model.muscle_names])
    push = np.einsum("cdp,cd->cp", J[cheeks, :, :M], normals) * fibre  # (c, M) outward m per unit activation
    linear_bound_mm = np.clip(push, 0, None).sum(axis=1) * 1e3
    pushers = np.flatnonzero((push > 0).any(axis=0))
    best = {}
    rest_m = cap.markers.positions(state.x_m)[cheeks]
    for j, name in enumerate(take.marker_names[i] for i in cheeks):
        c = c0.copy()
        c[np.flatnonzero(push[j] > 0)] = 1.0  # every muscle that pushes this marker outward, fully on
        s = rig.equilibrium(c, state.y_m)
        moved = cap.markers.positions(s.x_m)[cheeks[j]] - rest_m[j]
        best[name] = float(moved @ normals[j] * 1e3)
    names = [take.marker_names[i] for i in cheeks]
    pressure = {}
    if "intraoral_pressure" in model.pressure_actuators:
        for a in (1.0, -1.0):
            c = c0.copy()
            c[model.muscle_index("intraoral_pressure")] = a
            moved = cap.markers.positions(rig.equilibrium(c, state.y_m).x_m)[cheeks] - rest_m
            pressure["puff" if a > 0 else "suck"] = dict(
                zip(names, (np.einsum("cd,cd->c", moved, normals) * 1e3).tolist(), strict=True)
            )
    return {
        "frames": int(len(pos)),
        "cheek_markers": names,
        "capture_outward_max_mm": dict(zip(names, outward_mm.max(axis=0).tolist(), strict=True)),
        "capture_outward_p95_mm": dict(zip(names, np.percentile(outward_mm, 95, axis=0).tolist(), strict=True)),
        "capture_inward_max_mm": dict(zip(names, (-outward_mm.min(axis=0)).tolist(), strict=True)),
        "capture_tangential_max_mm": dict(zip(names, along_mm.max(axis=0).tolist(), strict=True)),
        "model_outward_linear_bound_mm": dict(zip(names, linear_bound_mm.tolist(), strict=True)),
        "model_outward_all_pushers_on_mm": best,
        "muscles_pushing_a_cheek_outward": [model.muscle_names[i] for i in pushers],
        "pressure_outward_mm": pressure,
        "outward_mm": outward_mm.tolist(),
        "fps": take.rate_hz,
    }


def plot(path: Path, res: dict) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = np.asarray(res["outward_mm"])
    t = np.arange(len(out)) / res["fps"]
    fig, ax = plt.subplots(figsize=(10, 4))
    for j, name in enumerate(res["cheek_markers"]):
        (line,) = ax.plot(t, out[:, j], lw=1.0, label=f"{name} (capture)")
        ax.axhline(res["model_outward_all_pushers_on_mm"][name], color=line.get_color(), ls="--", lw=0.8)
        for reach in res["pressure_outward_mm"].values():
            ax.axhline(reach[name], color=line.get_color(), ls=":", lw=0.8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("outward motion along the skin normal (mm)")
    title = "CheeksMoCap: cheek markers vs the muscles' reach (dashed: every outward-pushing muscle at 1"
    ax.set_title(
        title + ("; dotted: intra-oral pressure at +1 / -1)" if res["pressure_outward_mm"] else ")"), fontsize=9
    )
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--model", help="face model (.npz); default the built-in face with --tets")
    p.add_argument("--tets", type=int, default=5000, help="size of the built-in face (default 5000)")
    p.add_argument("--frames", type=int, default=1499, help="frames of the capture to analyse (default all)")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = load_model(args.model) if args.model else build_face(args.tets)
    take = read_mocap(data_dir() / "animface" / "CheeksMoCap.c3d")
    res = analyse(model, take, args.frames)
    (out / "cheek_puff.json").write_text(json.dumps({k: v for k, v in res.items() if k != "outward_mm"}, indent=2))
    plot(out / "cheek_puff.png", res)
    for name in res["cheek_markers"]:
        print(
            f"{name}: capture outward max {res['capture_outward_max_mm'][name]:.1f} mm "
            f"(p95 {res['capture_outward_p95_mm'][name]:.1f}), inward max {res['capture_inward_max_mm'][name]:.1f}; "
            f"muscles at most {res['model_outward_all_pushers_on_mm'][name]:.2f} mm outward "
            f"(linear bound {res['model_outward_linear_bound_mm'][name]:.2f})"
            + "".join(f"; pressure {k} {v[name]:+.1f} mm" for k, v in res["pressure_outward_mm"].items())
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
