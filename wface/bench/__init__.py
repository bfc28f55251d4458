"""Benchmarks behind ``wface bench --suite NAME``: one module per suite exposing

``add_arguments(parser)`` (optional) and ``run(args) -> dict`` (JSON-ready results).
"""

from __future__ import annotations

import os
import platform

import numpy as np

__all__ = ["SUITES", "machine_info"]

SUITES = ("forward", "jacobian", "track", "basis", "waters", "build", "dynamic")


def machine_info() -> dict:
    """Where a benchmark ran: CPU, core count, Warp device, versions."""

    info = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "numpy": np.__version__,
    }
    try:
        import warp as wp

        info["warp"] = wp.config.version
    except ImportError:  # pragma: no cover
        pass
    return info
