"""The closing lines of a command: every file it wrote, with what opens each."""

from __future__ import annotations

from pathlib import Path

from wface.tracking.output import describe_outputs

__all__ = ["print_outputs"]


def print_outputs(out_dir: str | Path, paths=None, *, since: float | None = None) -> None:
    """Print ``wrote OUT/:`` and one line per file (``paths``, else the files directly in ``out_dir``
    modified at or after ``since``, a ``time.time()``), then the count of frames/ files if any."""
    out = Path(out_dir)
    if paths is None:
        paths = sorted(
            (p for p in out.iterdir() if p.is_file() and (since is None or p.stat().st_mtime >= since - 1.0)),
            key=lambda p: p.name,
        )
    print(f"wrote {out}/:")
    rows = describe_outputs(paths)
    width = max([24, *(len(r["file"]) + 1 for r in rows)])  # one column for what opens each
    for row in rows:
        print(f"  {row['file']:<{width}} {row['opens_in']}".rstrip())
    n = len(list((out / "frames").glob("frame_*.npz"))) if (out / "frames").is_dir() else 0
    if n:
        print(f"  frames/ ({n} frame files; --resume continues from them)")
        for d in sorted(out.iterdir()):
            if not (d.is_dir() and (d.name == "survey" or d.name.startswith("refine"))):
                continue
            print(f"  {d.name}/ ({sum(1 for _ in d.glob('*.npz'))} frame files of an earlier pass)")
