"""A bad value in a preset names the file that set it: ``Preset.origins`` through every
``extends``, and ``origin_hint`` on the errors of ``stage_config``."""

from __future__ import annotations

import copy
import pickle
from collections.abc import Callable
from pathlib import Path

import pytest

from excavator_surrogate.config import Preset, origin_hint, stage_config
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.stages import build_configs, load_preset
from excavator_surrogate.training import TrainConfig


@pytest.fixture
def chain(tmp_path: Path) -> Path:
    """``c.toml`` extends ``b.toml`` (epochs = -3), which extends the shipped ``tiny``."""
    (tmp_path / "b.toml").write_text('extends = "tiny"\n[train]\nepochs = -3\n')
    (tmp_path / "c.toml").write_text(
        f'extends = "{(tmp_path / "b.toml").as_posix()}"\n[train]\nlr = 0.01\n'
    )
    return tmp_path


def test_origins_follow_the_file_that_set_each_key_last(chain: Path) -> None:
    preset = load_preset(chain / "c.toml")
    assert isinstance(preset, Preset)
    assert preset.origins["train.lr"] == str(chain / "c.toml")
    assert preset.origins["train.epochs"] == str(chain / "b.toml")
    # a key of the shipped base that no file overrides
    shipped = {k for k, v in preset.origins.items() if v == "preset 'tiny'"}
    assert shipped and all(k.split(".")[0] in preset for k in shipped)
    assert preset["train"]["epochs"] == -3 and preset["train"]["lr"] == 0.01
    assert preset["name"] == "c"


def test_a_bad_value_names_the_extended_file_that_set_it(chain: Path) -> None:
    with pytest.raises(ConfigError) as e:
        build_configs(load_preset(chain / "c.toml"), sections=["train"], where="preset 'c'")
    msg = str(e.value)
    assert msg.startswith("[train] epochs must be >= 1")
    assert msg.endswith(f"(train.epochs: from {chain / 'b.toml'})")
    assert "c.toml" not in msg


def test_a_value_of_the_wrong_type_names_its_file(tmp_path: Path) -> None:
    (tmp_path / "a.toml").write_text('name = "mine"\n[train]\nepochs = "x"\n')
    with pytest.raises(
        ConfigError, match=r"expected an integer, got 'x' \(train\.epochs: from .*a\.toml\)$"
    ):
        build_configs(load_preset(tmp_path / "a.toml"), sections=["train"], where="preset 'mine'")


def test_an_override_is_named_as_such_and_wins_over_the_file(chain: Path) -> None:
    preset = load_preset(chain / "c.toml")
    with pytest.raises(ConfigError) as e:
        build_configs(preset, sections=["train"], overrides={"train": {"epochs": 0}})
    assert str(e.value).endswith("(train.epochs: from --set or a flag)")


def test_a_check_across_keys_names_each_keys_source(chain: Path) -> None:
    preset = load_preset(chain / "c.toml")
    over = {"train": {"epochs": 5, "seq_len": 2, "burn_in": 4}}
    with pytest.raises(ConfigError) as e:
        build_configs(preset, sections=["train"], overrides=over)
    assert str(e.value) == (
        "[train] seq_len must exceed burn_in (train.seq_len, train.burn_in: from --set or a flag)"
    )


def test_a_message_that_names_no_key_gets_the_tables_sources() -> None:
    hint = origin_hint(
        "[train] batch sizes must be >= 1",
        "train",
        {"batch_size": 0, "lr": 0.1},
        {"lr": 0.1},
        {"train.batch_size": "my.toml"},
    )
    assert hint == " ([train]: from my.toml and --set or a flag)"


def test_no_hint_without_a_known_source() -> None:
    assert origin_hint("[train] epochs must be >= 1", "train", {"epochs": 0}, {}, {}) == ""
    # a plain dict preset: the message as before
    with pytest.raises(ConfigError) as e:
        stage_config(TrainConfig, {"train": {"epochs": 0}}, "train")
    assert str(e.value) == "[train] epochs must be >= 1"


def test_a_preset_copies_and_pickles_with_its_origins(chain: Path) -> None:
    preset = load_preset(chain / "c.toml")
    for again in (copy.deepcopy(preset), pickle.loads(pickle.dumps(preset))):
        assert again == preset and again.origins == preset.origins


def test_the_cli_names_the_file(chain: Path, cli: Callable[..., tuple[int, str, str]]) -> None:
    rc, _, err = cli("run", "--preset", chain / "c.toml", "--dry-run")
    assert rc != 0
    assert err.strip().splitlines()[-1] == (
        f"exsur: error: [train] epochs must be >= 1 (train.epochs: from {chain / 'b.toml'})"
    )
