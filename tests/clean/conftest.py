"""Fixtures for the cleaning-stage tests: synthetic excavator motion through the sensor model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.clean.synthetic import noisy_batch, synthetic_episode
from excavator_surrogate.data import Episode, write_dataset
from excavator_surrogate.simulate.sensors import SensorConfig
from excavator_surrogate.spec import excavator_spec


@pytest.fixture(scope="session")
def make_batch():
    """``make_batch(n_batch, n_step, n_joint, dt=, seed=, sensor=None)`` -> dict of (n_batch, n_step, n_joint) arrays."""
    return noisy_batch


@pytest.fixture
def heavy_faults() -> SensorConfig:
    """Many and long offsets, so the lock-out guard fires."""
    return SensorConfig(offset_rate=0.25, offset_max_s=4.0, spike_rate=0.2)


@pytest.fixture
def noisy_episode() -> Episode:
    """A 4-joint, 20 Hz, 60 s episode with truth and the jump mask."""
    return synthetic_episode(
        1200, spec=excavator_spec(20.0), rng=np.random.default_rng(3), sensor=SensorConfig()
    )


@pytest.fixture
def noisy_dataset(tmp_path: Path) -> Path:
    """A small dataset folder with train/val/test episodes of different lengths."""
    spec = excavator_spec(20.0)
    rng = np.random.default_rng(4)
    items = [
        (synthetic_episode(n, spec=spec, rng=rng, sensor=SensorConfig(), name=f"ep{i}"), split)
        for i, (n, split) in enumerate(
            [(900, "train"), (700, "train"), (600, "val"), (500, "test")]
        )
    ]
    return write_dataset(tmp_path / "raw", items, config={"simulate": {"seed": 4}})
