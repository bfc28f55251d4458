"""``wface bench --suite dynamic``: implicit dynamic steps on the built-in face.

Per mesh size (``--tets``, default 5K / 20K) and scheme (implicit midpoint, backward Euler): a
sudden smile (both zygomatici major switched on at t = 0 from rest) integrated for
``4 * --repeat`` time steps of 1/480 s (30 fps with 16 substeps, the ``wface resim`` default)
with the default damping.
Reported: seconds per step (median and mean), Newton iterations per step (mean and max),
factorisations per step, exact-Hessian fallbacks, the largest node displacement reached (mm) and
the quasistatic solve time of the same load for comparison.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from wface.bench import suite_result
from wface.faces.builtin import build_face
from wface.physics import Simulator
from wface.physics.dynamics import DynamicSimulator
from wface.warp_runtime import init_warp, resolve_device

__all__ = ["run", "DEFAULT_TETS", "bench_size"]

DEFAULT_TETS = (5_000, 20_000)
SCHEMES = ("midpoint", "be")


def bench_size(target_tets: int, *, device: str = "cpu", steps: int = 12, dt_s: float = 1.0 / 480.0) -> dict:
    """Timings for one mesh size (see module docstring)."""

    model = build_face(target_tets)
    sim = Simulator(model, device=device)
    a = model.activation_vector({"zygomaticus_major_l": 1.0, "zygomaticus_major_r": 1.0})
    out: dict = {"tets": model.n_tets, "nodes": model.n_nodes, "dt_s": dt_s, "steps": steps}
    sim.energy_and_forces(None, a)  # compile / load kernels outside the timings
    t0 = time.perf_counter()
    eq = sim.solve(a)
    out["quasistatic_seconds"] = time.perf_counter() - t0
    out["quasistatic_newton_iterations"] = eq.iterations
    for scheme in SCHEMES:
        dyn = DynamicSimulator(sim, scheme=scheme)
        state = dyn.initial_state()
        secs, its, facts, fails, disp = [], [], [], [], 0.0
        for _ in range(steps):
            state, st = dyn.step(state, dt_s, a)
            secs.append(st.seconds)
            its.append(st.newton_iterations)
            facts.append(st.factorizations)
            fails.append(st.exact_failures)
            disp = max(disp, float(np.linalg.norm(state.x_m - model.rest_positions_m, axis=1).max()))
        dyn.free()
        out[scheme] = {
            "seconds_per_step_median": statistics.median(secs),
            "seconds_per_step_mean": float(np.mean(secs)),
            "newton_iterations_per_step_mean": float(np.mean(its)),
            "newton_iterations_per_step_max": int(np.max(its)),
            "factorizations_per_step_mean": float(np.mean(facts)),
            "exact_failures": int(np.sum(fails)),
            "max_displacement_mm": disp * 1e3,
            "converged": True if not steps else bool(st.converged),
            "solver": dyn.engine,
        }
    out["quasistatic_max_displacement_mm"] = float(np.linalg.norm(eq.x - model.rest_positions_m, axis=1).max() * 1e3)
    out["device"] = sim.device
    return out


def run(args) -> dict:
    """Entry point of ``wface bench --suite dynamic``: ``suite_result`` with one entry per size."""
    import warp as wp

    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)  # no banner on stdout (--json)
    init_warp()
    device = resolve_device(getattr(args, "device", "auto"))
    sizes = getattr(args, "tets", None) or list(DEFAULT_TETS)
    steps = 4 * max(1, int(getattr(args, "repeat", 3) or 3))
    return suite_result("dynamic", device, [bench_size(int(n), device=device, steps=steps) for n in sizes])
