"""Arguments shared by several subcommands (not a subcommand: no ``cmd_`` prefix)."""

from __future__ import annotations

import argparse
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
