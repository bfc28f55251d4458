"""Compile wface's CUDA kernels ahead of time, on any machine (no GPU needed), into a kernel cache.

Warp compiles a kernel module with NVRTC the first time it runs on a GPU: a minute or more of a
GPU machine's time for the FEM kernels in both precisions. NVRTC ships inside Warp's own library,
so the same CUBINs can be made on a CPU-only machine and carried over:

    python examples/gpu_aot.py --cache gpu_cache --arch 90     # H100 / H200 (sm_90)
    WFACE_KERNEL_CACHE=gpu_cache wface bench --suite track --device cuda:0 ...   # on the GPU machine

The cache must be read by the same Warp version. Warp's own generic kernels (its CG's vector
operations) are still compiled there at first use: they are small.
"""

from __future__ import annotations

import argparse
import os
import time


def _kernels(ns) -> list:
    import warp as wp

    return [v for v in vars(ns).values() if isinstance(v, wp.Kernel)]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cache", required=True, help="kernel cache directory to fill (WFACE_KERNEL_CACHE there)")
    p.add_argument("--arch", type=int, action="append", help="CUDA compute capability, e.g. 90 (repeatable)")
    args = p.parse_args(argv)
    os.environ["WFACE_KERNEL_CACHE"] = os.path.abspath(args.cache)
    from wface.warp_runtime import init_warp

    init_warp()
    import warp as wp

    import wface.kernels.geometry as geometry
    import wface.kernels.waters as waters
    from wface.kernels.fem import fem_kernels

    modules = [geometry, waters]
    for dtype in (wp.float64, wp.float32):
        modules += [k.module for k in _kernels(fem_kernels(dtype))]
    arches = args.arch or [90]
    t0 = time.perf_counter()
    for m in modules:
        wp.compile_aot_module(m, arch=arches)
    print(f"{len(modules)} modules for sm_{', sm_'.join(map(str, arches))} in {time.perf_counter() - t0:.0f} s")
    print(f"into {wp.config.kernel_cache_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
