"""The design document stands alone and the code's references to it hold.

- No file of the project (code, tests, examples, README, docs, USD scenes) cites a document
  outside the repository: the papers are cited by author and year, the design by its file and a
  section name.
- Every reference to the design, docs/design.md followed by a section name in double quotes
  (after a comma, a space or an opening parenthesis), in the code, tests, examples and README
  names a ``## `` or ``### `` heading of docs/design.md.
- The layer table of the design's Layers section lists exactly the units of
  ``tests/test_layers.LAYERS``, layer by layer.

The examples below build their strings from pieces, so that this file passes its own checks.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "docs" / "design.md"
SCANNED = ("wface", "kernels", "tests", "examples")  # and README.md
ALSO_FORBIDDEN_IN = ("docs", "usd_scenes")  # the outside citations are banned here too
SUFFIXES = {".py", ".md", ".txt", ".toml", ".cfg", ".json", ".usda"}
# Built from pieces so that this file does not contain them itself.
FORBIDDEN = tuple(["seed " + n for n in ("000", "003", "004")] + ["DESIGN" + ".md"])
# the design file name, an optional comma and parenthesis, then "Section name"; whitespace may wrap a line
REFERENCE = re.compile(r'docs/design\.md,?\s*\(?"([^"\n]+)"')
HEADING = re.compile(r"^#{2,3} +(.+?) *$", re.MULTILINE)


def _scanned_files(root: Path = ROOT, tops: tuple[str, ...] = SCANNED) -> list[Path]:
    files = [root / "README.md"] if (root / "README.md").exists() else []
    for top in tops:
        base = root / top
        if not base.is_dir():
            continue
        for path in sorted(base.rglob("*")):
            if path.is_file() and path.suffix in SUFFIXES and "__pycache__" not in path.parts:
                if top == "wface" and path.relative_to(base).parts[:1] == ("kernels",):
                    continue  # the wface/kernels link: the same files as kernels/
                files.append(path)
    return files


def _headings(text: str) -> set[str]:
    return {m.group(1) for m in HEADING.finditer(text)}


def forbidden_mentions(files: list[Path], root: Path = ROOT) -> list[str]:
    bad = []
    for path in files:
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
            for word in FORBIDDEN:
                if word in line:
                    bad.append(f"{path.relative_to(root)}:{number}: {word!r}")
    return bad


def broken_references(files: list[Path], headings: set[str], root: Path = ROOT) -> list[str]:
    bad = []
    for path in files:
        text = path.read_text(errors="replace")
        for m in REFERENCE.finditer(text):
            name = re.sub(r"\s+", " ", m.group(1)).strip()
            if name not in headings:
                line = text.count("\n", 0, m.start()) + 1
                bad.append(f"{path.relative_to(root)}:{line}: no heading {name!r} in docs/design.md")
    return bad


def layer_table(text: str) -> list[tuple[str, ...]]:
    """The units of each row of the table under ``## Layers``, in order."""
    section = re.search(r"^## Layers\n(.*?)(?=^## )", text, re.MULTILINE | re.DOTALL)
    assert section, 'docs/design.md has no "## Layers" section'
    rows = []
    for line in section.group(1).splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and len(cells) >= 2 and cells[0].isdigit():
            assert int(cells[0]) == len(rows), f"layer rows out of order at {line!r}"
            rows.append(tuple(re.findall(r"`([^`]+)`", cells[1])))
    return rows


def _layers():
    sys.path.insert(0, str(ROOT / "tests"))
    try:
        import test_layers
    finally:
        sys.path.pop(0)
    return test_layers.LAYERS


# ---------------------------------------------------------------------- the checks
def test_no_citation_of_documents_outside_the_repository():
    bad = forbidden_mentions(_scanned_files(tops=SCANNED + ALSO_FORBIDDEN_IN))
    assert not bad, "cite the papers (author, year) and docs/design.md instead:\n" + "\n".join(bad)


def test_references_to_the_design_name_existing_sections():
    headings = _headings(DESIGN.read_text())
    files = _scanned_files()
    refs = sum(len(REFERENCE.findall(p.read_text(errors="replace"))) for p in files)
    assert refs >= 10, f"only {refs} references to docs/design.md found: is the pattern still right?"
    bad = broken_references(files, headings)
    assert not bad, "references to missing sections:\n" + "\n".join(bad)


def test_layer_table_matches_the_declared_layers():
    table = layer_table(DESIGN.read_text())
    declared = [tuple(units) for units in _layers()]
    diff = [
        f"  layer {k}: table {table[k : k + 1]} / declared {declared[k : k + 1]}"
        for k in range(max(len(table), len(declared)))
        if table[k : k + 1] != declared[k : k + 1]
    ]
    assert not diff, "the Layers table of docs/design.md and tests/test_layers.LAYERS differ:\n" + "\n".join(diff)


# ---------------------------------------------------------------------- the checks can fail
@pytest.mark.parametrize("case", ["forbidden", "reference", "table"])
def test_the_checks_catch_what_they_claim(tmp_path, case):
    (tmp_path / "wface").mkdir()
    design = (
        "# d\n\n## Layers\n\n| layer | units | owns |\n| --- | --- | --- |\n"
        "| 0 | `wface`, `wface.model` | x |\n| 1 | `wface.cli` | y |\n\n## Flesh\n\n### Sub part\n"
    )
    if case == "forbidden":
        (tmp_path / "wface" / "a.py").write_text(f'"""As in {FORBIDDEN[0]}, section 4; see {FORBIDDEN[3]}."""\n')
        assert len(forbidden_mentions(_scanned_files(tmp_path), tmp_path)) == 2
    elif case == "reference":
        doc = "docs/design" + ".md"
        (tmp_path / "wface" / "a.py").write_text(
            f'"""See {doc}, "Flesh", {doc}\n    "Sub part" and {doc} ("Fleshy")."""\n'
        )
        bad = broken_references(_scanned_files(tmp_path), _headings(design), tmp_path)
        assert bad == ["wface/a.py:2: no heading 'Fleshy' in docs/design.md"]
    else:
        assert layer_table(design) == [("wface", "wface.model"), ("wface.cli",)]
        assert layer_table(design) != [("wface",), ("wface.model", "wface.cli")]
