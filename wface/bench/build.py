"""``wface bench --suite build``: building the built-in face and importing the ArtiSynth face.

Per ``--tets`` size (default 5,000 and 20,000): seconds to build the built-in face, its size and
tet quality. When the ArtiSynth "Badin" data is present (../shared/data/artisynth-face or
$WFACE_DATA), also the import: seconds in total and for the sliver removal, tets, added nodes and
the smallest / largest dihedral angle after the hex split and after the sliver removal.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from wface.bench import suite_result
from wface.faces.artisynth import import_artisynth
from wface.faces.builtin import build_face
from wface.mesh.quality import quality_report

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:  # pragma: no cover - registry hook
    pass


def _artisynth_dir() -> Path:
    root = Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
    return root / "artisynth-face"


def run(args: argparse.Namespace) -> dict:

    sizes = args.tets or [5_000, 20_000]
    builtin = []
    for target in sizes:
        start = time.perf_counter()
        model = build_face(target)
        seconds = time.perf_counter() - start
        q = quality_report(model.rest_positions_m, model.tets)
        builtin.append(
            {
                "face": "builtin",
                "target_tets": target,
                "tets": model.n_tets,
                "nodes": model.n_nodes,
                "seconds": seconds,
                "min_dihedral_deg": q.min_dihedral_deg,
                "max_dihedral_deg": q.max_dihedral_deg,
            }
        )
    data = _artisynth_dir()
    if not (data / "badinface_oop_csa_midsagittal.node").exists():
        return suite_result("build", "cpu", builtin, {"artisynth": f"skipped: no ArtiSynth face data at {data}"})

    start = time.perf_counter()
    timings: dict = {}
    model = import_artisynth(data, progress=False, timings=timings)
    seconds = time.perf_counter() - start
    info = model.metadata["sliver_removal"]
    split = info["tet_quality_after_split"]
    artisynth = {
        "face": "artisynth",
        "seconds": seconds,
        "tets": model.n_tets,
        "nodes": model.n_nodes,
        "added_nodes": model.metadata["added_nodes"]["count"],
        "after_split": {k: split[k] for k in ("min_dihedral_deg", "max_dihedral_deg", "slivers_below_5deg")},
        "after_sliver_removal": {
            k: model.metadata["tet_quality"][k] for k in ("min_dihedral_deg", "max_dihedral_deg", "slivers_below_5deg")
        },
        "sliver_removal_seconds": timings["sliver_removal"],
        "sliver_removal_operations": info["operations"],
    }
    return suite_result("build", "cpu", [*builtin, artisynth])  # numpy / scipy only
