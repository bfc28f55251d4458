"""The command line's own exception: a usage error found after argparse (exit code 2)."""

from __future__ import annotations

__all__ = ["UsageError"]


class UsageError(ValueError):
    """Options that cannot go together, or that would do nothing in this run: exit code 2 before any
    work, like argparse's own errors (``wface.cli.main``)."""
