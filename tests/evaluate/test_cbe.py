"""``evaluate_checkpoint`` checks its output folder before it loads or scores anything."""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.evaluate import evaluate_checkpoint
from tests.helpers.training import tiny_dataset


def test_evaluate_keeps_a_users_folder(tmp_path: Path) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "table.md").write_text("mine")
    with pytest.raises(ConfigError, match="'table.md', which exsur did not write"):
        evaluate_checkpoint(tmp_path / "missing.pt", tiny_dataset(2), out=out, figure=False)
    assert sorted(p.name for p in out.iterdir()) == ["table.md"]
    assert (out / "table.md").read_text() == "mine"


@pytest.mark.parametrize(
    ("dataset", "out", "line"),
    [(None, "e", "dataset: a path is needed, got NoneType"), ("ds", None, "out: a path is needed")],
    ids=["none-dataset", "none-out"],
)
def test_a_missing_path_is_one_line(tmp_path: Path, dataset, out, line: str) -> None:
    with pytest.raises(ConfigError, match=line):
        evaluate_checkpoint(
            tmp_path / "best.pt", dataset, out=tmp_path / out if out else None, figure=False
        )
    assert list(tmp_path.iterdir()) == []
