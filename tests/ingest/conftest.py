"""Fixtures for the import tests: logs of the independent 3-joint test arm and CLI helpers."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import arm3_plant


@pytest.fixture(scope="session")
def arm3_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Folder with logs/run01.csv, run02.csv, run03.csv, run04.csv.gz (30 s each) and arm3.toml."""
    root = tmp_path_factory.mktemp("arm3")
    for i in range(4):
        name = f"run{i + 1:02d}.csv" + (".gz" if i == 3 else "")
        arm3_plant.write_csv(root / "logs" / name, arm3_plant.simulate(duration_s=30.0, seed=i))
    (root / "arm3.toml").write_text(arm3_plant.MAPPING_TOML)
    return root


@pytest.fixture(scope="session")
def short_cols() -> dict[str, np.ndarray]:
    """Columns of a 10 s log (1000 rows at 100 Hz)."""
    return arm3_plant.simulate(duration_s=10.0, seed=7)


@pytest.fixture
def work(tmp_path: Path, arm3_dir: Path) -> Path:
    """A scratch folder holding a copy of arm3.toml."""
    shutil.copy(arm3_dir / "arm3.toml", tmp_path / "arm3.toml")
    return tmp_path
