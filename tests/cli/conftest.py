"""Fixtures for the CLI reliability tests: tiny synthetic datasets and one trained checkpoint."""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import write_dataset
from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split

TINY_TRAIN = (
    "[train]\nwindow = 6\nhidden = 8\nhead_hidden = 8\ntensorboard = false\n"
    'seq_len = 40\nburn_in = 6\ntbptt = 10\nmode = "stateful"\n'
)


def _dataset(root: Path, n_joint: int, rate_hz: float = 20.0) -> Path:
    spec = synthetic_spec(n_joint, rate_hz=rate_hz)
    items = synthetic_split(spec, n_train=2, n_val=1, n_test=1, n_step=120, noise=0.001)
    return write_dataset(root, items)


@pytest.fixture(scope="session")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Folder with ds3 (3 joints, 20 Hz), ds3_10hz (10 Hz), ds4 (4 joints) and tiny.toml."""
    root = tmp_path_factory.mktemp("data")
    _dataset(root / "ds3", 3)
    _dataset(root / "ds3_10hz", 3, rate_hz=10.0)
    _dataset(root / "ds4", 4)
    (root / "tiny.toml").write_text(TINY_TRAIN)
    return root


@pytest.fixture(scope="session")
def model3(data_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3-joint 20 Hz model folder (best.pt, last.pt) trained for one epoch."""
    out = tmp_path_factory.mktemp("m") / "m3"
    argv = ["train", data_dir / "ds3", "--out", out, "--preset", data_dir / "tiny.toml"]
    assert main([str(a) for a in [*argv, "--epochs", "1"]]) == 0
    return out
