"""A refused resume file leaves nothing behind, and another machine's is named as such."""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.surrogate import save_checkpoint
from excavator_surrogate.training import train
from tests.helpers.surrogates import make_surrogate
from tests.helpers.training import tiny_dataset, tiny_train_config


def test_a_bad_resume_file_leaves_no_folder(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint")
    cfg, ds = tiny_train_config(epochs=1, static_map=False), tiny_dataset(2, n_step=120)
    with pytest.raises(CheckpointError, match="garbage.pt: not a readable exsur checkpoint"):
        train(cfg, ds, out=tmp_path / "x", resume=garbage, show_progress=False)
    assert not (tmp_path / "x").exists()  # was: a folder holding only .exsur.json


def test_another_machines_checkpoint_is_named_not_dumped(tmp_path: Path) -> None:
    arm3 = tiny_dataset(3, n_step=120)
    ckpt = save_checkpoint(tmp_path / "arm3.pt", make_surrogate(arm3.spec, arm3.episodes["train"]))
    cfg, ds = tiny_train_config(epochs=1, static_map=False), tiny_dataset(2, n_step=120)
    with pytest.raises(
        CheckpointError, match=r"arm3.pt: the checkpoint does not fit .*joints"
    ) as e:
        train(cfg, ds, out=tmp_path / "y", resume=ckpt, show_progress=False)
    assert "architecture" not in str(e.value)  # was: both architecture dicts, "same window..."
    assert not (tmp_path / "y").exists()
