"""Checkpoint round trip with weights_only=True; corrupt/missing/incompatible files."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.surrogate import load_checkpoint, rollout, save_checkpoint
from excavator_surrogate.surrogate.checkpoint import checkpoint_dict
from tests.helpers.surrogates import make_surrogate


@pytest.mark.parametrize("cell", ["lstm", "gru", "arx"])
def test_round_trip_weights_only(tmp_path, spec, episodes, cell):
    mode = "windowed" if cell == "arx" else "stateful"
    sur = make_surrogate(spec, episodes, cell=cell, mode=mode, window=5)
    sur.metrics = {"val_error": 0.5}
    path = save_checkpoint(tmp_path / "m.pt", sur, history=[{"epoch": 0, "val_error": 0.5}])
    raw = torch.load(path, weights_only=True)  # plain types only
    assert raw["format"] == "exsur-surrogate" and raw["spec"]["joints"][0]["name"] == spec.names[0]
    back = load_checkpoint(path)
    assert back.mode == mode and back.spec == spec and back.model_cfg == sur.model_cfg
    assert back.metrics == {"val_error": 0.5}
    ep = episodes[0]
    a = rollout(sur, ep.theta[None, :30], ep.u[None, :30])
    b = rollout(back, ep.theta[None, :30], ep.u[None, :30])
    np.testing.assert_array_equal(a[0], b[0])


def test_missing_and_corrupt_checkpoints(tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        load_checkpoint(tmp_path / "nope.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"this is not a torch file")
    with pytest.raises(CheckpointError, match="not a readable") as ei:
        load_checkpoint(bad)
    assert "\n" not in str(ei.value)
    other = tmp_path / "other.pt"
    torch.save({"model": {}}, other)
    with pytest.raises(CheckpointError, match="not an exsur"):
        load_checkpoint(other)


def test_truncated_and_incompatible_checkpoints(tmp_path, spec, episodes):
    sur = make_surrogate(spec, episodes)
    good = save_checkpoint(tmp_path / "good.pt", sur)
    trunc = tmp_path / "trunc.pt"
    trunc.write_bytes(good.read_bytes()[:300])
    with pytest.raises(CheckpointError):
        load_checkpoint(trunc)
    ck = checkpoint_dict(sur)
    ck["format_version"] = 99
    torch.save(ck, tmp_path / "v99.pt")
    with pytest.raises(CheckpointError, match="format_version"):
        load_checkpoint(tmp_path / "v99.pt")
    ck = checkpoint_dict(sur)
    ck["model"]["hidden"] = 7
    torch.save(ck, tmp_path / "shape.pt")
    with pytest.raises(CheckpointError, match="do not fit"):
        load_checkpoint(tmp_path / "shape.pt")
    ck = checkpoint_dict(sur)
    ck["evil"] = np.zeros(3)  # a pickled non-tensor object is refused by weights_only
    torch.save(ck, tmp_path / "pickle.pt")
    with pytest.raises(CheckpointError, match="not a readable"):
        load_checkpoint(tmp_path / "pickle.pt")


def test_equal_content_gives_equal_bytes(tmp_path, spec, episodes):
    """Pickle writes a string it has seen as a reference to the first: a config default
    shared by two entries, and the same string read back from TOML or ``last.pt`` (two
    objects), gave ``best.pt`` files of equal content but other bytes (a replayed or resumed
    run failed a sha256 check).  The tensors are written unchanged."""
    from excavator_surrogate.surrogate.checkpoint import read_checkpoint, write_checkpoint_dict

    sur = make_surrogate(spec, episodes, mode="stateful", window=5)
    shared = checkpoint_dict(sur)
    word = "spanned"
    shared["train_config"].update(prior_drive=word, note=word)  # one object, twice
    apart = checkpoint_dict(sur)
    apart["train_config"].update(prior_drive="".join(["span", "ned"]), note="span" + "ned")
    a = write_checkpoint_dict(tmp_path / "a.pt", shared)
    b = write_checkpoint_dict(tmp_path / "b.pt", apart)
    assert a.read_bytes() == b.read_bytes()
    back = read_checkpoint(a)["state_dict"]
    for k, v in sur.net.state_dict().items():
        assert torch.equal(back[k], v), k
