"""The README's Python blocks run as they stand, and the commands and examples it names exist."""

from __future__ import annotations

import re

import pytest
from conftest import REPO_ROOT

README = (REPO_ROOT / "README.md").read_text()


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README, flags=re.S)


def test_the_python_blocks_run(tmp_path, monkeypatch):
    """The Python API section, executed in order in one namespace (they share ``face``, ``state``)."""
    pytest.importorskip("pxr")  # the last block writes USD
    blocks = _python_blocks()
    assert len(blocks) >= 2
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)  # noqa: S102 - the README's own code
    J, face = namespace["J"], namespace["face"]
    assert J.shape == (face.n_nodes, 3, face.n_muscles + 24)
    assert namespace["again"].n_frames == namespace["take"].n_frames == 2
    assert (tmp_path / "edited" / "animation.usdc").exists()


def test_the_commands_the_readme_names_exist():
    from wface.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    named = set(re.findall(r"`wface ([a-z]+)", README))
    assert named and named <= set(sub.choices), f"README names unknown commands: {named - set(sub.choices)}"


def test_the_examples_the_readme_names_exist():
    named = set(re.findall(r"examples/([a-z_]+\.py)", README))
    missing = [n for n in named if not (REPO_ROOT / "examples" / n).exists()]
    assert named and not missing, missing
