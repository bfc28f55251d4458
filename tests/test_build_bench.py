"""`wface bench --suite build` runs and reports sizes, seconds and quality as JSON."""

from __future__ import annotations

import json

from wface.cli import main


def test_build_suite(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("WFACE_DATA", str(tmp_path))  # no ArtiSynth data here: that part says so
    assert main(["bench", "--suite", "build", "--tets", "1000", "--repeat", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    (row,) = [r for r in out["results"] if r["face"] == "builtin"]
    assert row["target_tets"] == 1000 and 500 < row["tets"] < 2000 and row["seconds"] > 0
    assert 3.0 < row["min_dihedral_deg"] < row["max_dihedral_deg"] < 180.0  # 3.9 deg at 1K (README)
    assert out["notes"]["artisynth"].startswith("skipped: no ArtiSynth face data")
