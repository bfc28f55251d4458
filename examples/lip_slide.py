"""Does the upper lip's deep surface riding on the teeth and gum explain NoseMoCap's sneer misfit?

    python examples/lip_slide.py --out out/lip_slide                   # 5,000 tets, 0:300, ~3 min a variant
    python examples/lip_slide.py --out out/lip_slide --tilt-deg 0 25 -25 --take Nose --frames 0:300

On the built-in face the upper lip's bone side is free in the oral vestibule (docs/design.md,
"Built-in face attachments"): in the sneer the tracked lip bulges up and forward where the capture's
goes up and back (README, "NoseMoCap's misfit"). A real lip rides on the incisors and the gum, which
slope back. This study holds the free deep-surface nodes of the upper lip (the skin's ``inner``
surface above the mouth line, within ``--theta-max`` radians of the midline) to a sliding plane
through each node's rest position: a bilateral penalty E = k/2 (n . (y - Y))^2 in the cranium frame
(k = ``--stiffness-factor`` times the contact penalty's default, ``default_contact_stiffness``), with
the plane's normal n the deep surface's own normal turned back about the left-right axis by
``--tilt-deg`` (positive: moving up means moving back, a proclined incisor and gum; 0 the face's own
near-upright bone; negative the opposite slope, a control).

The penalty is a study, not part of the model: it is added to ``Simulator.energy`` and ``energy_and_forces`` and to
the stiffness (``Tangent.matvec``, ``diagonal``, ``assemble_blocks``: a constant k n n^T block on each
held node) for the duration of one ``wface track`` run, in-process and on the CPU. It does not
depend on the activations or the jaw, so the tracker's Jacobians stay exact. Each variant runs
``wface track --mocap TAKE --frames F --tets N --holdout 5`` and the table gives the used and held-out
marker RMS (the face's mm) and the upper-lip markers' RMS; ``lip_slide.json`` holds the numbers.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
from pathlib import Path

import numpy as np

from wface.cli import main as wface_main
from wface.faces.builtin.shape import Y_MOUTH, FaceShape
from wface.physics import simulator as simulator_module
from wface.physics import stiffness as stiffness_module
from wface.physics.penalty import default_contact_stiffness

LIP_MARKERS = ("Mouth_Up", "Mouth_UpL1", "Mouth_UpR1")


def held_nodes(model, theta_max: float, tilt_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """(node ids, (k, 3) unit plane normals) of the upper lip's free deep-surface nodes (module docstring)."""
    X = model.rest_positions_m
    tri = np.asarray(model.surface_groups["inner"], dtype=np.int64)
    area_normal = 0.5 * np.cross(X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]])
    normal = np.zeros_like(X)
    for j in range(3):
        np.add.at(normal, tri[:, j], area_normal)
    free = np.zeros(model.n_nodes, dtype=bool)
    free[model.free_nodes] = True
    theta = np.arctan2(X[:, 0], X[:, 2] - FaceShape().z_centre_m)
    nodes = np.unique(tri)
    nodes = nodes[free[nodes] & (X[nodes, 1] > Y_MOUTH) & (np.abs(theta[nodes]) < theta_max)]
    n = normal[nodes] / np.linalg.norm(normal[nodes], axis=1, keepdims=True)
    c, s = np.cos(tilt_rad), np.sin(tilt_rad)  # turn about x: (n_y, n_z) -> (c n_y + s n_z, -s n_y + c n_z)
    n = np.stack([n[:, 0], c * n[:, 1] + s * n[:, 2], -s * n[:, 1] + c * n[:, 2]], axis=1)
    return nodes, n


@contextlib.contextmanager
def sliding_upper_lip(stiffness_factor: float, theta_max: float, tilt_deg: float):
    """Add the sliding-plane penalty to every Simulator and Tangent while the block runs."""
    cache: dict[int, tuple] = {}

    def spring(model):
        if id(model) not in cache:
            nodes, n = held_nodes(model, theta_max, np.radians(tilt_deg))
            k = stiffness_factor * default_contact_stiffness(model)
            cache[id(model)] = (nodes, n, k * n[:, :, None] * n[:, None, :], k)
            print(f"lip_slide: {nodes.size} nodes held, k {k:.3g} N/m, tilt {tilt_deg:g} deg", flush=True)
        return cache[id(model)]

    Sim, Tan = simulator_module.Simulator, stiffness_module.Tangent
    saved = {name: getattr(Tan, name) for name in ("matvec", "diagonal", "assemble_blocks")}
    saved_eaf, saved_energy = Sim.energy_and_forces, Sim.energy

    def offsets(sim):
        """(held nodes, normals, k, d): d = n . (y - Y) at the state the last call set."""
        nodes, n, _, k = spring(sim.model)
        y = sim._x.numpy().astype(np.float64)[nodes]
        return nodes, n, k, np.einsum("ij,ij->i", n, y - sim.model.rest_positions_m[nodes])

    def energy_and_forces(self, x=None, activations=None):
        e, f = saved_eaf(self, x, activations)
        nodes, n, k, d = offsets(self)
        f = np.array(f, dtype=np.float64)
        f[nodes] -= k * d[:, None] * n
        return e + 0.5 * k * float(d @ d), f

    def energy(self, x=None, activations=None):  # the line searches' energy
        e = saved_energy(self, x, activations)
        _, _, k, d = offsets(self)
        return e + 0.5 * k * float(d @ d)

    def matvec(self, v):
        out = saved["matvec"](self, v)
        nodes, _, blocks, _ = spring(self._sim.model)
        out[nodes] += np.einsum("kij,kj->ki", blocks, np.asarray(v, dtype=np.float64).reshape(-1, 3)[nodes])
        return out

    def diagonal(self):
        out = saved["diagonal"](self)
        nodes, _, blocks, _ = spring(self._sim.model)
        out[nodes] += np.einsum("kii->ki", blocks)
        return out

    def assemble_blocks(self, pattern):
        values = saved["assemble_blocks"](self, pattern)
        nodes, _, blocks, _ = spring(self._sim.model)
        col = np.full(pattern.n_nodes, -1)
        col[pattern.col_nodes] = np.arange(pattern.col_nodes.size)
        rows, cols = pattern.node_to_dof[nodes], col[nodes]
        keep = (rows >= 0) & (cols >= 0)
        if not keep.any():
            return values
        host = values.numpy()
        for r, c, b in zip(rows[keep], cols[keep], blocks[keep], strict=True):
            start = pattern.indptr[r]
            host[start + int(np.flatnonzero(pattern.indices[start : pattern.indptr[r + 1]] == c)[0])] += b
        values.assign(host)
        return values

    Sim.energy_and_forces, Sim.energy = energy_and_forces, energy
    for name, fn in (("matvec", matvec), ("diagonal", diagonal), ("assemble_blocks", assemble_blocks)):
        setattr(Tan, name, fn)
    try:
        yield
    finally:
        Sim.energy_and_forces, Sim.energy = saved_eaf, saved_energy
        for name, fn in saved.items():
            setattr(Tan, name, fn)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True)
    p.add_argument("--take", default="Nose", help="AnimFace take (default Nose)")
    p.add_argument("--frames", default="0:300")
    p.add_argument("--tets", type=int, default=5000)
    p.add_argument("--tilt-deg", type=float, nargs="+", default=[0.0, 25.0, -25.0])
    p.add_argument("--theta-max", type=float, default=0.5, help="half-width of the held band (radians, default 0.5)")
    p.add_argument("--stiffness-factor", type=float, default=1.0)
    args = p.parse_args(argv)
    data = Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    mocap = data / "animface" / f"{args.take}MoCap.c3d"
    if not mocap.exists():
        raise SystemExit(f"{mocap} not found (set WFACE_DATA to the shared data folder)")
    out = Path(args.out)
    variants = [("free", None)] + [(f"tilt {t:g} deg", t) for t in args.tilt_deg]
    results = {}
    for name, tilt in variants:
        run = out / name.replace(" ", "_")
        argv = ["track", "--mocap", str(mocap), "--frames", args.frames, "--tets", str(args.tets), "--holdout", "5"]
        argv += ["--no-pictures", "--no-usd", "--no-movie", "--overwrite", "--out", str(run)]
        held = sliding_upper_lip(args.stiffness_factor, args.theta_max, tilt) if tilt is not None else None
        with held or contextlib.nullcontext():
            if wface_main(argv) != 0:
                raise SystemExit(f"{name}: wface track failed")
        report = json.loads((run / "report.json").read_text())
        per = report["marker_rms_mm_per_marker"]
        results[name] = {
            "marker_rms_mm_mean": report["marker_rms_mm_mean"],
            "holdout_rms_mm_mean": report["holdout_rms_mm_mean"],
            **{m: per.get(m) for m in LIP_MARKERS},
        }
    (out / "lip_slide.json").write_text(json.dumps(results, indent=2) + "\n")
    print("| upper lip's deep surface | used RMS | held-out RMS | " + " | ".join(LIP_MARKERS) + " |")
    for name, r in results.items():
        cells = [r["marker_rms_mm_mean"], r["holdout_rms_mm_mean"], *(r[m] for m in LIP_MARKERS)]
        print(f"| {name} | " + " | ".join("-" if v is None else f"{v:.3f}" for v in cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
