"""The CUDA path end to end: simulator, Newton with Warp CG (or cuDSS), Jacobians and tracking on cuda:0,
checked against the CPU. Every test skips with a reason on a machine without a CUDA device; the
cuDSS test also skips without nvmath-python. ``examples/gpu_check.py`` runs these and the benches."""

from __future__ import annotations

import numpy as np
import pytest

from wface.physics import Simulator
from wface.testing.models import box_model


def _cuda_device() -> str:
    try:
        import warp as wp

        wp.config.quiet = True
        wp.init()
        if wp.get_cuda_device_count() > 0:
            return "cuda:0"
    except Exception as exc:  # noqa: BLE001 - a broken driver is "no GPU" here
        pytest.skip(f"Warp could not start: {exc}")
    pytest.skip("no CUDA device: the GPU path is checked only where one is present")


@pytest.fixture(scope="module")
def cuda():
    return _cuda_device()


@pytest.fixture(scope="module")
def box():
    return box_model((5, 3, 3), cranium_faces=("x-",), muscles=2)


def test_forces_and_stiffness_on_the_gpu_match_the_cpu(cuda, box):
    x = box.rest_positions_m + 1e-3 * np.random.default_rng(0).normal(size=box.rest_positions_m.shape)
    a = np.array([0.7, 0.2])
    cpu, gpu = Simulator(box, device="cpu"), Simulator(box, device=cuda)
    f_cpu, f_gpu = cpu.forces(x, a), gpu.forces(x, a)
    assert np.abs(f_gpu - f_cpu).max() <= 1e-9 * np.abs(f_cpu).max()  # float64 on both: sums in another order
    v = np.random.default_rng(1).normal(size=x.shape)
    kv_cpu, kv_gpu = cpu.stiffness_matvec(x, a, v), gpu.stiffness_matvec(x, a, v)
    assert np.abs(kv_gpu - kv_cpu).max() <= 1e-9 * np.abs(kv_cpu).max()
    K = gpu.assemble_stiffness(x, a, nodes="free")
    assert abs(K - cpu.assemble_stiffness(x, a, nodes="free")).max() <= 1e-9 * abs(K).max()


@pytest.mark.parametrize("solver", ["cg", "auto"])
def test_newton_on_the_gpu_finds_the_cpu_equilibrium(cuda, box, solver):
    a = {"muscle_0": 0.8, "muscle_1": 0.3}
    ref = Simulator(box, device="cpu").solve(a, tol=1e-10)
    eq = Simulator(box, device=cuda, solver=solver).solve(a, tol=1e-10)
    assert eq.converged
    scale = np.abs(ref.x - box.rest_positions_m).max()
    assert np.abs(eq.x - ref.x).max() <= 1e-7 * scale  # both converged to 1e-10 in the residual


def test_jacobian_on_the_gpu_matches_the_cpu(cuda):
    from wface.faces.builtin import build_face
    from wface.tracking.rig import FaceRig

    model = build_face(2000)
    c = FaceRig(model).rest_controls()
    c[model.muscle_index("zygomaticus_major_l")] = 0.5
    J = {}
    for device in ("cpu", cuda):
        rig = FaceRig(model, device=device, tol=1e-10)
        J[device] = rig.jacobian_y(rig.equilibrium(c))
    assert np.abs(J[cuda] - J["cpu"]).max() <= 1e-6 * np.abs(J["cpu"]).max()  # CG to 1e-10 vs a factor


def test_tracking_on_the_gpu_recovers_the_activations(cuda):
    from wface.faces.builtin import build_face
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import embed_model_markers, track_sequence
    from wface.tracking.synthetic import synthesize_performance

    model = build_face(2000)
    markers = embed_model_markers(model)
    perf = synthesize_performance(FaceRig(model), markers, frames=3, seed=3, max_jaw_deg=8.0)
    recs = track_sequence(
        model, perf.clean_markers_m, marker_names=model.marker_names, markers=markers, rig_kwargs={"device": cuda}
    )
    err_mm = np.array([r.marker_error_m for r in recs]) * 1e3
    assert np.sqrt(np.mean(err_mm**2)) < 0.05  # clean data: as on the CPU (tests/test_tracking.py)


def test_cudss_factor_solves_the_stiffness(cuda, box):
    from wface.solvers.linear import cudss_available

    if not cudss_available():
        pytest.skip("nvmath-python (cuDSS) is not installed")
    from wface.solvers.cudss import CudssFactor

    sim = Simulator(box, device=cuda)
    x = box.rest_positions_m + 1e-3 * np.random.default_rng(2).normal(size=box.rest_positions_m.shape)
    tan = sim.tangent(x, np.array([0.5, 0.5]))
    pattern = sim.pattern("free")
    K = tan.assemble(pattern)
    B = np.random.default_rng(3).normal(size=(K.shape[0], 5))
    X = CudssFactor.of_operator(tan, pattern).solve(B)
    assert np.abs(K @ X - B).max() <= 1e-9 * np.abs(B).max()  # a Cholesky factor: round-off times cond


def test_the_gpu_checks_cpu_reference_round_trips(tmp_path):
    """``examples/gpu_check.py --make-reference`` on the CPU, then its comparison, here against the CPU:
    the prepared GPU check compares before it benchmarks (runs without a GPU)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("gpu_check", Path(__file__).parents[1] / "examples" / "gpu_check.py")
    gpu_check = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gpu_check)
    ref = tmp_path / "ref.npz"
    assert gpu_check.main(["--make-reference", str(ref)]) == 0
    assert gpu_check.compare_with_reference(ref, "cpu")
    data = dict(np.load(ref))
    data["forces"] = data["forces"] * (1 + 1e-6)  # a wrong answer is caught
    np.savez(ref, **data)
    assert not gpu_check.compare_with_reference(ref, "cpu")
