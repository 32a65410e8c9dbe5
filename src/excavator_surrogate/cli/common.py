"""Arguments shared by several subcommands (not a subcommand: no ``cmd_`` prefix)."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def add_out(
    p: argparse.ArgumentParser, what: str, *, replaced: bool, required: bool = True
) -> None:
    """``--out DIR`` and ``--overwrite`` under the output-folder rule (docs/design.md).

    Args:
        p: the subcommand's parser.
        what: what the folder is, for the help text (``"output dataset folder"``).
        replaced: the command replaces the folder (True) or writes into it (False).
        required: ``--out`` is required.
    """
    how = "replaced when complete" if replaced else "written into"
    p.add_argument(
        "--out",
        type=Path,
        required=required,
        default=None,
        metavar="DIR",
        help=f"{what} (new, empty, or an exsur output; {how})",
    )
    add_overwrite(p, replaced=replaced)


def add_overwrite(p: argparse.ArgumentParser, *, replaced: bool) -> None:
    """``--overwrite``: consent to replace (or write into) a folder exsur did not write."""
    p.add_argument(
        "--overwrite",
        action="store_true",
        help=f"{'replace' if replaced else 'write into'} --out even if it holds files exsur did "
        "not write (docs/design.md)",
    )


def add_log_options(p: argparse.ArgumentParser) -> None:
    """``-q/--quiet`` and ``-v/--verbose``: how much of the ``[exsur] ...`` chatter is shown.

    ``-q`` shows warnings and errors only: no progress lines or bars, and nothing on stdout
    (the command's result is in its ``--out``; ``exsur config show`` and a ``--dry-run`` still
    show theirs); ``-v``
    adds debug lines.
    """
    g = p.add_argument_group("output")
    x = g.add_mutually_exclusive_group()
    x.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="warnings and errors only (no progress, no result on stdout)",
    )
    x.add_argument("-v", "--verbose", action="store_true", help="also debug lines")


def log_level(args: argparse.Namespace) -> int:
    """The ``logging`` level that ``-q`` / ``-v`` ask for (INFO without either)."""
    if getattr(args, "quiet", False):
        return logging.WARNING
    if getattr(args, "verbose", False):
        return logging.DEBUG
    return logging.INFO


def leaf_parsers(p: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """The parsers under ``p`` that run a command (``exsur config show``, not ``exsur config``)."""
    subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return [p]
    return [
        leaf for a in subs for sp in dict.fromkeys(a.choices.values()) for leaf in leaf_parsers(sp)
    ]


def add_cpus_option(p: argparse.ArgumentParser) -> None:
    """``--cpus N``: plan and run as a computer of ``N`` CPUs (:func:`use_cpus` applies it)."""
    p.add_argument(
        "--cpus",
        type=_cpu_count,
        default=None,
        dest="plan_cpus",
        metavar="N",
        help="plan the training for N CPUs and run that many workers (default: the CPUs this "
        "process may use, within a container's CPU quota; EXSUR_CPUS sets it too). The "
        "recipe's plan depends on it: --cpus 2 trains the README's 2-CPU models on a larger "
        "computer",
    )


def _cpu_count(text: str) -> int:
    """argparse ``type`` of ``--cpus``: a whole number >= 1."""
    from ..cpus import parse_cpus
    from ..errors import ConfigError

    n = parse_cpus(text)
    if n is None:
        raise ConfigError(f"--cpus {text}: give a whole number of CPUs >= 1")
    return n


@contextmanager
def use_cpus(args: argparse.Namespace) -> Iterator[None]:
    """Within the block (every command, :func:`~excavator_surrogate.cli.main`): ``--cpus``, if
    the command has it and it was given, as ``EXSUR_CPUS`` for this process and the workers it
    starts (with a warning when it asks for more CPUs than this process may use), and NumPy's
    BLAS threads at the CPU count (:func:`~excavator_surrogate.cpus.blas_threads`); the
    environment is restored after (a command run in-process leaves no trace)."""
    from ..cpus import ENV, blas_threads, environ_set, oversubscribed
    from ..io_utils import LOGGER_NAME

    n = getattr(args, "plan_cpus", None)
    with environ_set(ENV, None if n is None else str(n)):
        warning = oversubscribed() if n is not None else None
        if warning:
            logging.getLogger(LOGGER_NAME).warning(f"--cpus: {warning}")
        with blas_threads():
            yield
