"""The ``wface`` command line: one sub-command module per job under ``wface.cli``.

Each module in ``COMMAND_MODULES`` exposes ``register(subparsers)`` which adds its sub-command and
sets ``func`` (a callable taking the parsed arguments and returning an exit code). Option values are
checked by the ``type=`` checkers of ``wface.cli.validate``.

``main`` is the one top-level handler: a user error (a missing or unreadable file, a bad value, a
directory that holds another take, a missing optional package) becomes one line on stderr,
``wface CMD: error: ...``, with these exit codes:

    0    success          2    usage error (argparse: unknown option, bad value)
    1    failure          3    a solve did not converge (``wface simulate``) or diverged (NaN,
                              a dynamic step that ran away: ``FloatingPointError``)
    130  interrupted (Ctrl-C)        141  stdout closed early (``wface ... | head``): quiet

``--debug`` (anywhere on the command line) shows the traceback instead; warnings print as
``wface: warning: ...``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from wface import __version__
from wface.cli.errors import UsageError
from wface.warp_runtime import NoCudaDeviceError

__all__ = [
    "EXIT_FAILURE",
    "EXIT_INTERRUPT",
    "EXIT_NOT_CONVERGED",
    "EXIT_PIPE",
    "EXIT_USAGE",
    "build_parser",
    "main",
]

EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_NOT_CONVERGED = 3
EXIT_INTERRUPT = 130
EXIT_PIPE = 141

# optional third-party package (top-level import name) -> the extra that installs it
OPTIONAL_EXTRAS = {
    "ezc3d": "mocap",
    "pxr": "usd",
    "pyvista": "viz",
    "vtk": "viz",
    "vtkmodules": "viz",
    "matplotlib": "viz",
    "imageio": "viz",
    "imageio_ffmpeg": "viz",
    "dask": "dask",
    "distributed": "dask",
    "pypardiso": "direct",
}
RESUMABLE = ("track", "demo")  # commands whose frames survive an interrupt
# what a user did wrong (or the machine refused), as opposed to a bug in wface
USER_ERRORS = (OSError, ValueError, KeyError, ImportError, EOFError, NoCudaDeviceError)

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

Run `wface COMMAND --help` for the options of each command. Exit codes: 0 success, 1 failure,
2 usage error, 3 not converged (simulate) or a solve that broke down (NaN, a diverged time step),
130 interrupted; --debug shows the traceback of an error.
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
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (also after COMMAND)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def _message(exc: BaseException) -> str:
    """One line saying what went wrong."""
    if isinstance(exc, ImportError):
        top = (getattr(exc, "name", None) or "").split(".")[0]
        if top in OPTIONAL_EXTRAS:
            return f"this needs the optional package {top!r}: pip install 'wface[{OPTIONAL_EXTRAS[top]}]'"
    if isinstance(exc, KeyError) and exc.args:
        return str(exc.args[0])
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        hint = {
            FileExistsError: " (a file is in the way where a directory is needed)",
            NotADirectoryError: " (a file is in the way where a directory is needed)",
            PermissionError: " (choose a writable place)",
        }.get(type(exc), "")
        return f"{exc.filename}: {exc.strerror}{hint}"
    text = str(exc).strip() or type(exc).__name__
    return " ".join(text.split()) if "\n" in text else text


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"wface: warning: {message}", file=sys.stderr if file is None else file)


def _quiet_pipe() -> int:
    """stdout was closed by the reader (``| head``): stop quietly, without Python's second error at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return EXIT_PIPE


def main(argv: list[str] | None = None) -> int:
    """Run the ``wface`` command line; returns the exit code (see the module docstring)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    command = next((a for a in argv if not a.startswith("-")), "")
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return EXIT_USAGE
        command = " ".join(filter(None, (args.command, getattr(args, f"{args.command}_command", None))))
        with warnings.catch_warnings():
            if not debug:
                warnings.showwarning = _show_warning
            return int(args.func(args) or 0)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    except KeyboardInterrupt:
        if debug:
            raise
        hint = " (the frames done so far are kept: rerun with --resume to continue)" if command in RESUMABLE else ""
        print(f"\nwface {command}: interrupted{hint}", file=sys.stderr)
        return EXIT_INTERRUPT
    except BrokenPipeError:
        return _quiet_pipe()
    except UsageError as exc:  # options that contradict each other or do nothing: as argparse's errors
        if debug:
            raise
        print(f"wface {command}: error: {_message(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except FloatingPointError as exc:  # a solve that broke down (NaN, a diverged time step): not converged
        if debug:
            raise
        print(f"wface {command}: error: {_message(exc)}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    except USER_ERRORS as exc:
        if debug:
            raise
        print(f"wface {command}: error: {_message(exc)}".replace("wface : ", "wface: "), file=sys.stderr)
        return EXIT_FAILURE
    except Exception as exc:  # noqa: BLE001 - a bug: one line, the traceback with --debug
        if debug:
            raise
        print(
            f"wface {command}: internal error: {type(exc).__name__}: {_message(exc)} "
            "(rerun with --debug for the traceback, and please report it)",
            file=sys.stderr,
        )
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
