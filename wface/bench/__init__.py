"""Benchmarks behind ``wface bench --suite NAME``: one module per suite exposing

``add_arguments(parser)`` (optional) and ``run(args) -> dict`` (JSON-ready results).

Every suite returns the same shape (``suite_result``)::

    {"suite": "forward", "machine": {...machine_info()...}, "device": "cpu" | "cuda:0" | ...,
     "results": [{...one entry per measured size or case...}, ...], "notes": {...}}

``device`` is the Warp device the suite ran on ("cpu" for a suite without Warp kernels); each
entry carries its own size ("tets", "vertices", "frames", ...); the optional ``notes`` say in words
what was skipped or substituted ({topic: text}).
"""

from __future__ import annotations

import os
import platform

import numpy as np

__all__ = ["SUITES", "machine_info", "suite_result"]

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


def suite_result(suite: str, device: str, results: list[dict], notes: dict[str, str] | None = None) -> dict:
    """The JSON of one suite run: {"suite", "machine", "device", "results": [...]} (+ "notes" when any)."""
    out = {"suite": suite, "machine": machine_info(), "device": device, "results": list(results)}
    if notes:
        out["notes"] = dict(notes)
    return out
