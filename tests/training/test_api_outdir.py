"""``train`` follows the output-folder rule: a folder exsur did not write needs ``overwrite``."""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.outdir import MARKER
from excavator_surrogate.training import api
from tests.helpers.training import tiny_dataset, tiny_train_config


def test_train_keeps_a_users_folder_unless_told_to_overwrite(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "config.toml").write_text("my precious notes")
    cfg, ds = tiny_train_config(epochs=1, static_map=False), tiny_dataset(2, n_step=120)
    with pytest.raises(ConfigError, match="'config.toml', which exsur did not write"):
        api.train(cfg, ds, out=out, show_progress=False)
    assert sorted(p.name for p in out.iterdir()) == ["config.toml"]  # no marker either
    assert (out / "config.toml").read_text() == "my precious notes"

    def fake_network(cfg, dataset, *, out, **kw) -> Path:
        return Path(out) / "best.pt"

    monkeypatch.setattr(api, "train_network", fake_network)
    monkeypatch.setattr(api, "calibrate_best", lambda cfg, dataset, best: None)
    assert api.train(cfg, ds, out=out, overwrite=True) == out / "best.pt"
    assert not (out / MARKER).exists()  # the fake wrote nothing


def test_train_refuses_a_dataset_folder_as_out(tmp_path: Path) -> None:
    from excavator_surrogate.io_utils import mark_output

    data = mark_output(tmp_path / "data", "dataset")
    (data / "manifest.json").write_text("{}")
    cfg, ds = tiny_train_config(epochs=1, static_map=False), tiny_dataset(2, n_step=120)
    with pytest.raises(ConfigError, match="is an exsur dataset output"):
        api.train(cfg, ds, out=data, show_progress=False)
