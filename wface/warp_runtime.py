"""Warp start-up: one place that sets the kernel cache, picks devices and keeps start-up quiet.

The kernel cache lives in a stable directory so compiled kernels survive between runs and
between CI steps: ``$WFACE_KERNEL_CACHE`` if set, else ``~/.cache/wface/warp-<warp version>``.

Two things a user sees at start-up are handled here:

- Warp's native library prints "Could not find or load the NVIDIA CUDA driver" on every machine
  without one. ``init_warp`` captures the native stderr while Warp initialises and drops that line
  (everything else is passed on); the line is kept and shown only when CUDA is asked for
  (``resolve_device("cuda...")`` raises with it).
- A cold kernel compile takes about a minute on a 2-core CPU (docs/design.md, "Performance").
  While a kernel module is compiled because the cache holds no binary for it, one line says so on
  stderr, once per process.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

__all__ = ["NoCudaDeviceError", "init_warp", "kernel_cache_dir", "quiet_warp", "resolve_device"]

_initialised = False
_cuda_messages: list[str] = []  # what Warp's native start-up said about CUDA (shown when CUDA is asked for)
_compile_announced = False
_CUDA_DRIVER_NOTE = "Could not find or load the NVIDIA CUDA driver"


def kernel_cache_dir() -> Path:
    """Directory where Warp keeps compiled kernels."""
    import warp as wp

    env = os.environ.get("WFACE_KERNEL_CACHE")
    if env:
        return Path(env).expanduser()
    return Path.home() / ".cache" / "wface" / f"warp-{wp.config.version}"


def _init_capturing_stderr(wp, *, keep_cuda_note: bool) -> None:
    """``wp.init()`` with the process's native stderr captured; lines other than the CUDA-driver
    note are written back, so no other diagnostic is lost."""
    fd = 2  # the native library writes to the process's file descriptor 2, whatever sys.stderr is now
    sys.stderr.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            wp.init()
        finally:
            os.dup2(saved, fd)
            os.close(saved)
        tmp.seek(0)
        text = tmp.read().decode(errors="replace")
    for line in text.splitlines(keepends=True):
        if _CUDA_DRIVER_NOTE in line:
            _cuda_messages.append(line.strip())
            if not keep_cuda_note:
                continue
        sys.stderr.write(line)
    sys.stderr.flush()


def _announce_cold_compiles(wp) -> None:
    """Print one line (stderr, once per process) when Warp starts compiling a module it has not cached.

    Wraps Warp's ``Module._compile`` (which returns False when the cached binary exists); a Warp
    without that method is left alone.
    """
    try:
        from warp._src.context import Module
    except ImportError:  # pragma: no cover - other Warp layouts
        return
    original = getattr(Module, "_compile", None)
    if original is None or getattr(original, "_wface_announces", False):
        return

    def _compile(self, device=None, output_dir=None, output_name=None, *args, **kwargs):
        global _compile_announced
        if not _compile_announced and output_dir is not None and output_name is not None:
            if not os.path.exists(os.path.join(output_dir, output_name)):
                _compile_announced = True
                print(
                    f"wface: compiling Warp kernels for {device} (first run with this Warp; about a minute on a "
                    f"2-core CPU, then cached in {wp.config.kernel_cache_dir})",
                    file=sys.stderr,
                    flush=True,
                )
        return original(self, device, output_dir, output_name, *args, **kwargs)

    _compile._wface_announces = True
    Module._compile = _compile


def init_warp(*, quiet: bool = True, cuda_requested: bool = False) -> None:
    """Initialise Warp once with the stable kernel cache (idempotent).

    Args:
        quiet: keep Warp's banner and per-module load messages off stdout.
        cuda_requested: show Warp's CUDA-driver note if it prints one (otherwise it is dropped on a
            machine without a driver; ``resolve_device`` reports it when CUDA is asked for later).
    """
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
    try:
        _init_capturing_stderr(wp, keep_cuda_note=cuda_requested)
    except OSError:  # no usable file descriptor 2: initialise plainly
        wp.init()
    _announce_cold_compiles(wp)
    _initialised = True


def quiet_warp() -> None:
    """Keep Warp's per-module load messages off stdout (Warp 1.19 logs them at INFO level)."""
    import warp as wp

    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)


class NoCudaDeviceError(RuntimeError):
    """A CUDA device was asked for on a machine where Warp sees none (a user's choice, not a bug)."""


def resolve_device(device: str | None = None) -> str:
    """Return a Warp device name: ``"cpu"``, ``"cuda:0"``...; ``None`` or ``"auto"`` picks CUDA when present.

    Raises:
        NoCudaDeviceError: a CUDA device is asked for and Warp sees none (with Warp's own note on the driver).
    """
    import warp as wp

    if device not in (None, "auto", "cpu") and not (isinstance(device, str) and device.startswith("cuda")):
        raise ValueError(f"device must be 'cpu', 'cuda', 'cuda:N' or 'auto', got {device!r}")
    asks_cuda = device is not None and device.startswith("cuda")
    init_warp(cuda_requested=asks_cuda)
    if device in (None, "auto"):
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    if asks_cuda and not wp.is_cuda_available():
        note = f" (Warp: {_cuda_messages[-1]})" if _cuda_messages else ""
        raise NoCudaDeviceError(
            f"device {device!r} requested but Warp sees no CUDA device on this machine{note}: use --device cpu "
            "(or auto, which takes CUDA where there is one)"
        )
    return device
