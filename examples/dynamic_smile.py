"""A sudden smile with inertia: the mouth corner overshoots its quasistatic target and rings.

    python examples/dynamic_smile.py --tets 5000 --out out/dynamic_smile

Both zygomatici major switch on at t = 0 on the built-in face at rest; implicit midpoint and
backward Euler integrate 0.1 s at dt = 1 ms (``wface.physics.dynamics``). Writes the trajectory
of the skin node that moves most (``trajectory.csv``, ``trajectory.png`` when matplotlib is
installed) and the midpoint run's skin as ``smile.usdc`` (every 4th step, 250 frames per second).
Runs headless; a test runs it with tiny options.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    from wface.faces.builtin import build_face
    from wface.physics import Damping, DynamicSimulator, Simulator
    from wface.takes.usd import skin_mesh, write_take_usd

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tets", type=int, default=5000, help="size of the built-in face in tetrahedra")
    ap.add_argument("--duration", type=float, default=0.1, help="simulated time in seconds")
    ap.add_argument("--dt", type=float, default=1e-3, help="time step in seconds")
    ap.add_argument("--beta", type=float, default=Damping().beta_s, help="stiffness damping beta in seconds")
    ap.add_argument("--out", default="out/dynamic_smile", help="output directory")
    args = ap.parse_args(argv)

    model = build_face(args.tets, progress=True)
    sim = Simulator(model)
    smile = model.activation_vector({"zygomaticus_major_l": 1.0, "zygomaticus_major_r": 1.0})
    target = sim.solve(smile).x  # the quasistatic smile
    rest = model.rest_positions_m
    skin, _ = skin_mesh(model)
    node = int(skin[np.argmax(np.linalg.norm(target[skin] - rest[skin], axis=1))])
    direction = (target[node] - rest[node]) / np.linalg.norm(target[node] - rest[node])
    static_mm = float(np.linalg.norm(target[node] - rest[node]) * 1e3)

    steps = max(1, int(round(args.duration / args.dt)))
    times = np.arange(steps + 1) * args.dt
    excursion_mm, frames = {}, []
    for scheme in ("midpoint", "be"):
        dyn = DynamicSimulator(sim, scheme=scheme, damping=Damping(0.0, args.beta))
        state = dyn.initial_state()
        path = [0.0]
        for k in range(steps):
            state, stats = dyn.step(state, args.dt, smile)
            path.append(float((state.x_m[node] - rest[node]) @ direction * 1e3))
            if scheme == "midpoint" and k % 4 == 0:
                frames.append(state.x_m.copy())
        dyn.free()
        excursion_mm[scheme] = np.array(path)
        peak = excursion_mm[scheme].max()
        print(
            f"{scheme:8s}: peak {peak:.2f} mm vs quasistatic {static_mm:.2f} mm "
            f"(overshoot {peak - static_mm:+.2f} mm), final {path[-1]:.2f} mm"
        )

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = np.column_stack([times, excursion_mm["midpoint"], excursion_mm["be"], np.full_like(times, static_mm)])
    np.savetxt(out / "trajectory.csv", table, delimiter=",", header="t_s,midpoint_mm,be_mm,quasistatic_mm")
    write_take_usd(out / "smile.usdc", model, np.array(frames), fps=1.0 / (4 * args.dt))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot")
    else:
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.plot(times * 1e3, excursion_mm["midpoint"], label="implicit midpoint")
        ax.plot(times * 1e3, excursion_mm["be"], label="backward Euler")
        ax.axhline(static_mm, color="k", ls="--", lw=1, label="quasistatic")
        ax.set_xlabel("time after onset (ms)")
        ax.set_ylabel(f"mouth corner (node {node}) along its smile (mm)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(out / "trajectory.png", dpi=120)
        plt.close(fig)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
