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
