"""Can the muscles make the upper-lip motion of NoseMoCap? The data against what the model can produce.

    python examples/lip_sneer.py --out out/sneer                  # built-in face, 5,000 tets
    python examples/lip_sneer.py --out out/sneer --model actor.npz
    python examples/lip_sneer.py --out out/jaw_lip --take Jaw     # the same measures on another take

The capture (``$WFACE_DATA/animface/NoseMoCap.c3d``, or ``--take``'s) is aligned and embedded at its neutral frame 0
(``prepare_capture``) and the head motion is removed frame by frame with the forehead and nose-top
markers (``remove_head_motion``). Each upper-lip and nose marker's displacement from neutral is then
written in the face's own axes, taken from the model's markers at rest: lateral (towards the
actor's left, ForeHead_R -> ForeHead_L), up (Chin -> ForeHead_M, made orthogonal) and forward (out
of the face). Against it, what the muscles can do along each axis: the linear bound (the sum of
the positive parts of the rig's Jacobian at rest along that axis, over the muscles: no combination of
activations in [0, 1] moves the marker further near rest) and the motion when every muscle that
moves the marker that way at rest is fully active at once, solved as one nonlinear equilibrium with
the jaw closed. Those bound one axis at a time; the sneer moves the lip along all three at once, so
also: the frames where Mouth_UpL1 is more than 75 % of its largest displacement from neutral (the
sneer's peaks), their mean displacement of the four markers, and the bounded linear least-squares
fit of it by the muscles (``scipy.optimize.lsq_linear``, activations within their bounds, the four
markers alone: the best any activation can do for them, ignoring every other marker), with its
residual linear and solved as a nonlinear equilibrium. Writes ``lip_sneer.png`` (the displacements
per frame against the one-axis reaches) and ``lip_sneer.json``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np
from scipy.optimize import lsq_linear

from wface.faces.builtin import build_face
from wface.io.mocap import read_mocap
from wface.mesh.align import remove_head_motion
from wface.model import load_model
from wface.tracking.capture import prepare_capture
from wface.tracking.rig import FaceRig

STABLE = ("ForeHead_L", "ForeHead_M", "ForeHead_R", "NoseTop")
LIP = ("Mouth_Up", "Mouth_UpL1", "Mouth_UpR1", "NoseHead")
AXES = ("lateral", "up", "forward")


def data_dir() -> Path:
    return Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))


def face_axes(rest_m: np.ndarray, names: list[str]) -> np.ndarray:
    """(3, 3) rows: lateral (to the actor's left), up, forward, from the markers at rest (k, 3)."""
    p = {n: rest_m[names.index(n)] for n in ("ForeHead_L", "ForeHead_R", "ForeHead_M", "Chin", "NoseHead")}
    lat = p["ForeHead_L"] - p["ForeHead_R"]
    lat /= np.linalg.norm(lat)
    up = p["ForeHead_M"] - p["Chin"]
    up -= lat * (lat @ up)
    up /= np.linalg.norm(up)
    fwd = np.cross(lat, up)
    if fwd @ (p["NoseHead"] - 0.5 * (p["ForeHead_M"] + p["Chin"])) < 0:
        fwd = -fwd
    return np.stack([lat, up, fwd])


def analyse(model, take, frames: int) -> dict:
    """The numbers of the module docstring."""
    names = list(take.marker_names)
    cap = prepare_capture(model, take.positions_m[:frames], names, reference_positions_m=take.positions_m[0])
    stable = [i for i, n in enumerate(names) if n in STABLE]
    still, _ = remove_head_motion(cap.targets_m, stable, reference_m=cap.targets_m[0])
    lip = [names.index(n) for n in LIP]
    rig = FaceRig(model, tol=1e-6)
    c0 = rig.rest_controls()
    state = rig.equilibrium(c0)
    rest_m = cap.markers.positions(state.x_m)
    R = face_axes(rest_m, names)
    d_mm = np.einsum("ad,fkd->fka", R, still[:, lip] - still[0, lip]) * 1e3  # (F, lip, axis)
    J = cap.markers.jacobian(rig.jacobian(state, cap.markers.nodes)).reshape(len(names), 3, -1)
    M = model.n_muscles
    fibre = np.array([n not in model.pressure_actuators for n in model.muscle_names])
    reach: dict = {}
    for k in lip:
        per = np.einsum("ad,dp->ap", R, J[k, :, :M]) * fibre * 1e3  # (axis, M) mm per unit activation
        entry = {}
        for a, axis in enumerate(AXES):
            for sign, word in ((1.0, "+"), (-1.0, "-")):
                movers = np.flatnonzero(sign * per[a] > 0)
                c = c0.copy()
                c[movers] = 1.0
                moved = (cap.markers.positions(rig.equilibrium(c, state.y_m).x_m)[k] - rest_m[k]) @ R[a] * 1e3
                entry[word + axis] = {
                    "linear_bound_mm": float(np.clip(sign * per[a], 0, None).sum()),
                    "all_movers_on_mm": float(sign * moved),
                    "strongest": [model.muscle_names[i] for i in movers[np.argsort(-sign * per[a][movers])][:3]],
                }
        reach[names[k]] = entry
    peak = np.abs(d_mm).max(axis=0)
    fit = peak_fit(model, rig, state, cap.markers, J[lip, :, :M], still[:, lip] - still[0, lip], lip, R)
    return {
        "peak_fit": fit,
        "frames": int(frames),
        "markers": list(LIP),
        "axes": list(AXES),
        "capture_max_abs_mm": {n: dict(zip(AXES, peak[j].tolist(), strict=True)) for j, n in enumerate(LIP)},
        "capture_min_mm": {n: dict(zip(AXES, d_mm[:, j].min(axis=0).tolist(), strict=True)) for j, n in enumerate(LIP)},
        "capture_max_mm": {n: dict(zip(AXES, d_mm[:, j].max(axis=0).tolist(), strict=True)) for j, n in enumerate(LIP)},
        "model_reach": reach,
        "displacement_mm": d_mm.tolist(),
        "fps": take.rate_hz,
    }


def peak_fit(model, rig, state, markers, J_lip, d_m, lip, R) -> dict:
    """The sneer's peaks (Mouth_UpL1 beyond 75 % of its largest displacement) and the muscles' best
    bounded linear fit of their mean displacement at the lip markers (module docstring)."""
    size = np.linalg.norm(d_m[:, 1], axis=1)
    peaks = np.flatnonzero(size > 0.75 * size.max())
    want = d_m[peaks].mean(axis=0)  # (lip, 3) m
    M = model.n_muscles
    A = J_lip.reshape(-1, M)
    sol = lsq_linear(A, want.reshape(-1), bounds=(model.activation_lower_bounds, np.ones(M)))
    linear = (A @ sol.x).reshape(-1, 3) - want
    c = rig.rest_controls()
    c[:M] = sol.x
    rest_m = markers.positions(state.x_m)[lip]
    solved = markers.positions(rig.equilibrium(c, state.y_m).x_m)[lip] - rest_m - want
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e**2, axis=1))) * 1e3)  # noqa: E731
    order = np.argsort(-sol.x)[:6]
    return {
        "frames": peaks.tolist(),
        "capture_mm": {n: (R @ want[j] * 1e3).tolist() for j, n in enumerate(LIP)},
        "linear_residual_mm": {n: (R @ linear[j] * 1e3).tolist() for j, n in enumerate(LIP)},
        "solved_residual_mm": {n: (R @ solved[j] * 1e3).tolist() for j, n in enumerate(LIP)},
        "linear_rms_mm": rms(linear),
        "solved_rms_mm": rms(solved),
        "capture_rms_mm": rms(want),
        "activations": {model.muscle_names[i]: float(sol.x[i]) for i in order},
    }


def plot(path: Path, res: dict) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = np.asarray(res["displacement_mm"])
    t = np.arange(len(d)) / res["fps"]
    shown = res["markers"][:2]
    fig, axes = plt.subplots(1, len(shown), figsize=(11, 4), sharey=True)
    for ax, name in zip(axes, shown, strict=True):
        j = res["markers"].index(name)
        for a, axis in enumerate(res["axes"]):
            (line,) = ax.plot(t, d[:, j, a], lw=1.0, label=f"{axis} (capture)")
            sign = "+" if res["peak_fit"]["capture_mm"][name][a] >= 0 else "-"  # the way the sneer moves it
            reach = res["model_reach"][name][sign + axis]["all_movers_on_mm"]
            ax.axhline(reach if sign == "+" else -reach, color=line.get_color(), ls="--", lw=0.8)
        ax.set_title(f"{name}", fontsize=9)
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("displacement from neutral, head motion removed (mm)")
    axes[0].legend(fontsize=7)
    fit = res["peak_fit"]
    fig.suptitle(
        f"{res['take']}MoCap: upper lip vs the muscles' reach, one axis at a time (dashed: every muscle moving the "
        f"marker that way at 1).\nAll three at once, at the sneer's peaks: the best bounded fit of the lip markers "
        f"alone leaves {fit['solved_rms_mm']:.1f} mm RMS of {fit['capture_rms_mm']:.1f} mm",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--model", help="face model (.npz); default the built-in face with --tets")
    p.add_argument("--tets", type=int, default=5000, help="size of the built-in face (default 5000)")
    p.add_argument("--frames", type=int, default=300, help="frames of the capture to analyse (default 300)")
    p.add_argument("--take", default="Nose", choices=("Nose", "Jaw", "Cheeks", "Eyebrows"), help="AnimFace take (Nose)")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = load_model(args.model) if args.model else build_face(args.tets)
    take = read_mocap(data_dir() / "animface" / f"{args.take}MoCap.c3d")
    res = analyse(model, take, args.frames)
    res["take"] = args.take
    (out / "lip_sneer.json").write_text(json.dumps({k: v for k, v in res.items() if k != "displacement_mm"}, indent=2))
    plot(out / "lip_sneer.png", res)
    for name in res["markers"]:
        lo, hi = res["capture_min_mm"][name], res["capture_max_mm"][name]
        parts = []
        for axis in res["axes"]:
            r = res["model_reach"][name]
            parts.append(
                f"{axis} {lo[axis]:+.1f}..{hi[axis]:+.1f} (muscles {-r['-' + axis]['all_movers_on_mm']:+.1f}.."
                f"{r['+' + axis]['all_movers_on_mm']:+.1f}, linear {-r['-' + axis]['linear_bound_mm']:+.1f}.."
                f"{r['+' + axis]['linear_bound_mm']:+.1f})"
            )
        print(f"{name}: capture " + "; ".join(parts) + " mm")
    fit = res["peak_fit"]
    print(
        f"sneer peaks ({len(fit['frames'])} frames): the lip markers move {fit['capture_rms_mm']:.1f} mm RMS; the "
        f"muscles' best bounded fit of them alone leaves {fit['linear_rms_mm']:.2f} mm linear, "
        f"{fit['solved_rms_mm']:.2f} mm solved"
    )
    for name in res["markers"]:
        cap_mm, left = np.round(fit["capture_mm"][name], 1), np.round(fit["solved_residual_mm"][name], 1)
        print(f"  {name}: capture {cap_mm.tolist()} mm (lateral, up, forward), solved residual {left.tolist()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
