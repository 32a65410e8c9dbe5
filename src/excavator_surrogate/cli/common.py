"""Arguments shared by several subcommands (not a subcommand: no ``cmd_`` prefix)."""

from __future__ import annotations

import argparse
import logging
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
