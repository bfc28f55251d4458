"""``wface bench --suite forward`` on a tiny built-in face: valid JSON on stdout with every timing."""

from __future__ import annotations

import json

from wface.cli import main


def test_forward_bench_prints_json_with_all_timings(capsys):
    rc = main(["bench", "--suite", "forward", "--tets", "2000", "--repeat", "1", "--device", "cpu", "--json"])
    assert rc == 0
    result = json.loads(capsys.readouterr().out)  # nothing else on stdout
    (size,) = result["results"]
    for key in (
        "forces_seconds",
        "tangent_seconds",
        "kv_seconds",
        "csr_matvec_seconds",
        "kv_over_csr_matvec",
        "cg_seconds",
        "quasistatic_seconds",
    ):
        assert size[key] > 0, key
    assert size["quasistatic_converged"] and size["cg_converged"] and size["inverted_elements"] == 0
    assert size["tets"] > 1000 and result["device"] == "cpu"
