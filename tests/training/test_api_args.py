"""``train``'s arguments: a dataset folder works; a wrong type is one ConfigError line."""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.data.dataset import write_dataset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.training import api
from tests.helpers.training import tiny_dataset, tiny_train_config


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (({"epochs": 1}, "ds", "x"), "cfg: a TrainConfig is needed, got dict; build one with"),
        ((None, "ds", None), "out: a path is needed, got NoneType"),
        ((None, 5, "x"), "dataset: a path is needed, got int"),
    ],
    ids=["dict-config", "none-out", "int-dataset"],
)
def test_wrong_types_are_one_line(tmp_path: Path, args: tuple, line: str) -> None:
    cfg, dataset, out = args
    cfg = tiny_train_config() if cfg is None else cfg
    with pytest.raises(ConfigError, match=line):
        api.train(cfg, dataset, out=tmp_path / out if out else None)
    assert list(tmp_path.iterdir()) == []


def test_a_dataset_folder_is_loaded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ds = tiny_dataset(2, n_step=120)
    items = [(e, s) for s, eps in ds.episodes.items() for e in eps]
    write_dataset(tmp_path / "ds", items)
    seen = {}

    def fake_network(cfg, dataset, *, out, **kw) -> Path:
        seen["n_train"] = len(dataset.episodes["train"])
        return Path(out) / "best.pt"

    monkeypatch.setattr(api, "train_network", fake_network)
    monkeypatch.setattr(api, "calibrate_best", lambda cfg, dataset, best: None)
    cfg = tiny_train_config(epochs=1, static_map=False)
    assert api.train(cfg, str(tmp_path / "ds"), out=tmp_path / "m") == tmp_path / "m" / "best.pt"
    assert seen == {"n_train": len(ds.episodes["train"])}
