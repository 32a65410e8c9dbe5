"""io_utils' rarer paths: what the sweep of killed runs' temporary files keeps and removes,
refusals of atomic_dir / atomic_files that leave nothing behind, JSON of numpy values and
paths, and log lines that carry a traceback."""

from __future__ import annotations

import errno
import json
import logging
import math
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.io_utils import (
    LogFormatter,
    atomic_dir,
    atomic_files,
    mark_output,
    sweep_stale,
    write_json,
)
from excavator_surrogate.outdir import MARKER

DEAD = 4_194_305  # above Linux's PID_MAX_LIMIT: no process has it
FOREIGN = 4_194_306  # os.kill is made to answer "not yours" for it
ALIVE = 4_194_307  # ... and "alive" for it


@pytest.fixture
def fake_kill(monkeypatch: pytest.MonkeyPatch) -> None:
    real = os.kill

    def kill(pid: int, sig: int) -> None:
        if pid == FOREIGN:
            raise PermissionError(errno.EPERM, "Operation not permitted")
        if pid == ALIVE:
            return
        real(pid, sig)

    monkeypatch.setattr(os, "kill", kill)


def test_sweep_keeps_what_live_or_foreign_processes_own(tmp_path: Path, fake_kill: None) -> None:
    out = tmp_path / "ds"
    dead_file = tmp_path / f".ds.{DEAD}-a1bcdefg.tmp"  # atomic_path's temporary file
    dead_link = tmp_path / f".ds.{DEAD}-a2bcdefg.tmp"
    dead_dir = tmp_path / f".ds.{DEAD}-a3bcdefg.tmp"
    foreign = tmp_path / f".ds.{FOREIGN}-bbcdefgh.tmp"
    alive = tmp_path / f".ds.{ALIVE}-cbcdefgh.tmp"
    no_pid_old = tmp_path / ".ds.old-x"  # not written by exsur: kept
    unrelated = tmp_path / ".ds.notes"  # neither .tmp nor .old-: kept
    (tmp_path / "elsewhere").mkdir()
    dead_file.write_text("half")
    dead_link.symlink_to(tmp_path / "elsewhere")  # removed as a link, its target kept
    for p in (dead_dir, foreign, alive, no_pid_old, unrelated):
        mark_output(p, "dataset")
    assert sorted(sweep_stale(out)) == sorted([dead_file, dead_link, dead_dir])
    assert (tmp_path / "elsewhere").is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        p.name for p in (foreign, alive, no_pid_old, unrelated, tmp_path / "elsewhere")
    )


def test_sweep_removes_only_exsurs_own_temporaries(tmp_path: Path) -> None:
    """Hidden ``.NAME.*.tmp`` files and folders of the user's beside an output stay: only
    exsur's exact ``.NAME.<pid>-XXXXXXXX.tmp`` shape of a dead process goes, and a folder only
    when it holds exsur's marker or is empty."""
    backup = tmp_path / ".ds.backup.tmp"  # the user's, no pid
    backup.mkdir()
    (backup / "notes.txt").write_text("my notes")
    draft = tmp_path / ".ds.draft.tmp"
    draft.write_text("draft")
    theirs = tmp_path / f".ds.{DEAD}-x.tmp"  # a pid, but not mkstemp's name
    theirs.write_text("theirs")
    unmarked = tmp_path / f".ds.{DEAD}-abcdefgh.tmp"  # exsur's shape, not exsur's content
    unmarked.mkdir()
    (unmarked / "notes.txt").write_text("mine")
    old_file = tmp_path / f".ds.old-{FOREIGN}"  # exsur's replaced folders are never files
    old_file.write_text("mine")
    empty = tmp_path / f".ds.{DEAD}-emptyfld.tmp"  # killed before its marker
    empty.mkdir()
    marked = mark_output(tmp_path / f".ds.{DEAD}-marked00.tmp", "dataset")
    (marked / "episodes").mkdir()
    nested = mark_output(tmp_path / f"..ds.{DEAD}-marked00.tmp.{DEAD}-nested00.tmp", "dataset")
    old = mark_output(tmp_path / f".ds.old-{DEAD}", "dataset")
    assert sorted(sweep_stale(tmp_path / "ds")) == sorted([empty, marked, nested, old])
    assert (backup / "notes.txt").read_text() == "my notes" and draft.read_text() == "draft"
    assert theirs.is_file() and (unmarked / "notes.txt").is_file() and old_file.is_file()


def test_sweep_of_a_missing_folder_or_an_undeletable_entry(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert sweep_stale(tmp_path / "missing" / "ds") == []
    stuck = mark_output(tmp_path / f".ds.{DEAD}-abcdefgh.tmp", "dataset")

    def refuse(path: object, *args: object, **kw: object) -> None:
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(shutil, "rmtree", refuse)
    assert sweep_stale(tmp_path / "ds") == []  # not removed, not reported, no error
    assert stuck.is_dir()


def test_atomic_dir_refusals_leave_nothing(tmp_path: Path) -> None:
    f = tmp_path / "out"
    f.write_text("a file")
    with pytest.raises(
        ConfigError, match=r"out: output folder exists and is a file; give a folder"
    ):
        with atomic_dir(f):
            pass
    assert f.read_text() == "a file"
    out = tmp_path / "new"
    with pytest.raises(FileExistsError, match=r"new exists"), atomic_dir(out, overwrite=False) as t:
        (t / "x.json").write_text("{}")
        mark_output(out, "dataset")  # another writer got there first
    assert sorted(p.name for p in out.iterdir()) == [MARKER]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new", "out"]


def test_atomic_files_refuses_a_folder_before_moving_anything(tmp_path: Path) -> None:
    ev = tmp_path / "ev"
    with pytest.raises(IsADirectoryError, match="sub is a folder; use atomic_dir"):
        with atomic_files(ev, kind="evaluation") as t:
            (t / "a.json").write_text("{}")  # sorts before the folder
            (t / "sub").mkdir()
    assert list(tmp_path.iterdir()) == []  # neither ev nor a temporary folder


def test_write_json_of_numpy_values_and_paths(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    obj = {"n": np.int64(3), "x": np.float32(0.5), "a": np.arange(3), "p": tmp_path / "d"}
    write_json(path, obj)
    assert json.loads(path.read_text()) == {
        "n": 3,
        "x": 0.5,
        "a": [0, 1, 2],
        "p": str(tmp_path / "d"),
    }
    with pytest.raises(TypeError, match="not JSON serialisable: set"):
        write_json(tmp_path / "bad.json", {"s": {1, 2}})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_a_log_line_with_a_traceback() -> None:
    try:
        raise ValueError("boom")
    except ValueError:
        exc_info = sys.exc_info()
    record = logging.LogRecord(
        "excavator_surrogate.x", logging.ERROR, __file__, 1, "failed %s", ("a",), exc_info
    )
    text = LogFormatter("seed1").format(record)
    first, *rest = text.splitlines()
    assert first == "[seed1] error: failed a"
    assert rest[0].startswith("Traceback") and rest[-1] == "ValueError: boom"


def test_write_json_writes_an_undefined_number_as_null(tmp_path: Path) -> None:
    """``NaN`` / ``Infinity`` are not JSON (``exsur run``'s ``metrics.json`` held ``NaN`` for a
    pace the cost model does not cover, and other readers refused the file): every writer of
    JSON writes them as ``null``."""
    nan = float("nan")
    obj = {"pace": nan, "x": [1.0, -math.inf], "a": np.array([np.nan, 2.0]), "s": np.float32(nan)}
    write_json(tmp_path / "m.json", obj)

    def refuse(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    got = json.loads((tmp_path / "m.json").read_text(), parse_constant=refuse)
    assert got == {"pace": None, "x": [1.0, None], "a": [None, 2.0], "s": None}


def test_a_replaced_file_keeps_its_permissions(tmp_path: Path) -> None:
    """atomic_path gave every replaced file the umask's mode: a private (0600) checkpoint
    became world readable, a read-only one writable.  A new file still gets the umask's."""
    from excavator_surrogate.io_utils import write_text

    for mode in (0o600, 0o444):
        path = tmp_path / f"m{mode:o}.pt"
        path.write_text("old")
        path.chmod(mode)
        write_text(path, "new")
        assert path.read_text() == "new" and path.stat().st_mode & 0o777 == mode
    write_text(tmp_path / "new.txt", "x")
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "new.txt").stat().st_mode & 0o777 == 0o666 & ~mask


def test_replacing_a_linked_folder_leaves_no_link_behind(tmp_path: Path) -> None:
    """``simulate --out link --overwrite`` left a hidden ``.link.old-PID`` symlink to the
    user's folder (rmtree refuses a link, and the error was swallowed)."""
    from excavator_surrogate.outdir import replace_allowed

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("keep")
    link = tmp_path / "link"
    link.symlink_to(elsewhere, target_is_directory=True)
    with replace_allowed(link), atomic_dir(link, kind="dataset") as tmp:
        (tmp / "manifest.json").write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "link"]
    assert not link.is_symlink() and (link / "manifest.json").is_file()
    assert (elsewhere / "keep.txt").read_text() == "keep"
