"""usd_scenes/ is current: regenerating every scene gives the committed content (within float32 round-off)."""

from __future__ import annotations

import importlib.util
import shutil

import numpy as np
import pytest

pytest.importorskip("pxr")

from conftest import REPO_ROOT  # noqa: E402

from wface.io.usd import compare_stages  # noqa: E402

_SCRIPT = REPO_ROOT / "examples" / "make_usd_scenes.py"
_FIX = "usd_scenes/ is out of date: run `python examples/make_usd_scenes.py` and commit usd_scenes/"


def _script():
    spec = importlib.util.spec_from_file_location("make_usd_scenes", _SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_committed_scenes_are_current():
    problems = _script().check_scenes(REPO_ROOT / "usd_scenes")
    assert not problems, _FIX + "\n" + "\n".join(problems)


def test_committed_scenes_are_small_text():
    scenes = sorted((REPO_ROOT / "usd_scenes").glob("*.usda"))
    assert {p.stem for p in scenes} >= {"synthetic_take", "synthetic_basis"}
    if importlib.util.find_spec("wface.basis") is not None:
        assert "synthetic_tracked_take" in {p.stem for p in scenes}
    for p in scenes:
        assert p.stat().st_size < 1_000_000, f"{p.name} is over 1 MB"
        assert p.read_text().startswith("#usda 1.0")


def test_compare_stages_reports_a_changed_value(tmp_path):
    from pxr import Usd, UsdGeom, Vt

    src = REPO_ROOT / "usd_scenes" / "synthetic_take.usda"
    copy = tmp_path / "copy.usda"
    shutil.copy(src, copy)
    assert compare_stages(src, copy) == []
    stage = Usd.Stage.Open(str(copy))
    pts = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr()
    p = np.array(pts.Get(5))
    p[3, 1] += 1e-4  # 0.1 mm
    pts.Set(Vt.Vec3fArray.FromNumpy(p.astype(np.float32)), 5)
    stage.GetPrimAtPath("/Face/Muscles").GetAttribute("wface:activation:frontalis").Set(0.5, 7)
    stage.Save()
    diffs = compare_stages(src, copy)
    assert any("/Face/Skin.points at time 5" in d for d in diffs), diffs
    assert any("wface:activation:frontalis" in d for d in diffs), diffs


def test_script_runs_headless_with_only(tmp_path):
    mod = _script()
    assert mod.main(["--out", str(tmp_path), "--only", "synthetic_basis"]) == 0
    assert (tmp_path / "synthetic_basis.usda").exists()
    assert mod.main(["--out", str(tmp_path), "--only", "synthetic_basis", "--check"]) == 0


def test_compare_stages_tolerates_round_off_in_layer_metadata(tmp_path):
    from pxr import Sdf

    src = REPO_ROOT / "usd_scenes" / "synthetic_take.usda"
    a, b = tmp_path / "a.usda", tmp_path / "b.usda"
    for path, value in ((a, 0.81930001), (b, 0.8193)):
        shutil.copy(src, path)
        layer = Sdf.Layer.FindOrOpen(str(path))
        data = dict(layer.customLayerData)
        data["wface"] = {**data["wface"], "marker_rms_mm_mean": value}
        layer.customLayerData = data
        layer.Save()
    assert compare_stages(a, b) == []
    layer = Sdf.Layer.FindOrOpen(str(b))
    layer.customLayerData = {**dict(layer.customLayerData), "wface": {"kind": "other"}}
    layer.Save()
    assert any("customLayerData" in d for d in compare_stages(a, b))


def test_sparse_blend_shapes_compare_as_dense_offsets(tmp_path):
    """A point listed with a zero offset in one stage and left out in the other is no difference (the
    writer's sparsity threshold decides the listing); a changed offset is."""
    from pxr import Usd, UsdSkel, Vt

    def write(path, indices, offsets):
        stage = Usd.Stage.CreateNew(str(path))
        shape = UsdSkel.BlendShape.Define(stage, "/Shape")
        shape.CreatePointIndicesAttr(Vt.IntArray(indices))
        shape.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(offsets, dtype=np.float32)))
        stage.Save()
        return path

    a = write(tmp_path / "a.usda", [0, 2], [[1e-3, 0, 0], [0, 2e-3, 0]])
    b = write(tmp_path / "b.usda", [0, 1, 2], [[1e-3, 0, 0], [0, 0, 1e-9], [0, 2e-3, 0]])
    c = write(tmp_path / "c.usda", [0, 2], [[1e-3, 0, 0], [0, 2.5e-3, 0]])
    assert compare_stages(a, b, atol=1e-7) == []
    diffs = compare_stages(a, c, atol=1e-7)
    assert len(diffs) == 1 and "/Shape.offsets" in diffs[0] and "dense" in diffs[0], diffs
