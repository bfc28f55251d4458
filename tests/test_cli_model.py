"""`wface model build/info` and the built-in face example."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from wface.cli import main

REPO = Path(__file__).resolve().parents[1]


def test_build_and_info_json(tmp_path, capsys):
    out = tmp_path / "face.npz"
    assert (
        main(["model", "build", "--tets", "3000", "--out", str(out), "--quiet", "--vtu", str(tmp_path / "f.vtu")]) == 0
    )
    assert out.exists() and (tmp_path / "f.vtu").exists()
    capsys.readouterr()
    assert main(["model", "info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    for key in ("nodes", "tets", "muscles", "markers", "attached_nodes", "min_dihedral_deg", "min_volume_m3", "bbox_m"):
        assert key in info
    assert set(info["attached_nodes"]) == {"cranium", "jaw"}
    assert info["min_dihedral_deg"] > 5 and len(info["muscles"]) >= 26 and len(info["markers"]) >= 40


def test_build_with_a_freer_midface(tmp_path, capsys):
    """--free-to-mm frees the bone side higher (fewer cranium nodes), is kept in the file, and a value
    out of range is a one-line error naming it."""
    from wface.model import load_model

    base, free = tmp_path / "base.npz", tmp_path / "free.npz"
    assert main(["model", "build", "--tets", "2000", "--out", str(base), "--quiet"]) == 0
    assert main(["model", "build", "--tets", "2000", "--free-to-mm", "34", "--out", str(free), "--quiet"]) == 0
    a, b = load_model(base), load_model(free)
    assert b.metadata["free_to_mm"] == 34.0 and len(b.nodes_of_bone("cranium")) < len(a.nodes_of_bone("cranium"))
    capsys.readouterr()
    assert main(["model", "info", str(free)]) == 0
    assert "bone side free to 34 mm above the mouth line" in capsys.readouterr().out
    assert main(["model", "info", str(free), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["free_to_mm"] == 34.0
    assert main(["model", "build", "--tets", "2000", "--free-to-mm", "60", "--out", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err
    assert "--free-to-mm" in err and "60" in err and "Traceback" not in err and not (tmp_path / "x.npz").exists()


def test_info_on_missing_file_is_one_line_error(tmp_path, capsys):
    assert main(["model", "info", str(tmp_path / "nope.npz")]) == 1
    err = capsys.readouterr().err
    assert "not found" in err and "Traceback" not in err


def test_help_teaches(capsys):
    try:
        main(["model", "build", "--help"])
    except SystemExit:
        pass
    assert "--tets" in capsys.readouterr().out


def test_builtin_face_example_renders(tmp_path):
    sys.path.insert(0, str(REPO / "examples"))
    try:
        import builtin_face
    finally:
        sys.path.pop(0)
    png = tmp_path / "face.png"
    assert builtin_face.main(["--tets", "2000", "--out", str(png), "--width", "400"]) == 0
    assert png.stat().st_size > 10_000


def test_help_examples_break_lines_where_they_are_written():
    """A long example continued with a backslash prints the backslash and the line break (a bare one in
    the source joined the lines into one with a gap: 'mentalis_l=1       --activation ...')."""
    import re

    from wface.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    joined = [
        f"{name}: {line.strip()}"
        for name, parser in sub.choices.items()
        for line in parser.format_help().splitlines()
        if re.search(r"\S {4,}--\w", line)
    ]
    assert not joined
