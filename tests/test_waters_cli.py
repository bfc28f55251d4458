"""``wface waters``, the bench suite and the example, run headless with tiny options."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT, data_path

from wface.cli import main
from wface.mesh.meshfile import read_surface_mesh, write_obj
from wface.testing.synthetic_head import synthetic_head


def _env() -> dict:
    env = dict(os.environ, PYVISTA_OFF_SCREEN="true")
    env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def test_cli_poses_the_ict_head(tmp_path, capsys):
    mesh = data_path("ict-facekit", "generic_neutral_mesh.obj")
    rc = main(
        [
            "waters",
            "--mesh",
            str(mesh),
            "--expression",
            "happy",
            "--au",
            "AU26=0.5",
            "--size",
            "160",
            "--out",
            str(tmp_path),
        ]
    )
    assert rc == 0
    summary = json.loads((tmp_path / "happy+AU26.json").read_text())
    assert summary["jaw_opening_deg"] == pytest.approx(6.0)
    assert summary["contractions"]["zygomaticus_major_l"] == 1.0
    posed = read_surface_mesh(tmp_path / "happy+AU26.obj", units="m")
    assert posed.n_vertices == 26719 and 3.0 < summary["max_displacement_mm"] < 60.0
    # the smile's muscles reach the layout's 15 mm cap: the summary and the log line say so
    assert summary["displacement_cap_mm"] == 15.0 and summary["vertices_at_cap"] > 0
    assert f"{summary['vertices_at_cap']} vertices at it" in capsys.readouterr().out
    for key in ("png", "png_displacement", "usd"):
        assert Path(summary["files"][key]).stat().st_size > 1000
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(summary["files"]["usd"])
    pts = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/WatersFace/Mesh")).GetPointsAttr().Get())
    np.testing.assert_allclose(pts, posed.vertices_m, atol=1e-6)


def test_cli_fits_the_layout_to_another_mesh_by_landmarks(tmp_path):
    from wface.testing.synthetic_head import synthetic_landmarks
    from wface.waters.layout import load_layout

    head = synthetic_head(40, 80)
    write_obj(tmp_path / "head.obj", head)
    marks = synthetic_landmarks(load_layout("ict"))
    ids = {k: int(np.argmin(np.linalg.norm(head.vertices_m - p, axis=1))) for k, p in marks.items()}
    (tmp_path / "marks.json").write_text(json.dumps(ids))
    rc = main(
        [
            "waters",
            "--mesh",
            str(tmp_path / "head.obj"),
            "--units",
            "m",
            "--landmarks",
            str(tmp_path / "marks.json"),
            "--expression",
            "surprise",
            "--no-render",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert rc == 0
    assert json.loads((tmp_path / "o" / "surprise.json").read_text())["max_displacement_mm"] > 1.0


def test_cli_reports_bad_input_in_one_line(tmp_path, capsys):
    head = synthetic_head(10, 20)
    write_obj(tmp_path / "head.obj", head)
    assert main(["waters", "--mesh", str(tmp_path / "head.obj"), "--expression", "bored", "--out", str(tmp_path)]) == 1
    assert main(["waters", "--mesh", str(tmp_path / "nope.obj"), "--out", str(tmp_path)]) == 1
    assert (
        main(["waters", "--mesh", str(tmp_path / "head.obj"), "--out", str(tmp_path)]) == 1
    )  # not ICT: needs a layout
    err = capsys.readouterr().err
    assert "unknown expression 'bored'" in err and "mesh file not found" in err and "--landmarks" in err


def test_bench_suite_runs_and_says_what_it_timed(monkeypatch):
    from wface.bench import waters

    monkeypatch.setenv("WFACE_DATA", "/nonexistent")  # force the synthetic fallback: fast and data-free
    result = waters.run(Namespace(repeat=1))
    (out,) = result["results"]
    assert out["frames_per_second"] > 0 and out["muscles"] >= 20
    assert "synthetic" in out["mesh"] and "absent" in result["notes"]["mesh"]


def test_example_runs_headless(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            str(REPO_ROOT / "examples" / "waters_expressions.py"),
            "--presets",
            "happy",
            "--size",
            "200",
            "--blend-frames",
            "2",
            "--out",
            str(tmp_path),
        ],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "happy.png").stat().st_size > 1000
    assert (tmp_path / "expressions.usdc").is_file()
    report = json.loads((tmp_path / "expressions.json").read_text())
    assert report["presets"]["happy"]["max_displacement_mm"] > 1.0


def test_cli_poses_the_builtin_face(tmp_path):
    rc = main(
        ["waters", "--mesh", "builtin", "--tets", "3000", "--expression", "sad", "--no-render", "--out", str(tmp_path)]
    )
    assert rc == 0
    summary = json.loads((tmp_path / "sad.json").read_text())
    assert summary["layout"].startswith("ict-facekit-on") and summary["max_displacement_mm"] > 1.0


def test_cli_blends_between_presets(tmp_path):
    rc = main(
        [
            "waters",
            "--mesh",
            "builtin",
            "--tets",
            "3000",
            "--expression",
            "neutral",
            "--blend-to",
            "surprise",
            "--frames",
            "4",
            "--no-render",
            "--out",
            str(tmp_path),
        ]
    )
    assert rc == 0
    from pxr import Usd, UsdGeom

    summary = json.loads((tmp_path / "neutral.json").read_text())
    assert summary["files"]["animation"].endswith("neutral_to_surprise.usda")  # the summary names it; text USD
    stage = Usd.Stage.Open(str(tmp_path / "neutral_to_surprise.usda"))  # as the pose's own (--usdc: binary)
    attr = UsdGeom.Mesh(stage.GetPrimAtPath("/WatersFace/Mesh")).GetPointsAttr()
    first, last = np.asarray(attr.Get(0)), np.asarray(attr.Get(3))
    assert np.max(np.linalg.norm(last - first, axis=1)) > 0.005  # the jaw opens by 12 degrees
    assert main(["waters", "--mesh", "builtin", "--blend-to", "nope", "--out", str(tmp_path)]) == 1


def test_bench_json_on_stdout_is_clean(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "wface", "bench", "--suite", "waters", "--json", "--repeat", "1", "--device", "cpu"],
        env=dict(_env(), WFACE_DATA=str(tmp_path)),
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO_ROOT,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout)
    assert out["suite"] == "waters" and out["results"][0]["warp_direct_frames_per_second"] > 0


def test_cli_with_a_layout_file(tmp_path):
    from wface.testing.synthetic_head import synthetic_landmarks
    from wface.waters.fit import fit_layout
    from wface.waters.layout import load_layout, save_layout

    head = synthetic_head(30, 60)
    write_obj(tmp_path / "head.obj", head)
    base = load_layout("ict")
    lay = fit_layout(
        base, synthetic_landmarks(base), target_vertices_m=head.vertices_m, target_triangles=head.triangles()
    )
    save_layout(lay, tmp_path / "layout.json", units="mm")
    rc = main(
        [
            "waters",
            "--mesh",
            str(tmp_path / "head.obj"),
            "--units",
            "m",
            "--layout",
            str(tmp_path / "layout.json"),
            "--expression",
            "happy",
            "--no-render",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert rc == 0
    summary = json.loads((tmp_path / "o" / "happy.json").read_text())
    assert summary["muscles"] == len(lay.muscles) and summary["max_displacement_mm"] > 1.0


def test_options_that_would_do_nothing_are_refused(tmp_path, capsys):
    """--landmarks or --units with the built-in face, --tets with a mesh file and --frames without --blend-to were
    silently ignored."""
    for args, flag in [
        (["--mesh", "builtin", "--landmarks", "lm.json"], "--landmarks"),
        (["--mesh", "builtin", "--units", "cm"], "--units"),
        (["--mesh", "head.obj", "--tets", "3000"], "--tets"),
        (["--mesh", "builtin", "--frames", "5"], "--frames"),
    ]:
        assert main(["waters", *args, "--out", str(tmp_path)]) == 2  # a usage error
        assert f"{flag} does nothing here" in capsys.readouterr().err


def _small_head(tmp_path) -> list[str]:
    """A synthetic head with landmarks for the ICT layout: the mesh options of a fast waters run."""
    from wface.testing.synthetic_head import synthetic_landmarks
    from wface.waters.layout import load_layout

    head = synthetic_head(20, 40)
    write_obj(tmp_path / "head.obj", head)
    marks = synthetic_landmarks(load_layout("ict"))
    ids = {k: int(np.argmin(np.linalg.norm(head.vertices_m - p, axis=1))) for k, p in marks.items()}
    (tmp_path / "marks.json").write_text(json.dumps(ids))
    return ["--mesh", str(tmp_path / "head.obj"), "--units", "m", "--landmarks", str(tmp_path / "marks.json")]


def test_an_input_is_never_written_over(tmp_path, capsys):
    """`wface waters --mesh wself/happy.obj --expression happy --out wself` replaced the input mesh with the
    posed one; now it is refused before any work, even with --overwrite."""
    mesh = _small_head(tmp_path)
    (tmp_path / "wself").mkdir()
    (tmp_path / "head.obj").rename(tmp_path / "wself" / "happy.obj")
    before = (tmp_path / "wself" / "happy.obj").read_bytes()
    mesh[1] = str(tmp_path / "wself" / "happy.obj")
    args = ["waters", *mesh, "--expression", "happy", "--no-render", "--out", str(tmp_path / "wself")]
    for extra in ([], ["--overwrite"]):
        assert main([*args, *extra]) == 2
        err = capsys.readouterr().err
        assert "--mesh" in err and "happy.obj" in err and "even with --overwrite" in err, err
    assert (tmp_path / "wself" / "happy.obj").read_bytes() == before
    assert sorted(p.name for p in (tmp_path / "wself").iterdir()) == ["happy.obj"]  # nothing claimed


def test_waters_claims_its_directory(tmp_path, capsys):
    """Two runs into one --out (the second at --intensity 0.2) silently replaced happy.obj/.json/.usda; now
    the second is refused unless --overwrite, and the very same command again reruns."""
    args = ["waters", *_small_head(tmp_path), "--expression", "happy", "--no-render", "--out", str(tmp_path / "w")]
    assert main(args) == 0
    assert "provenance.json" in capsys.readouterr().out
    first = {n: (tmp_path / "w" / n).read_bytes() for n in ("happy.obj", "happy.json", "happy.usda")}
    assert main([*args, "--intensity", "0.2"]) == 1
    err = capsys.readouterr().err
    assert "holds another take's results" in err and "--overwrite" in err, err
    assert {n: (tmp_path / "w" / n).read_bytes() for n in first} == first
    assert main(args) == 0  # the very same command again
    assert main([*args, "--intensity", "0.2", "--overwrite"]) == 0
    zyg = json.loads((tmp_path / "w" / "happy.json").read_text())["contractions"]["zygomaticus_major_l"]
    assert zyg == pytest.approx(0.2 * json.loads(first["happy.json"])["contractions"]["zygomaticus_major_l"])


def test_waters_does_not_write_into_a_take(tmp_path, capsys):
    """`waters --out TRACK_OUT` mixed its files into the take and listed the track's frames/ as its own;
    a directory of another run's results, or an older waters run's files without provenance, is refused."""
    mesh = _small_head(tmp_path)
    take = tmp_path / "take"
    (take / "frames").mkdir(parents=True)
    (take / "frames" / "frame_000000.npz").write_bytes(b"x")
    (take / "report.json").write_text('{"frames": 1}')
    (take / "provenance.json").write_text(json.dumps({"kind": "track", "fingerprint": "0" * 16}))
    old = tmp_path / "old"
    old.mkdir()
    (old / "happy.obj").write_text("v 0 0 0\n")
    for out in (take, old):
        assert main(["waters", *mesh, "--expression", "happy", "--no-render", "--out", str(out)]) == 1
        err = capsys.readouterr().err
        assert "--overwrite" in err, err
    assert not (take / "happy.obj").exists() and (old / "happy.obj").read_text() == "v 0 0 0\n"
