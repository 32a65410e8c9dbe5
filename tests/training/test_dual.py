"""Exogenous inputs chosen on networks that learned both ways: ``input_dropout`` (dual.py)."""

from __future__ import annotations

import csv
import tomllib
from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, read_checkpoint
from excavator_surrogate.training import train
from excavator_surrogate.training.batches import make_data
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.dual import blinded
from excavator_surrogate.training.modes import make_mode
from tests.helpers.training import tiny_train_config
from tests.training.test_variants import (
    _cfg,
    _dataset,
    _dataset2,
    _episode2,
    _gear_effect,
    _omega,
)


def _gear_effect_of(sur) -> float:
    """Largest change of ``sur``'s predicted omega when the gear column is flipped."""
    ep = _episode2(7)
    return float((_omega(sur, ep) - _omega(sur, ep, flip_gear=True)).abs().max())


def test_input_dropout_is_checked():
    with pytest.raises(ConfigError, match=r"input_dropout = 1.0 must be in \[0, 1\)"):
        tiny_train_config(input_dropout=1.0)
    with pytest.raises(ConfigError, match='set feedback = "teacher"'):
        tiny_train_config(input_dropout=0.5, feedback="free")
    with pytest.raises(ConfigError, match='read only by mode = "stateful"'):
        TrainConfig(mode="windowed", input_dropout=0.5)


def test_blanked_sub_sequences_see_the_inputs_at_their_training_mean(tmp_path):
    """A drawn share of the sub-sequences has the gear's feature at 0 (what a network with its
    input weights of it zeroed sees) over every step; the other features, and the other
    sub-sequences, are the data's; the draw is the seed's, epoch's and start's."""
    ds = _dataset2()
    cfg = _cfg(exogenous="use", input_dropout=0.5, seq_batch=64)
    best = train(replace(cfg, epochs=1, patience=1), ds, out=tmp_path / "m", show_progress=False)
    sur = load_checkpoint(best)
    data = make_data(ds.train, sur.norm, torch.device("cpu"))
    mode = make_mode(cfg, data, sur)
    index = np.arange(0, 640, 10)
    g = torch.as_tensor(index)[:, None] + torch.arange(cfg.seq_len)
    x = data.x[g]
    got = mode._blanked(x, index, 3)
    col = sur.spec.n_feature - 1  # the gear's feature column
    off = (got[..., col] == 0).all(dim=1) & (x[..., col] != 0).any(dim=1)
    assert 0.25 < float(off.float().mean()) < 0.75
    torch.testing.assert_close(got[~off], x[~off], rtol=0, atol=0)
    keep = [c for c in range(x.shape[-1]) if c != col]
    torch.testing.assert_close(got[..., keep], x[..., keep], rtol=0, atol=0)
    torch.testing.assert_close(mode._blanked(x, index, 3), got, rtol=0, atol=0)
    assert not torch.equal(mode._blanked(x, index, 4), got)  # another epoch, another draw
    none = make_mode(_cfg(exogenous="use"), data, sur)
    assert none._blanked(x, index, 3) is x


def test_blinded_cannot_depend_on_the_inputs(tmp_path):
    ds = _dataset2()
    best = train(
        _cfg(exogenous="use", input_dropout=0.5), ds, out=tmp_path / "m", show_progress=False
    )
    sur = load_checkpoint(best)
    blind = blinded(sur)
    assert _gear_effect_of(sur) > 1e-3 and _gear_effect_of(blind) == 0.0
    w, w0 = blind.net.rnn.weight_ih_l0, sur.net.rnn.weight_ih_l0
    assert torch.count_nonzero(w[:, -1]) == 0 and torch.count_nonzero(w0[:, -1]) > 0
    torch.testing.assert_close(w[:, :-1], w0[:, :-1], rtol=0, atol=0)  # a copy: sur untouched


@pytest.mark.parametrize("informative", [True, False])
def test_dual_choice_keeps_an_informative_input_and_ignores_a_noise_one(tmp_path, informative):
    ds = _dataset(informative=informative)
    cfg = _cfg(exogenous="choose", input_dropout=0.5, members=2, member_workers=1)
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    ck = read_checkpoint(best)
    record = ck["metrics"]["training"]["exogenous"]
    assert record["dual"] is True and record["kept"] is informative, record["why"]
    way = "use" if informative else "ignore"
    assert ck["train_config"]["exogenous"] == way and ck["train_config"]["members"] == 2
    assert (_gear_effect(best) > 1e-3) is informative
    # every network trained both ways into the ensemble's folders: none lost the choice
    for i in range(2):
        net = load_checkpoint(tmp_path / "m" / f"member_{i}" / "best.pt")
        assert net.train_config["input_dropout"] == 0.5 and net.train_config["exogenous"] == "use"
    assert not (tmp_path / "m" / "use").exists() and not (tmp_path / "m" / "ignore").exists()
    rows = list(csv.DictReader((tmp_path / "m" / "log.csv").open()))
    assert [r["exogenous"] for r in rows] == [way, way, way]
    notes = tomllib.loads((tmp_path / "m" / "config.toml").read_text())
    assert notes["exogenous"]["kept"] is informative and notes["exogenous"]["dual"] is True


def test_dual_choice_gives_the_inputs_to_the_joints_they_help(tmp_path, monkeypatch):
    """The whole ``use`` way refused (forced here); the boom takes the gear alone: each
    network with the gear on the boom and without it (blinded) on the arm, averaged."""
    from excavator_surrogate.training import input_choice

    calls: list = []

    def rule(use, ignore):  # the whole way refused, the sets judged as usual
        calls.append(use)
        return (False, "refused (test)") if len(calls) == 1 else (True, "kept")

    # the choice's rule, for the whole way and the joint sets (input_choice.decide_inputs)
    monkeypatch.setattr(input_choice, "choose_inputs", rule)
    monkeypatch.setattr(input_choice, "input_joints", lambda use, ignore: [True, False])
    ds = _dataset2()
    cfg = _cfg(exogenous="choose", input_dropout=0.5, members=2, member_workers=1)
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    ck = read_checkpoint(best)
    record = ck["metrics"]["training"]["exogenous"]
    assert record["kept"] and record["per_joint"] and record["joints"] == ["boom"]
    assert ck["train_config"]["exogenous"] == "use"
    rows = list(csv.DictReader((tmp_path / "m" / "log.csv").open()))
    assert [r["exogenous"] for r in rows] == ["per joint"] * 3
    model = load_checkpoint(best)
    nets = [load_checkpoint(tmp_path / "m" / f"member_{i}" / "best.pt") for i in range(2)]
    ep = _episode2(9)
    want = torch.stack(
        [
            torch.stack([_omega(n, ep)[:, 0] for n in nets]).mean(0),
            torch.stack([_omega(blinded(n), ep)[:, 1] for n in nets]).mean(0),
        ],
        dim=-1,
    )
    torch.testing.assert_close(_omega(model, ep), want, rtol=1e-4, atol=1e-5)


def test_dual_choice_with_the_kind_choice(tmp_path):
    """The map-correcting networks learn both ways beside the plain ones and follow the
    chosen way; the kind choice runs on them."""
    ds = _dataset(informative=True)
    cfg = _cfg(
        exogenous="choose", input_dropout=0.5, prior_choice=True, members=2, member_workers=1
    )
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    training = read_checkpoint(best)["metrics"]["training"]
    assert training["exogenous"]["dual"] is True and "chosen" in training["kinds"]
    for d in ("plain/member_0", "plain/member_1", "prior/member_0"):
        net = load_checkpoint(tmp_path / "m" / d / "best.pt")
        assert net.train_config["input_dropout"] == 0.5
    assert load_checkpoint(tmp_path / "m" / "prior" / "member_0" / "best.pt").net.prior is not None
    kept = training["exogenous"]["kept"]
    assert (_gear_effect(best) > 1e-3) is kept, training["exogenous"]["why"]
