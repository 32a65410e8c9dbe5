"""User-facing errors.

Every error a user can cause (bad log, bad checkpoint, bad option) is raised as an
:class:`ExsurError`.  Its message is ONE line that names the file, the column or row,
and what to do.  The CLI prints it as ``exsur: error: <message>`` and exits non-zero;
the Python API lets it propagate.
"""

from __future__ import annotations

import os
from pathlib import Path


class ExsurError(Exception):
    """Base class for every error a user can cause.  ``str(err)`` is one line."""

    exit_code: int = 2

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(str(message).split()))


class DataError(ExsurError):
    """An episode, dataset or log that breaks the data contract."""

    def __init__(
        self,
        path: str | Path | None,
        problem: str,
        *,
        column: str | None = None,
        row: int | None = None,
        fix: str | None = None,
    ) -> None:
        where = [str(path) if path is not None else "<memory>"]
        if column is not None:
            where.append(f"column '{column}'")
        if row is not None:
            where.append(f"row {row}")
        msg = ": ".join([", ".join(where), problem])
        if fix:
            msg += f" ({fix})"
        self.path = path
        self.problem = problem
        self.column = column
        self.row = row
        super().__init__(msg)


class ConfigError(ExsurError):
    """A preset, config file or option that cannot be used."""


class CheckpointError(ExsurError):
    """A checkpoint that is missing, corrupt, or from an incompatible version."""


def need_path(x: object, what: str) -> Path:
    """``x`` as a Path, if it is one (a ``str`` or ``os.PathLike``).

    Raises:
        ConfigError: one line naming the argument ``what`` (``out``, ``dataset``) and the
            type it got instead (``None``, a number, a dict).
    """
    if isinstance(x, str | os.PathLike):
        return Path(x)
    raise ConfigError(f"{what}: a path is needed, got {type(x).__name__}")


def error_summary(e: BaseException, n: int = 120) -> str:
    """``Type: first line of the message`` (the line cut at ``n`` characters), or ``Type``
    alone without a message: another library's exception inside one of exsur's lines."""
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0][:n]}" if text else type(e).__name__
