"""``wface bench --suite NAME``: timings as JSON (speed goals live here, never in tests)."""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path

from wface.bench import SUITES
from wface.cli.errors import UsageError
from wface.cli.validate import face_tets, positive_int, refuse_existing
from wface.files import write_text
from wface.tracking.estimator import TrackOptions


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench",
        help="run a benchmark suite and print timings (JSON with --json)",
        description="Benchmarks. Suites: " + ", ".join(SUITES) + ". Numbers are wall-clock seconds on this machine.",
    )
    p.add_argument("--suite", required=True, choices=SUITES, help="which benchmark to run")
    p.add_argument("--tets", type=face_tets, action="append", help="mesh size(s) in tetrahedra (repeatable)")
    p.add_argument("--device", default="auto", help="Warp device: cpu, cuda:0 or auto (default)")
    p.add_argument("--repeat", type=positive_int, default=3, help="repetitions per timing; the median is reported")
    p.add_argument("--frames", type=positive_int, help="frames to track (track suite; default 6)")
    p.add_argument(
        "--prior",
        choices=["auto", "temporal", "off"],
        default="auto",
        help="the tracker's priors (track suite): auto (default, as wface track: a first pass, then --prior-passes "
        "passes under the take-wide usage prior), temporal (one pass)",
    )
    p.add_argument(
        "--prior-passes",
        type=positive_int,
        default=TrackOptions.prior_passes,
        help="with --prior auto (track suite): usage passes after the first, at most "
        f"(default {TrackOptions.prior_passes})",
    )
    p.add_argument(
        "--prior-refit-change",
        type=float,
        default=TrackOptions.prior_refit_change,
        help="with --prior auto (track suite): as wface track, refit the usage prior only when its first pass "
        f"moved the activations by more than this RMS (default {TrackOptions.prior_refit_change:g})",
    )
    p.add_argument("--json", action="store_true", help="print JSON only")
    p.add_argument("--out", help="also write the JSON to this file (.json)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=_run)


def _check_out(path: str | None, overwrite: bool) -> None:
    """--out must be a new .json file that can be written, checked before the benchmark runs (its results
    were lost after the run on a directory, a missing folder was created, and an existing face model was
    replaced by the JSON)."""
    if not path:
        return
    out = Path(path)
    if out.is_dir():
        raise UsageError(f"--out {path}: is a directory: give a file name, e.g. {out / 'bench.json'}")
    if not out.parent.is_dir():
        raise UsageError(f"--out {path}: folder {out.parent} does not exist")
    if out.suffix.lower() != ".json":
        raise UsageError(f"--out {path}: the benchmark writes JSON: give a file name ending in .json")
    refuse_existing(("--out", path), overwrite=overwrite)


def _run(args: argparse.Namespace) -> int:
    _check_out(args.out, args.overwrite)
    module = importlib.import_module(f"wface.bench.{args.suite}")
    result = module.run(args)  # wface.bench.suite_result: {"suite", "machine", "device", "results", "notes"?}
    text = json.dumps(result, indent=2)
    if args.out:
        write_text(args.out, text + "\n")
    if args.json:
        print(text)
    else:
        print(_summary(result))
        print(f"(full JSON written to {args.out})" if args.out else "(--json prints the full JSON)")
    return 0


def _number(value) -> str:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    return f"{value:,}" if isinstance(value, int) else f"{value:.4g}"


def _summary(result: dict) -> str:
    """The suite's results for a reader: one block per result, its numbers and names one level deep
    (nested tables are in the JSON)."""
    lines = [f"wface bench --suite {result.get('suite')} on {result.get('device')}"]
    for k, row in enumerate(result.get("results", [])):
        lines.append(f"result {k + 1}:")
        scalars = {key: v for key, v in row.items() if not isinstance(v, dict | list)}
        width = max([len(key) for key in scalars] or [0])
        lines += [f"  {key:<{width}}  {_number(v)}" for key, v in scalars.items()]
    for key, value in (result.get("notes") or {}).items():
        lines.append(f"note {key}: {value}")
    return "\n".join(lines)
