"""Warp start-up: one place that sets the kernel cache and picks devices.

The kernel cache lives in a stable directory so compiled kernels survive between runs and
between CI steps: ``$WFACE_KERNEL_CACHE`` if set, else ``~/.cache/wface/warp-<warp version>``.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["init_warp", "kernel_cache_dir", "quiet_warp", "resolve_device"]

_initialised = False


def kernel_cache_dir() -> Path:
    """Directory where Warp keeps compiled kernels."""
    import warp as wp

    env = os.environ.get("WFACE_KERNEL_CACHE")
    if env:
        return Path(env).expanduser()
    return Path.home() / ".cache" / "wface" / f"warp-{wp.config.version}"


def init_warp(*, quiet: bool = True) -> None:
    """Initialise Warp once with the stable kernel cache (idempotent)."""
    global _initialised
    if _initialised:
        return
    import warp as wp

    cache = kernel_cache_dir()
    cache.mkdir(parents=True, exist_ok=True)
    wp.config.kernel_cache_dir = str(cache)
    wp.config.quiet = quiet
    if quiet and hasattr(wp, "LOG_WARNING"):  # Warp 1.19 prints its banner at info level
        wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    wp.init()
    _initialised = True


def quiet_warp() -> None:
    """Keep Warp's per-module load messages off stdout (Warp 1.19 logs them at INFO level)."""
    import warp as wp

    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)


def resolve_device(device: str | None = None) -> str:
    """Return a Warp device name: ``"cpu"``, ``"cuda:0"``...; ``None`` or ``"auto"`` picks CUDA when present."""
    import warp as wp

    init_warp()
    if device in (None, "auto"):
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise RuntimeError(f"device {device!r} requested but Warp sees no CUDA device on this machine")
    return device
