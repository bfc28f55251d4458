"""``wface bench --suite jacobian``: all Jacobian columns vs one quasistatic solve from a nearby start.

The paper's claim (Sifakis et al. 2005, section 6): computing the M + 12 solved columns against one
factorisation costs about as much as one quasistatic solve. Reported as ``jacobian_over_solve``.
"""

from __future__ import annotations

import time

import numpy as np

from wface.bench import suite_result
from wface.controls import jaw_from_intuitive
from wface.faces.builtin import build_face
from wface.tracking.rig import FaceRig
from wface.warp_runtime import resolve_device

DEFAULT_TETS = (20_000, 100_000)


def _one(n_tets: int, device: str, repeat: int) -> dict:

    model = build_face(n_tets)
    rig = FaceRig(model, device="cpu" if device == "auto" else device, tol=1e-6)
    M = model.n_muscles
    rng = np.random.default_rng(0)
    c = rig.rest_controls()
    c[:M] = rng.uniform(0.0, 0.3, size=M)
    c[M + 12 :] = jaw_from_intuitive(model.jaw_joint, 6.0)
    state = rig.equilibrium(c)
    solve_s, jac_s, iters = [], [], []
    for _ in range(repeat):
        near = c.copy()
        near[:M] = np.clip(near[:M] + rng.uniform(-0.05, 0.05, size=M), 0, 1)
        t = time.perf_counter()
        s2 = rig.equilibrium(near, state.y_m)
        solve_s.append(time.perf_counter() - t)
        iters.append(s2.newton_iterations)
        t = time.perf_counter()
        rig.jacobian_y(state)
        jac_s.append(time.perf_counter() - t)
    solve, jac = float(np.median(solve_s)), float(np.median(jac_s))
    return {
        "tets": model.n_tets,
        "nodes": model.n_nodes,
        "columns": M + 12,
        "quasistatic_seconds_nearby": solve,
        "newton_iterations_nearby": int(np.median(iters)),
        "jacobian_seconds": jac,
        "jacobian_over_solve": jac / solve,
        "solver": rig.sim.linear_solver,
    }


def run(args) -> dict:
    sizes = args.tets or list(DEFAULT_TETS)
    device = resolve_device("cpu" if args.device == "auto" else args.device)
    return suite_result("jacobian", device, [_one(int(n), device, max(1, args.repeat)) for n in sizes])
