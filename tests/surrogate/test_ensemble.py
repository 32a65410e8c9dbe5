"""Seed ensembles: the merged network equals its members averaged step by step."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.cli import main
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate import free_run_error, rollout, rollout_reference
from excavator_surrogate.surrogate.angles import joint_limits
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, save_checkpoint
from excavator_surrogate.surrogate.ensemble import merge, n_member
from excavator_surrogate.training import member_configs, train
from tests.helpers.surrogates import make_surrogate
from tests.helpers.training import tiny_dataset, tiny_train_config

PLAY = (0.05, 0.2)


def _members(spec, episodes, *, cell="lstm", mode="stateful", drive=0.0):
    """Three members with different seeds, widths and normalisations (fitted on different
    episodes), with play features and end stops."""
    kw = dict(cell=cell, mode=mode, window=5, play=PLAY, end_stops=True, drive=drive)
    return [
        make_surrogate(spec, episodes[:2], seed=0, hidden=12, **kw),
        make_surrogate(spec, episodes[1:], seed=1, hidden=7, **kw),
        make_surrogate(spec, episodes, seed=2, hidden=12, **kw),
    ]


@pytest.mark.parametrize(
    ("cell", "mode"),
    [("lstm", "stateful"), ("gru", "stateful"), ("lstm", "windowed"), ("gru", "windowed")],
)
def test_merged_rollout_equals_the_members_averaged_in_a_plain_loop(spec, episodes, cell, mode):
    members = _members(spec, episodes, cell=cell, mode=mode, drive=6.0)
    ens = merge(members)
    assert ens.model_cfg.hidden == 31 and ens.model_cfg.head_hidden == 31
    assert n_member(ens) == 3 and n_member(members[0]) == 1
    n = 60
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_b, om_b = rollout(ens, theta, u)
    for i in range(len(episodes)):
        th_r, om_r = rollout_reference(members, theta[i], u[i])
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5)
        np.testing.assert_allclose(om_b[i], om_r, atol=1e-4)
    # driven into the stops: the merged loop rests on them like the members' average does
    lo, hi = joint_limits(spec)
    assert (np.isclose(th_b, lo) | np.isclose(th_b, hi)).any()
    # the test can fail: one member alone runs elsewhere
    assert np.abs(rollout(members[0], theta, u)[0] - th_b).max() > 1e-4


def test_merge_of_one_member_is_that_member(spec, episodes):
    sur = make_surrogate(spec, episodes, mode="stateful", window=5, play=PLAY)
    one = merge([sur])
    assert one.name == sur.name and one.model_cfg == sur.model_cfg
    theta = np.stack([e.theta[:50] for e in episodes])
    u = np.stack([e.u[:50] for e in episodes])
    np.testing.assert_allclose(rollout(one, theta, u)[0], rollout(sur, theta, u)[0], atol=1e-5)


def test_merged_checkpoint_round_trips(spec, episodes, tmp_path: Path):
    ens = merge(_members(spec, episodes))
    back = load_checkpoint(save_checkpoint(tmp_path / "ens.pt", ens))
    assert n_member(back) == 3 and back.name == "lstm-ensemble-3"
    assert back.metrics["ensemble"]["hidden"] == [12, 7, 12]
    theta = np.stack([e.theta[:40] for e in episodes])
    u = np.stack([e.u[:40] for e in episodes])
    np.testing.assert_allclose(rollout(back, theta, u)[0], rollout(ens, theta, u)[0], atol=1e-6)


def test_merge_rejects_members_that_do_not_fit(spec, episodes):
    a = make_surrogate(spec, episodes, mode="stateful", play=PLAY)
    for other, what in (
        (make_surrogate(spec, episodes, mode="stateful", play=(0.1,)), "play widths"),
        (make_surrogate(spec, episodes, mode="windowed", play=PLAY), "rollout mode"),
        (make_surrogate(spec, episodes, mode="stateful", play=PLAY, window=4), "window"),
        (make_surrogate(spec, episodes, mode="stateful", cell="gru", play=PLAY), "cell"),
    ):
        with pytest.raises(ConfigError, match=f"member 1 .* {what}"):
            merge([a, other])
    with pytest.raises(ConfigError, match="at least one"):
        merge([])


def _tiny_ensemble_config(**overrides):
    return tiny_train_config(epochs=2, seq_batch=4, play=PLAY, members=2, **overrides)


@pytest.mark.parametrize("workers", [1, 2], ids=["sequential", "parallel"])
def test_training_a_seed_ensemble(tmp_path: Path, workers: int):
    ds = tiny_dataset(2, n_train=2, n_step=120)
    cfg = _tiny_ensemble_config(member_workers=workers, seed=3)
    best = train(cfg, ds, out=tmp_path, show_progress=False)
    ens = load_checkpoint(best)
    assert n_member(ens) == 2 and ens.model_cfg.hidden == 2 * cfg.hidden
    assert [m["seed"] for m in ens.metrics["ensemble"]["members"]] == [3, 4]
    members = [load_checkpoint(tmp_path / f"member_{i}" / "best.pt") for i in range(2)]
    assert [m.train_config["seed"] for m in members] == [3, 4]
    assert [m.train_config["members"] for m in members] == [1, 1]
    # best.pt is exactly the merge of the members' best checkpoints, scored on validation
    ep = ds.test[0]
    np.testing.assert_allclose(
        rollout(ens, ep.theta[None], ep.u[None])[0],
        rollout(merge(members), ep.theta[None], ep.u[None])[0],
        atol=1e-6,
    )
    assert ens.metrics["val_error"] == pytest.approx(free_run_error(ens, ds.val)["val_error"])
    rows = list(csv.DictReader(open(tmp_path / "log.csv")))
    assert [r["member"] for r in rows] == ["0", "1", "ensemble"]
    assert (tmp_path / "config.toml").read_text().count("members = 2") == 1


def test_member_configs_and_unsupported_combinations(tmp_path: Path):
    cfg = _tiny_ensemble_config(seed=5)
    assert [(c.seed, c.members) for c in member_configs(replace(cfg, members=3))] == [
        (5, 1),
        (6, 1),
        (7, 1),
    ]
    ds = tiny_dataset(2, n_train=2, n_step=120)
    with pytest.raises(ConfigError, match="resume"):
        train(cfg, ds, out=tmp_path, resume=tmp_path / "last.pt")
    with pytest.raises(ConfigError, match="members"):
        replace(cfg, members=0)


def test_cli_merge(spec, episodes, tmp_path: Path, capsys):
    paths = [
        save_checkpoint(tmp_path / f"m{i}.pt", s) for i, s in enumerate(_members(spec, episodes))
    ]
    out = tmp_path / "ens" / "best.pt"
    assert main(["merge", *map(str, paths), "--out", str(out)]) == 0
    ens = load_checkpoint(out)
    assert n_member(ens) == 3
    assert "3 members (3 checkpoints)" in capsys.readouterr().out
    # one checkpoint is no merge (it is already a model): refused, nothing written
    assert main(["merge", str(paths[0]), "--out", str(tmp_path / "one.pt")]) == 2
    assert "needs at least 2 checkpoints" in capsys.readouterr().err
    assert not (tmp_path / "one.pt").exists()
    # a merge of merges counts the members it averages
    again = tmp_path / "ens2.pt"
    assert main(["merge", str(out), str(paths[0]), "--out", str(again)]) == 0
    assert f"{n_member(load_checkpoint(again))} members (2 checkpoints)" in capsys.readouterr().out
    # a member that does not fit: one line, non-zero exit, nothing written
    odd = save_checkpoint(tmp_path / "odd.pt", make_surrogate(spec, episodes, mode="windowed"))
    out2 = tmp_path / "bad.pt"
    assert main(["merge", str(paths[0]), str(odd), "--out", str(out2)]) != 0
    err = capsys.readouterr().err
    assert f"{odd} differs from {paths[0]}" in err and len(err.strip().splitlines()) == 1
    assert not out2.exists()
    torch.save({"x": 1}, tmp_path / "junk.pt")
    assert main(["merge", str(paths[0]), str(tmp_path / "junk.pt"), "--out", str(out2)]) != 0
    assert "junk.pt" in capsys.readouterr().err and not out2.exists()
