"""Warp start-up as a user sees it: no CUDA-driver note unless CUDA is asked for, one line on a cold compile."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("warp")

_NOTE = "Could not find or load the NVIDIA CUDA driver"
_SCRIPT = textwrap.dedent(
    """
    import warp as wp
    from wface.warp_runtime import init_warp
    init_warp()

    @wp.kernel
    def twice(a: wp.array(dtype=float), out: wp.array(dtype=float)):
        i = wp.tid()
        out[i] = 2.0 * a[i]

    a = wp.array([1.0, 2.0], dtype=float, device="cpu")
    out = wp.zeros(2, dtype=float, device="cpu")
    wp.launch(twice, dim=2, inputs=[a], outputs=[out], device="cpu")
    print("RESULT", out.numpy().tolist())
    """
)


def _run(code: str, cache) -> subprocess.CompletedProcess:
    """Run ``code`` from a file (Warp reads kernel source from files) with its own kernel cache."""
    script = cache.parent / "script.py"
    script.write_text(code)
    env = {**os.environ, "WFACE_KERNEL_CACHE": str(cache)}
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=300)


def test_cold_compile_says_so_once_and_warm_runs_are_quiet(tmp_path):
    cold = _run(_SCRIPT, tmp_path / "cache")
    assert cold.returncode == 0, cold.stderr
    assert "RESULT [2.0, 4.0]" in cold.stdout
    assert cold.stderr.count("wface: compiling Warp kernels for cpu") == 1
    assert _NOTE not in cold.stderr + cold.stdout
    warm = _run(_SCRIPT, tmp_path / "cache")
    assert warm.returncode == 0 and "compiling" not in warm.stderr and _NOTE not in warm.stderr


def test_asking_for_cuda_without_a_driver_says_why(tmp_path):
    import warp as wp

    from wface.warp_runtime import init_warp

    init_warp()
    if wp.is_cuda_available():
        pytest.skip("this machine has CUDA: the driver note is never printed")
    code = "from wface.warp_runtime import resolve_device\nresolve_device('cuda:0')"
    run = _run(code, tmp_path / "cache")
    assert run.returncode != 0
    assert "device 'cuda:0' requested but Warp sees no CUDA device" in run.stderr


def test_asking_for_cuda_without_one_is_a_user_error_on_the_command_line(capsys, tmp_path):
    """One line and exit 1 naming the cure; it used to be reported as an internal error to report."""
    import warp as wp

    from wface.cli import main
    from wface.warp_runtime import init_warp

    init_warp()
    if wp.is_cuda_available():
        pytest.skip("this machine has CUDA")
    assert (
        main(
            [
                "edit",
                "blend",
                "--from",
                "smile",
                "--to",
                "sad",
                "--frames",
                "2",
                "--tets",
                "1000",
                "--device",
                "cuda",
                "--out",
                str(tmp_path / "out"),
            ]
        )
        == 1
    )
    err = capsys.readouterr().err
    assert "Warp sees no CUDA device" in err and "use --device cpu" in err and "internal error" not in err, err
