"""``train``'s own free runs (merge, choices, bands) run with ``[train] num_threads`` threads."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from excavator_surrogate.data.dataset import Dataset
from excavator_surrogate.training import api
from excavator_surrogate.training.config import TrainConfig


def test_an_ensembles_work_after_training_runs_with_the_configs_threads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, spec, episodes
) -> None:
    seen: dict[str, int] = {}

    def fake_ensemble(cfg, dataset, *, out, show_progress=None, notes=None) -> Path:
        seen["merge"] = torch.get_num_threads()  # the members train in their own processes
        return Path(out) / "best.pt"

    def fake_calibrate(cfg, dataset, best) -> None:
        seen["bands"] = torch.get_num_threads()

    monkeypatch.setattr(api, "train_ensemble", fake_ensemble)
    monkeypatch.setattr(api, "calibrate_best", fake_calibrate)
    dataset = Dataset(spec=spec, episodes={"train": episodes, "val": episodes})
    prev = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        cfg = TrainConfig(members=2, num_threads=1, static_map=False)
        api.train(cfg, dataset, out=tmp_path / "run")
        assert seen == {"merge": 1, "bands": 1}
        assert torch.get_num_threads() == 2  # the caller's count, restored
        api.train(
            TrainConfig(members=2, num_threads=0, static_map=False), dataset, out=tmp_path / "b"
        )
        assert seen == {"merge": 2, "bands": 2}  # 0: torch's count as it was
    finally:
        torch.set_num_threads(prev)
