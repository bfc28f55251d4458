"""The prepared GPU check: the CUDA tests, then the forward and track benches on cuda:0, in one run.

Run it on a machine with an NVIDIA GPU (README, "Performance"):

    python examples/gpu_check.py --out gpu_out                 # 100K and 370K tets
    python examples/gpu_check.py --out gpu_out --tets 20000    # a quick look

On a short lease, compile the kernels beforehand on any machine (``examples/gpu_aot.py``) and run
this with ``WFACE_KERNEL_CACHE`` pointing at that cache. It writes gpu_out/forward_cuda.json and
gpu_out/track_cuda.json (the ``wface bench`` JSON shape) and prints one line per size. Without a CUDA
device it says so and exits 0, so it also runs (as a no-op) in the test suite. cuDSS (nvmath-python)
is used when it is importable; without it the Jacobians run Warp CG column by column, which is slow
at 370K, so the track bench then keeps to the smallest size.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _cuda_device() -> str | None:
    import warp as wp

    wp.config.quiet = True
    wp.init()
    return "cuda:0" if wp.get_cuda_device_count() > 0 else None


def _bench(suite: str, tets: list[int], out: Path, extra: list[str], timeout_s: float) -> dict | None:
    cmd = [sys.executable, "-m", "wface", "bench", "--suite", suite, "--device", "cuda:0", "--json"]
    cmd += [a for n in tets for a in ("--tets", str(n))] + ["--out", str(out)] + extra
    print("$", " ".join(cmd[1:]), flush=True)
    t0 = time.perf_counter()
    try:
        subprocess.run(cmd, check=True, timeout=timeout_s, stdout=subprocess.DEVNULL)
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as exc:
        print(f"  {suite} bench failed or ran out of time: {exc}", flush=True)
        return None
    print(f"  {suite}: {time.perf_counter() - t0:.0f} s", flush=True)
    return json.loads(out.read_text())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="gpu_out", help="output directory")
    p.add_argument("--tets", type=int, action="append", help="mesh sizes (default 100000 and 370000)")
    p.add_argument("--frames", type=int, default=4, help="tracked frames per size (default 4)")
    p.add_argument("--timeout", type=float, default=240.0, help="seconds allowed per bench run")
    p.add_argument("--skip-tests", action="store_true", help="benches only")
    args = p.parse_args(argv)
    device = _cuda_device()
    if device is None:
        print("no CUDA device here: nothing to check (run this on a machine with an NVIDIA GPU)")
        return 0
    from wface.solvers.linear import cudss_available

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sizes = args.tets or [100_000, 370_000]
    print(f"device {device}; cuDSS (nvmath-python): {'yes' if cudss_available() else 'no'}", flush=True)
    status = 0
    if not args.skip_tests:
        status = subprocess.run([sys.executable, "-m", "pytest", "-q", str(REPO / "tests" / "test_gpu.py")]).returncode
    forward = _bench("forward", sizes, out / "forward_cuda.json", ["--repeat", "1"], args.timeout)
    track_sizes = sizes if cudss_available() else sizes[:1]
    extra = ["--repeat", "1", "--frames", str(args.frames)]
    track = _bench("track", track_sizes, out / "track_cuda.json", extra, args.timeout)
    for r in (forward or {}).get("results", []):
        print(
            f"forward {r['tets']:>7} tets: forces {r['forces_seconds'] * 1e3:.1f} ms, "
            f"K.v {r['kv_seconds'] * 1e3:.2f} ms, "
            f"quasistatic {r['quasistatic_seconds']:.2f} s ({r['quasistatic_newton_iterations']} it)"
        )
    for r in (track or {}).get("results", []):
        print(
            f"track   {r['tets']:>7} tets: {r['seconds_per_frame']:.3f} s/frame, limit ratio {r.get('limit_ratio')}, "
            f"peak RSS {r['peak_rss_mb']:.0f} MB, activation error {r['accuracy']['activation_rms_error']:.4f}"
        )
    return status or (0 if forward and track else 1)


if __name__ == "__main__":
    raise SystemExit(main())
