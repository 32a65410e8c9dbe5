"""The output-folder rule: what exsur may replace or write into, and when.

Every command that writes ``--out`` checks it first with :func:`check_out_dir` (folders) or
:func:`check_out_file` (single files), before it reads or computes anything expensive:

- a folder that does not exist, or is empty, is always fine;
- an existing folder is replaced (``simulate``, ``clean``, ``run``, ``import``) or written into
  (``train``, ``evaluate``, ``compare``, ``sweep``) only when exsur wrote it: it holds one of
  the files that mark an exsur output (``manifest.json``, ``metrics.json``, ``best.pt`` ...)
  and nothing but names exsur writes (:func:`is_exsur_output`); anything else needs an explicit
  ``--overwrite``;
- an input of the command (a log, the mapping, a dataset) never lies inside the output folder,
  not even with ``--overwrite``;
- the current folder, or one of its parents, is never an output folder;
- a file output (``export``, ``merge``) is never an existing folder nor one of the inputs.

:func:`~excavator_surrogate.io_utils.atomic_dir` applies the same rule when it replaces a
folder, so the Python API is protected too; ``--overwrite`` reaches it through
:func:`replace_allowed`.
"""

from __future__ import annotations

import contextlib
import contextvars
import fnmatch
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

from .errors import ConfigError

SIGNATURES = ("manifest.json", "metrics.json", "best.pt", "last.pt", "sweep.json", "report.md")
"""Files that mark a folder as an exsur output (a dataset, a model, an evaluation, a run)."""

FILES = (
    *SIGNATURES,
    "config.toml",
    "import_report.json",
    "import_report.md",
    "table.md",
    "cbe.png",
    "cbe_*.png",
    "fusion_*.png",
    "compare.png",
    "trajectories.npz",
    "log.csv",
    "sweep.md",
    "sweep.png",
    "study.db",
    "study.db-*",
    "*.pt",
    "*.onnx",
)
"""Names exsur writes at any level of its output folders (shell patterns)."""

DIRS = {"episodes": ("*.parquet", "*.png"), "figures": ("*.png",), "tb": ("events.out.tfevents.*",)}
"""Sub-folders with a fixed content pattern (`exsur plot` puts PNGs next to episodes); other
sub-folders must follow the rule themselves."""

TEMP = (".*.tmp", ".*.old-*", ".*.tmp.npz")
"""Temporary names of exsur's atomic writes (left behind only by a killed process)."""

_ALLOWED: contextvars.ContextVar[frozenset[Path]] = contextvars.ContextVar(
    "exsur_replace_allowed", default=frozenset()
)


def _match(name: str, patterns: Iterable[str]) -> bool:
    return any(fnmatch.fnmatchcase(name, p) for p in patterns)


def foreign_entry(path: Path, *, top: bool = True) -> str | None:
    """The first entry of folder ``path`` that exsur would not have written (None: all are exsur's).

    At the top level one of :data:`SIGNATURES` must be present (an empty folder passes).
    """
    try:
        entries = sorted(path.iterdir())
    except OSError as e:
        return f"{path.name} ({e.strerror})"
    if not entries:
        return None
    for e in entries:
        name = e.name
        if _match(name, TEMP):
            continue
        if e.is_symlink():
            return name
        if e.is_dir():
            if name in DIRS:
                bad = next((c.name for c in e.iterdir() if not _match(c.name, DIRS[name])), None)
                if bad is not None:
                    return f"{name}/{bad}"
                continue
            sub = foreign_entry(e, top=False)
            if sub is not None:
                return f"{name}/{sub}"
            continue
        if not _match(name, FILES):
            return name
    if top and not any((path / s).is_file() for s in SIGNATURES):
        return entries[0].name
    return None


def is_exsur_output(path: str | Path) -> bool:
    """True if ``path`` is an empty folder or an output folder that exsur wrote."""
    p = Path(path)
    return p.is_dir() and not p.is_symlink() and foreign_entry(p) is None


@contextlib.contextmanager
def replace_allowed(path: str | Path) -> Iterator[None]:
    """Within the block, :func:`~excavator_surrogate.io_utils.atomic_dir` may replace ``path``
    even if exsur did not write it (the user passed ``--overwrite``)."""
    token = _ALLOWED.set(_ALLOWED.get() | {Path(path).resolve()})
    try:
        yield
    finally:
        _ALLOWED.reset(token)


def may_replace(path: Path) -> bool:
    """True if ``path`` is absent, empty, exsur's own, or allowed by :func:`replace_allowed`."""
    return not path.exists() or is_exsur_output(path) or path.resolve() in _ALLOWED.get()


def check_not_cwd(path: Path, flag: str = "--out") -> None:
    """Refuse the current folder or one of its parents (``.``, ``..``, ``/``) as an output."""
    rp, cwd = path.resolve(), Path.cwd().resolve()
    if rp == cwd or rp in cwd.parents:
        raise ConfigError(
            f"{path}: {flag} is the current folder or one of its parents; give a new folder name"
        )


def _writable(path: Path, flag: str) -> None:
    """The nearest existing folder of ``path`` accepts new entries."""
    p = path
    while not p.exists():
        if p.parent == p:
            break
        p = p.parent
    if p.exists() and not p.is_dir():
        raise ConfigError(f"{path}: {p} is a file, not a folder; give another {flag}")
    if not os.access(p, os.W_OK | os.X_OK):
        raise ConfigError(
            f"{path}: {p} is not writable; give another {flag} or fix its permissions"
        )


def _inputs_inside(out: Path, inputs: Iterable[str | Path], flag: str) -> None:
    ro = out.resolve()
    for s in inputs:
        rs = Path(s).resolve()
        if rs == ro or ro in rs.parents:
            raise ConfigError(
                f"{s}: this input lies inside {flag} {out}, which exsur writes; "
                "move it out or write elsewhere"
            )


def check_out_dir(
    out: str | Path,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | Path] = (),
    flag: str = "--out",
) -> Path:
    """Check an output folder against the output-folder rule (see the module docstring).

    Args:
        out: the folder a command will replace or write into.
        overwrite: the user passed ``--overwrite``: a folder exsur did not write may be used.
        inputs: files and folders the command reads; none may lie inside ``out``.
        flag: option name used in messages.

    Returns:
        ``out`` as a Path.

    Raises:
        ConfigError: one line naming the folder, what is wrong and what to do.
    """
    out = Path(out)
    check_not_cwd(out, flag)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: {flag} exists and is a file; give a folder")
    _inputs_inside(out, inputs, flag)
    _writable(out, flag)
    if out.is_dir():
        if out.is_symlink() and not overwrite:
            raise ConfigError(
                f"{out}: {flag} is a symbolic link; give a real folder, or pass --overwrite"
            )
        bad = foreign_entry(out)
        if bad is not None and not overwrite:
            raise ConfigError(
                f"{out}: {flag} holds '{bad}', which exsur did not write; choose a new or empty "
                "folder, or pass --overwrite to replace it"
            )
        if not os.access(out, os.W_OK | os.X_OK):
            raise ConfigError(f"{out}: {flag} is not writable; give another {flag}")
    return out


def check_out_file(
    out: str | Path, *, inputs: Iterable[str | Path] = (), flag: str = "--out", example: str
) -> Path:
    """Check a single output file: not a folder, not an input, in a writable folder.

    ``example`` is a file name shown in messages (``model.onnx``).
    """
    out = Path(out)
    if out.is_dir() or out.name in ("", ".", ".."):
        raise ConfigError(f"{out}: {flag} is a folder; give a file name such as {example}")
    ro = out.resolve()
    for s in inputs:
        if Path(s).resolve() == ro:
            raise ConfigError(f"{s}: {flag} is one of the inputs; write to another file")
    _writable(out.parent, flag)
    if out.exists() and not os.access(out, os.W_OK):
        raise ConfigError(f"{out}: {flag} is not writable; give another file")
    return out


@contextlib.contextmanager
def out_dir(
    out: str | Path,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | Path] = (),
    flag: str = "--out",
) -> Iterator[Path]:
    """:func:`check_out_dir`, then a block in which ``overwrite`` lets exsur replace ``out``."""
    p = check_out_dir(out, overwrite=overwrite, inputs=inputs, flag=flag)
    if overwrite:
        with replace_allowed(p):
            yield p
    else:
        yield p


def preset_files(preset: str | Path | None) -> list[Path]:
    """``[preset]`` if it names a file (an input that must not lie inside ``--out``), else ``[]``."""
    if preset is None:
        return []
    p = Path(str(preset))
    return [p] if p.suffix == ".toml" or p.is_file() else []
