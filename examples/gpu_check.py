"""The prepared GPU check: the CUDA tests, then the forward and track benches on cuda:0, in one run.

Run it on a machine with an NVIDIA GPU (README, "Performance"):

    python examples/gpu_check.py --out gpu_out                 # 100K and 370K tets
    python examples/gpu_check.py --out gpu_out --tets 20000    # a quick look
    python examples/gpu_check.py --make-reference ref.npz      # on any machine: the CPU's answers
    python examples/gpu_check.py --reference ref.npz --out gpu_out   # on the GPU: compared first

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


# The stack of a bench that stalls, every STACK_DUMP_S seconds on stderr: how the first lease found
# cuDSS stalled in one factorisation (docs/design.md, "The GPU path").
_BENCH_WITH_DUMPS = (
    "import faulthandler, runpy, sys; faulthandler.dump_traceback_later(float(sys.argv[1]), repeat=True); "
    "sys.argv = ['wface'] + sys.argv[2:]; runpy.run_module('wface', run_name='__main__')"
)


def reference_cases(device: str) -> dict:
    """What the GPU must reproduce, as arrays: forces, K v and K_UU of a deformed box, a Newton
    equilibrium, and the 2,000-tet built-in face's equilibrium and marker Jacobian."""
    import numpy as np

    from wface.faces.builtin import build_face
    from wface.physics import Simulator
    from wface.testing.models import box_model
    from wface.tracking.rig import FaceRig

    box = box_model((5, 3, 3), cranium_faces=("x-",), muscles=2)
    x = box.rest_positions_m + 1e-3 * np.random.default_rng(0).normal(size=box.rest_positions_m.shape)
    a = np.array([0.7, 0.2])
    sim = Simulator(box, device=device)
    out = {"box_rest": box.rest_positions_m, "forces": sim.forces(x, a)}
    out["kv"] = sim.stiffness_matvec(x, a, np.random.default_rng(1).normal(size=x.shape))
    out["K"] = sim.assemble_stiffness(x, a, nodes="free").toarray()
    out["equilibrium"] = Simulator(box, device=device).solve({"muscle_0": 0.8, "muscle_1": 0.3}, tol=1e-10).x
    face = build_face(2000)
    rig = FaceRig(face, device=device, tol=1e-10)
    c = rig.rest_controls()
    c[face.muscle_index("zygomaticus_major_l")] = 0.5
    state = rig.equilibrium(c)
    out.update(face_rest=face.rest_positions_m, face_equilibrium=state.x_m, marker_jacobian=rig.jacobian_y(state))
    return out


def compare_with_reference(path: Path, device: str) -> bool:
    """Print each case's largest relative difference from the reference file; False past 1e-8 (1e-6 for
    the equilibria and the Jacobian, which Warp CG solves to 1e-10 where cuDSS is absent)."""
    import numpy as np

    ref, got = dict(np.load(path)), reference_cases(device)
    ok = True
    for key, r in ref.items():
        g = got[key]
        rel = float(np.abs(g - r).max() / max(float(np.abs(r).max()), 1e-300)) if g.shape == r.shape else np.inf
        ok &= rel <= (1e-6 if "equilibrium" in key or "jacobian" in key else 1e-8)
        print(f"  {key:17s} largest relative difference {rel:.1e}", flush=True)
    return ok


def _bench(suite: str, tets: list[int], out: Path, extra: list[str], timeout_s: float, dump_s: float) -> dict | None:
    cmd = [sys.executable, "-c", _BENCH_WITH_DUMPS, str(dump_s), "bench", "--suite", suite, "--device", "cuda:0"]
    cmd += ["--json"] + [a for n in tets for a in ("--tets", str(n))] + ["--out", str(out)] + extra
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
    p.add_argument("--make-reference", metavar="NPZ", help="write the CPU reference (any machine) and stop")
    p.add_argument("--reference", metavar="NPZ", help="compare the GPU with this CPU reference first")
    p.add_argument("--stack-dump-s", type=float, default=30.0, help="a stalled bench's stack every N s")
    args = p.parse_args(argv)
    if args.make_reference:
        import numpy as np

        np.savez_compressed(args.make_reference, **reference_cases("cpu"))
        print(f"CPU reference written to {args.make_reference}")
        return 0
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
    if args.reference:
        print("against the CPU reference:", flush=True)
        status = 0 if compare_with_reference(Path(args.reference), device) else 1
    if not args.skip_tests:
        status |= subprocess.run([sys.executable, "-m", "pytest", "-q", str(REPO / "tests" / "test_gpu.py")]).returncode
    forward = _bench("forward", sizes, out / "forward_cuda.json", ["--repeat", "1"], args.timeout, args.stack_dump_s)
    track_sizes = sizes if cudss_available() else sizes[:1]
    extra = ["--repeat", "1", "--frames", str(args.frames)]
    track = _bench("track", track_sizes, out / "track_cuda.json", extra, args.timeout, args.stack_dump_s)
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
