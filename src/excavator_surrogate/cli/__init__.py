"""The ``exsur`` command line.

Each subcommand lives in its own module ``excavator_surrogate/cli/cmd_<name>.py`` that
defines ``register(subparsers) -> None``; the parser it adds sets ``func`` to a handler
``(args: argparse.Namespace) -> int``.  Modules are discovered automatically, so a new
stage adds a command without touching this file.

User errors (:class:`~excavator_surrogate.errors.ExsurError`) are printed as one line,
``exsur: error: <message>``, with a non-zero exit code.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from .. import __version__
from ..errors import ExsurError


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every discovered subcommand."""
    parser = argparse.ArgumentParser(
        prog="exsur",
        description="Learn and use LSTM surrogates of hydraulic excavators.",
    )
    parser.add_argument("--version", action="version", version=f"exsur {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    pkg = importlib.import_module(__name__)
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda i: i.name):
        if info.name.startswith("cmd_"):
            mod = importlib.import_module(f"{__name__}.{info.name}")
            mod.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``exsur`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ExsurError as e:
        print(f"exsur: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("exsur: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
