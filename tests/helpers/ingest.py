"""Helpers of the import tests (logs of the 3-joint test arm, nothing-written checks)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from . import arm3_plant


def assert_nothing_written(out: Path) -> None:
    """``out`` does not exist and no temporary sibling was left behind."""
    assert not out.exists(), f"{out} was written"
    leftovers = [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]
    assert not leftovers, f"temporary files left behind: {leftovers}"


def write_lines(
    path: Path,
    cols: dict[str, np.ndarray],
    edit: Callable[[list[str]], list[str]] | None = None,
    columns: tuple[str, ...] = arm3_plant.LOG_COLUMNS,
) -> Path:
    """Write a CSV log, optionally editing its text lines (line 0 is the header)."""
    arm3_plant.write_csv(path, cols, columns=columns)
    if edit is not None:
        lines = path.read_text().splitlines()
        path.write_text("\n".join(edit(lines)) + "\n")
    return path


def set_cell(lines: list[str], row: int, col: str, value: str) -> list[str]:
    """Replace the cell of data row ``row`` (0-based) in column ``col`` of CSV text lines."""
    header = lines[0].split(",")
    cells = lines[row + 1].split(",")
    cells[header.index(col)] = value
    lines[row + 1] = ",".join(cells)
    return lines


def import_fails(
    cli: Callable[..., tuple[int, str, str]], log: Path, mapping: Path, out: Path, *extra: str
) -> str:
    """``exsur import LOG --mapping MAPPING --out OUT --quiet EXTRA...`` fails as a user error
    should: exit code 2, one line on stderr, nothing written; returns that line."""
    rc, _, err = cli("import", log, "--mapping", mapping, "--out", out, "--quiet", *extra)
    assert rc == 2, err
    assert err.startswith("exsur: error: ") and err.count("\n") == 1, err
    assert_nothing_written(out)
    return err
