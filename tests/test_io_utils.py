"""recorded_path: paths written into an output folder (relative inside it, absolute outside)."""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.io_utils import recorded_path


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
