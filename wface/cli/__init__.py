"""The ``wface`` command line: one sub-command module per job under ``wface.cli``.

Each module in ``COMMAND_MODULES`` exposes ``register(subparsers)`` which adds its sub-command and
sets ``func`` (a callable taking the parsed arguments and returning an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from wface import __version__

__all__ = ["main", "build_parser"]

COMMAND_MODULES = [
    "wface.cli.track",
    "wface.cli.model",
    "wface.cli.bench",
    "wface.cli.simulate",
    "wface.cli.basis",
    "wface.cli.waters",
    "wface.cli.speech",
    "wface.cli.edit",
    "wface.cli.resim",
]

_EPILOG = """\
examples:
  wface demo --out demo_out                 track a synthetic performance on the built-in face
  wface model build --tets 20000 --out face.npz
  wface model info face.npz --json
  wface bench --suite forward --tets 20000 --json
  wface waters --mesh head.obj --expression happy --au AU26=0.3 --out waters_out
  wface speech --model badin.npz --gesture closure --out closure_out
  wface simulate --model face.npz --activation orbicularis_oris_upper=1 --contact lips,teeth --out lips_out
  wface edit blend --from smile --to surprise --frames 24 --out blend_out
  wface resim --take run1 --out run1_dyn    replay a tracked take with inertia (implicit dynamic FEM)

Run `wface COMMAND --help` for the options of each command.
"""


def build_parser() -> argparse.ArgumentParser:

    parser = argparse.ArgumentParser(
        prog="wface",
        description="Anatomically based, muscle-driven facial animation: FEM faces, muscle activations from "
        "motion capture, actuation bases, vector muscles, USD export.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"wface {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (FileNotFoundError, ValueError, KeyError) as exc:
        # User errors: say what is wrong in one line, no traceback.
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"wface {args.command}: error: {msg}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
