"""The package's imports run one way: a declared layer order, no cycles, own modules at module top.

Walks every module of ``wface`` with ``ast`` (imports inside functions included) and fails with the
offending edge. The layer order is the one docs/design.md ("Layers") explains; a package may import
itself and any package of a lower layer, never one of its own layer or above.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "wface"

# lowest first; a unit is a top-level module or subpackage of wface
LAYERS: list[tuple[str, ...]] = [
    ("wface", "wface.files"),
    ("wface.kernels", "wface.warp_runtime", "wface.model", "wface.facs"),
    ("wface.controls",),
    ("wface.mesh",),
    ("wface.solvers",),
    ("wface.physics",),
    ("wface.faces",),
    ("wface.viz",),
    ("wface.io",),
    ("wface.takes",),
    ("wface.tracking", "wface.basis", "wface.waters"),
    ("wface.speech",),
    ("wface.testing",),
    ("wface.bench",),
    ("wface.cli",),
    ("wface.__main__",),
]
LAYER_OF = {unit: k for k, units in enumerate(LAYERS) for unit in units}
# Device code imports warp at import time, so it may be imported where a kernel is first needed.
LAZY_OK = ("wface.kernels",)
# Heavy or optional third-party packages, imported inside the functions that need them (a missing
# optional extra fails only the feature that needs it, and `import wface.x` stays fast).
LAZY_THIRD_PARTY = {
    "warp",
    "pxr",
    "pyvista",
    "vtk",
    "vtkmodules",
    "matplotlib",
    "imageio",
    "imageio_ffmpeg",
    "ezc3d",
    "dask",
    "distributed",
    "pypardiso",
    "sksparse",
    "cholespy",
    "pyamg",
    "nvmath",
}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _unit(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else parts[0]


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        if "kernels" in path.relative_to(PACKAGE).parts[:1]:
            continue  # the wface/kernels link: device code, no wface imports
        out[_module_name(path)] = path
    return out


def _imports(path: Path, known: set[str]) -> list[tuple[str, int, bool]]:
    """(imported wface module, line, inside a function) of a file; ``from a import b`` counts as
    a.b when a.b is a module."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: list[tuple[str, int, bool]] = []

    def visit(node, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                found.extend((a.name, child.lineno, in_function) for a in child.names if a.name.startswith("wface"))
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and (child.module or "").startswith("wface"):
                for a in child.names:
                    sub = f"{child.module}.{a.name}"
                    found.append((sub if sub in known else child.module, child.lineno, in_function))
            visit(child, inner)

    visit(tree, False)
    return found


def _graph():
    modules = _modules()
    known = set(modules)
    edges: dict[str, list[tuple[str, int, bool]]] = {}
    for name, path in modules.items():
        edges[name] = [(t, line, fn) for t, line, fn in _imports(path, known) if t != name]
    return modules, edges


def test_every_unit_has_a_layer():
    modules, _ = _graph()
    missing = sorted({_unit(m) for m in modules} - set(LAYER_OF))
    assert not missing, f"declare a layer for {missing} in tests/test_layers.py (and docs/design.md)"


def test_imports_run_down_the_layers():
    modules, edges = _graph()
    bad = []
    for src, targets in edges.items():
        su = _unit(src)
        for tgt, line, _ in targets:
            tu = _unit(tgt)
            if tu == su or tgt == "wface":
                continue
            if LAYER_OF.get(tu, -1) >= LAYER_OF[su]:
                bad.append(f"{modules[src].relative_to(ROOT)}:{line}: {src} -> {tgt} ({su} may not import {tu})")
    assert not bad, "imports that run up or across the layers:\n" + "\n".join(bad)


def test_no_import_cycles():
    modules, edges = _graph()
    graph = {m: sorted({t for t, _, _ in ts if t in modules}) for m, ts in edges.items()}
    # a package's __init__ importing its own submodules is how it re-exports them; a submodule
    # importing its package's __init__ is what would close a cycle, so keep both kinds of edge
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def strongconnect(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, []):
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            strongconnect(v)
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_own_modules_are_imported_at_module_top():
    modules, edges = _graph()
    lazy = [
        f"{modules[src].relative_to(ROOT)}:{line}: {tgt}"
        for src, targets in edges.items()
        for tgt, line, in_function in targets
        if in_function and not tgt.startswith(LAZY_OK)
    ]
    assert not lazy, "import these at module top (only heavy optional third-party packages load lazily):\n" + "\n".join(
        lazy
    )


def test_only_heavy_optional_packages_load_lazily():
    lazy = []
    for path in _modules().values():
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for inner in ast.walk(node):
                names = []
                if isinstance(inner, ast.Import):
                    names = [a.name for a in inner.names]
                elif isinstance(inner, ast.ImportFrom) and inner.level == 0:
                    names = [inner.module or ""]
                for name in names:
                    top = name.split(".")[0]
                    if top != "wface" and top not in LAZY_THIRD_PARTY:
                        lazy.append(f"{path.relative_to(ROOT)}:{inner.lineno}: {name}")
    assert not lazy, "import these at module top:\n" + "\n".join(sorted(set(lazy)))


@pytest.mark.parametrize("rule", ["layers", "cycle"])
def test_the_checks_catch_what_they_claim(tmp_path, monkeypatch, rule):
    """The walker itself: a lower layer importing a higher one, and a two-module cycle, are found."""
    pkg = tmp_path / "wface"
    (pkg / "mesh").mkdir(parents=True)
    (pkg / "cli").mkdir()
    for init in (pkg / "__init__.py", pkg / "mesh" / "__init__.py", pkg / "cli" / "__init__.py"):
        init.write_text("")
    if rule == "layers":
        (pkg / "mesh" / "a.py").write_text("def f():\n    from wface.cli import b\n")
        (pkg / "cli" / "b.py").write_text("")
    else:
        (pkg / "mesh" / "a.py").write_text("from wface.mesh import b\n")
        (pkg / "mesh" / "b.py").write_text("from wface.mesh import a\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", pkg)
    check = test_imports_run_down_the_layers if rule == "layers" else test_no_import_cycles
    with pytest.raises(AssertionError, match="wface.cli" if rule == "layers" else "wface.mesh.a <-> wface.mesh.b"):
        check()
