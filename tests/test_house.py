"""House rules on size: every module of ``wface`` is at most 600 lines, every function at most 120.

A function counts from its ``def`` line to its last line, docstring and nested functions included.
Exempt: the kernel factories of ``kernels/`` (linked as ``wface/kernels``), functions whose body
defines ``@wp.func`` / ``@wp.kernel`` closures (one closure per scalar type keeps the float32 and
float64 variants identical). A longer function is split into a short public function over small
private helpers with one job each; a module that would pass 600 lines into a sibling module.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "wface"
KERNELS = ROOT / "kernels"

MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 120


def _files() -> list[Path]:
    """Every .py file of the package and of the kernels directory, once (wface/kernels is a link)."""
    found = {p.resolve() for p in PACKAGE.rglob("*.py")} | {p.resolve() for p in KERNELS.rglob("*.py")}
    return sorted(found)


def _rel(path: Path) -> str:
    try:
        return str(path.relative_to(ROOT.resolve()))
    except ValueError:
        return str(path)


def _is_kernel_decorator(node: ast.expr) -> bool:
    """``@wp.func``, ``@wp.kernel`` or ``@wp.kernel(...)``."""
    if isinstance(node, ast.Call):
        node = node.func
    return (
        isinstance(node, ast.Attribute)
        and node.attr in ("func", "kernel")
        and isinstance(node.value, ast.Name)
        and node.value.id == "wp"
    )


def _is_kernel_factory(path: Path, func: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    in_kernels = path.is_relative_to(KERNELS.resolve())
    return in_kernels and any(
        isinstance(inner, ast.FunctionDef) and any(_is_kernel_decorator(d) for d in inner.decorator_list)
        for inner in ast.walk(func)
        if inner is not func
    )


def _long_modules(limit: int) -> list[str]:
    out = []
    for path in _files():
        n = len(path.read_text().splitlines())
        if n > limit:
            out.append(f"{_rel(path)}: {n} lines")
    return out


def _long_functions(limit: int) -> list[str]:
    out = []
    for path in _files():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            length = node.end_lineno - node.lineno + 1
            if length > limit and not _is_kernel_factory(path, node):
                out.append(f"{_rel(path)}:{node.lineno}: {node.name} is {length} lines")
    return out


def test_modules_are_at_most_600_lines():
    long = _long_modules(MAX_MODULE_LINES)
    assert not long, f"modules over {MAX_MODULE_LINES} lines (split into a sibling module):\n" + "\n".join(long)


def test_functions_are_at_most_120_lines():
    long = _long_functions(MAX_FUNCTION_LINES)
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines (split into private helpers):\n" + "\n".join(long)


def test_the_walk_sees_the_package_and_the_kernels():
    files = {_rel(p) for p in _files()}
    assert "wface/physics/newton.py" in files and "kernels/fem.py" in files
    assert not any(f.startswith("wface/kernels/") for f in files)  # the link counted once, as kernels/


def test_the_checks_catch_what_they_claim(tmp_path, monkeypatch):
    """A long function and a long module are named with file:line and length; a kernel factory in
    kernels/ is exempt, the same function outside kernels/ is not."""
    pkg, kernels = tmp_path / "wface", tmp_path / "kernels"
    pkg.mkdir()
    kernels.mkdir()
    body = "".join(f"    x{i} = {i}\n" for i in range(130))
    head = 'import warp as wp\n\n\ndef factory():\n    @wp.kernel(module="unique")\n    def k():\n        pass\n\n'
    factory = head + body
    (pkg / "long.py").write_text("\n\ndef long_one():\n" + body + "\n" * 480)
    (pkg / "factory_outside.py").write_text(factory)
    (kernels / "factory.py").write_text(factory)
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", pkg)
    monkeypatch.setattr(sys.modules[__name__], "KERNELS", kernels)
    assert _long_modules(MAX_MODULE_LINES) == ["wface/long.py: 613 lines"]
    assert _long_functions(MAX_FUNCTION_LINES) == [
        "wface/factory_outside.py:4: factory is 135 lines",
        "wface/long.py:3: long_one is 131 lines",
    ]
    with pytest.raises(AssertionError, match=r"wface/long\.py:3: long_one is 131 lines"):
        test_functions_are_at_most_120_lines()
    with pytest.raises(AssertionError, match=r"wface/long\.py: 613 lines"):
        test_modules_are_at_most_600_lines()
