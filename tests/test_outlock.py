"""The writer lock beside an --out (``outlock``): held, re-entrant, released with what it
made, torchrun ranks, and file systems and parents that do not allow one."""

from __future__ import annotations

import errno
import fcntl
import os
from pathlib import Path

import pytest

from excavator_surrogate import outlock
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.outdir import check_out_dir
from excavator_surrogate.outlock import lock_file, lock_out, release_locks
from tests.helpers.locks import lock_held_elsewhere


def test_the_writer_lock(tmp_path: Path, monkeypatch) -> None:
    out = tmp_path / "M"
    with lock_held_elsewhere(out) as proc:
        assert lock_file(out) == tmp_path / ".M.lock"
        with pytest.raises(ConfigError, match=rf"another exsur process \(pid {proc.pid}\)"):
            check_out_dir(out, lock=True)
        check_out_dir(out)  # the check alone does not lock
        monkeypatch.setenv("RANK", "1")
        with pytest.raises(ConfigError, match="another exsur process"):
            lock_out(out)  # RANK alone is not a torchrun job
        monkeypatch.setenv("WORLD_SIZE", "2")  # a torchrun rank > 0: rank 0 holds the lock
        lock_out(out)
        monkeypatch.delenv("RANK")
        monkeypatch.delenv("WORLD_SIZE")
    # the holder has ended (its stdin closed): the lock went with it
    try:
        lock_out(out)
        lock_out(out)  # re-entrant in one process
        assert lock_file(out).read_text().strip() == str(os.getpid())
    finally:
        release_locks()
    assert not lock_file(out).exists() and not out.exists()


def test_a_file_system_without_locks_writes_unlocked(tmp_path: Path, monkeypatch) -> None:
    def no_locks(fd: int, op: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    lock_out(tmp_path / "M")  # no error: the command runs as it did before locks
    assert lock_file(tmp_path / "M") not in outlock._HELD
    assert not lock_file(tmp_path / "M").exists()  # and no lock file is left behind
    lock_out(tmp_path / "new" / "M")
    assert not (tmp_path / "new").exists()  # nor the folder made to hold it


def test_a_lock_file_replaced_under_the_opener_is_retried_then_named(
    tmp_path: Path, monkeypatch
) -> None:
    lock = lock_file(tmp_path / "M")
    real = os.stat

    def stat(p, *a, **k):
        if Path(p) == lock:  # the releasing owner unlinked it between open and flock
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", str(p))
        return real(p, *a, **k)

    monkeypatch.setattr(os, "stat", stat)
    try:
        with pytest.raises(ConfigError) as e:
            lock_out(tmp_path / "M")
    finally:
        release_locks()
    assert str(e.value) == f"{tmp_path / 'M'}: could not lock {lock}; retry"
    assert lock not in outlock._HELD


def test_a_held_lock_without_a_readable_owner_is_named_without_pid(
    tmp_path: Path, monkeypatch
) -> None:
    def held(fd: int, op: int) -> None:
        raise BlockingIOError(errno.EWOULDBLOCK, "Resource temporarily unavailable")

    def unreadable(fd: int, n: int, offset: int) -> bytes:
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(fcntl, "flock", held)
    monkeypatch.setattr(os, "pread", unreadable)
    with pytest.raises(ConfigError) as e:
        lock_out(tmp_path / "M", "--out")
    assert str(e.value) == (
        f"{tmp_path / 'M'}: another exsur process is writing this --out; wait for it to "
        "finish or give another --out"
    )


def test_a_world_size_that_is_not_a_number_is_no_torchrun_job(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("WORLD_SIZE", "two")
    monkeypatch.setenv("RANK", "1")
    try:
        lock_out(tmp_path / "M")  # rank 0 of no job: takes the lock itself
        assert lock_file(tmp_path / "M") in outlock._HELD
    finally:
        release_locks()


def test_folders_made_for_a_lock_go_when_nothing_was_written(tmp_path: Path) -> None:
    """The folders ``lock_out`` creates to hold the lock beside ``--out`` are removed at
    release when the command wrote nothing into them; a written output, and folders that
    existed before, stay."""
    out = tmp_path / "new" / "deeper" / "ds"
    lock_out(out)
    assert lock_file(out).is_file()
    release_locks()
    assert not (tmp_path / "new").exists() and tmp_path.is_dir()
    lock_out(out)
    out.mkdir()  # the command wrote its output
    release_locks()
    assert out.is_dir() and not lock_file(out).exists()
    kept = tmp_path / "kept"
    kept.mkdir()
    lock_out(kept / "ds")
    release_locks()
    assert kept.is_dir()


def test_a_lock_that_cannot_be_created_beside_a_writable_out_is_named(
    tmp_path: Path, monkeypatch
) -> None:
    """A writable --out in a read-only parent (a mount point, a granted folder in a
    root-owned one) was refused with 'cannot write --out there': the lock beside it is what
    cannot be written, and the message says so."""
    out = tmp_path / "ro" / "w"
    out.mkdir(parents=True)
    real = os.open

    def read_only(path, flags, mode=0o777):
        if Path(path) == lock_file(out):
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real(path, flags, mode)

    monkeypatch.setattr(os, "open", read_only)
    with pytest.raises(ConfigError) as e:
        lock_out(out)
    assert str(e.value) == (
        f"{out}: cannot create its writer lock {tmp_path / 'ro' / '.w.lock'} (Read-only file "
        f"system): exsur locks --out beside it, so {tmp_path / 'ro'} must be writable too; "
        "give another --out"
    )
