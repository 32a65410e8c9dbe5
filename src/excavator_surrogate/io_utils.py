"""Small I/O helpers: atomic files and folders, JSON, progress bars.

No output is ever left half-written: files are written to a temporary sibling and
renamed into place; output folders are built in a temporary sibling folder and renamed
when complete.
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import logging
import math
import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # exists, owned by someone else
    return True


def _temp_prefix(name: str) -> str:
    """``.<name>.<pid>-``: the owner's pid lets a later run remove what a killed run left."""
    return f".{name}.{os.getpid()}-"


def sweep_stale(path: str | Path) -> list[Path]:
    """Remove temporary siblings of ``path`` left by killed exsur processes; returns them.

    Only exsur's exact shapes whose process is gone: ``.<name>.<pid>-XXXXXXXX.tmp`` (a file of
    :func:`atomic_path`, or a folder of :func:`atomic_dir` / :func:`atomic_files`, also nested:
    ``..<name>.<pid>-X.tmp.<pid>-Y.tmp``) and ``.<name>.old-<pid>`` (a replaced folder not yet
    deleted).  A folder goes only if it holds exsur's marker (the writers put it there first)
    or is empty: a file or folder of the user's that merely looks like one is kept.
    """
    from .outdir import TEMP_RANDOM, read_marker

    path = Path(path)
    base = re.escape(path.name.lstrip("."))
    nested = rf"(?:\.\d+-{TEMP_RANDOM}\.tmp)*"
    shape = re.compile(rf"\.+{base}(?:\.(\d+)-{TEMP_RANDOM}\.tmp{nested}|\.old-(\d+))")
    removed: list[Path] = []
    try:
        entries = list(path.parent.iterdir()) if path.name else []
    except OSError:
        return removed
    for e in entries:
        m = shape.fullmatch(e.name)
        if m is None or _pid_alive(int(m[1] or m[2])):
            continue
        try:
            if e.is_symlink() or (m[1] and not e.is_dir()):
                e.unlink()
            elif read_marker(e) is not None:
                shutil.rmtree(e)
            else:
                e.rmdir()  # only when empty (killed before its marker): else the user's
            removed.append(e)
        except OSError:
            pass
    return removed


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    On any exception the temporary file is removed and ``path`` is left untouched.
    """
    path = Path(path)
    if path.is_dir():  # os.replace would fail at the end, naming the temporary file
        from .errors import ConfigError

        raise ConfigError(f"{path}: is a folder; give a file name inside it or another path")
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path)
    fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(path.name), suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp creates 0600 files: a replaced file keeps its permissions (a private
        # checkpoint stays private), a new one gets those a plain open() would give it
        mode = stat.S_IMODE(os.stat(path).st_mode) if path.exists() else 0o666 & ~_umask()
        os.chmod(tmp_path, mode)
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    note_written(path)


def note_written(path: str | Path) -> None:
    """Add file ``path`` to the record of the output folder it is in (the nearest marked
    folder above it), if that folder keeps one (a dataset, a run, a control report:
    :func:`atomic_dir`), so the folder still holds only what exsur wrote.  A temporary folder
    being built keeps no record yet: it records everything when complete."""
    from .outdir import MARKER, read_marker

    p = Path(os.path.abspath(path))
    folder = next((f for f in p.parents if (f / MARKER).is_file()), None)
    if folder is None or p.name == MARKER:
        return
    m = read_marker(folder)
    if m is None or not isinstance(m.get("files"), list):
        return
    rel = p.relative_to(folder).parts
    parts = {"/".join(rel[: i + 1]) for i in range(len(rel))}
    if not parts <= set(m["files"]):
        write_json(folder / MARKER, {**m, "files": sorted(parts | set(m["files"]))})


@contextlib.contextmanager
def atomic_dir(path: str | Path, *, overwrite: bool = True, kind: str = "output") -> Iterator[Path]:
    """Yield a temporary folder next to ``path``; move it onto ``path`` when the block succeeds.

    The temporary folder starts with the output marker of ``kind`` (:func:`mark_output`), so
    the result is recognised as exsur's by content.  An existing ``path`` is replaced only
    after the new content is complete (``overwrite=True``), and only if the output-folder rule
    allows it (:func:`~excavator_surrogate.outdir.may_replace`: empty, written by exsur, or
    ``--overwrite``).  On failure the temporary folder is deleted.  Temporary folders that
    killed runs left next to ``path`` are removed first.

    Raises:
        ConfigError: ``path`` is the current folder, a file, or a folder exsur did not write.
    """
    path = Path(path)
    check_replaceable(path, kind)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path)
    tmp = Path(tempfile.mkdtemp(prefix=_temp_prefix(path.name), suffix=".tmp", dir=path.parent))
    try:
        mark_output(tmp, kind)
        yield tmp
        record_output(tmp)
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp creates 0700 folders
        if path.exists():
            if not overwrite:
                raise FileExistsError(f"{path} exists")
            check_replaceable(path, kind)
            old = path.with_name(f".{path.name}.old-{os.getpid()}")
            os.replace(path, old)
            os.replace(tmp, path)
            if old.is_symlink():  # a linked --out: the link goes, its target stays
                old.unlink()
            else:
                shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def atomic_files(path: str | Path, *, kind: str, replaces: Sequence[str] = ()) -> Iterator[Path]:
    """All or nothing for a command that writes files INTO folder ``path`` (keeping what is
    already there): yield a temporary folder next to ``path``; when the block succeeds, mark
    ``path`` (:func:`mark_output`) and rename every file of the temporary folder into it.

    ``replaces``: shell patterns of names the command writes a varying set of (an
    evaluation's ``cbe_<episode>.png``): a file of ``path`` matching one that this call did
    not write is an earlier call's and no longer describes the folder, so it is removed
    after the renames, if exsur wrote it (by content,
    :func:`~excavator_surrogate.outdir.is_exsur_file`: a user's ``cbe_mine.png`` stays).

    A failure in the block (a full disk while writing a figure) leaves ``path`` untouched.
    The renames need no space, so once they start they complete.
    """
    from .outdir import MARKER, is_exsur_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path)
    tmp = Path(tempfile.mkdtemp(prefix=_temp_prefix(path.name), suffix=".tmp", dir=path.parent))
    try:
        mark_output(tmp, kind)  # exsur's by content, should a kill leave it (sweep_stale)
        yield tmp
        written = sorted(f for f in tmp.iterdir() if f.name != MARKER)
        for f in written:  # before the first rename: all or nothing
            if f.is_dir():
                raise IsADirectoryError(f"atomic_files: {f.name} is a folder; use atomic_dir")
        mark_output(path, kind)
        for f in written:
            os.chmod(f, 0o666 & ~_umask())
            os.replace(f, path / f.name)
        for f in written:  # into a folder that keeps a record (evaluate --overwrite into it)
            note_written(path / f.name)
        names = {f.name for f in written}
        for old in path.iterdir():
            if old.name not in names and old.is_file():
                if any(fnmatch.fnmatchcase(old.name, p) for p in replaces) and is_exsur_file(old):
                    old.unlink(missing_ok=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def mark_output(path: str | Path, kind: str) -> Path:
    """Create folder ``path`` (if needed) and write its output marker
    (:data:`~excavator_surrogate.outdir.MARKER`, ``{"format", "kind", "version", "created"}``)
    atomically, BEFORE the first file of the output; a folder already marked keeps its
    marker.  Returns ``path``."""
    from .outdir import MARKER, marker, read_marker

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    if read_marker(path) is None:
        write_json(path / MARKER, marker(kind))
    return path


def record_output(path: str | Path) -> None:
    """Record in the marker of the complete output folder ``path`` every file and folder in it
    (``files``, relative, with ``/``): the exact list of what exsur wrote there, which
    :func:`~excavator_surrogate.outdir.foreign_entry` holds the folder to from then on."""
    from .outdir import MARKER, read_marker

    path = Path(path)
    names = []
    for root, dirs, files in os.walk(path):
        rel = Path(root).relative_to(path)
        names += [(rel / n).as_posix() for n in (*dirs, *files)]
    m = read_marker(path)
    if m is not None:
        write_json(path / MARKER, {**m, "files": sorted(n for n in names if n != MARKER)})


def check_replaceable(path: Path, kind: str) -> None:
    """The check :func:`atomic_dir` makes of ``path`` before it writes a ``kind`` output: a
    caller that computes for long before its write (a simulation) makes it first too.

    Raises:
        ConfigError: ``path`` is the current folder, a file, or a folder exsur did not write
            (or of a kind a ``kind`` output may not replace).
    """
    from .errors import ConfigError
    from .outdir import check_not_cwd, kind_refusal, may_replace, other_kind, refusal

    check_not_cwd(path, "output folder")
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{path}: output folder exists and is a file; give a folder")
    if not may_replace(path, kind):
        found = other_kind(path, kind)
        flag = "output folder"
        raise ConfigError(kind_refusal(path, found, kind, flag) if found else refusal(path, flag))


def write_text(path: str | Path, text: str) -> None:
    """Atomically write a text file."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json(path: str | Path, obj: Any) -> None:
    """Atomically write pretty, strict JSON: a NaN or infinite number (an undefined metric)
    is written as ``null`` (``NaN`` is not JSON: other readers refuse the file)."""
    text = json.dumps(json_ready(obj), indent=2, default=_json_default, allow_nan=False)
    write_text(path, text + "\n")


def json_ready(o: Any) -> Any:
    """``o`` with every non-finite float as None (strict JSON has no NaN), mappings as dicts,
    tuples as lists, NumPy arrays and scalars as lists and numbers."""
    if isinstance(o, Mapping):
        return {k: json_ready(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [json_ready(v) for v in o]
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if hasattr(o, "tolist") and hasattr(o, "dtype"):  # numpy arrays and scalars
        return json_ready(o.tolist())
    return o


def recorded_path(path: str | Path, root: str | Path) -> str:
    """``path`` as written into a file of the output folder ``root``.

    Inside ``root``: relative to it, with ``/`` (``"model/best.pt"``), so the record stays
    right when the folder is renamed or moved (e.g. from its temporary build folder into
    place).  Outside ``root``: absolute.  Resolve a relative record with ``root / path``.
    """
    p, r = Path(path).resolve(), Path(root).resolve()
    return p.relative_to(r).as_posix() if p.is_relative_to(r) else str(p)


def _json_default(o: Any) -> Any:
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def progress(
    it: Iterable[T], *, total: int | None = None, desc: str = "", disable: bool | None = None
) -> Iterable[T]:
    """A tqdm progress bar on stderr; silent when stderr is not a terminal unless forced.

    ``disable=None`` shows the bar when the ``excavator_surrogate`` logger lets INFO lines
    through (not with ``exsur -q`` or a WARNING level) and stderr is a TTY or
    ``EXSUR_PROGRESS=1``.  ``disable=False`` forces the bar.
    """
    if disable is None:
        disable = not logging.getLogger(LOGGER_NAME).isEnabledFor(logging.INFO) or not (
            sys.stderr.isatty() or os.environ.get("EXSUR_PROGRESS") == "1"
        )
    from tqdm.auto import tqdm

    return tqdm(it, total=total, desc=desc, disable=disable, leave=False, dynamic_ncols=True)


LOGGER_NAME = "excavator_surrogate"
"""The package logger: every module logs to ``logging.getLogger(__name__)`` below it."""


class LogFormatter(logging.Formatter):
    """``[exsur] message``; other levels than INFO say theirs (``[exsur] warning: ...``).

    ``tag`` replaces ``exsur`` (a worker process names its job, ``[seed1] ...``).
    """

    def __init__(self, tag: str = "exsur") -> None:
        super().__init__()
        self.tag = tag

    def format(self, record: logging.LogRecord) -> str:
        """One line (plus a traceback if the record carries one)."""
        level = "" if record.levelno == logging.INFO else f"{record.levelname.lower()}: "
        text = f"[{self.tag}] {level}{record.getMessage()}"
        if record.exc_info:
            text += "\n" + self.formatException(record.exc_info)
        return text


class _StderrHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """Writes to the current ``sys.stderr`` (looked up on every line, as pytest swaps it)."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property  # type: ignore[override]
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, value: Any) -> None:
        pass


def setup_logging(level: int = logging.INFO, *, tag: str = "exsur") -> logging.Handler:
    """Show exsur's log lines on stderr as ``[exsur] ...`` from ``level`` up; returns the handler.

    The CLI calls this (``-q``: WARNING, ``-v``: DEBUG); a script or notebook may too.  It
    replaces the handler of an earlier call, so calling it twice does not double the lines.
    Undo with :func:`remove_logging`.
    """
    pkg = logging.getLogger(LOGGER_NAME)
    remove_logging()
    handler = _StderrHandler()
    handler.setFormatter(LogFormatter(tag))
    handler._exsur = True  # type: ignore[attr-defined]
    pkg.addHandler(handler)
    pkg.setLevel(level)
    return handler


def remove_logging() -> None:
    """Remove the handler of :func:`setup_logging` (the package logger keeps its level)."""
    pkg = logging.getLogger(LOGGER_NAME)
    for h in list(pkg.handlers):
        if getattr(h, "_exsur", False):
            pkg.removeHandler(h)


def worker_log_config() -> tuple[int, bool]:
    """What a spawned worker needs to log like this process: ``(level, shown)``.

    ``shown``: some handler other than a ``NullHandler`` would print the package's lines here
    (the CLI's, or the user's ``logging.basicConfig``).  Pass it to :func:`init_worker_logging`.
    """
    pkg = logging.getLogger(LOGGER_NAME)
    shown = False
    lg: logging.Logger | None = pkg
    while lg is not None and not shown:
        shown = any(not isinstance(h, logging.NullHandler) for h in lg.handlers)
        lg = lg.parent if lg.propagate else None
    return pkg.getEffectiveLevel(), shown


def init_worker_logging(config: tuple[int, bool], *, tag: str = "") -> None:
    """In a spawned worker: log at the parent's level, on stderr if the parent shows its lines.

    Args:
        config: :func:`worker_log_config` of the parent process.
        tag: the worker's name in its lines (``[seed1] ...``); empty: ``exsur``.
    """
    level, shown = config
    if shown:
        setup_logging(level, tag=tag or "exsur")
    else:
        logging.getLogger(LOGGER_NAME).setLevel(level)


def log(msg: str) -> None:
    """One INFO line on the package logger (a callback for code that takes ``log=``).

    Modules log to their own ``logging.getLogger(__name__)``; this is for callers that
    pass a plain function.
    """
    logging.getLogger(LOGGER_NAME).info(msg)
