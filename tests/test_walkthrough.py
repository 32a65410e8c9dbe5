"""docs/walkthrough.md runs: its python code blocks, in order, in a fresh folder.

The page's code is run verbatim (it uses the ``tiny`` preset and small MPPI sizes and says
how to scale up), so a changed API breaks this test instead of the page's readers.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import pytest

from excavator_surrogate.io_utils import LOGGER_NAME, remove_logging

PAGE = Path(__file__).resolve().parents[1] / "docs" / "walkthrough.md"
BLOCK = re.compile(r"^```python\n(.*?)^```$", re.S | re.M)


def python_blocks(text: str) -> list[str]:
    """The ```python fenced blocks of a Markdown page, in order."""
    return BLOCK.findall(text)


def test_python_blocks_are_found() -> None:
    text = "a\n```python\nx = 1\n```\n```bash\nls\n```\n```python\ny = x\n```\n"
    assert python_blocks(text) == ["x = 1\n", "y = x\n"]


@pytest.fixture
def _restore_logging():
    yield
    remove_logging()
    logging.getLogger(LOGGER_NAME).setLevel(logging.NOTSET)


@pytest.mark.usefixtures("_restore_logging")
def test_the_walkthrough_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    blocks = python_blocks(PAGE.read_text())
    assert len(blocks) >= 6  # logging, simulate, train, evaluate, env, MPPI
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "walkthrough"}
    for i, code in enumerate(blocks):
        exec(compile(code, f"{PAGE.name} block {i + 1}", "exec"), namespace)
    # what the page promises the reader sees
    out, err = capsys.readouterr()
    assert "best checkpoint:" in out and "tracking RMSE per joint" in out
    assert "[exsur] simulate: wrote" in err  # setup_logging shows the progress lines
    assert (tmp_path / "walk" / "model" / "best.pt").is_file()
    assert (tmp_path / "walk" / "eval" / "metrics.json").is_file()
    result = namespace["result"]
    assert result.theta.shape == (40, 4)  # type: ignore[attr-defined]
