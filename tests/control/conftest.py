"""Fixtures for the control tests: tiny untrained surrogates and their checkpoints."""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from tests.helpers.surrogates import tiny_surrogate


@pytest.fixture(scope="session")
def tiny_ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Path of a tiny untrained stateful LSTM checkpoint of the excavator."""
    return save_checkpoint(tmp_path_factory.mktemp("ctl") / "tiny.pt", tiny_surrogate())
