"""``exsur train DATASET`` without a preset: the recipe follows the data."""

from __future__ import annotations

import pytest

from excavator_surrogate.data import Dataset
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training.auto import WINDOW, auto_config
from excavator_surrogate.training.batches import split_episodes as _episodes


def _dataset(lengths: list[int]) -> Dataset:
    spec = synthetic_spec(3)
    ds = Dataset(spec=spec)
    for i, n in enumerate(lengths):
        ds.episodes["train"].append(synthetic_episode(spec, kind="step", n_step=n, seed=i))
    ds.episodes["val"].append(synthetic_episode(spec, kind="step", n_step=200, seed=99))
    return ds


def test_short_runs_that_end_at_a_stop_are_all_trained_on():
    # the h1 shape: many runs of 110-2000 samples
    ds = _dataset([110, 115, 150, 300, 600, 2000])
    cfg, why = auto_config(ds, cpus=2)
    assert cfg.window == WINDOW and cfg.burn_in == WINDOW
    assert cfg.seq_len + 1 <= 110
    train_eps, _ = _episodes(cfg, ds)
    assert len(train_eps) == len(ds.train)
    assert any("none is left out" in w for w in why)


def test_long_episodes_use_the_longest_sequence_and_very_short_ones_shrink_the_window():
    cfg, _ = auto_config(_dataset([3000, 3000]), cpus=2)
    assert cfg.seq_len == 150
    cfg, why = auto_config(_dataset([40, 45, 50]), cpus=2)
    assert cfg.window < WINDOW and cfg.seq_len + 1 <= 40
    assert len(_episodes(cfg, _dataset([40, 45, 50]))[0]) == 3
    assert any("shortest runs" in w for w in why)


def test_members_and_budget_follow_the_cpus():
    ds = _dataset([300, 300])
    two, _ = auto_config(ds, cpus=2, budget_s=600)
    one, _ = auto_config(ds, cpus=1, budget_s=600)
    assert (two.members, two.member_workers, two.max_train_seconds) == (4, 2, 300)
    assert (one.members, one.member_workers, one.max_train_seconds) == (2, 1, 300)


def test_overrides_are_strict():
    ds = _dataset([300, 300])
    cfg, why = auto_config(ds, overrides={"members": 1, "seed": 7}, cpus=2)
    assert (cfg.members, cfg.seed) == (1, 7) and "overridden" in why[-1]
    with pytest.raises(ConfigError, match="hiden"):
        auto_config(ds, overrides={"hiden": 3})


def test_no_training_episode_is_a_data_error():
    ds = _dataset([300])
    ds.episodes["train"] = []
    with pytest.raises(DataError, match="no training episodes"):
        auto_config(ds)


def test_recipe_reasons_are_written_next_to_the_config_once(tmp_path):
    import tomllib

    from excavator_surrogate.training import train

    ds = _dataset([120, 130])
    cfg, why = auto_config(ds, overrides={"members": 1, "epochs": 1, "hidden": 8}, cpus=1)
    from excavator_surrogate.training.auto import recipe_table

    train(cfg, ds, out=tmp_path, show_progress=False, notes={"recipe": recipe_table(why)})
    written = tomllib.loads((tmp_path / "config.toml").read_text())
    assert written["train"]["hidden"] == 8 and written["train"]["seq_len"] == cfg.seq_len
    assert written["recipe"] == recipe_table(why) and written["recipe"]
