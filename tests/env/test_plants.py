"""The checkpoint's own plant: a tiny model trained on hydraulic MuJoCo data records its
source; ``compare`` defaults to that plant and refuses another in one line naming both."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import load_dataset
from excavator_surrogate.env.compare import compare
from excavator_surrogate.env.plants import checkpoint_plant, data_source, trained_plant
from excavator_surrogate.errors import CheckpointError, ConfigError
from excavator_surrogate.simulate.config import SimulateConfig
from excavator_surrogate.simulate.generate import simulate_dataset
from excavator_surrogate.spec import EXCAVATOR, JointSpec
from excavator_surrogate.training import train
from tests.helpers.training import tiny_train_config


@pytest.fixture(scope="module")
def hydraulic_ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny surrogate trained for one epoch on a tiny hydraulic-plant dataset."""
    root = tmp_path_factory.mktemp("hyd")
    cfg = SimulateConfig(
        plant="hydraulic",
        n_train=2,
        n_val=1,
        n_test=1,
        steps_train=120,
        steps_val=120,
        steps_test=60,
        workers=1,
    )
    ds = load_dataset(simulate_dataset(cfg, out=root / "data"))
    tcfg = tiny_train_config(epochs=1, seq_batch=2, val_steps=60)
    return train(tcfg, ds, out=root / "model", show_progress=False)


def test_training_records_the_data_source(hydraulic_ckpt: Path) -> None:
    from excavator_surrogate.surrogate.checkpoint import load_checkpoint

    spec = load_checkpoint(hydraulic_ckpt).spec
    assert data_source(spec) == "mujoco-hydraulic"
    assert trained_plant(spec) == "hydraulic"


def test_compare_defaults_to_the_checkpoints_plant(hydraulic_ckpt: Path) -> None:
    res = compare(hydraulic_ckpt, "steps:n_step=12")
    assert res.metrics["run"]["reference"] == "ExcavatorMujoco-v0 (plant=hydraulic)"


def test_compare_refuses_another_plant_in_one_line(
    hydraulic_ckpt: Path, tmp_path: Path, capsys
) -> None:
    with pytest.raises(CheckpointError, match="hydraulic MuJoCo plant.*not on the ideal plant"):
        compare(hydraulic_ckpt, "steps:n_step=12", plant="ideal")
    argv = ["compare", str(hydraulic_ckpt), "--commands", "steps:n_step=12", "--plant", "ideal"]
    assert main([*argv, "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hydraulic" in err[0] and "ideal" in err[0]
    assert not (tmp_path / "c").exists()
    # the checkpoint's own plant, asked for explicitly, is fine
    assert main([*argv[:-1], "hydraulic", "--out", str(tmp_path / "h")]) == 0
    assert "plant=hydraulic" in (tmp_path / "h" / "table.md").read_text()


def test_checkpoint_plant_rules() -> None:
    def with_source(source: str):
        return replace(EXCAVATOR, meta={**EXCAVATOR.meta, "data_source": source})

    # not recorded (older checkpoints): the caller's default or the plant asked for
    assert checkpoint_plant(EXCAVATOR, ckpt="a.pt", default="ideal") == "ideal"
    assert checkpoint_plant(EXCAVATOR, "hydraulic", ckpt="a.pt") == "hydraulic"
    assert (
        checkpoint_plant(with_source("mujoco-ideal"), ckpt="a.pt", default="hydraulic") == "ideal"
    )
    with pytest.raises(CheckpointError, match="ideal MuJoCo plant.*not on the hydraulic plant"):
        checkpoint_plant(with_source("mujoco-ideal"), "hydraulic", ckpt="a.pt")
    # data of another machine (imported logs, mixed sources) never runs against the built-in plant
    for source in ("import", "mujoco-hydraulic+import"):
        with pytest.raises(CheckpointError, match=re.escape(f"trained on '{source}' data")):
            checkpoint_plant(with_source(source), ckpt="a.pt")
    # an imported machine with the same joint names and a non-periodic swing
    joints = (JointSpec("swing", theta_min=-1.0, theta_max=1.0), *EXCAVATOR.joints[1:])
    with pytest.raises(CheckpointError, match="swing' periodic False vs True"):
        checkpoint_plant(replace(EXCAVATOR, joints=joints), ckpt="a.pt")
    with pytest.raises(ConfigError, match="plant must be one of ideal, hydraulic"):
        checkpoint_plant(EXCAVATOR, "stage3", ckpt="a.pt")
