"""The four-fold real-data example runs headless with tiny options."""

from __future__ import annotations

import json

from tests.conftest import data_path


def test_example_four_folds_tiny(tmp_path):
    import importlib.util
    from pathlib import Path

    data = data_path("animface", "JawMoCap.c3d").parents[1]
    data_path("ict-facekit", "ict_expressions.npz")
    path = Path(__file__).resolve().parents[1] / "examples" / "basis_ict_animface.py"
    spec = importlib.util.spec_from_file_location("basis_ict_animface", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    summary = mod.main(["--data", str(data), "--out", str(tmp_path), "--frame-step", "60", "--max-iterations", "1",
                        "--no-select", "--regularization", "1", "--no-plot"])  # fmt: skip
    assert len(summary["folds"]) == 4
    on_disk = json.loads((tmp_path / "folds.json").read_text())
    assert on_disk["folds"][0]["test"] == "JawMoCap.c3d"
    for fold in summary["folds"]:
        errs = fold["train_rms_mm_per_iteration"]
        assert errs[-1] < errs[0]  # refinement lowers the training error even in one step
        assert 0 < fold["test_rms_mm_before"] < 10
