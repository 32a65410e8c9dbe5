"""What a training run writes besides checkpoints: config.toml's notes."""

from __future__ import annotations

import tomllib

from excavator_surrogate.training.records import update_notes, write_config
from tests.helpers.training import tiny_train_config


def test_update_notes_replaces_only_the_tables_the_run_wrote(tmp_path):
    cfg = tiny_train_config(epochs=2)
    write_config(tmp_path, cfg, notes={"exogenous": {"kept": True, "joints": ["boom"]}})
    path = tmp_path / "config.toml"
    new = {"kept": False, "joints": [], "dropped": ["boom"]}
    assert update_notes(path, {"exogenous": new, "kinds": {"chosen": ["boom"]}})
    back = tomllib.loads(path.read_text())
    assert back["exogenous"] == new and "kinds" not in back  # no table is added
    assert back["train"]["epochs"] == 2
    before = path.read_bytes()
    assert not update_notes(path, {"recipe": {"why": "x"}}) and path.read_bytes() == before
    assert not update_notes(tmp_path / "missing.toml", {"exogenous": new})
    assert not (tmp_path / "missing.toml").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.toml"]  # no temporary left


def test_a_note_outside_the_record_tables_is_refused_before_it_is_written(tmp_path):
    """A record holding a table the preset loader does not know would not load back as
    ``--preset`` (``[kinds]`` and ``[exogenous]`` did not): every note is one of
    ``config.RECORD_TABLES``."""
    import pytest

    with pytest.raises(ValueError, match=r"\[choice\] is not one of config.RECORD_TABLES"):
        write_config(tmp_path, tiny_train_config(), notes={"choice": {"why": "x"}})
    assert not (tmp_path / "config.toml").exists()


def test_a_data_parallel_record_trains_its_model_again_only_with_its_global_batch(
    tmp_path, monkeypatch, capsys
):
    """A DDP run's ``config.toml`` held the per-process ``seq_batch`` and not the number of
    processes, so ``train --preset`` of it in one process trained with half the global batch,
    another model (max weight difference 0.016).  The record now has a ``[parallel]`` table;
    a replay with another process count and the same per-process batch is one line."""
    from dataclasses import replace

    import pytest

    from excavator_surrogate.cli import main
    from excavator_surrogate.errors import ConfigError
    from excavator_surrogate.evaluate.training_report import training_markdown
    from excavator_surrogate.stages import load_preset
    from excavator_surrogate.surrogate.synthetic import synthetic_spec, write_synthetic_dataset
    from excavator_surrogate.training.records import (
        check_parallel_replay,
        parallel_record,
        training_summary,
    )

    cfg = tiny_train_config(mode="stateful", seq_batch=4)
    rec = parallel_record(cfg, 2)
    assert rec == {"world_size": 2, "batch": "seq_batch", "per_rank": 4, "global_batch": 8}
    write_config(tmp_path, cfg, notes={"parallel": rec})
    record = tmp_path / "config.toml"
    preset = load_preset(record)  # still a preset
    assert preset["parallel"] == rec
    message = (
        f"{record}: records a data-parallel run of 2 processes x seq_batch 4 = global batch 8; "
        "1 process would train with global batch 4, another model: launch it on 2 processes "
        "(torchrun --nproc_per_node=2), or give --set train.seq_batch=8"
    )
    with pytest.raises(ConfigError) as e:
        check_parallel_replay(preset, cfg, world_size=1, where=str(record))
    assert str(e.value) == message
    check_parallel_replay(preset, cfg, world_size=2, where="r")  # as recorded
    check_parallel_replay(preset, replace(cfg, seq_batch=8), world_size=1, where="r")  # global 8
    check_parallel_replay(preset, cfg.for_mode("windowed"), world_size=1, where="r")
    # through the CLI: refused before any folder is made
    monkeypatch.delenv("WORLD_SIZE", raising=False)
    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=80
    )
    out = tmp_path / "replay"
    assert main(["train", str(data), "--out", str(out), "--preset", str(record)]) == 2
    assert capsys.readouterr().err.strip() == f"exsur: error: {message}"
    assert not out.exists()
    # best.pt's training record and the reports say it
    summary = training_summary(cfg, epochs_done=3, stopped="planned", budget=1e9, world_size=2)
    assert summary["parallel"] == rec
    assert "parallel" not in training_summary(cfg, epochs_done=3, stopped="planned", budget=1e9)
    assert (
        "Data parallel: 2 processes × seq_batch 4 = global batch 8; its config.toml trains "
        "this model again on 2 processes (or with seq_batch 8 in one, up to rounding)."
    ) in training_markdown(summary)
