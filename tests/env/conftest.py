"""Fixtures for the environment tests: tiny untrained checkpoints (no training needed)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.model import Surrogate
from shared_helpers import tiny_surrogate


@pytest.fixture(scope="session")
def make_surrogate() -> Callable[..., Surrogate]:
    """Factory of tiny untrained surrogates (see :func:`tiny_surrogate`)."""
    return tiny_surrogate


@pytest.fixture(scope="session")
def ckpt_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("ckpt")


@pytest.fixture(scope="session")
def stateful_ckpt(ckpt_dir: Path) -> Path:
    """Path of a tiny stateful LSTM checkpoint."""
    return save_checkpoint(ckpt_dir / "stateful.pt", tiny_surrogate(mode="stateful"))


@pytest.fixture(scope="session")
def windowed_ckpt(ckpt_dir: Path) -> Path:
    """Path of a tiny windowed LSTM checkpoint."""
    return save_checkpoint(ckpt_dir / "windowed.pt", tiny_surrogate(mode="windowed", seed=1))
