"""recorded_path: paths written into an output folder (relative inside it, absolute outside);
atomic_files: all of a command's files written into a folder, or none."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from excavator_surrogate.io_utils import atomic_files, mark_output, recorded_path
from excavator_surrogate.outdir import MARKER, PNG_SOFTWARE, read_marker


def test_inside_the_folder_is_relative_and_resolves_after_a_move(tmp_path: Path) -> None:
    out = tmp_path / "run"
    (out / "model").mkdir(parents=True)
    (out / "model" / "best.pt").write_text("x")
    rec = recorded_path(out / "model" / "best.pt", out)
    assert rec == "model/best.pt"
    assert recorded_path(out / "data", out) == "data"
    assert recorded_path(out, out) == "."
    moved = tmp_path / "elsewhere"
    out.rename(moved)
    assert (moved / rec).read_text() == "x"


def test_outside_the_folder_is_absolute(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "run"
    out.mkdir()
    assert recorded_path(tmp_path / "data", out) == str((tmp_path / "data").resolve())
    # a sibling whose name starts like the folder is not inside it
    assert recorded_path(tmp_path / "run2" / "x", out) == str((tmp_path / "run2" / "x").resolve())
    # relative arguments are taken from the current folder
    monkeypatch.chdir(tmp_path)
    assert recorded_path("run/model/best.pt", "run") == "model/best.pt"
    assert recorded_path("data", "run") == str((tmp_path / "data").resolve())


def test_atomic_files_writes_all_or_nothing_into_a_folder(tmp_path: Path) -> None:
    model = mark_output(tmp_path / "model", "model")
    (model / "best.pt").write_text("weights")
    with pytest.raises(OSError, match="No space left"), atomic_files(model, kind="evaluation") as t:
        (t / "metrics.json").write_text("{}")
        (t / "table.md").write_text("|")
        raise OSError(errno.ENOSPC, "No space left on device", str(t / "cbe.png"))
    assert sorted(p.name for p in model.iterdir()) == [MARKER, "best.pt"]
    assert [p.name for p in tmp_path.iterdir()] == ["model"]  # no temporary folder left
    with atomic_files(model, kind="evaluation") as t:
        (t / "metrics.json").write_text("{}")
    assert sorted(p.name for p in model.iterdir()) == [MARKER, "best.pt", "metrics.json"]
    assert read_marker(model)["kind"] == "model"  # the folder keeps its marker
    with atomic_files(tmp_path / "new", kind="evaluation") as t:
        (t / "table.md").write_text("|")
    assert read_marker(tmp_path / "new")["kind"] == "evaluation"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def _png(path: Path, software: str = PNG_SOFTWARE) -> None:
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    info.add_text("Software", software)
    Image.new("RGB", (2, 2)).save(path, pnginfo=info)


def test_atomic_files_removes_an_earlier_calls_files_of_a_varying_set(tmp_path: Path) -> None:
    ev = tmp_path / "ev"
    with atomic_files(ev, kind="evaluation", replaces=("cbe_*.png",)) as t:
        for name in ("cbe.png", "cbe_a.png", "cbe_b.png"):
            _png(t / name)
        (t / "table.md").write_text("table.md")
    (ev / "notes.txt").write_text("mine")
    with atomic_files(ev, kind="evaluation", replaces=("cbe_*.png",)) as t:
        for name in ("cbe.png", "cbe_c.png"):
            _png(t / name, f"{PNG_SOFTWARE} 2")
        (t / "table.md").write_text("table.md2")
    # cbe_a and cbe_b were the earlier evaluation's; what matches no pattern stays
    assert sorted(p.name for p in ev.iterdir()) == [
        MARKER,
        "cbe.png",
        "cbe_c.png",
        "notes.txt",
        "table.md",
    ]
    assert (ev / "table.md").read_text() == "table.md2"
    with pytest.raises(RuntimeError), atomic_files(ev, kind="evaluation", replaces=("*",)) as t:
        raise RuntimeError("a failed call removes nothing")
    assert len(list(ev.iterdir())) == 5


def test_atomic_files_removes_only_figures_exsur_drew(tmp_path: Path) -> None:
    """``evaluate --overwrite`` into a user's folder deleted the user's ``cbe_mine.png`` (a
    name the evaluation's figures have) although it had not drawn it."""
    u = tmp_path / "u"
    u.mkdir()
    _png(u / "cbe_mine.png", "matplotlib")
    (u / "horizon.png").write_text("my figure")
    with atomic_files(u, kind="evaluation", replaces=("cbe_*.png", "horizon.png")) as t:
        _png(t / "cbe.png")
    assert sorted(p.name for p in u.iterdir()) == [MARKER, "cbe.png", "cbe_mine.png", "horizon.png"]
