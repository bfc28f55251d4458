"""Every ``wface bench`` suite prints one JSON shape: {"suite", "machine", "device", "results": [...]}.

Each suite runs through the command line at its smallest setting (the built-in face's minimum of
1,000 tets, one repetition, no real data so the data-free fallbacks run); the suites' own tests
check what they measure.
"""

from __future__ import annotations

import functools
import json

import pytest

from wface.bench import SUITES
from wface.cli import main

TINY = {
    "forward": ["--tets", "1000"],
    "jacobian": ["--tets", "1000"],
    "track": ["--tets", "1000"],
    "basis": [],
    "waters": [],
    "build": ["--tets", "1000"],
    "dynamic": ["--tets", "1000"],
}
# a size key every entry of the suite carries
SIZE_KEY = {
    "forward": "tets",
    "jacobian": "tets",
    "track": "tets",
    "basis": "frames",
    "waters": "vertices",
    "build": "tets",
    "dynamic": "tets",
}


def test_every_suite_is_covered():
    assert set(TINY) == set(SUITES) == set(SIZE_KEY)


@pytest.mark.parametrize("suite", SUITES)
def test_suite_prints_the_common_shape(suite, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("WFACE_DATA", str(tmp_path))  # no real data: synthetic meshes and takes
    if suite == "basis":  # the synthetic performance has the real take's 1590 frames; 200 keep it short
        from wface.bench import basis

        monkeypatch.setattr(basis, "_synthetic", functools.partial(basis._synthetic, frames=200))
    args = ["bench", "--suite", suite, *TINY[suite], "--repeat", "1", "--device", "cpu", "--json"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)  # nothing else on stdout
    assert set(out) - {"notes"} == {"suite", "machine", "device", "results"}
    assert out["suite"] == suite and out["device"] == "cpu"
    assert out["machine"]["cpu_count"] >= 1 and out["machine"]["python"]
    assert isinstance(out["results"], list) and out["results"]
    for entry in out["results"]:
        assert isinstance(entry, dict) and entry[SIZE_KEY[suite]] > 0
    notes = out.get("notes", {})
    assert isinstance(notes, dict) and all(isinstance(v, str) for v in notes.values())
