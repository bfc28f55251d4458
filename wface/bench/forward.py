"""``wface bench --suite forward``: the physics operator and the quasistatic solver on the built-in face.

Per mesh size (``--tets``, default 20K / 100K / 400K), median wall-clock seconds over ``--repeat``:
force kernel (one launch on one thread, float64 and float32) and the ``energy_and_forces`` call,
tangent (``Simulator.tangent``), matrix-free K.v (one launch, and ``Tangent.matvec`` which on the
CPU splits tets over all cores and includes the host copies), assembly into CSR, scipy CSR matvec
of the same K (``kv_over_csr_matvec`` = ``Tangent.matvec`` time / CSR matvec time), sparse direct
factor and solves (1 and 44 right-hand sides), Jacobi-PCG on the matrix-free K.v, and one full
quasistatic solve (``quasistatic_seconds``: zygomaticus_major_l = 0.6, orbicularis_oris_lower = 0.3,
jaw opened 5 degrees, from rest).

``solvers``: every linear solver installed here side by side on the same K_UU (the projected tangent
at the deformed state): PARDISO, CHOLMOD (scikit-sparse, or the cholespy wheel), AMG-preconditioned
CG (pyamg, rigid-body near-nullspace) and Jacobi CG (both on the CSR matrix). For each: ``setup_seconds``
(first factorisation with its analysis, or the AMG hierarchy), ``refactor_seconds`` (a numeric
factorisation with the analysis kept; direct only), one right-hand side to round-off (direct) or to
rtol 1e-6 and 1e-10 (CG: iterations and seconds), ``columns_seconds`` for the M + 12 Jacobian columns
(direct: one block solve; CG: 47 times the 1e-10 column, an estimate) and ``frame_seconds`` = the
per-frame linear algebra of tracking (refactor or setup + the columns).
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from wface.bench import suite_result
from wface.controls import attached_positions_from_affines, jaw_opening_affine
from wface.faces.builtin import build_face
from wface.physics import Simulator
from wface.solvers.amg import AMGPreconditioner, amg_available
from wface.solvers.cudss import CudssFactor
from wface.solvers.linear import (
    DirectFactor,
    JacobiPreconditioner,
    available_direct_backends,
    cudss_available,
    direct_backend,
    forget_analysis,
    pcg,
)
from wface.solvers.warp_cg import warp_pcg
from wface.warp_runtime import init_warp, resolve_device

__all__ = ["run", "DEFAULT_TETS"]

DEFAULT_TETS = (20_000, 100_000, 400_000)


def _median_time(fn, repeat: int, sync) -> float:
    times = []
    for _ in range(max(1, repeat)):
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_size(target_tets: int, *, device: str = "cpu", repeat: int = 3, cg_maxiter: int = 3000) -> dict:
    """Timings for one mesh size (see module docstring)."""
    import warp as wp

    out: dict = {}
    t0 = time.perf_counter()
    model = build_face(target_tets)
    out["build_seconds"] = time.perf_counter() - t0
    out.update(tets=model.n_tets, nodes=model.n_nodes, muscles=model.n_muscles, fibre_entries=int(model.fibre_tet.size))
    sim = Simulator(model, device=device)
    out["device"] = sim.device

    def sync():
        wp.synchronize_device(sim.device)

    X = model.rest_positions_m
    rng = np.random.default_rng(0)
    x = X + 2e-4 * rng.normal(size=X.shape)  # a deformed state (0.2 mm noise)
    a = model.activation_vector({"zygomaticus_major_l": 0.6, "orbicularis_oris_lower": 0.3})
    _time_forces(out, sim, device, x, a, repeat, sync)
    tan = _time_tangent(out, sim, x, a, rng, repeat, sync)
    pattern, b = _time_direct(out, sim, tan, x, a, rng)
    _time_cg(out, tan, pattern, b, cg_maxiter)
    positions = model.rest_positions_m[pattern.dof_nodes]
    out["solvers"] = compare_solvers(tan, pattern, b, positions, columns=model.n_muscles + 12, cg_maxiter=cg_maxiter)
    _time_quasistatic(out, sim, a)
    return out


def _time_forces(out: dict, sim, device: str, x, a, repeat: int, sync) -> None:
    """The force kernel (one launch, float64 and float32) and ``energy_and_forces``."""
    import warp as wp

    model = sim.model
    sim.energy_and_forces(x, a)  # compile / load kernels
    sim._set_state(x, a)

    def forces():
        sim._f.zero_()
        inputs = [*sim._model_inputs(), sim._x, sim._a, sim._f, sim._e]
        wp.launch(sim._k.element_forces, model.n_tets, inputs=inputs, device=sim.device)

    out["forces_kernel_seconds"] = _median_time(forces, repeat, sync)  # one launch, one CPU thread
    out["forces_ns_per_tet"] = 1e9 * out["forces_kernel_seconds"] / model.n_tets
    out["forces_seconds"] = _median_time(lambda: sim.energy_and_forces(x, a), repeat, sync)  # API call
    sim32 = Simulator(model, device=device, precision="float32")
    sim32.energy_and_forces(x, a)
    sim32._set_state(x, a)

    def forces32():
        sim32._f.zero_()
        wp.launch(
            sim32._k.element_forces,
            model.n_tets,
            inputs=[*sim32._model_inputs(), sim32._x, sim32._a, sim32._f, sim32._e],
            device=sim32.device,
        )

    out["forces_float32_seconds"] = _median_time(forces32, repeat, sync)


def _time_tangent(out: dict, sim, x, a, rng, repeat: int, sync):
    """``Simulator.tangent``, matrix-free K.v (kernel and ``Tangent.matvec``), CSR assembly and matvec; the
    tangent at x."""
    import warp as wp

    model = sim.model
    X = model.rest_positions_m
    tangent_holder = {}
    tangent_holder["t"] = sim.tangent(x, a)

    def tangent():
        tangent_holder["t"] = sim.tangent(x, a)

    out["tangent_seconds"] = _median_time(tangent, repeat, sync)  # Simulator.tangent, all cores
    out["tangent_ns_per_tet"] = 1e9 * out["tangent_seconds"] / model.n_tets
    tan = tangent_holder["t"]
    v = rng.normal(size=X.shape)
    tan.matvec(v)
    sim._v.assign(v)

    def kv():
        sim._out.zero_()
        inputs = [sim._tets, sim._dm_inv, tan.element_tangents, sim._v, sim._out]
        wp.launch(sim._k.tangent_matvec, model.n_tets, inputs=inputs, device=sim.device)

    out["kv_kernel_seconds"] = _median_time(kv, repeat, sync)  # one launch, one CPU thread
    out["kv_seconds"] = _median_time(lambda: tan.matvec(v), max(repeat, 5), sync)  # Tangent.matvec, all cores
    t0 = time.perf_counter()
    pattern_all = sim.pattern("all")
    out["pattern_seconds"] = time.perf_counter() - t0
    holder = {}

    def assemble():
        holder["K"] = tan.assemble(pattern_all)

    out["assemble_csr_seconds"] = _median_time(assemble, repeat, sync)
    K = holder["K"]
    out["nnz"] = int(K.nnz)
    vf = v.ravel().copy()
    out["csr_matvec_seconds"] = _median_time(lambda: K @ vf, max(repeat, 5), lambda: None)
    out["kv_over_csr_matvec"] = out["kv_seconds"] / out["csr_matvec_seconds"]
    np.testing.assert_allclose(tan.matvec(v).ravel(), K @ vf, atol=1e-8 * np.abs(K @ vf).max())
    return tan


def _time_direct(out: dict, sim, tan, x, a, rng):
    """Sparse direct factorisation and solves (1 and 44 right-hand sides) of K_UU; (free pattern, f_U(x))."""
    pattern = sim.pattern("free")
    Kf = tan.assemble(pattern)
    b = pattern.gather(sim.forces(x, a))
    backend = direct_backend()
    out["direct_backend"] = backend
    if backend is not None:
        t0 = time.perf_counter()
        factor = DirectFactor(Kf)
        out["direct_factor_seconds"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        factor.solve(b)
        out["direct_solve_seconds"] = time.perf_counter() - t0
        B = rng.normal(size=(Kf.shape[0], 44))
        t0 = time.perf_counter()
        factor.solve(B)
        out["direct_solve_44_seconds"] = time.perf_counter() - t0
        factor.free()
        del factor
    return pattern, b


def _time_cg(out: dict, tan, pattern, b, cg_maxiter: int) -> None:
    """Jacobi-PCG on the matrix-free K.v."""
    diag = pattern.gather(tan.diagonal())

    def matvec(u):
        return pattern.gather(tan.matvec(pattern.scatter(u)))

    t0 = time.perf_counter()
    res = pcg(matvec, b, preconditioner=JacobiPreconditioner(diag), rtol=1e-6, maxiter=cg_maxiter)
    out["cg_seconds"] = time.perf_counter() - t0
    out["cg_iterations"] = res.iterations
    out["cg_rtol"] = 1e-6
    out["cg_converged"] = res.converged
    out["cg_seconds_per_iteration"] = out["cg_seconds"] / max(res.iterations, 1)


def _time_quasistatic(out: dict, sim, a) -> None:
    """One full quasistatic solve with the jaw opened 5 degrees, from rest."""
    model = sim.model
    targets = attached_positions_from_affines(model, jaw=jaw_opening_affine(model, 5.0))
    eq = sim.solve(a, targets)
    out["quasistatic_seconds"] = eq.seconds
    out["quasistatic_newton_iterations"] = eq.iterations
    out["quasistatic_projected_steps"] = eq.projected_steps
    out["quasistatic_factorizations"] = eq.factorizations
    out["quasistatic_cg_iterations"] = eq.cg_iterations
    out["quasistatic_residual_rel"] = eq.residual_rel
    out["quasistatic_converged"] = eq.converged
    out["quasistatic_solver"] = eq.solver
    out["inverted_elements"] = eq.inverted_elements


def run(args) -> dict:
    """Entry point of ``wface bench --suite forward``: ``suite_result`` with one entry per size."""
    import warp as wp

    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)  # before init: no banner on stdout (--json)
    init_warp()
    device = resolve_device(getattr(args, "device", "auto"))
    sizes = getattr(args, "tets", None) or list(DEFAULT_TETS)
    repeat = int(getattr(args, "repeat", 3) or 3)
    results = [bench_size(int(n), device=device, repeat=repeat) for n in sizes]
    return suite_result("forward", device, results)


def compare_solvers(
    tan, pattern, b: np.ndarray, positions_m: np.ndarray, *, columns: int = 47, cg_maxiter: int = 3000
) -> dict:
    """The installed linear solvers on K_UU side by side (module docstring); {name: timings}.

    Args:
        tan: the stiffness (``Tangent``); pattern: its unknowns; b: (3k,) a right-hand side;
        positions_m: (k, 3) positions of the unknowns (AMG near-nullspace); columns: Jacobian columns.
    """
    B = np.random.default_rng(1).normal(size=(pattern.shape[0], columns))
    out: dict = {}
    if str(tan.device).startswith("cuda"):
        return _compare_gpu_solvers(tan, pattern, b, B)
    for backend in available_direct_backends():
        out[backend] = _time_direct_backend(tan, pattern, b, B, backend)
    K = tan.assemble(pattern)
    if amg_available():
        t0 = time.perf_counter()
        amg = AMGPreconditioner(K, positions_m)
        setup = time.perf_counter() - t0
        out["amg_cg"] = _time_cg_backend(K, b, amg, setup, columns, cg_maxiter)
        out["amg_cg"].update(levels=amg.levels, operator_complexity=amg.operator_complexity)
    out["jacobi_cg"] = _time_cg_backend(K, b, JacobiPreconditioner(K.diagonal()), 0.0, columns, cg_maxiter)
    return out


def _time_direct_backend(tan, pattern, b, B, backend: str) -> dict:
    """Setup (with analysis), numeric refactorisation, 1 and M + 12 right-hand sides of one backend."""
    values = tan.assemble_upper(pattern)
    if backend == "pardiso":  # a fresh analysis for the setup time, as a new mesh would have
        forget_analysis(pattern)
    t0 = time.perf_counter()
    factor = DirectFactor.of_pattern(pattern, values, backend=backend)
    setup = time.perf_counter() - t0
    factor.free()
    t0 = time.perf_counter()
    factor = DirectFactor.of_pattern(pattern, values, backend=backend)
    refactor = time.perf_counter() - t0
    t0 = time.perf_counter()
    x = factor.solve(b)
    one = time.perf_counter() - t0
    t0 = time.perf_counter()
    factor.solve(B)
    cols = time.perf_counter() - t0
    factor.free()
    K = tan.assemble(pattern)
    rel = float(np.linalg.norm(K @ x - b) / np.linalg.norm(b))
    return {
        "setup_seconds": setup,
        "refactor_seconds": refactor,
        "solve_seconds": one,
        "columns": B.shape[1],
        "columns_seconds": cols,
        "frame_seconds": refactor + cols,
        "residual_rel": rel,
    }


def _time_cg_backend(K, b, preconditioner, setup: float, columns: int, maxiter: int) -> dict:
    """CG on the CSR K with a preconditioner: one right-hand side to 1e-6 and to 1e-10."""
    out = {"setup_seconds": setup}
    for rtol, key in ((1e-6, "rtol_1e-6"), (1e-10, "rtol_1e-10")):
        t0 = time.perf_counter()
        res = pcg(lambda v: K @ v, b, preconditioner=preconditioner, rtol=rtol, maxiter=maxiter)
        out[key] = {"seconds": time.perf_counter() - t0, "iterations": res.iterations, "converged": res.converged}
    out["columns"] = columns
    out["columns_seconds"] = columns * out["rtol_1e-10"]["seconds"]  # an estimate: 47 x one column
    out["frame_seconds"] = setup + out["columns_seconds"]
    return out


def _compare_gpu_solvers(tan, pattern, b, B) -> dict:
    """On CUDA: cuDSS (when nvmath-python is installed) and the matrix-free Warp CG with Jacobi."""
    out: dict = {}
    if cudss_available():
        values = tan.assemble_upper(pattern)
        timings = []
        for _ in range(2):  # the first includes cuDSS's plan (analysis)
            t0 = time.perf_counter()
            factor = CudssFactor(pattern, values)
            timings.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        factor.solve(b)
        one = time.perf_counter() - t0
        t0 = time.perf_counter()
        factor.solve(B)
        cols = time.perf_counter() - t0
        out["cudss"] = {
            "setup_seconds": timings[0],
            "refactor_seconds": timings[1],
            "solve_seconds": one,
            "columns": B.shape[1],
            "columns_seconds": cols,
            "frame_seconds": timings[1] + cols,
        }
    entry: dict = {"setup_seconds": 0.0}
    for rtol, key in ((1e-6, "rtol_1e-6"), (1e-10, "rtol_1e-10")):
        t0 = time.perf_counter()
        _, its = warp_pcg(tan, pattern, b, rtol=rtol)
        entry[key] = {"seconds": time.perf_counter() - t0, "iterations": its}
    entry["columns"] = B.shape[1]
    entry["columns_seconds"] = B.shape[1] * entry["rtol_1e-10"]["seconds"]  # an estimate: 47 x one column
    entry["frame_seconds"] = entry["columns_seconds"]
    out["warp_jacobi_cg"] = entry
    return out
