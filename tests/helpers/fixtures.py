"""Fixtures of tiny synthetic machines and episodes (imported by the conftest.py files that use them)."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.data import Episode
from excavator_surrogate.spec import MachineSpec
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec


@pytest.fixture(params=[2, 4], ids=["2j", "4j"])
def spec(request: pytest.FixtureRequest) -> MachineSpec:
    return synthetic_spec(request.param, periodic_first=True)


@pytest.fixture
def episodes(spec: MachineSpec) -> list[Episode]:
    return [
        synthetic_episode(spec, kind=k, n_step=n, seed=s)
        for k, n, s in (("sine", 80, 1), ("step", 64, 2), ("sine", 71, 3))
    ]


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)
