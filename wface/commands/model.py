"""``wface model build`` / ``wface model info``: the built-in face and model summaries."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("model", help="build, inspect or import face models")
    p.set_defaults(func=lambda a: p.print_help() or 2)
