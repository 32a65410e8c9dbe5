"""The writer lock of an output folder: one exsur command writes a folder at a time.

:func:`lock_out` takes an OS ``flock`` on ``.<name>.lock`` next to the folder (a sibling, so a
command that replaces the whole folder holds it across the swap); the OS releases it when the
process dies, so a killed run leaves no stale lock.  :func:`release_locks` (the CLI, when a
command ends) releases them and removes the folders made for them, or for a file output
(:func:`note_folders_made`), that are still empty.  The output-folder rule itself is
:mod:`.outdir`'s.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
from pathlib import Path

from .errors import ConfigError


def first_missing(path: str | Path) -> Path | None:
    """The outermost folder of ``path`` (absolute) that does not exist yet: the one a
    ``mkdir(parents=True)`` of ``path`` would create first (None: ``path`` exists)."""
    new, p = None, Path(os.path.abspath(path))
    while not p.exists() and not p.is_symlink() and p.parent != p:
        new, p = p, p.parent
    return new


def lock_file(out: str | Path) -> Path:
    """The writer lock of output folder ``out``: ``.<name>.lock`` next to it (a sibling, so a
    command that replaces the whole folder holds it across the swap)."""
    p = Path(os.path.abspath(out))
    return p.parent / f".{p.name}.lock"


_HELD: dict[Path, int] = {}

_CHECKED: set[Path] = set()

_MADE: dict[Path, Path] = {}
"""Lock file -> the outermost folder :func:`lock_out` created to hold it, or file output ->
the outermost folder its write will create (:func:`note_folders_made`): removed again at
release when it is still empty (a command that failed before writing leaves no folders)."""


def note_folders_made(out: str | Path) -> None:
    """The folders a write of file ``out`` will create (its missing parents) are removed
    again at :func:`release_locks` if they are still empty then (the command failed)."""
    made = first_missing(Path(out).parent)
    if made is not None:
        _MADE[Path(os.path.abspath(out))] = made


def lock_out(out: str | Path, flag: str = "--out") -> None:
    """Take the exclusive writer lock of output folder ``out`` (an OS ``flock``, held until
    :func:`release_locks` or the end of the process; a killed run leaves no stale lock).

    Re-entrant within a process.  Processes that an exsur command spawns to write parts of the
    folder (ensemble members, sweep trials) do not lock: the command holds the lock for them;
    so do the ranks > 0 of a torchrun job (``RANK``): rank 0 holds it for the job.

    Raises:
        ConfigError: another process holds the lock, or the path cannot be created.
    """
    path = lock_file(out)
    if path in _HELD or _torchrun_rank() > 0:
        return
    made = first_missing(path.parent)
    for _ in range(5):  # the file may be unlinked by its releasing owner between open and lock
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as e:
            if Path(out).is_dir():  # a writable folder in a parent exsur may not write
                raise ConfigError(
                    f"{out}: cannot create its writer lock {path} ({e.strerror}): exsur locks "
                    f"{flag} beside it, so {path.parent} must be writable too; give another "
                    f"{flag}"
                ) from e
            raise ConfigError(
                f"{out}: cannot write {flag} there ({e.strerror}); give another {flag}"
            ) from e
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            owner = _read_owner(fd)
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise ConfigError(
                    f"{out}: another exsur process{owner} is writing this {flag}; wait for it "
                    f"to finish or give another {flag}"
                ) from None
            # a file system without locks: write unlocked, as before, and leave no lock file
            with contextlib.suppress(OSError):
                path.unlink()
            _remove_made(path.parent, made)
            return
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except OSError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            _HELD[path] = fd
            if made is not None:
                _MADE[path] = made
            return
        os.close(fd)
    raise ConfigError(f"{out}: could not lock {path}; retry")


def note_checked(out: str | Path) -> None:
    """Record that the output-folder rule passed for ``out`` while this process holds its
    writer lock (:func:`~.outdir.check_out_dir`); forgotten when the lock is released."""
    path = lock_file(out)
    if path in _HELD:
        _CHECKED.add(path)


def checked_under_lock(out: str | Path) -> bool:
    """True if this process holds the writer lock of ``out`` and checked the folder as it took
    it (:func:`note_checked`): nothing else of exsur writes it until the lock is released."""
    path = lock_file(out)
    return path in _HELD and path in _CHECKED


def _torchrun_rank() -> int:
    """``RANK`` of a torchrun job with ``WORLD_SIZE`` > 1 (0 outside one)."""
    try:
        if int(os.environ.get("WORLD_SIZE", "1")) > 1:
            return int(os.environ.get("RANK", "0"))
    except ValueError:
        pass
    return 0


def _read_owner(fd: int) -> str:
    try:
        pid = os.pread(fd, 32, 0).decode().strip()
    except OSError:
        return ""
    return f" (pid {pid})" if pid.isdigit() else ""


def release_locks() -> None:
    """Release every writer lock this process holds (the CLI calls it when a command ends),
    and remove the folders made for the locks and file outputs that are still empty."""
    for path, fd in list(_HELD.items()):
        with contextlib.suppress(OSError):
            path.unlink()  # while still locked: a waiting opener re-checks the inode
        os.close(fd)
        del _HELD[path]
        _CHECKED.discard(path)
        _remove_made(path.parent, _MADE.pop(path, None))
    for out in list(_MADE):  # the folders of file outputs
        _remove_made(out.parent, _MADE.pop(out))


def _remove_made(folder: Path, made: Path | None) -> None:
    """Remove ``folder`` and its parents up to ``made`` (the outermost one a lock created)
    while they are empty: ``rmdir`` only, so what a command wrote there stays."""
    while made is not None and (folder == made or made in folder.parents):
        try:
            folder.rmdir()
        except OSError:
            return
        folder = folder.parent
