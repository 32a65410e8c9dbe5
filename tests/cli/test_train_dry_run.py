"""``exsur train DATASET --dry-run``: the plan, printed before anything is trained or written."""

from __future__ import annotations

import tomllib
from pathlib import Path

from excavator_surrogate.cli import main
from excavator_surrogate.config import from_dict
from excavator_surrogate.data.dataset import load_dataset
from excavator_surrogate.training.auto import auto_config
from excavator_surrogate.training.config import TrainConfig


def _train_table(text: str) -> dict:
    return tomllib.loads(text[text.index("[train]") :])["train"]


def test_the_dry_run_prints_the_recipes_plan_and_writes_nothing(
    data_dir: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "never"
    assert main(["train", str(data_dir / "ds3"), "--dry-run", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert not out.exists()
    assert text.startswith("data: 2 train episode(s), 0.2 min; 1 val episode(s)")
    assert "recipe (docs/real.md):" in text and "  - window " in text
    assert "planned work (the reference machine's time; nothing is trained):" in text
    assert "training(s)" in text and "round(s)" in text and "capped at" in text
    # the [train] table is the config a training of the same command would use
    cfg, _ = auto_config(load_dataset(data_dir / "ds3", splits=("train", "val")))
    assert from_dict(TrainConfig, _train_table(text), where="[train]") == cfg


def test_a_presets_dry_run_is_the_config_its_training_records(
    data_dir: Path, model3: Path, capsys
) -> None:
    """``model3`` was trained with the tiny preset and ``--epochs 1``: the dry run of the same
    command prints the ``[train]`` table its ``config.toml`` holds."""
    argv = ["train", str(data_dir / "ds3"), "--preset", str(data_dir / "tiny.toml")]
    assert main([*argv, "--epochs", "1", "--dry-run", "-q"]) == 0  # -q keeps what it shows
    text = capsys.readouterr().out
    assert f"preset: {data_dir / 'tiny.toml'}" in text and "recipe" not in text
    assert "1 training(s)" in text and "1 epochs of" in text
    recorded = tomllib.loads((model3 / "config.toml").read_text())["train"]
    assert _train_table(text) == recorded


def test_training_without_out_is_one_line(data_dir: Path, capsys) -> None:
    assert main(["train", str(data_dir / "ds3")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "exsur: error: --out DIR is required (or --dry-run to only print the plan)"


def test_a_training_logs_its_planned_work_first(data_dir: Path, tmp_path: Path, capsys) -> None:
    argv = ["train", str(data_dir / "ds3"), "--preset", str(data_dir / "tiny.toml")]
    assert main([*argv, "--epochs", "1", "--out", str(tmp_path / "m")]) == 0
    err = capsys.readouterr().err
    planned = [ln for ln in err.splitlines() if "planned work: " in ln]
    assert len(planned) == 3 and "1 training(s) (1 plain member(s))" in planned[0]
    # and last, how fast this computer trained it (a tiny network: no reference time)
    assert "Time on this computer: 1 network(s), 1 epochs in all; their training steps took" in err
    assert err.index("planned work: ") < err.index("epoch 0")
