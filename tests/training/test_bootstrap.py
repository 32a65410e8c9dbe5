"""Bagging: each network draws its batches from its own bootstrap resample of the episodes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.config import from_dict, to_dict
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.training.batches import bootstrap_counts, make_data
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.ensembles import member_configs
from excavator_surrogate.training.modes import make_mode
from tests.helpers.surrogates import make_surrogate

STATEFUL = dict(mode="stateful", seq_len=20, burn_in=5, tbptt=5, seq_batch=4)
WINDOWED = dict(mode="windowed", window=8, horizon=3, batch_size=16)


def _batches(spec, episodes, epoch: int = 0, **kw) -> list[list[int]]:
    cfg = TrainConfig(**kw)
    sur = make_surrogate(spec, episodes, mode=cfg.mode)
    data = make_data(episodes, sur.norm, torch.device("cpu"))
    mode = make_mode(cfg, data, sur)
    return [b.tolist() for b in mode.batches(np.random.default_rng([cfg.seed, epoch]), 1)]


def _drawn(spec, episodes, **kw) -> list[int]:
    """Every sample index of epoch 0's batches, in order."""
    return [i for b in _batches(spec, episodes, **kw) for i in b]


def _episode_of(index: list[int], lengths: list[int]) -> np.ndarray:
    return np.searchsorted(np.cumsum(lengths), np.asarray(index), side="right")


def test_counts_are_a_resample_reproducible_and_differ_between_members() -> None:
    n = 40
    draws = [bootstrap_counts(n, seed) for seed in range(4)]
    for c in draws:
        assert c.shape == (n,) and c.sum() == n and (c >= 0).all()
        assert (c == 0).any() and (c >= 2).any()  # a resample, not a permutation
    # 4 draws of 40: P(two equal) is negligible; the members' seeds are seed + i
    seeds = [c.seed for c in member_configs(TrainConfig(members=4, bootstrap=True, seed=7))]
    assert seeds == [7, 8, 9, 10]
    member_draws = [bootstrap_counts(n, s) for s in seeds]
    for i in range(4):
        for k in range(i + 1, 4):
            assert not np.array_equal(member_draws[i], member_draws[k])
    for seed, c in enumerate(draws):
        np.testing.assert_array_equal(bootstrap_counts(n, seed), c)


# The batches before bagging existed (recorded from the code of commit aa5c926), fixture
# episodes of 80, 64 and 71 samples: bootstrap = false must leave them as they were.
BEFORE = {
    ("stateful", 0): [[106, 152, 45, 168], [90, 122, 29, 13], [184]],
    ("stateful", 1): [[175, 24, 110, 56], [40, 94, 8, 159], [191]],
    ("windowed", 0): [[200, 114, 87, 133, 169, 193, 176, 174, 7, 122]],
    ("windowed", 1): [[119, 9, 45, 90, 57, 41, 56, 170, 8, 18]],
}


@pytest.mark.parametrize("spec", [2], indirect=True)
@pytest.mark.parametrize("kw", [STATEFUL, {**WINDOWED, "epoch_samples": 10}], ids=["st", "win"])
def test_without_bootstrap_the_batches_are_as_before(spec, episodes, kw) -> None:
    assert [e.n_step for e in episodes] == [80, 64, 71]
    for epoch in (0, 1):
        assert _batches(spec, episodes, epoch, **kw) == BEFORE[(kw["mode"], epoch)]


@pytest.mark.parametrize("spec", [2], indirect=True)
@pytest.mark.parametrize("kw", [STATEFUL, WINDOWED], ids=["st", "win"])
def test_bootstrap_draws_from_the_resampled_episodes(spec, episodes, kw) -> None:
    """Each episode's samples appear as often as its count says; a left-out episode never;
    the same seed gives the same batches, another seed other ones."""
    lengths = [e.n_step for e in episodes]
    plain = _drawn(spec, episodes, **kw)
    per_plain = np.bincount(_episode_of(plain, lengths), minlength=3)
    seen = set()
    for seed in range(6):
        counts = bootstrap_counts(3, seed)
        got = _drawn(spec, episodes, seed=seed, bootstrap=True, **kw)
        per = np.bincount(_episode_of(got, lengths), minlength=3)
        if kw["mode"] == "windowed":  # every window end of a drawn episode, counts times
            np.testing.assert_array_equal(per, counts * per_plain)
        else:  # a sub-sequence tiling per copy (its offset may drop one start)
            assert ((per == 0) == (counts == 0)).all()
            assert (per >= counts * (per_plain - 1)).all() and (
                per <= counts * (per_plain + 1)
            ).all()
        assert got == _drawn(spec, episodes, seed=seed, bootstrap=True, **kw)
        seen.add(tuple(counts))
    assert len(seen) > 1  # the seeds drew different resamples


def test_bootstrap_is_a_checked_and_recorded_bool() -> None:
    with pytest.raises(ConfigError, match="bootstrap"):
        replace(TrainConfig(), bootstrap="yes")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="bootstrap"):
        from_dict(TrainConfig, {"bootstrap": "yes"}, where="[train]")
    cfg = TrainConfig(members=2, bootstrap=True)
    assert to_dict(cfg)["bootstrap"] is True  # what config.toml records
    assert from_dict(TrainConfig, to_dict(cfg)) == cfg
    assert all(c.bootstrap for c in member_configs(cfg))
