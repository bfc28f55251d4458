"""Shared fixtures: where the real data lives, and skips when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = Path(os.environ.get("WFACE_DATA", REPO_ROOT.parent / "shared" / "data"))


def data_path(*parts: str) -> Path:
    """Path into ../shared/data; skips the calling test with a reason when it is absent."""
    path = DATA_DIR.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not present: {path} (set WFACE_DATA or check out ../shared/data)")
    return path


@pytest.fixture(scope="session")
def shared_data_dir() -> Path:
    if not DATA_DIR.exists():
        pytest.skip(f"real data directory absent: {DATA_DIR}")
    return DATA_DIR
