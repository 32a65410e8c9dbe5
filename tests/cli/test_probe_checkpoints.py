"""Issue 25 probe: a checkpoint that loads but cannot be a trained model is refused in one line.

NaN/inf weights or a normalisation no training writes used to be evaluated (rc 0, metrics
null), compared and served by the environments; a model folder given as the checkpoint was
'not found'.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from tests.helpers.cli import fails as _fails

from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.surrogate.checkpoint import load_checkpoint


def _altered(model3: Path, tmp_path: Path, name: str, change) -> Path:
    raw = torch.load(model3 / "best.pt", weights_only=True)
    change(raw)
    path = tmp_path / name
    torch.save(raw, path)
    return path


def _nan_weight(raw: dict) -> None:
    key = next(k for k in raw["state_dict"] if k.endswith("weight_ih_l0"))
    raw["state_dict"][key] = torch.full_like(raw["state_dict"][key], float("nan"))


def _inf_mean(raw: dict) -> None:
    raw["norm"]["y_mean"] = torch.full_like(raw["norm"]["y_mean"], float("inf"))


def _zero_std(raw: dict) -> None:
    raw["norm"]["x_std"] = torch.zeros_like(raw["norm"]["x_std"])


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (_nan_weight, "non-finite weights (rnn.weight_ih_l0)"),
        (_inf_mean, "non-finite normalisation (y_mean)"),
        (_zero_std, "normalisation 'x_std' is not positive"),
    ],
)
def test_a_broken_checkpoint_is_not_evaluated(
    change, said: str, model3: Path, data_dir: Path, tmp_path: Path, capsys
) -> None:
    bad = _altered(model3, tmp_path, "bad.pt", change)
    out = tmp_path / "ev"
    line = _fails(capsys, "evaluate", bad, data_dir / "ds3", "--out", out)
    assert f"{bad}: {said}" in line
    assert not out.exists()
    with pytest.raises(CheckpointError, match="re-train"):
        load_checkpoint(bad)  # the Python API (and so the environments) refuses it too


def test_the_unaltered_checkpoint_still_loads(model3: Path) -> None:
    sur = load_checkpoint(model3 / "best.pt")
    assert all(bool(torch.isfinite(p).all()) for p in sur.net.parameters())


def test_a_model_folder_given_as_the_checkpoint_is_named_as_such(
    model3: Path, data_dir: Path, tmp_path: Path, capsys
) -> None:
    line = _fails(capsys, "evaluate", model3, data_dir / "ds3", "--out", tmp_path / "ev")
    assert f"{model3}: is a folder, not a checkpoint file" in line
    assert str(model3 / "best.pt") in line


def test_no_checkpoint_path_is_a_config_error() -> None:
    from excavator_surrogate.errors import ConfigError

    with pytest.raises(ConfigError, match="a checkpoint path is needed .* got NoneType"):
        load_checkpoint(None)  # e.g. gym.make("ExcavatorSurrogate-v0", ckpt=None)


def test_a_max_steps_below_the_warm_up_says_so(
    model3: Path, data_dir: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "ev"
    argv = ["evaluate", model3 / "best.pt", data_dir / "ds3", "--max-steps", 2, "--out", out]
    line = _fails(capsys, *argv)
    assert line.startswith("exsur: error: episode '") and "has 2 samples after max_steps" in line
    assert "or a larger max_steps" in line
    assert not out.exists()
