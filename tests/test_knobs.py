"""One way to set a knob: --set SECTION.KEY=VALUE, stage_config, exsur config show."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.config import field_docs, load_preset, parse_sets, stage_config
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.stages import STAGE_NAMES, build_configs
from excavator_surrogate.training import TrainConfig


def test_parse_sets_nests_and_reads_toml_values() -> None:
    got = parse_sets(
        [
            "train.lr=3e-4",
            "train.play=[0.02, 0.05]",
            "train.device=cuda",
            "train.tensorboard=false",
            "simulate.hydraulics.drift=true",
        ]
    )
    assert got == {
        "train": {"lr": 3e-4, "play": [0.02, 0.05], "device": "cuda", "tensorboard": False},
        "simulate": {"hydraulics": {"drift": True}},
    }
    for bad in ("lr=3", "train.=1", "train.lr"):
        with pytest.raises(ConfigError, match="SECTION.KEY=VALUE"):
            parse_sets([bad])
    with pytest.raises(ConfigError, match=r"reads only \[train\]"):
        parse_sets(["simulate.n_train=3"], sections=("train",))


def test_stage_config_applies_overrides_through_the_strict_parser() -> None:
    preset = {"train": {"mode": "stateful", "seq_len": 60, "lr": 1e-3}}
    cfg = stage_config(TrainConfig, preset, "train", overrides={"lr": 3e-4, "epochs": None})
    assert (cfg.lr, cfg.seq_len, cfg.epochs) == (3e-4, 60, TrainConfig().epochs)
    with pytest.raises(ConfigError, match=r"preset 'x' \[train\]\.lr: expected a number"):
        stage_config(TrainConfig, preset, "train", overrides={"lr": "fast"}, where="preset 'x'")
    with pytest.raises(ConfigError, match="unknown key"):
        stage_config(TrainConfig, preset, "train", overrides={"lrr": 1.0})
    # nested tables merge key by key
    sim = build_configs(
        load_preset("quick-compound"),
        sections=("simulate",),
        overrides={"simulate": {"hydraulics": {"drift": False}}},
    )["simulate"]
    assert sim.hydraulics.drift is False and sim.soil.enabled is True
    with pytest.raises(ConfigError, match=r"no \[train\] table here"):
        build_configs({}, sections=("simulate",), overrides={"train": {"lr": 1.0}})


def test_every_shipped_preset_resolves_and_reads_every_train_knob_it_sets() -> None:
    from excavator_surrogate.config import preset_names

    for name in preset_names():
        preset = load_preset(name)
        cfgs = build_configs(preset, where=f"preset '{name}'")
        unread = set(cfgs["train"].unread_fields())
        assert unread and not unread & set(preset.get("train", {})), name


def test_config_show_prints_resolved_toml_with_field_docs(capsys) -> None:
    assert main(["config", "show", "paper-compound", "--set", "train.lr=3e-4"]) == 0
    text = capsys.readouterr().out
    tables = tomllib.loads(text)
    assert list(tables) == list(STAGE_NAMES)
    assert tables["train"]["lr"] == 3e-4 and tables["train"]["mode"] == "stateful"
    assert "horizon" not in tables["train"]  # not read by the stateful mode: commented out
    assert "# horizon = 1  (not read in this configuration)" in text
    for doc in field_docs(TrainConfig).values():
        assert doc.split()[0] in text
    assert "# Adam learning rate." in text
    assert main(["config", "show", "tiny", "--section", "train", "--set", "train.horizon=4"]) == 2
    assert 'horizon is read only by mode = "windowed"' in capsys.readouterr().err


def test_set_reaches_training_and_named_flags_win(tmp_path: Path, capsys) -> None:
    from excavator_surrogate.surrogate.synthetic import synthetic_spec, write_synthetic_dataset

    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=120
    )
    argv = ["train", str(data), "--out", str(tmp_path / "m"), "--preset", "tiny"]
    sets = ["--set", "train.lr=2e-3", "--set", "train.epochs=5", "--set", "train.tensorboard=false"]
    assert main([*argv, *sets, "--epochs", "1"]) == 0
    rec = tomllib.loads((tmp_path / "m" / "config.toml").read_text())["train"]
    assert (rec["lr"], rec["epochs"], rec["tensorboard"]) == (2e-3, 1, False)
    assert main([*argv, "--set", "train.nope=1"]) == 2
    assert "unknown key(s) ['nope']" in capsys.readouterr().err
