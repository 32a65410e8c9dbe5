"""The ``exsur`` command line.

Each subcommand lives in its own module ``excavator_surrogate/cli/cmd_<name>.py`` that
defines ``register(subparsers) -> None``; the parser it adds sets ``func`` to a handler
``(args: argparse.Namespace) -> int``.  Modules are discovered automatically, so a new
stage adds a command without touching this file.

User errors (:class:`~excavator_surrogate.errors.ExsurError`) are printed as one line,
``exsur: error: <message>``, with a non-zero exit code.

Every subcommand takes ``-q`` (warnings and errors only) and ``-v`` (debug lines); the
library's ``logging`` lines are shown on stderr as ``[exsur] ...`` while a command runs.
"""

from __future__ import annotations

import argparse
import codecs
import contextlib
import errno
import importlib
import io
import logging
import math
import os
import pkgutil
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from .. import __version__, numerics
from ..errors import ConfigError, ExsurError
from ..io_utils import LOGGER_NAME, remove_logging, setup_logging
from .common import add_log_options, leaf_parsers, log_level, use_cpus

_OS_ERRORS = (
    errno.EACCES,
    errno.EPERM,
    errno.EROFS,
    errno.ENOSPC,
    errno.EDQUOT,
    errno.ENOTDIR,
    errno.EISDIR,
    errno.ENAMETOOLONG,
    errno.EEXIST,
    errno.ENOTEMPTY,
    errno.EBUSY,
    errno.EXDEV,
    errno.ENOENT,
    errno.EINVAL,
)
"""OS errors a user causes with a path (permissions, full disk ...): one line, exit 2."""


def _checked(
    option: str, convert: type, ok: Callable[[Any], bool], need: str
) -> Callable[[str], Any]:
    """argparse ``type``: ``convert(text)``, then a one-line ``ConfigError`` unless ``ok``."""

    def parse(text: str) -> Any:
        try:
            x = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid {convert.__name__}: {text!r}") from None
        if not ok(x):
            raise ConfigError(f"{option} {text}: {need}")
        return x

    return parse


def _check_numbers(parser: argparse.ArgumentParser) -> None:
    """Every ``type=float`` option of ``parser`` and its subcommands rejects NaN and inf, and
    every ``--seed`` negative numbers (numpy seeds cannot be negative)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _check_numbers(sub)
        elif action.type is float:
            name = action.option_strings[0] if action.option_strings else action.dest
            action.type = _checked(name, float, math.isfinite, "give a finite number")
        elif action.type is int and action.dest == "seed":
            action.type = _checked(
                action.option_strings[0], int, lambda x: x >= 0, "a seed must be >= 0"
            )


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
    for leaf in leaf_parsers(parser):
        if leaf is not parser:
            add_log_options(leaf)
    _check_numbers(parser)
    return parser


@contextlib.contextmanager
def _logging(level: int) -> Iterator[None]:
    """Show the package's log lines at ``level`` up on stderr while a command runs."""
    pkg = logging.getLogger(LOGGER_NAME)
    before = pkg.level
    setup_logging(level)
    logging.getLogger(__name__).debug(
        "exsur %s, python %s, argv %s", __version__, sys.version.split()[0], sys.argv[1:]
    )
    try:
        yield
    finally:  # main() may run several times in one process (tests, scripts)
        remove_logging()
        pkg.setLevel(before)


@contextlib.contextmanager
def _muted_stdout(mute: bool) -> Iterator[None]:
    """Drop what the command prints on stdout while ``mute`` (``-q``)."""
    if not mute:
        yield
        return
    with open(os.devnull, "w", encoding="utf-8") as null, contextlib.redirect_stdout(null):
        yield


def _escaped_stdout() -> None:
    """Where the locale cannot encode what exsur prints (θ, ω, R² of a table: ASCII or Latin-1
    without Python's UTF-8 mode), print it escaped (``\\u03b8``) instead of failing after the
    work is done; the files themselves are UTF-8 whatever the locale."""
    out = sys.stdout
    if isinstance(out, io.TextIOWrapper) and codecs.lookup(out.encoding).name != "utf-8":
        out.reconfigure(errors="backslashreplace")


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, ``docker stop``, a batch scheduler), raised in the main
    thread so that every cleanup a Ctrl-C runs runs too (temporary files, locks)."""


def _terminate(signum: int, frame: Any) -> None:
    raise Terminated


@contextlib.contextmanager
def _sigterm_cleans_up() -> Iterator[None]:
    """While a command runs, SIGTERM raises :class:`Terminated` (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:  # main() may run several times in one process (tests, scripts)
        signal.signal(signal.SIGTERM, before)


def _not_utf8(text: str) -> str | None:
    """``text`` with its bytes that are not UTF-8 shown as ``\\xff`` (None: it is UTF-8).

    Python keeps such bytes of a file name as lone surrogates, which no library that writes
    UTF-8 (pyarrow, TensorBoard) can encode."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        try:
            return os.fsencode(text).decode("utf-8", "backslashreplace")
        except UnicodeEncodeError:  # not a file name's byte: show the code point
            return text.encode("utf-8", "backslashreplace").decode()
    return None


def _utf8_error(name: str) -> str:
    return f"{name}: the name is not valid UTF-8 (e.g. a Latin-1 file name); rename it"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``exsur`` console script; returns the exit code."""
    _escaped_stdout()
    parser = build_parser()
    try:
        for arg in sys.argv[1:] if argv is None else argv:
            if (shown := _not_utf8(str(arg))) is not None:
                raise ConfigError(_utf8_error(shown))
        args = parser.parse_args(argv)
        numerics.apply()  # EXSUR_NUMERICS=portable: no oneDNN in this process either
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        # -q: nothing but warnings and errors; only a command whose purpose is to show
        # something (``exsur config show``, a ``--dry-run``) still prints it
        shows = getattr(args, "shows", False) or getattr(args, "dry_run", False)
        mute = getattr(args, "quiet", False) and not shows
        with _sigterm_cleans_up(), _logging(log_level(args)), _muted_stdout(mute), use_cpus(args):
            return int(args.func(args) or 0)
    except ExsurError as e:
        print(f"exsur: error: {e}", file=sys.stderr)
        return e.exit_code
    except OSError as e:
        if e.errno not in _OS_ERRORS:
            raise
        where = f"{e.filename}: " if e.filename else ""
        full = e.errno in (errno.ENOSPC, errno.EDQUOT)
        fix = "free disk space and rerun" if full else "check the path and its permissions"
        print(f"exsur: error: {where}{e.strerror or e} ({fix})", file=sys.stderr)
        return 2
    except UnicodeEncodeError as e:  # a name in a folder the command lists (import LOGS)
        shown = _not_utf8(e.object) if isinstance(e.object, str) else None
        if shown is None:
            raise
        print(f"exsur: error: {_utf8_error(shown)}", file=sys.stderr)
        return 2
    except Terminated:
        print("exsur: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print("exsur: interrupted", file=sys.stderr)
        return 130
    finally:
        from ..outlock import release_locks

        release_locks()  # the command's --out writer lock (outlock.lock_out)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
