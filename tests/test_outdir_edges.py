"""Edge cases of the output-folder rule (outdir.py): unreadable folders, temporary names, links,
read-only files and files of other kinds (the writer lock: test_outlock.py)."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.io_utils import mark_output
from excavator_surrogate.outdir import (
    MARKER,
    check_out_dir,
    check_out_file,
    foreign_entry,
    is_exsur_file,
)


def _unlistable(monkeypatch: pytest.MonkeyPatch, *folders: Path) -> None:
    """``Path.iterdir`` of ``folders`` fails as a folder without read permission does (the
    tests run as any user, root included, so permissions alone cannot make one)."""
    real = Path.iterdir

    def iterdir(self: Path):
        if self in folders:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "iterdir", iterdir)


def _dataset(root: Path) -> Path:
    mark_output(root, "dataset")
    (root / "episodes").mkdir()
    (root / "episodes" / "a.parquet").write_bytes(b"x")
    (root / "manifest.json").write_text("{}")
    return root


def test_an_unreadable_folder_is_not_known_to_be_exsurs(tmp_path: Path, monkeypatch) -> None:
    ds = _dataset(tmp_path / "ds")
    (ds / "model").mkdir()
    _unlistable(monkeypatch, ds / "episodes", ds / "model")
    assert foreign_entry(ds) == "episodes (Permission denied)"
    with pytest.raises(ConfigError, match=r"holds 'episodes \(Permission denied\)'.*--overwrite"):
        check_out_dir(ds)
    _unlistable(monkeypatch, ds)
    assert foreign_entry(ds) == "ds (Permission denied)"


def test_temporary_names_of_killed_writers_are_exsurs(tmp_path: Path) -> None:
    ds = _dataset(tmp_path / "ds")
    (ds / ".manifest.json.123-abcdefgh.tmp").write_text("")
    assert foreign_entry(ds) is None
    (ds / "notes.txt").write_text("")
    assert foreign_entry(ds) == "notes.txt"


@pytest.mark.parametrize(
    "entry",
    [
        ".my-backup.tmp/precious.txt",  # a folder, no pid
        ".notes.lock",  # exsur's locks are siblings of the folder, never inside
        ".draft.tmp",
        ".best.pt.old-123",
        ".x.123-abcdefgh.tmp/precious.txt",  # exsur's temporaries inside are files
        "episodes/.notes.tmp",
    ],
)
def test_hidden_names_of_the_users_are_not_exsurs(tmp_path: Path, entry: str) -> None:
    """Only exsur's exact temporary file shape is exempt from the rule: a user's
    ``.my-backup.tmp/`` folder or ``.notes.lock`` makes the folder the user's."""
    ds = _dataset(tmp_path / "ds")
    (ds / entry).parent.mkdir(parents=True, exist_ok=True)
    (ds / entry).write_text("precious")
    assert foreign_entry(ds).startswith(entry.split("/precious.txt")[0])
    with pytest.raises(ConfigError, match="which exsur did not write"):
        check_out_dir(ds)


def test_a_killed_write_into_episodes_is_exsurs(tmp_path: Path) -> None:
    """``exsur plot`` killed while it wrote a PNG next to an episode left its temporary
    file in ``episodes/``: a rerun into the dataset accepts it."""
    ds = _dataset(tmp_path / "ds")
    (ds / "episodes" / ".test_000.png.24026-6qkpier_.tmp").write_bytes(b"half")
    (ds / "figures").mkdir()
    (ds / "figures" / ".a.png.24026-abcdefgh.tmp").write_bytes(b"half")
    assert foreign_entry(ds) is None
    assert check_out_dir(ds) == ds


def test_a_linked_out_folder_needs_overwrite(tmp_path: Path) -> None:
    real = _dataset(tmp_path / "real")
    link = tmp_path / "link"
    link.symlink_to(real, target_is_directory=True)
    with pytest.raises(ConfigError) as e:
        check_out_dir(link)
    assert str(e.value) == (
        f"{link}: --out is a symbolic link; give a real folder, or pass --overwrite"
    )
    assert check_out_dir(link, overwrite=True) == link


def test_a_read_only_file_output_is_named(tmp_path: Path, monkeypatch) -> None:
    torch = pytest.importorskip("torch")
    out = tmp_path / "m.pt"
    torch.save({"format": "exsur-surrogate"}, out)
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, m: Path(p) != out and real(p, m))
    with pytest.raises(ConfigError) as e:
        check_out_file(out, example="merged.pt")
    assert str(e.value) == f"{out}: --out is not writable; give another file"


def test_only_regular_files_of_the_known_kinds_are_exsurs(tmp_path: Path) -> None:
    (tmp_path / "d.pt").mkdir()
    (tmp_path / "notes.txt").write_text("exsur")
    (tmp_path / "link.png").symlink_to(tmp_path / "notes.txt")
    assert not any(is_exsur_file(tmp_path / n) for n in ("d.pt", "notes.txt", "link.png"))
    assert not is_exsur_file(tmp_path / "absent.onnx")


def test_the_marker_alone_is_an_empty_output(tmp_path: Path) -> None:
    d = tmp_path / "d"
    mark_output(d, "model")
    assert [p.name for p in d.iterdir()] == [MARKER] and foreign_entry(d) is None


def test_a_dangling_link_is_refused_up_front(tmp_path: Path) -> None:
    """A symbolic link to a missing folder passed every check (it does not exist), and the
    command failed only at its final rename, after its work, naming a temporary."""
    link = tmp_path / "dangling"
    link.symlink_to(tmp_path / "nonexistent_target")
    with pytest.raises(ConfigError) as e:
        check_out_dir(link, kind="dataset")
    assert str(e.value) == (
        f"{link}: --out is a symbolic link to a missing folder; give another --out"
    )
    with pytest.raises(ConfigError) as e:
        check_out_dir(link / "ds", overwrite=True)
    assert str(e.value) == (
        f"{link / 'ds'}: {link} is a symbolic link to a missing folder; give another --out"
    )
    with pytest.raises(ConfigError) as e:
        check_out_file(link / "m.onnx", example="model.onnx")
    assert str(e.value) == (
        f"{link / 'm.onnx'}: {link} is a symbolic link to a missing folder; give another --out"
    )
    onnx = tmp_path / "m.onnx"
    onnx.symlink_to(tmp_path / "gone.onnx")
    with pytest.raises(ConfigError, match="m.onnx: --out is a symbolic link to a missing"):
        check_out_file(onnx, example="model.onnx", overwrite=True)
    onnx.unlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling"]
