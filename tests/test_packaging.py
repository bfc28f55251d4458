"""The wheel installs wface.kernels (never a top-level `kernels`) and its kernels run on the CPU."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
import textwrap
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_installs_kernels_as_wface_kernels(tmp_path):
    pytest.importorskip("setuptools", minversion="69")
    dist = tmp_path / "dist"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(REPO), "--no-deps", "--no-build-isolation", "-w", str(dist), "-q"],
        check=True,
    )
    wheel = next(dist.glob("wface-*.whl"))
    import zipfile

    names = zipfile.ZipFile(wheel).namelist()
    assert "wface/kernels/geometry.py" in names
    assert not any(n.startswith("kernels/") for n in names), "a top-level `kernels` package must never be installed"

    # A fresh virtual environment gets the wheel alone; its dependencies (warp, numpy, ...) are
    # borrowed from the running environment through a .pth line, so the test needs no network.
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)], check=True)
    site = Path(
        subprocess.check_output(
            [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], text=True
        ).strip()
    )
    (site / "_wface_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")

    script = textwrap.dedent(
        """
        import importlib.util, numpy as np, warp as wp, wface
        from wface.warp_runtime import init_warp
        assert importlib.util.find_spec("kernels") is None
        assert "site-packages" in wface.__file__, wface.__file__
        init_warp()
        from wface.kernels.geometry import tet_signed_volume
        corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
        x = wp.array(corners, dtype=wp.vec3d, device="cpu")
        t = wp.array(np.array([[0, 1, 2, 3]], dtype=np.int32), dtype=wp.int32, device="cpu")
        v = wp.zeros(1, dtype=wp.float64, device="cpu")
        wp.launch(tet_signed_volume, dim=1, inputs=[x, t], outputs=[v], device="cpu")
        print(v.numpy()[0])
        """
    )
    out = subprocess.run([str(py), "-c", script], cwd=tmp_path, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert abs(float(out.stdout.strip().splitlines()[-1]) - 1.0 / 6.0) < 1e-15  # exact in float64
